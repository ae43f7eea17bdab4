// Forward kinematics from drive readings: the C++ twin of model/forward.py (check_readings, the
// Gauss-Newton loop of solve_forward and _assembled, the residual test). The Python module is the
// reference and owns every message: a reading, resolution or start that the checks here refuse,
// and a start that does not assemble by the warm Newton, are handed back (a status) and the Python
// path redoes the call, raising the package's error; readings that no pose explains come back with
// the best pose, from which Python builds the SensorError naming the suspect drive.
//
// Faster than the Python loop, not different: the solution of the last call is kept, so a call
// warm-started at its configuration (the estimator's case) skips the start's assembly; a trial
// pose is assembled from the first-order prediction q ⊕ T δy (off the closures by O(δy²), not
// O(δy)) with the current K⁺ as the Newton preconditioner; the Gauss-Newton step is a Householder
// QR of the weighted drive Jacobian when the |R_ii| ratio shows it well conditioned (the unique
// least-squares step, as lstsq's), the SVD with lstsq's rcond otherwise (rank-deficient drives).
#include <Eigen/QR>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <nanobind/eigen/dense.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/vector.h>
#include <stdexcept>

#include "model_update.hpp"

namespace pgpc {
namespace {
constexpr double MAX_DRIVE_STEP = 0.1;  // forward.MAX_DRIVE_STEP (rad or m)
constexpr int HALVINGS = 30;            // forward._HALVINGS
constexpr double LSTSQ_RCOND = 1e-12;   // np.linalg.lstsq(..., rcond=1e-12) in solve_forward
constexpr double QR_RCOND = 1e-6;       // |R_ii| ratio above which the QR step is taken (no rank question)

// what ModelUpdate.solve_forward found (forward.FORWARD_STATUS in Python)
enum Status : long { SOLVED = 0, REFERENCE = 1, INCONSISTENT = 2 };

// a vector for the Python callback as a list of floats (an Eigen argument failed to convert there)
nb::list as_list(const Vec &v) {
  nb::list out;
  for (Index i = 0; i < v.size(); ++i) out.append(v[i]);
  return out;
}
}  // namespace

// Workspace and state of forward kinematics on one ModelUpdate (its q_, T_, pinv_ are scratch).
struct ForwardSolver {
  explicit ForwardSolver(ModelUpdate &m) : m(m) {}

  // drives: q indices, range [lo, hi] (rad or m) for the readings check
  void set_drives(std::vector<long> q_idx, const Vec &lower, const Vec &upper) {
    if (static_cast<long>(q_idx.size()) != m.n_u || lower.size() != m.n_u || upper.size() != m.n_u)
      throw std::invalid_argument("set_drives: n_u drive q indices and ranges expected");
    for (long i : q_idx)
      if (i < 0 || i >= m.kin.model.nq) throw std::invalid_argument("set_drives: a drive q index out of range");
    drive_q = std::move(q_idx);
    lo = lower;
    hi = upper;
    has_last = false;
  }

  // check_readings' value tests and the finiteness of σ and q_guess: false = the reference decides
  bool inputs_ok(const Vec &r, const Vec &sigma, const Vec &q_guess) const {
    if (!q_guess.allFinite()) return false;
    for (Index i = 0; i < m.n_u; ++i) {
      if (!(std::isfinite(sigma[i]) && sigma[i] > 0) || !std::isfinite(r[i])) return false;
      if (r[i] < lo[i] - 2 * sigma[i] || r[i] > hi[i] + 2 * sigma[i]) return false;
    }
    return true;
  }

  // forward._assembled at pose from the start q_start (preconditioned by pinv_hint) into m.q_, m.T_,
  // m.pinv_; validated: then the Python path from q_guess (handler.assembled) when the warm Newton fails
  bool assembled(const Vec &pose, const Vec &q_start, const Mat *pinv_hint, const Vec &q_guess, bool validated) {
    if (m.assemble_warm(pose, q_start, pinv_hint, false)) return true;
    if (!validated) return false;
    // forward.assemble_validated: robot.assemble from q_guess (None where the pose does not assemble
    // or is singular), then T here by the SVD rank test (a borderline K that Python accepted and
    // this test refuses counts as not assembled: the step is halved)
    nb::object out = m.handler_.attr("assembled")(as_list(pose), as_list(q_guess));
    if (out.is_none()) return false;
    Vec q = nb::cast<Vec>(out);
    m.kin.eval(q);
    if (!m.map_from(m.kin.jac_, true)) return false;
    m.q_ = std::move(q);
    return true;
  }

