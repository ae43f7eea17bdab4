// Forward kinematics from drive readings: the C++ twin of the Gauss-Newton loop of
// model/forward.py (solve_forward, _assembled). The Python module is the reference; the residual
// check and the SensorError naming the suspect drive stay there (they run once per call on the
// result). A start that does not assemble by the warm Newton is handed back whole (forward returns
// -1); a trial pose that does not is tried on the validated Python path (handler.assembled), as
// forward._assembled does.
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>

#include "model_update.hpp"

namespace pgpc {
namespace {
constexpr double MAX_DRIVE_STEP = 0.1;  // forward.MAX_DRIVE_STEP (rad or m)
constexpr int HALVINGS = 30;            // forward._HALVINGS
constexpr double LSTSQ_RCOND = 1e-12;   // np.linalg.lstsq(..., rcond=1e-12) in solve_forward

// a vector for the Python callback as a list of floats (an Eigen argument failed to convert there)
nb::list as_list(const Vec &v) {
  nb::list out;
  for (Index i = 0; i < v.size(); ++i) out.append(v[i]);
  return out;
}
}  // namespace

bool ModelUpdate::assembled(const Vec &pose, const Vec &q_guess, bool validated) {
  if (assemble_warm(pose, q_guess, nullptr, false)) return true;
  if (!validated) return false;
  // forward.assemble_validated: robot.assemble from q_guess (None where the pose does not assemble
  // or is singular), then T here by the SVD rank test as in fallback (a borderline K that Python
  // accepted and this test refuses counts as not assembled: the step is halved)
  nb::object out = handler_.attr("assembled")(as_list(pose), as_list(q_guess));
  if (out.is_none()) return false;
  Vec q = nb::cast<Vec>(out);
  kin.eval(q);
  if (!map_from(kin.jac_, true)) return false;
  q_ = std::move(q);
  return true;
}

void ModelUpdate::drive_state(const Vec &readings, const Vec &sigma, Vec &e, Mat &J, double &cost) const {
  e.resize(n_u);
  J.resize(n_u, n_y);
  for (Index i = 0; i < n_u; ++i) {
    e[i] = q_[drive_q[i]] - readings[i];
    J.row(i) = T_.row(cfg.drive_idx[i]);
  }
  cost = e.cwiseQuotient(sigma).squaredNorm();
}

long ModelUpdate::forward(const Vec &readings, const Vec &sigma, const Vec &q_guess, long max_iter, Vec &pose, Vec &q,
                          Mat &J, Vec &e) {
  // the start pose: the output of q_guess (robot.platform_pose)
  pose.resize(n_y);
  if (kin.task) {
    kin.eval(q_guess);
    pose = kin.res_.tail(n_y);
  } else {
    for (Index i = 0; i < n_y; ++i) pose[i] = q_guess[cfg.y_q[i]];
  }
  if (!assembled(pose, q_guess, false)) return -1;  // unusual: the Python reference takes it
  q = q_;
  double cost;
  drive_state(readings, sigma, e, J, cost);
  const Vec inv_sigma = sigma.cwiseInverse();
  Vec trial, e_new, step, predicted;
  Mat J_new;
  long it = 0;
  for (it = 1; it <= max_iter; ++it) {
    const Mat Jw = inv_sigma.asDiagonal() * J;
    Eigen::JacobiSVD<Mat> svd(Jw, Eigen::ComputeThinU | Eigen::ComputeThinV);
    svd.setThreshold(LSTSQ_RCOND);
    step = -svd.solve(e.cwiseProduct(inv_sigma));
    predicted.noalias() = J * step;
    if (!(predicted.cwiseProduct(inv_sigma).cwiseAbs().maxCoeff() > 1e-6)) break;  // a millionth of a count
    double lam = std::min(1.0, MAX_DRIVE_STEP / std::max(predicted.cwiseAbs().maxCoeff(), 1e-300));
    bool found = false;
    double cost_new = 0.0;
    for (int h = 0; h < HALVINGS; ++h) {
      trial = pose + lam * step;
      if (assembled(trial, q, true)) {
        drive_state(readings, sigma, e_new, J_new, cost_new);
        if (cost_new <= cost * (1 + 1e-12) + 1e-18) {
          found = true;
          break;
        }
      }
      lam *= 0.5;
    }
    if (!found) break;  // no step lowers the cost: a (local) minimum of the residual
    const double improvement = cost - cost_new;
    pose = trial;
    q = q_;
    e = e_new;
    J = J_new;
    cost = cost_new;
    if (improvement <= 1e-14 * std::max(cost, 1.0) && lam < 1.0) break;
  }
  return std::min(it, max_iter);
}
}  // namespace pgpc
