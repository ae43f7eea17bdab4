// Jacobian ∂Φ/∂X of the stage map X(i+1) = Φ(X(i), u(i)) = A_d(X) X + B_d(X) u + c_d(X) (the ZOH
// map of the pre-simulation, eq. (10)) along a trajectory, in one call: the compiled twin of the
// central differences of ReducedModel.stage_jacobians (model/dynamics.py), which is the reference.
// The nonlinear MPC iterations (gpc/nmpc.py) linearize along each plan with it.
#include <algorithm>
#include <cmath>
#include <stdexcept>

#include <nanobind/eigen/dense.h>
#include <nanobind/ndarray.h>

#include "bindings.hpp"
#include "model_update.hpp"

namespace pgpc {
namespace {
using RowMat = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using Input2 = nb::ndarray<const double, nb::ndim<2>, nb::c_contig, nb::device::cpu>;

/// (K·n_x, n_x): rows i·n_x … (i+1)·n_x − 1 hold ∂Φ/∂X at (X(i), u(i)), i = 0..K−1; column k the
/// central difference with step h_k = step·max(1, |X_k(i)|) (the Python reference's rule).
RowMat stage_jacobians(ModelUpdate &self, Input2 X, Input2 u, double Ts, double step) {
  const long K = static_cast<long>(u.shape(0)), n = self.n_x, m = self.n_u;
  if (u.shape(1) != size_t(m) || X.shape(1) != size_t(n) || X.shape(0) < size_t(K))
    throw std::invalid_argument("stage_jacobians: X_seq must be (>= K, n_x) and u_seq (K, n_u)");
  if (!(Ts > 0.0) || !(step > 0.0))
    throw std::invalid_argument("stage_jacobians: Ts and step must be > 0");
  RowMat J(K * n, n), E(n, self.n_aug);
  Vec xi(self.n_aug), fp(n);
  xi[self.n_aug - 1] = 1.0;
  for (long i = 0; i < K; ++i) {
    const Eigen::Map<const Vec> x(X.data() + i * n, n);
    xi.segment(n, m) = Eigen::Map<const Vec>(u.data() + i * m, m);
    for (long k = 0; k < n; ++k) {
      const double h = step * std::max(1.0, std::abs(x[k]));
      xi.head(n) = x;
      xi[k] = x[k] + h;
      const double xp = xi[k];
      self.discrete(xi.head(n), Ts, E.data());  // (n, n_aug) row-major: [A_d | B_d | c_d]
      fp.noalias() = E * xi;
      xi[k] = x[k] - h;
      const double xm = xi[k];
      self.discrete(xi.head(n), Ts, E.data());
      J.block(i * n, k, n, 1) = (fp - E * xi) / (xp - xm);
    }
  }
  return J;
}
}  // namespace

void bind_stage_jacobian(nb::module_ &m) {
  m.def("stage_jacobians", &stage_jacobians, nb::arg("update"), nb::arg("X_seq"), nb::arg("u_seq"), nb::arg("Ts"),
        nb::arg("step"),
        "(K·n_x, n_x) ∂Φ/∂X of the ZOH stage map of a ModelUpdate at (X_seq[i], u_seq[i]), i < K, by central "
        "differences with step·max(1, |X_k|)");
}
}  // namespace pgpc
