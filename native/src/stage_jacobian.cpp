// Jacobian ∂Φ/∂X of the stage map X(i+1) = Φ(X(i), u(i)) = E(X)·[X; u; 1] (the ZOH map of the
// pre-simulation, eq. (10)) along a trajectory, in one call: the compiled twin of
// ReducedModel.stage_jacobians (model/dynamics.py), which is the reference. ∂Φ/∂X_k = E[:, k] +
// (∂E/∂X_k)·[X; u; 1], the second term the Fréchet derivative of the exponential along Ts·∂Z/∂X_k
// applied to one vector (TopRowsExpmDerivative); ∂Z/∂ẏ exact (Z is linear in ẏ), ∂Z/∂y forward
// differences of the factor rows Z along the closures' tangent, the velocity map there to first order.
// The nonlinear MPC iterations (gpc/nmpc.py) linearize with it.
#include <algorithm>
#include <cmath>
#include <stdexcept>

#include <nanobind/eigen/dense.h>
#include <nanobind/ndarray.h>

#include "bindings.hpp"
#include "model_update.hpp"
#include "pinocchio/algorithm/jacobian.hpp"

namespace pgpc {

void ModelUpdate::tangent_rates(Mat &P) {
  // computeJointJacobiansTimeVariation and RNEA without their kinematics passes: with the world Jacobian J
  // at q, a joint's world velocity at v is ov_k = ov_parent + J_k v_k and dJ_k = ov_k × J_k (Pinocchio's
  // formulas, jacobian.hxx); b(v, w) is the polarized world-frame RNEA of rnea-derivatives.hxx with zero
  // q̈ and gravity: a_k = a_parent + ½ (ov_k(v) × J_k w_k + ov_k(w) × J_k v_k),
  // f_k = oY_k a_k + ½ (ov_k(v) ×* oY_k ov_k(w) + ov_k(w) ×* oY_k ov_k(v)), τ_k = J_kᵀ Σ_subtree f
  // (exact for joints without a bias c_J, which christoffel_ ensures: every joint one degree of freedom)
  using pinocchio::Force;
  using pinocchio::Motion;
  const auto &model = kin.model;
  auto &data = kin.data;
  const int nj = model.njoints;
  const Index ny = n_y;
  pinocchio::computeJointJacobians(model, data, q_);  // oMi and J at q_ (eval_placed reads them too)
  tangent_ov_.resize(ny, std::vector<Motion>(nj, Motion::Zero()));
  tangent_oh_.resize(ny, std::vector<Force>(nj, Force::Zero()));
  tangent_dJ_.resize(ny, std::vector<Motion>(nj, Motion::Zero()));
  tangent_oY_.resize(nj);
  rate_dPhi_.resize(ny);
  for (int k = 1; k < nj; ++k) tangent_oY_[k] = data.oMi[k].act(model.inertias[k]);
  for (Index i = 0; i < ny; ++i) {
    auto &ov = tangent_ov_[i];
    for (int k = 1; k < nj; ++k) {
      const Index c = model.joints[k].idx_v();
      ov[k] = ov[model.parents[k]] + Motion(data.J.col(c) * T_(c, i));
      data.ov[k] = ov[k];
      tangent_dJ_[i][k] = ov[k].cross(Motion(data.J.col(c)));
      data.dJ.col(c) = tangent_dJ_[i][k].toVector();
      tangent_oh_[i][k] = tangent_oY_[k] * ov[k];
    }
    kin.jacobian_rate(q_, T_.col(i), rate_dPhi_[i], true);
  }
  std::vector<Motion> a(nj, Motion::Zero());
  std::vector<Force> f(nj);
  for (Index i = 0; i < ny; ++i)
    for (Index j = i; j < ny; ++j) {
      const auto &vi = tangent_ov_[i], &vj = tangent_ov_[j];
      const auto &hi = tangent_oh_[i], &hj = tangent_oh_[j];
      const auto &ci = tangent_dJ_[i], &cj = tangent_dJ_[j];
      for (int k = 1; k < nj; ++k) {
        const Index c = model.joints[k].idx_v();
        a[k] = a[model.parents[k]] + (ci[k] * T_(c, j) + cj[k] * T_(c, i)) * 0.5;
        f[k] = tangent_oY_[k] * a[k] + (vi[k].cross(hj[k]) + vj[k].cross(hi[k])) * 0.5;
      }
      for (int k = nj - 1; k > 0; --k) {
        const Index c = model.joints[k].idx_v();
        P(c, i * ny + j) = 2.0 * data.J.col(c).dot(f[k].toVector());
        if (model.parents[k] > 0) f[model.parents[k]] += f[k];
      }
      P.col(j * ny + i) = P.col(i * ny + j);
    }
}

namespace {

/// ((K − start)·n_x, n_x): rows (i − start)·n_x … hold ∂Φ/∂X at (X(i), u(i)), i = start..K−1; the y-columns
/// of ∂Z by forward differences along the tangent with step h_j = step·max(1, |y_j(i)|) (the Python rule).
RowMat stage_jacobians(ModelUpdate &self, In2 X, In2 u, double Ts, double step, long start) {
  const long K = static_cast<long>(u.shape(0)), n = self.n_x, m = self.n_u, ny = self.n_y, na = self.n_aug;
  if (u.shape(1) != size_t(m) || X.shape(1) != size_t(n) || X.shape(0) < size_t(K))
    throw std::invalid_argument("stage_jacobians: X_seq must be (>= K, n_x) and u_seq (K, n_u)");
  if (!(Ts > 0.0) || !(step > 0.0))
    throw std::invalid_argument("stage_jacobians: Ts and step must be > 0");
  if (start < 0 || start > K) throw std::invalid_argument("stage_jacobians: start must be in 0..K");
  TopRowsExpmDerivative expm;
  expm.set_table(self.cfg.degree_norms);
  RowMat J((K - start) * n, n);
  Mat M_top = Mat::Zero(n, na), rates, E, dE;
  M_top.block(0, ny, ny, ny).diagonal().setConstant(Ts);
  std::vector<Mat> D(n, Mat::Zero(n, na));  // Ts·∂(ZOH matrix)/∂X_k, top rows: only the ẏ rows move
  Vec xi(na), x(n), q, yd(ny);
  std::vector<Mat> dT(ny), dP(ny);
  xi[na - 1] = 1.0;
  Mat Zc, T, P, T_s, P_s;  // workspaces: assigned at equal sizes from the second stage on (no allocation)
  const std::vector<Warm> &sim = self.simulation_warm();  // usually at these very states
  for (long i = start; i < K; ++i) {
    x = Eigen::Map<const Vec>(X.data() + i * n, n);
    const Warm *base = i < static_cast<long>(sim.size()) && sim[i].y == x.head(ny) ? &sim[i] : nullptr;
    Zc = self.factor_rates(x, base, rates);
    M_top.bottomRightCorner(ny, na - ny) = Zc * Ts;
    for (long j = 0; j < ny; ++j) D[ny + j].block(ny, ny, ny, ny) = rates.middleCols(j * ny, ny) * Ts;
    // forward differences along the closures' tangent q + T e_j h (not assembled: the line has the
    // closures' first derivative; ReducedModel._factor_derivatives), with the first-order velocity map
    // T + h Ṫ_j, K⁺ + h K̇⁺_j there (Ṫ_j, K̇⁺_j from the rates Φ̇_q(T e_j) that factor_rates left) instead of
    // a kinematics pass and a factorization of the assembly Jacobian per step
    q = self.q_last;  // X's assembly (factor_rates) and its velocity map
    yd = x.tail(ny);
    T = self.velocity_map();
    P = self.pinv();
    self.kin.eval_placed();  // Ψ_q at q: factor_rates' rate passes left q's kinematics in the data
    self.velocity_map_rates(self.kin.jac_, T, P, self.rate_jacobians(), dT, dP);
    for (long j = 0; j < ny; ++j) {
      const double h = step * std::max(1.0, std::abs(x[j]));
      T_s = T + h * dT[j];
      P_s = P + h * dP[j];
      D[j].bottomRightCorner(ny, na - ny) =
          (self.factor_rows_with(self.kin.integrate(q, T.col(j) * h), T_s, P_s, yd) - Zc) * (Ts / h);
    }
    xi.head(n) = x;
    xi.segment(n, m) = Eigen::Map<const Vec>(u.data() + i * m, m);
    if (!expm.run(M_top, D, xi, E, dE)) self.handler().attr("nonfinite")();
    J.block((i - start) * n, 0, n, n) = E.leftCols(n) + dE;
  }
  return J;
}
}  // namespace

void bind_stage_jacobian(nb::module_ &m) {
  m.def("stage_jacobians", &stage_jacobians, nb::arg("update"), nb::arg("X_seq"), nb::arg("u_seq"), nb::arg("Ts"),
        nb::arg("step"), nb::arg("start") = 0,
        "((K − start)·n_x, n_x) ∂Φ/∂X of the ZOH stage map of a ModelUpdate at (X_seq[i], u_seq[i]), start ≤ i < K: the Fréchet "
        "derivative of the exponential, ẏ-derivatives of the factor rows exact, y-derivatives by forward "
        "differences along the closures' tangent with step·max(1, |y_j|)");
}
}  // namespace pgpc
