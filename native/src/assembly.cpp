// Warm-started assembly and velocity map: the C++ twin of ReducedModel._kinematics
// (model/dynamics.py) and AssemblyMixin.assemble_warm/_lstsq_z/_map_from (model/assembly.py).
// Anything unusual goes to the validated Python path (ModelUpdate::fallback), which raises the
// package's errors exactly as the pure-Python model does.
#include <Eigen/LU>
#include <Eigen/QR>
#include <Eigen/SVD>
#include <cmath>
#include <nanobind/eigen/dense.h>
#include <stdexcept>

#include "eigen_types.hpp"
#include "model_update.hpp"
#include "small_solve.hpp"

namespace pgpc {
namespace {
constexpr double SINGULAR_RCOND = 1e-8;  // assembly.SINGULAR_RCOND
constexpr double NEWTON_RCOND = 1e-10;   // assembly._NEWTON_RCOND

void columns_into(const Mat &a, const std::vector<long> &idx, Mat &out) {
  out.resize(a.rows(), static_cast<Index>(idx.size()));
  for (size_t j = 0; j < idx.size(); ++j) out.col(j) = a.col(idx[j]);
}

Mat columns(const Mat &a, const std::vector<long> &idx) {
  Mat out;
  columns_into(a, idx, out);
  return out;
}

// K⁺ of a K with full column rank by a fast factorization, and a lower bound of s_min/s_max
// (0 when not computed). K⁺ is unique then, so it equals the SVD's K⁺ to rounding: an LU inverse
// when K is square once its identically-zero rows are dropped (planar point closures, the usual
// case), Householder QR (K⁺ = R⁻¹ Qᵀ) otherwise. Bound: s_min/s_max ≥ 1/(‖K⁺‖_F ‖K‖_F). The
// square case works in workspaces kept per thread (no allocation once sized; the same arithmetic).
double fast_pinv(const Mat &K, Mat &P) {
  const Index n = K.cols();
  thread_local std::vector<Index> rows;
  thread_local Mat Ks, F, inv;
  rows.clear();
  for (Index i = 0; i < K.rows(); ++i)
    if (!(K.row(i).array() == 0.0).all()) rows.push_back(i);
  if (static_cast<Index>(rows.size()) == n) {
    Ks.resize(n, n);
    for (Index i = 0; i < n; ++i) Ks.row(i) = K.row(rows[i]);
    small_solve::lu_inverse(Ks, F, inv);
    P.setZero(n, K.rows());
    for (Index i = 0; i < n; ++i) P.col(rows[i]) = inv.col(i);
  } else if (K.rows() >= n) {
    Eigen::HouseholderQR<Mat> qr(K);
    const Mat Qt = (qr.householderQ() * Mat::Identity(K.rows(), n)).transpose();
    P = qr.matrixQR().topRows(n).triangularView<Eigen::Upper>().solve(Qt);
  } else {
    return 0.0;
  }
  const double bound = 1.0 / (P.norm() * K.norm());
  return std::isfinite(bound) ? bound : 0.0;
}
}  // namespace

void ModelUpdate::step(Vec &q, const Vec &dz) const {
  if (kin.flat) {
    for (Index i = 0; i < n_z; ++i) q[cfg.z_idx[i]] -= dz[i];
    return;
  }
  Vec dv = Vec::Zero(nv);
  for (Index i = 0; i < n_z; ++i) dv[cfg.z_idx[i]] = -dz[i];
  q = kin.integrate(q, dv);
}

void ModelUpdate::lstsq_z(const Mat &jac, const Vec &res, Vec &out) {
  const Mat Kz = columns(jac, cfg.z_idx);
  Mat P;
  if (fast_pinv(Kz, P) > NEWTON_RCOND) {  // no singular value is cut: the minimum-norm solution is K⁺ res
    out = P * res;
    return;
  }
  Eigen::JacobiSVD<Mat> svd(Kz, Eigen::ComputeThinU | Eigen::ComputeThinV);
  const Vec &s = svd.singularValues();
  Index r = 0;
  if (s[0] > 0)
    for (Index i = 0; i < s.size(); ++i) r += s[i] > NEWTON_RCOND * s[0];
  const Vec coef = (svd.matrixU().leftCols(r).transpose() * res).array() / s.head(r).array();
  out = svd.matrixV().leftCols(r) * coef;
}

bool ModelUpdate::map_from(const Mat &jac, bool exact) {
  thread_local Mat Kz, Ky, Tz;  // workspaces (every pre-simulated stage comes here: no allocation once sized)
  columns_into(jac, cfg.z_idx, Kz);
  // fast path accepted when the bound clears Python's rank test; else the SVD decides
  const bool ok = !exact && fast_pinv(Kz, pinv_) > SINGULAR_RCOND;
  if (!ok) {
    Eigen::JacobiSVD<Mat> svd(Kz, Eigen::ComputeThinU | Eigen::ComputeThinV);
    const Vec &s = svd.singularValues();
    if (!(s[n_z - 1] > SINGULAR_RCOND * s[0])) return false;
    pinv_ = (svd.matrixV().leftCols(n_z) * s.head(n_z).cwiseInverse().asDiagonal()) *
            svd.matrixU().leftCols(n_z).transpose();
  }
  if (!kin.task) {
    T_.setZero(nv, n_y);
    for (Index i = 0; i < n_y; ++i) T_(cfg.y_idx[i], i) = 1.0;
    columns_into(jac, cfg.y_idx, Ky);
    Tz.noalias() = pinv_ * Ky;
    for (Index i = 0; i < n_z; ++i) T_.row(cfg.z_idx[i]) = -Tz.row(i);
  } else {
    T_ = pinv_.rightCols(n_y);
  }
  return true;
}

void ModelUpdate::velocity_map_rates(const Mat &jac, const Mat &T, const Mat &pinv, const std::vector<Mat> &dPsi,
                                     std::vector<Mat> &dT, std::vector<Mat> &dP) {
  // K̇⁺ = −K⁺ K̇ K⁺ + K⁺K⁺ᵀ K̇ᵀ (I − K K⁺) (full column rank) on the rows of K that are not identically zero
  // in K and every K̇ (planar point closures' z rows): the others hold zero columns of K⁺ and K̇⁺ and add
  // nothing; the second term vanishes when the remaining K is square. The small products coefficient-wise,
  // each factor evaluated once (Eigen's blocked GEMM costs more than it saves here)
  const size_t nd = dPsi.size();
  // the workspaces are the model update's (map_rates_): assigned at equal sizes from the second call on
  std::vector<Index> &rows = map_rates_.rows;
  rows.clear();
  for (Index r = 0; r < jac.rows(); ++r) {
    bool zero = (jac.row(r).array() == 0.0).all();
    for (size_t j = 0; j < nd && zero; ++j) zero = (dPsi[j].row(r).array() == 0.0).all();
    if (!zero) rows.push_back(r);
  }
  const Index nr = static_cast<Index>(rows.size());
  auto &[K, Ps, dK, dKP, dPs, Q, N, dKtN, Ky, dKy, dTz] = map_rates_.mats;
  K.resize(nr, n_z);
  Ps.resize(n_z, nr);
  dK.resize(nr, n_z);
  for (Index r = 0; r < nr; ++r) {
    for (Index i = 0; i < n_z; ++i) K(r, i) = jac(rows[r], cfg.z_idx[i]);
    Ps.col(r) = pinv.col(rows[r]);
  }
  const bool square = nr == n_z;
  if (!square) {
    Q = Ps.lazyProduct(Ps.transpose());
    N = -K.lazyProduct(Ps);
    N.diagonal().array() += 1.0;
  }
  if (!kin.task) columns_into(jac, cfg.y_idx, Ky);
  dT.resize(nd);
  dP.resize(nd);
  for (size_t j = 0; j < nd; ++j) {
    for (Index r = 0; r < nr; ++r)
      for (Index i = 0; i < n_z; ++i) dK(r, i) = dPsi[j](rows[r], cfg.z_idx[i]);
    dKP.noalias() = dK.lazyProduct(Ps);
    dPs.noalias() = -Ps.lazyProduct(dKP);
    if (!square) {
      dKtN.noalias() = dK.transpose().lazyProduct(N);
      dPs.noalias() += Q.lazyProduct(dKtN);
    }
    dP[j].setZero(n_z, jac.rows());
    for (Index r = 0; r < nr; ++r) dP[j].col(rows[r]) = dPs.col(r);
    if (!kin.task) {  // T_z = −K⁺ Ψ_y: Ṫ_z = −(K̇⁺ Ψ_y + K⁺ Ψ̇_y)
      columns_into(dPsi[j], cfg.y_idx, dKy);
      dTz.noalias() = dP[j].lazyProduct(Ky);
      dTz.noalias() += pinv.lazyProduct(dKy);
      dT[j].setZero(T.rows(), T.cols());
      for (Index i = 0; i < n_z; ++i) dT[j].row(cfg.z_idx[i]) = -dTz.row(i);
    } else {  // T = K⁺'s output columns
      dT[j] = dP[j].rightCols(n_y);
    }
  }
}

bool ModelUpdate::assemble_warm(const Vec &pose, Vec q, const Mat *pinv_hint, bool near) {
  if (!kin.task)
    for (Index i = 0; i < n_y; ++i) q[cfg.y_q[i]] = pose[i];
  const double tol2 = 1e-12 * 1e-12;
  constexpr int max_iter = 8;
  Vec res, dz;
  int it = 0;
  for (; it < max_iter; ++it) {
    kin.eval(q);
    res = kin.res_;
    if (kin.task) res.tail(n_y) -= pose;
    const double err2 = res.dot(res);
    if (err2 <= tol2) break;
    if (!(err2 < 1e-4)) return false;
    if (it == 0 && pinv_hint != nullptr) {
      dz = *pinv_hint * res;
      dz += *pinv_hint * (res - columns(kin.jac_, cfg.z_idx) * dz);
    } else {
      lstsq_z(kin.jac_, res, dz);
    }
    step(q, dz);
  }
  if (it == max_iter) return false;
  if (!cfg.branch_q.empty() && !(near && it == 0)) {
    double lowest = INFINITY;
    for (size_t i = 0; i < cfg.branch_q.size(); ++i)
      lowest = std::min(lowest, std::sin(q[cfg.branch_q[i]]) * cfg.branch[i]);
    if (!(lowest > 0)) return false;
  }
  if (!map_from(kin.jac_, false)) return false;
  q_ = std::move(q);
  return true;
}

void ModelUpdate::fallback(const Vec &y) {
  // robot.assemble(y, q_last) + robot.velocity_map_nocopy(q) in Python: raises UnreachablePoseError,
  // SingularPoseError, ... with the package's messages
  Vec q = nb::cast<Vec>(handler_.attr("assemble")(y, q_last));
  kin.eval(q);
  if (!map_from(kin.jac_, true)) {
    handler_.attr("singular")(q);
    throw std::runtime_error("compiled velocity map singular where the Python one is not");
  }
  q_ = std::move(q);
}

bool ModelUpdate::project(const Vec &q, const Vec &v, const Mat *pinv_hint, Vec &q_out, Vec &v_out) {
  Vec pose(n_y), yd(n_y);
  if (kin.task) {  // y = h(q) and ẏ = H v from the assembly rows of the task output
    kin.eval(q);
    pose = kin.res_.tail(n_y);
    yd.noalias() = kin.jac_.bottomRows(n_y) * v;
  } else {
    for (Index i = 0; i < n_y; ++i) pose[i] = q[cfg.y_q[i]], yd[i] = v[cfg.y_idx[i]];
  }
  if (!assemble_warm(pose, q, pinv_hint, false)) return false;
  q_out = q_;
  v_out.noalias() = T_ * yd;
  return true;
}

void ModelUpdate::kinematics(const Vec &y, const Warm *base) {
  if (base != nullptr && base->y == y) {  // the base's own pose: its assembly (the same numbers)
    q_ = base->q;
    T_ = base->T;
    pinv_ = base->pinv;
  } else {
    bool near = base != nullptr;
    const Warm *b = base != nullptr ? base : (warm_ ? &*warm_ : nullptr);
    bool ok;
    if (b == nullptr) {
      ok = assemble_warm(y, q_last, nullptr, near);
    } else {
      const Vec dy = y - b->y;
      Vec step = b->T * dy;
      if (near) {  // an explicitly given base is ~0.1 mm away: first order is enough
        near = dy.dot(dy) < 1e-8;
      } else if (b->has_w) {  // z'' along δy ≈ −Φ_z⁺ Φ̇_q(T δy) T δy with T δy ≈ α T ẏ
        const double ss = b->yd.dot(b->yd);
        if (ss > 0.0) {
          const double a = 0.5 * dy.dot(b->yd) / ss;
          const Vec curv = a * (b->W * dy);
          for (Index i = 0; i < n_z; ++i) step[cfg.z_idx[i]] -= curv[i];
        }
      }
      ok = assemble_warm(y, kin.integrate(b->q, step), &b->pinv, near);
    }
    if (!ok) fallback(y);
  }
  q_last = q_;
  // into the previous warm start's storage (same sizes: no allocation); its factorization is stale
  if (!warm_) warm_.emplace();
  Warm &w = *warm_;
  w.q = q_;
  w.y = y;
  w.T = T_;
  w.pinv = pinv_;
  w.has_w = w.has_z = false;
}
}  // namespace pgpc
