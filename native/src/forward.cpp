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
// Along a path (flat configuration spaces), the first trial of a warm call also adds the
// second-order part of the previous call's first step, scaled to this step when the two are nearly
// parallel: the motion between samples changes slowly, and the start then lies O(δy³) instead of
// O(δy²) off the closures (on planar_4rrr's S-curve: 2.1 kinematics evaluations instead of 2.6).
// Per call nothing is allocated here: the readings and the iterate live in the solver's workspace
// (sized by set_drives), and the answer is written into the caller's buffer.
#include <Eigen/QR>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <nanobind/eigen/dense.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/vector.h>
#include <stdexcept>

#include "eigen_types.hpp"
#include "model_update.hpp"

namespace pgpc {
namespace {
constexpr double MAX_DRIVE_STEP = 0.1;  // forward.MAX_DRIVE_STEP (rad or m)
constexpr int HALVINGS = 30;            // forward._HALVINGS
constexpr double LSTSQ_RCOND = 1e-12;   // np.linalg.lstsq(..., rcond=1e-12) in solve_forward
constexpr double QR_RCOND = 1e-6;       // |R_ii| ratio above which the QR step is taken (no rank question)
constexpr double STOP_COUNTS = 1e-4;    // forward.STOP_COUNTS: converged when no drive would move more (counts)

// what ModelUpdate.solve_forward_into found (forward.SOLVED, forward.INCONSISTENT in Python)
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
    has_curvature = false;
    readings_.resize(m.n_u);
    sigma_.resize(m.n_u);
    inv_sigma_.resize(m.n_u);
    q_guess_.resize(m.kin.model.nq);
  }

  // the answer's length: [pose (n_y), q (nq), J (n_u × n_y, row by row), residual (n_u)]
  Index answer_size() const { return m.n_y + m.kin.model.nq + m.n_u * m.n_y + m.n_u; }

  // the inputs into the workspace: false where a shape is not (n_u,), (n_u,), (nq,) (Python decides)
  bool load(const double *r, size_t nr, const double *sigma, size_t ns, const double *qg, size_t nq) {
    if (nr != static_cast<size_t>(m.n_u) || ns != static_cast<size_t>(m.n_u) ||
        nq != static_cast<size_t>(m.kin.model.nq))
      return false;
    readings_ = Eigen::Map<const Vec>(r, m.n_u);
    sigma_ = Eigen::Map<const Vec>(sigma, m.n_u);
    q_guess_ = Eigen::Map<const Vec>(qg, m.kin.model.nq);
    return true;
  }

  // the solution (pose_, q_, J_, e_) into out (answer_size() doubles)
  void write(double *out) const {
    Eigen::Map<Vec>(out, m.n_y) = pose_;
    out += m.n_y;
    Eigen::Map<Vec>(out, q_.size()) = q_;
    out += q_.size();
    Eigen::Map<RowMat>(out, m.n_u, m.n_y) = J_;
    out += m.n_u * m.n_y;
    Eigen::Map<Vec>(out, m.n_u) = e_;
  }

