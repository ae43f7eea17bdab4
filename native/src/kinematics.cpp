// Assembly rows Ψ = [Φ; h − y], their Jacobian and Jacobian rate: the C++ twin of
// model/closures.py (ClosureMixin._eval, closure_jacobian_derivative), model/outputs.py
// (TaskOutput.value/jacobian/jacobian_derivative, hlog3) and model/universal.py.
#include <cmath>
#include <stdexcept>
#include <string>

#include "eigen_types.hpp"
#include "model_update.hpp"
#include "pinocchio/algorithm/frames.hpp"
#include "pinocchio/algorithm/jacobian.hpp"
#include "pinocchio/algorithm/joint-configuration.hpp"
#include "pinocchio/algorithm/kinematics.hpp"
#include "pinocchio/algorithm/rnea.hpp"
#include "pinocchio/spatial.hpp"

namespace pgpc {
namespace {
constexpr auto LWA = pinocchio::LOCAL_WORLD_ALIGNED;
// outputs._HLOG3_SERIES_BELOW: below this angle (rad) d/dt Jlog3 comes from its series
constexpr double HLOG3_SERIES_BELOW = 0.05;

Eigen::Matrix3d skew(const Eigen::Vector3d &w) {
  Eigen::Matrix3d S;
  S << 0.0, -w[2], w[1], w[2], 0.0, -w[0], -w[1], w[0], 0.0;
  return S;
}

// outputs.hlog3: d/dt Jlog3(R) for the angular velocity w (series near the identity)
Eigen::Matrix3d hlog3(const Eigen::Matrix3d &R, const Eigen::Vector3d &w) {
  double t;
  const Eigen::Vector3d theta = pinocchio::log3(R, t);
  Eigen::Matrix3d out;
  if (theta.dot(theta) >= HLOG3_SERIES_BELOW * HLOG3_SERIES_BELOW) {
    pinocchio::Hlog3(t, theta, w, out);
    return out;
  }
  Eigen::Matrix3d Jl;
  pinocchio::Jlog3(R, Jl);
  const Eigen::Matrix3d S = skew(theta), Sd = skew(Jl * w);
  const Eigen::Matrix3d S2 = S * S;
  const Eigen::Matrix3d d4 = Sd * S2 * S + S * Sd * S2 + S2 * Sd * S + S2 * S * Sd;
  return 0.5 * Sd + (Sd * S + S * Sd) / 12.0 - d4 / 720.0;
}
}  // namespace

Kinematics::Kinematics(pinocchio::Model model_, const RobotConfig &cfg_)
    : model(std::move(model_)), data(model), data_u(model), cfg(cfg_) {
  flat = model.nq == model.nv;
  mimic = model.nvExtended != model.nv;
  task = cfg.task_frame >= 0;
  task_rotation = false;
  for (long r : cfg.task_rows) task_rotation |= r >= 3;
  n_c = static_cast<long>(cfg.jac_rows.size());
  rows = n_c + (task ? cfg.n_y : 0);
  res_.resize(rows);
  jac_.resize(rows, model.nv);
  const size_t nc = cfg.closure_frames.size();
  Ja_.assign(nc, Mat6x::Zero(6, model.nv));
  Jb_ = Ja_;
  Jt_.setZero(6, model.nv);
  dJt_.setZero(6, model.nv);
  for (const auto &ab : cfg.closure_frames) frames_.insert(frames_.end(), ab.begin(), ab.end());
  if (task) frames_.push_back(cfg.task_frame);
  for (long f : frames_)
    if (f < 0 || f >= static_cast<long>(model.nframes))
      throw std::invalid_argument("ModelUpdate: frame index " + std::to_string(f) + " is not in the model");
  uni_cols_.assign(model.nframes, {});
  for (long f = 0; f < static_cast<long>(model.nframes); ++f) {  // UniversalJoints._frame_columns
    const auto &supports = model.supports[model.frames[f].parentJoint];
    for (const auto &jv : cfg.universal)
      for (auto jid : supports)
        if (static_cast<long>(jid) == jv[0]) uni_cols_[f].push_back(jv[1]);
  }
}

void Kinematics::place_frames() {
  // what updateFramePlacements does, for the closure and output frames only
  for (long f : frames_) {
    const auto &frame = model.frames[f];
    data.oMf[f] = data.oMi[frame.parentJoint] * frame.placement;
  }
}

Vec Kinematics::integrate(const Vec &q, const Vec &dv) const {
  if (flat) return q + dv;
  Vec out(model.nq);
  pinocchio::integrate(model, q, dv, out);
  return out;
}

void Kinematics::eval(const Vec &q) {
  pinocchio::computeJointJacobians(model, data, q);
  eval_placed();
}

void Kinematics::closure_rows() {
  // stage15 (issue 25): row r % 6 of frame a's LOCAL_WORLD_ALIGNED Jacobian minus frame b's, straight from
  // the world joint Jacobian over each frame's supporting columns: getFrameJacobian's arithmetic
  // (v − p × ω, ω) and the same difference (0 + a − b), without the two 6 × nv matrices per closure; each
  // translated column once for all the closure's rows (jac_rows lists a closure's rows together, in order)
  jac_.topRows(n_c).setZero();
  long begin = 0;
  for (size_t k = 0; k < cfg.closure_frames.size(); ++k) {
    long end = begin;
    while (end < n_c && cfg.jac_rows[end] / 6 == static_cast<long>(k)) ++end;
    for (int side = 0; side < 2; ++side) {
      const long f = cfg.closure_frames[k][side];
      const Eigen::Vector3d p = data.oMf[f].translation();
      const auto &joint = model.joints[model.frames[f].parentJoint];
      for (Eigen::Index j = joint.idx_v() + joint.nv() - 1; j >= 0; j = data.parents_fromRow[j]) {
        const auto col = data.J.col(j);
        Vec6 e;
        e.tail<3>() = col.tail<3>();
        e.head<3>() = col.head<3>() - p.cross(Eigen::Vector3d(e.tail<3>()));
        for (long i = begin; i < end; ++i) {
          if (side == 0)
            jac_(i, j) += e[cfg.jac_rows[i] % 6];
          else
            jac_(i, j) -= e[cfg.jac_rows[i] % 6];
        }
      }
    }
    begin = end;
  }
  if (begin != n_c) throw std::logic_error("Kinematics: the kept closure rows are not grouped by closure");
}

void Kinematics::eval_placed() {
  place_frames();
  long row = 0;
  for (size_t k = 0; k < cfg.closure_frames.size(); ++k) {
    const auto &oMa = data.oMf[cfg.closure_frames[k][0]];
    const auto &oMb = data.oMf[cfg.closure_frames[k][1]];
    res_.segment<3>(row) = oMa.translation() - oMb.translation();
    row += 3;
    if (row < n_c && cfg.jac_rows[row] / 6 == static_cast<long>(k)) {  // a weld: 3 more rows
      const Eigen::Matrix3d Rab = oMa.rotation().transpose() * oMb.rotation();
      res_.segment<3>(row) = (oMa.rotation() * pinocchio::log3(Rab)) * -1.0;
      row += 3;
    }
    if (mimic) {
      Ja_[k].setZero();
      Jb_[k].setZero();
      pinocchio::getFrameJacobian(model, data, cfg.closure_frames[k][0], LWA, Ja_[k]);
      pinocchio::getFrameJacobian(model, data, cfg.closure_frames[k][1], LWA, Jb_[k]);
    }
  }
  if (mimic) {
    for (long i = 0; i < n_c; ++i) {
      const long r = cfg.jac_rows[i];
      jac_.row(i) = Ja_[r / 6].row(r % 6) - Jb_[r / 6].row(r % 6);
    }
  } else {
    closure_rows();
  }
  if (!task) return;
  const auto &oMf = data.oMf[cfg.task_frame];
  Jt_.setZero();
  pinocchio::getFrameJacobian(model, data, cfg.task_frame, LWA, Jt_);
  Eigen::Matrix3d Jl;
  Eigen::Vector3d theta = Eigen::Vector3d::Zero();
  const Eigen::Matrix3d R_rel = cfg.R_ref.transpose() * oMf.rotation();
  Mat3x Hang;
  if (task_rotation) {
    theta = pinocchio::log3(R_rel);
    pinocchio::Jlog3(R_rel, Jl);
    Hang = Jl * (oMf.rotation().transpose() * Jt_.bottomRows<3>());
  }
  long out = n_c;
  for (long r : cfg.task_rows)  // positions first, then angles (TaskOutput.value)
    if (r < 3) {
      res_[out] = oMf.translation()[r];
      jac_.row(out++) = Jt_.row(r);
    }
  for (long r : cfg.task_rows)
    if (r >= 3) {
      res_[out] = theta[r - 3];
      jac_.row(out++) = Hang.row(r - 3);
    }
}

void Kinematics::frame_rate(long frame, const Vec &v, Mat6x &dJ) {
  dJ.setZero();
  pinocchio::getFrameJacobianTimeVariation(model, data, frame, LWA, dJ);
  const auto &cols = uni_cols_[frame];
  if (cols.empty()) return;
  // UniversalJoints.frame_jacobian_rate: remove q̇₂ (J₂ × J₁) from the first column
  const pinocchio::SE3 to_frame(Eigen::Matrix3d::Identity(), data.oMf[frame].translation());
  for (long i : cols) {
    const pinocchio::Motion a(data.J.col(i + 1)), b(data.J.col(i));
    const Eigen::Matrix<double, 6, 1> spurious = a.cross(b).toVector() * v[i + 1];
    dJ.col(i) -= to_frame.actInv(pinocchio::Motion(spurious)).toVector();
  }
}

void Kinematics::jacobian_rate(const Vec &q, const Vec &v, Mat &out, bool fresh) {
  out.resize(rows, model.nv);
  if (!fresh) pinocchio::computeJointJacobiansTimeVariation(model, data, q, v);
  if (!cfg.universal.empty()) place_frames();
  for (size_t k = 0; k < cfg.closure_frames.size(); ++k) {
    frame_rate(cfg.closure_frames[k][0], v, Ja_[k]);
    frame_rate(cfg.closure_frames[k][1], v, Jb_[k]);
  }
  for (long i = 0; i < n_c; ++i) {
    const long r = cfg.jac_rows[i];
    out.row(i) = Ja_[r / 6].row(r % 6) - Jb_[r / 6].row(r % 6);
  }
  if (!task) return;
  frame_rate(cfg.task_frame, v, dJt_);
  long row = n_c;
  for (long r : cfg.task_rows)
    if (r < 3) out.row(row++) = dJt_.row(r);
  if (!task_rotation) return;
  // TaskOutput.jacobian_derivative: Ḣ_ang = Hlog3(R_rel, ω) Rᵀ J_ang + Jlog3 (Rᵀ J̇_ang − [ω]× Rᵀ J_ang)
  Jt_.setZero();
  pinocchio::getFrameJacobian(model, data, cfg.task_frame, LWA, Jt_);
  const auto &frame = model.frames[cfg.task_frame];
  const Eigen::Matrix3d R = (data.oMi[frame.parentJoint] * frame.placement).rotation();
  const Eigen::Matrix3d R_rel = cfg.R_ref.transpose() * R;
  const Mat3x Jang = R.transpose() * Jt_.bottomRows<3>();
  const Eigen::Vector3d w = Jang * v;
  const Mat3x dJang = R.transpose() * dJt_.bottomRows<3>() - skew(w) * Jang;
  Eigen::Matrix3d Jl;
  pinocchio::Jlog3(R_rel, Jl);
  const Mat3x dH = hlog3(R_rel, w) * Jang + Jl * dJang;
  for (long r : cfg.task_rows)
    if (r >= 3) out.row(row++) = dH.row(r - 3);
}

void Kinematics::universal_bias_derivative(const Vec &q, const Vec &v, const Mat &T, Mat &out) {
  // h − g is quadratic in v: ∂h/∂v · w = h(v + w) − h(w) − (h(v) − g), exactly
  const Vec zero = Vec::Zero(model.nv);
  const Vec g = pinocchio::computeGeneralizedGravity(model, data_u, q);
  const Vec base = pinocchio::rnea(model, data_u, q, v, zero) - g;
  out.resize(model.nv, T.cols());
  for (Index j = 0; j < T.cols(); ++j) {
    const Vec hw = pinocchio::rnea(model, data_u, q, v + T.col(j), zero);
    out.col(j) = hw - pinocchio::rnea(model, data_u, q, T.col(j), zero) - base;
  }
}
}  // namespace pgpc