  // the assembled configuration m.q_ (its T, K⁺) as the current iterate, swapped in (no copy: the
  // model update's q_, T_, pinv_ are scratch); e = q_drive − readings, J = T[drives]
  double take(const Vec &readings, const Vec &inv_sigma, Vec &q, Mat &T, Mat &P, Vec &e, Mat &J) {
    q.swap(m.q_);
    T.swap(m.T_);
    P.swap(m.pinv_);
    drive_state(q, T, readings, inv_sigma, e, J);
    return e.cwiseProduct(inv_sigma).squaredNorm();
  }

  void drive_state(const Vec &q, const Mat &T, const Vec &readings, const Vec &inv_sigma, Vec &e, Mat &J) const {
    e.resize(m.n_u);
    J.resize(m.n_u, m.n_y);
    for (Index i = 0; i < m.n_u; ++i) {
      e[i] = q[drive_q[i]] - readings[i];
      J.row(i) = T.row(m.cfg.drive_idx[i]);
    }
  }

  // the weighted least-squares step −(W J)⁺ W e, W = diag(1/σ), as np.linalg.lstsq(rcond=1e-12)
  void gauss_newton_step(const Mat &J, const Vec &e, const Vec &inv_sigma, Vec &step) {
    Jw_.noalias() = inv_sigma.asDiagonal() * J;
    ew_ = e.cwiseProduct(inv_sigma);
    if (Jw_.rows() >= Jw_.cols()) {
      qr_.compute(Jw_);
      const auto d = qr_.matrixQR().diagonal().cwiseAbs();
      if (d.minCoeff() > QR_RCOND * d.maxCoeff()) {  // full column rank, far from the cut: unique LS step
        step = -qr_.solve(ew_);
        return;
      }
    }
    Eigen::JacobiSVD<Mat> svd(Jw_, Eigen::ComputeThinU | Eigen::ComputeThinV);
    svd.setThreshold(LSTSQ_RCOND);
    step = -svd.solve(ew_);
  }

  // solve_forward: the status, and in pose, q, J, e, it the solution (SOLVED, INCONSISTENT)
  Status solve(const Vec &readings, const Vec &sigma, const Vec &q_guess, long max_iter, double max_residual,
               Vec &pose, Vec &q, Mat &J, Vec &e, long &it) {
    if (!inputs_ok(readings, sigma, q_guess)) return REFERENCE;
    const Vec inv_sigma = sigma.cwiseInverse();
    if (has_last && q_guess == last_q) {  // warm at the last solution: its pose, T and K⁺ are known
      pose = last_pose;
      q = last_q;
      T_ = last_T;
      P_ = last_pinv;
      drive_state(q, T_, readings, inv_sigma, e, J);
    } else {
      // the start pose: the output of q_guess (robot.platform_pose)
      pose.resize(m.n_y);
      if (m.kin.task) {
        m.kin.eval(q_guess);
        pose = m.kin.res_.tail(m.n_y);
      } else {
        for (Index i = 0; i < m.n_y; ++i) pose[i] = q_guess[m.cfg.y_q[i]];
      }
      if (!assembled(pose, q_guess, nullptr, q_guess, false)) return REFERENCE;  // unusual: Python takes it
      take(readings, inv_sigma, q, T_, P_, e, J);
    }
    double cost = e.cwiseProduct(inv_sigma).squaredNorm();
    for (it = 1; it <= max_iter; ++it) {
      gauss_newton_step(J, e, inv_sigma, step_);
      predicted_.noalias() = J * step_;
      if (!(predicted_.cwiseProduct(inv_sigma).cwiseAbs().maxCoeff() > 1e-6)) break;  // a millionth of a count
      double lam = std::min(1.0, MAX_DRIVE_STEP / std::max(predicted_.cwiseAbs().maxCoeff(), 1e-300));
      bool found = false;
      double cost_new = 0.0;
      for (int h = 0; h < HALVINGS; ++h) {
        trial_ = pose + lam * step_;
        start_ = m.kin.integrate(q, T_ * (lam * step_));  // first-order prediction of q(trial)
        if (assembled(trial_, start_, &P_, q, true)) {
          drive_state(m.q_, m.T_, readings, inv_sigma, e_new_, J_new_);
          cost_new = e_new_.cwiseProduct(inv_sigma).squaredNorm();
          if (cost_new <= cost * (1 + 1e-12) + 1e-18) {
            found = true;
            break;
          }
        }
        lam *= 0.5;
      }
      if (!found) break;  // no step lowers the cost: a (local) minimum of the residual
      const double improvement = cost - cost_new;
      pose = trial_;
      cost = take(readings, inv_sigma, q, T_, P_, e, J);
      if (improvement <= 1e-14 * std::max(cost, 1.0) && lam < 1.0) break;
    }
    it = std::min(it, max_iter);
    has_last = true;
    last_q = q;
    last_pose = pose;
    last_T = T_;
    last_pinv = P_;
    const double worst = e.cwiseProduct(inv_sigma).cwiseAbs().maxCoeff();
    return worst <= max_residual ? SOLVED : INCONSISTENT;
  }