  // check_readings' value tests and the finiteness of σ and q_guess: false = the reference decides
  bool inputs_ok() const {
    if (!q_guess_.allFinite()) return false;
    for (Index i = 0; i < m.n_u; ++i) {
      const double r = readings_[i], sigma = sigma_[i];
      if (!(std::isfinite(sigma) && sigma > 0) || !std::isfinite(r)) return false;
      if (r < lo[i] - 2 * sigma || r > hi[i] + 2 * sigma) return false;
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
  // model update's q_, T_, pinv_ are scratch); its residual and drive Jacobian are the caller's
  void take() {
    q_.swap(m.q_);
    T_.swap(m.T_);
    P_.swap(m.pinv_);
  }

  // Σ (e_i/σ_i)² of a residual e
  double cost_of(const Vec &e) const { return e.cwiseProduct(inv_sigma_).squaredNorm(); }

  // e = q_drive − readings, J = T[drives]
  void drive_state(const Vec &q, const Mat &T, Vec &e, Mat &J) const {
    e.resize(m.n_u);
    J.resize(m.n_u, m.n_y);
    for (Index i = 0; i < m.n_u; ++i) {
      e[i] = q[drive_q[i]] - readings_[i];
      J.row(i) = T.row(m.cfg.drive_idx[i]);
    }
  }

  // the weighted least-squares step −(W J)⁺ W e, W = diag(1/σ), as np.linalg.lstsq(rcond=1e-12)
  void gauss_newton_step() {
    Jw_.noalias() = inv_sigma_.asDiagonal() * J_;
    ew_ = e_.cwiseProduct(inv_sigma_);
    if (Jw_.rows() >= Jw_.cols()) {
      qr_.compute(Jw_);
      const auto d = qr_.matrixQR().diagonal().cwiseAbs();
      if (d.minCoeff() > QR_RCOND * d.maxCoeff()) {  // full column rank, far from the cut: unique LS step
        step_.noalias() = qr_.solve(ew_);
        step_ = -step_;
        return;
      }
    }
    Eigen::JacobiSVD<Mat> svd(Jw_, Eigen::ComputeThinU | Eigen::ComputeThinV);
    svd.setThreshold(LSTSQ_RCOND);
    step_ = -svd.solve(ew_);
  }

  // the start of the first trial of a warm call (start_ = q ⊕ T δy, δy = step_): plus the
  // previous call's second-order part c of δy_c, scaled as (s = δy·δy_c / |δy_c|²)² where δy is
  // within 10 % of s δy_c (the quadratic term of the closures along a nearly unchanged direction)
  void curved_start() {
    if (!has_curvature) return;
    const double norm2 = curvature_dy_.squaredNorm();
    if (!(norm2 > 0)) return;
    const double s = step_.dot(curvature_dy_) / norm2;
    if (!((step_ - s * curvature_dy_).squaredNorm() <= 0.01 * step_.squaredNorm())) return;
    start_ += (s * s) * curvature_;
  }

  // solve_forward on the loaded inputs: the status; the solution in pose_, q_, J_, e_ (SOLVED,
  // INCONSISTENT) and the iterations taken in it
  Status solve(long max_iter, double max_residual, long &it) {
    it = 0;
    if (!inputs_ok()) return REFERENCE;
    inv_sigma_ = sigma_.cwiseInverse();
    // warm at the last solution (pose_, q_, T_, P_ are still its): its pose, T and K⁺ are known
    const bool warm = has_last && q_guess_ == q_;
    if (!warm) {
      // the start pose: the output of q_guess (robot.platform_pose), in trial_ until it assembles
      trial_.resize(m.n_y);
      if (m.kin.task) {
        m.kin.eval(q_guess_);
        trial_ = m.kin.res_.tail(m.n_y);
      } else {
        for (Index i = 0; i < m.n_y; ++i) trial_[i] = q_guess_[m.cfg.y_q[i]];
      }
      if (!assembled(trial_, q_guess_, nullptr, q_guess_, false)) return REFERENCE;  // unusual: Python takes it
      pose_.swap(trial_);
      take();
    }
    drive_state(q_, T_, e_, J_);
    double cost = cost_of(e_);
    for (it = 1; it <= max_iter; ++it) {
      gauss_newton_step();
      predicted_.noalias() = J_ * step_;
      if (!(predicted_.cwiseProduct(inv_sigma_).cwiseAbs().maxCoeff() > STOP_COUNTS)) break;
      double lam = std::min(1.0, MAX_DRIVE_STEP / std::max(predicted_.cwiseAbs().maxCoeff(), 1e-300));
      bool found = false;
      double cost_new = 0.0;
      Tstep_.noalias() = T_ * step_;  // first-order prediction of q(trial): q ⊕ T (λ step)
      for (int h = 0; h < HALVINGS; ++h) {
        trial_ = pose_ + lam * step_;
        dq_ = lam * Tstep_;
        const bool first = warm && it == 1 && h == 0 && m.kin.flat;  // the step between two samples
        if (m.kin.flat) {
          start_ = q_ + dq_;
          if (first) curved_start();
        } else {
          start_ = m.kin.integrate(q_, dq_);
        }
        if (assembled(trial_, start_, &P_, q_, true)) {
          if (first) {  // its second-order part: the assembled q minus the first-order prediction
            curvature_ = m.q_ - q_ - dq_;
            curvature_dy_ = lam * step_;
            has_curvature = true;
          }
          drive_state(m.q_, m.T_, e_new_, J_new_);
          cost_new = cost_of(e_new_);
          if (cost_new <= cost * (1 + 1e-12) + 1e-18) {
            found = true;
            break;
          }
        }
        lam *= 0.5;
      }
      if (!found) break;  // no step lowers the cost: a (local) minimum of the residual
      const double improvement = cost - cost_new;
      pose_.swap(trial_);  // the accepted trial, its residual and drive Jacobian as the iterate
      take();
      e_.swap(e_new_);
      J_.swap(J_new_);
      cost = cost_new;
      if (improvement <= 1e-14 * std::max(cost, 1.0) && lam < 1.0) break;
    }
    it = std::min(it, max_iter);
    has_last = true;
    const double worst = e_.cwiseProduct(inv_sigma_).cwiseAbs().maxCoeff();
    return worst <= max_residual ? SOLVED : INCONSISTENT;
  }

  ModelUpdate &m;
  std::vector<long> drive_q;
  Vec lo, hi;
  bool has_last = false;  // pose_, q_, T_, P_ hold the last solution, the start of a call warm-started at q_
  bool has_curvature = false;  // the second-order part of the last warm call's first step (flat q)
  Vec curvature_, curvature_dy_;

 private:
  Vec readings_, sigma_, inv_sigma_, q_guess_;  // the inputs of the call
  Vec pose_, q_, e_;                            // the current iterate: pose, q, residual
  Mat T_, P_, J_;                               // its T, K⁺ and drive Jacobian
  Mat Jw_, J_new_;                              // workspaces
  Vec ew_, step_, predicted_, Tstep_, trial_, dq_, start_, e_new_;
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
          "solve_forward_into",
          [](ModelUpdate &self, Floats readings, Floats resolution, Floats q_guess, long max_iter,
             double max_residual, Out1 out) {
            if (!self.forward_) throw std::invalid_argument("solve_forward_into: call set_drives first");
            ForwardSolver &fk = *self.forward_;
            if (static_cast<Index>(out.shape(0)) != fk.answer_size())
              throw std::invalid_argument("solve_forward_into: out must have n_y + nq + n_u n_y + n_u entries");
            long it = 0;
            Status status = REFERENCE;
            if (readings.ndim() == 1 && resolution.ndim() == 1 && q_guess.ndim() == 1 &&
                fk.load(readings.data(), readings.shape(0), resolution.data(), resolution.shape(0), q_guess.data(),
                        q_guess.shape(0))) {
              status = fk.solve(max_iter, max_residual, it);
              if (status != REFERENCE) fk.write(out.data());
            }
            return std::make_pair(static_cast<long>(status), it);
          },
          nb::arg("readings"), nb::arg("resolution"), nb::arg("q_guess"), nb::arg("max_iter"),
          nb::arg("max_residual"), nb::arg("out"),
          "(status, iterations) of forward kinematics from drive readings (forward.solve_forward), the "
          "solution written into out = [pose (n_y), q (nq), J (n_u × n_y, row by row), residual (n_u)]: "
          "status 0 solved, 2 no pose explains the readings within max_residual counts (out = the best "
          "pose), 1 take the Python reference path (a shape, reading, resolution or start its checks must "
          "judge; out untouched)");
}
}  // namespace pgpc
