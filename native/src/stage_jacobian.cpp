// Jacobian ∂Φ/∂X of the stage map X(i+1) = Φ(X(i), u(i)) = E(X)·[X; u; 1] (the ZOH map of the
// pre-simulation, eq. (10)) along a trajectory, in one call: the compiled twin of
// ReducedModel.stage_jacobians (model/dynamics.py), which is the reference. ∂Φ/∂X_k = E[:, k] +
// (∂E/∂X_k)·[X; u; 1], the second term the Fréchet derivative of the exponential along Ts·∂Z/∂X_k
// applied to one vector (TopRowsExpmDerivative); ∂Z/∂ẏ exact (Z is linear in ẏ), ∂Z/∂y forward
// differences of the factor rows Z along the closures' tangent. The nonlinear MPC iterations
// (gpc/nmpc.py) linearize with it.
#include <algorithm>
#include <cmath>
#include <stdexcept>

#include <nanobind/eigen/dense.h>
#include <nanobind/ndarray.h>

#include "bindings.hpp"
#include "model_update.hpp"

namespace pgpc {
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
  xi[na - 1] = 1.0;
  Mat Zc, T;  // workspaces: assigned at equal sizes from the second stage on (no allocation)
  const std::vector<Warm> &sim = self.simulation_warm();  // usually at these very states
  for (long i = start; i < K; ++i) {
    x = Eigen::Map<const Vec>(X.data() + i * n, n);
    const Warm *base = i < static_cast<long>(sim.size()) && sim[i].y == x.head(ny) ? &sim[i] : nullptr;
    Zc = self.factor_rates(x, base, rates);
    M_top.bottomRightCorner(ny, na - ny) = Zc * Ts;
    for (long j = 0; j < ny; ++j) D[ny + j].block(ny, ny, ny, ny) = rates.middleCols(j * ny, ny) * Ts;
    // forward differences along the closures' tangent q + T e_j h (not assembled: the line has the
    // closures' first derivative; ReducedModel._factor_derivatives)
    q = self.q_last;  // X's assembly (factor_rates) and its velocity map
    yd = x.tail(ny);
    T = self.velocity_map();
    for (long j = 0; j < ny; ++j) {
      const double h = step * std::max(1.0, std::abs(x[j]));
      D[j].bottomRightCorner(ny, na - ny) = (self.factor_rows_at(self.kin.integrate(q, T.col(j) * h), yd) - Zc) *
                                            (Ts / h);
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