  ModelUpdate &m;
  std::vector<long> drive_q;
  Vec lo, hi;
  bool has_last = false;  // the last solution, the start of a call warm-started at last_q
  Vec last_q, last_pose;
  Mat last_T, last_pinv;

 private:
  Mat T_, P_, Jw_, J_new_;  // T and K⁺ of the current iterate; workspaces
  Vec ew_, step_, predicted_, trial_, start_, e_new_;
  Eigen::HouseholderQR<Mat> qr_;
};

void bind_forward(nb::class_<ModelUpdate> &cls) {
  cls.def(
         "set_drives",
         [](ModelUpdate &self, std::vector<long> drive_q, const Vec &lower, const Vec &upper) {
           if (!self.forward_) self.forward_ = std::make_shared<ForwardSolver>(self);
           self.forward_->set_drives(std::move(drive_q), lower, upper);
         },
         nb::arg("drive_q"), nb::arg("lower"), nb::arg("upper"),
         "the drives' q indices and position ranges (rad or m): forward kinematics on this object")
      .def(
          "solve_forward",
          [](ModelUpdate &self, const Vec &readings, const Vec &resolution, const Vec &q_guess, long max_iter,
             double max_residual) -> nb::object {
            if (!self.forward_) throw std::invalid_argument("solve_forward: call set_drives first");
            if (readings.size() != self.n_u || resolution.size() != self.n_u || q_guess.size() != self.kin.model.nq)
              throw std::invalid_argument("solve_forward: readings and resolution must be (n_u,), q_guess (nq,)");
            Vec pose, q, e;
            Mat J;
            long it = 0;
            const Status status =
                self.forward_->solve(readings, resolution, q_guess, max_iter, max_residual, pose, q, J, e, it);
            if (status == REFERENCE) return nb::make_tuple(static_cast<long>(status), nb::none(), 0);
            // one array [pose, q, J row by row, e] (Python slices it): one conversion instead of four
            const size_t n = static_cast<size_t>(pose.size() + q.size() + J.size() + e.size());
            double *buf = new double[n];
            nb::capsule owner(buf, [](void *p) noexcept { delete[] static_cast<double *>(p); });
            Eigen::Map<Vec>(buf, pose.size()) = pose;
            Eigen::Map<Vec>(buf + pose.size(), q.size()) = q;
            Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(
                buf + pose.size() + q.size(), J.rows(), J.cols()) = J;
            Eigen::Map<Vec>(buf + pose.size() + q.size() + J.size(), e.size()) = e;
            const size_t shape[1] = {n};
            return nb::make_tuple(static_cast<long>(status), nb::ndarray<nb::numpy, double>(buf, 1, shape, owner), it);
          },
          nb::arg("readings"), nb::arg("resolution"), nb::arg("q_guess"), nb::arg("max_iter"),
          nb::arg("max_residual"),
          "(status, solution, iterations) of forward kinematics from drive readings (forward.solve_forward): "
          "status 0 solved, 2 no pose explains the readings within max_residual counts (solution = the best "
          "pose), 1 take the Python reference path (a reading, resolution or start its checks must judge; "
          "solution None); solution = [pose (n_y), q (nq), J (n_u × n_y, row by row), residual (n_u)]");
}
}  // namespace pgpc
