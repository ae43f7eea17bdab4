// The Kalman correction of StateEstimator.update (estimation/kalman.py, the reference): one call
// instead of ~15 NumPy operations on matrices of a few rows (each ~1-2 µs of call overhead).
// The measurement is the pose from forward kinematics (H = [I 0 0]) and, with drive rates, ẏ
// (H = [0 I 0]); its covariance is R = info⁻¹ with info = Jᵀ Σ⁻¹ J per block (J the drive
// Jacobian, Σ^(-1/2) the weights). K = P Hᵀ (H P Hᵀ + R)⁻¹, z⁺ = z + K ν, and the Joseph form
// P⁺ = (I − K H) P (I − K H)ᵀ + K R Kᵀ, computed as B − (B Hᵀ − K R) Kᵀ with B = (I − K H) P.
// A Cholesky factorization that fails (not positive definite) returns false: the Python path
// redoes the correction (its LU fallback, its error).
#include <Eigen/Cholesky>
#include <stdexcept>

#include "bindings.hpp"
#include "eigen_types.hpp"

namespace pgpc {
namespace {
// workspaces, sized on first use (one estimator per thread at a time)
struct Workspace {
  RowMat Jw, info, R, S, K, PHt, B;
  Vec z;
};

bool correct(Workspace &w, const In2 &J_, const In1 &w_pos, const In1 &w_rate, const In1 &innovation, const In1 &z_,
             const In2 &P_, Out1 &z_out, Out2 &P_out) {
  const Index n_u = J_.shape(0), n = J_.shape(1), m = innovation.shape(0), nx = z_.shape(0);
  if (static_cast<Index>(w_pos.shape(0)) != n_u || static_cast<Index>(w_rate.shape(0)) != n_u ||
      (m != n && m != 2 * n) || m > nx || static_cast<Index>(P_.shape(0)) != nx ||
      static_cast<Index>(P_.shape(1)) != nx || static_cast<Index>(z_out.shape(0)) != nx ||
      static_cast<Index>(P_out.shape(0)) != nx || static_cast<Index>(P_out.shape(1)) != nx)
    throw std::invalid_argument("kalman_correct: J (n_u, n), weights (n_u), innovation (n or 2n), z (nx), "
                                "P (nx, nx) and the outputs of the same sizes expected");
  const Eigen::Map<const RowMat> J(J_.data(), n_u, n), P(P_.data(), nx, nx);
  const Eigen::Map<const Vec> nu(innovation.data(), m), z(z_.data(), nx);
  w.info.setZero(m, m);
  w.Jw = Eigen::Map<const Vec>(w_pos.data(), n_u).asDiagonal() * J;
  w.info.topLeftCorner(n, n).noalias() = w.Jw.transpose() * w.Jw;
  if (m == 2 * n) {
    w.Jw = Eigen::Map<const Vec>(w_rate.data(), n_u).asDiagonal() * J;
    w.info.bottomRightCorner(n, n).noalias() = w.Jw.transpose() * w.Jw;
  }
  Eigen::LLT<RowMat> llt(w.info);
  if (llt.info() != Eigen::Success) return false;
  w.R = llt.solve(RowMat::Identity(m, m));
  w.S = P.topLeftCorner(m, m) + w.R;
  llt.compute(w.S);
  if (llt.info() != Eigen::Success) return false;
  w.PHt = llt.solve(P.topRows(m));  // S⁻¹ H P (m × nx); K = its transpose (S, P symmetric)
  w.K = w.PHt.transpose();
  w.z.noalias() = z + w.K * nu;
  w.B = P;
  w.B.noalias() -= w.K * P.topRows(m);
  w.S = w.B.leftCols(m);  // B Hᵀ − K R (nx × m), into a workspace
  w.S.noalias() -= w.K * w.R;
  Eigen::Map<RowMat> P_new(P_out.data(), nx, nx);
  P_new = w.B;
  P_new.noalias() -= w.S * w.K.transpose();
  Eigen::Map<Vec>(z_out.data(), nx) = w.z;
  return P_new.allFinite() && w.z.allFinite();
}
}  // namespace

void bind_kalman(nb::module_ &m) {
  m.def(
      "kalman_correct",
      [](In2 J, In1 w_pos, In1 w_rate, In1 innovation, In1 z, In2 P, Out1 z_out, Out2 P_out) {
        thread_local Workspace w;
        return correct(w, J, w_pos, w_rate, innovation, z, P, z_out, P_out);
      },
      nb::arg("J"), nb::arg("w_pos"), nb::arg("w_rate"), nb::arg("innovation"), nb::arg("z"), nb::arg("P"),
      nb::arg("z_out"), nb::arg("P_out"),
      "StateEstimator.update's correction (estimation/kalman.py): z_out = z + K ν and P_out by the "
      "Joseph form for the measured y (ν of n entries) or y and ẏ (2n), R⁻¹ = (W J)ᵀ (W J) per block "
      "with W = diag(w_pos), diag(w_rate); False (outputs undefined) where a Cholesky factor fails");
}
}  // namespace pgpc
