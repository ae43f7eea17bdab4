// The triangular solves of the small systems in every pre-simulated stage and Riccati step (M_r of a
// model update, 3×3 … 12×12; the assembly's K, 8×8 … 24×24; R + BᵀPB, m×m) as plain loops, on Eigen's
// own factorizations (LLT, PartialPivLU). Eigen's solve of a dynamic matrix blocks and packs its operands
// for large systems: at these sizes that is most of its time (callgrind: docs/performance.md). The
// arithmetic is the same substitution; only the order of a row's sum may differ (rounding).
#pragma once

#include <Eigen/Cholesky>
#include <Eigen/LU>

#include "eigen_types.hpp"

namespace pgpc::small_solve {

// X ← L⁻¹ X, L the lower triangle of F (unit diagonal when `unit`), every column of X
template <class F, class X>
void lower_in_place(const F &L, X &x, bool unit) {
  const Index n = L.rows();
  for (Index c = 0; c < x.cols(); ++c)
    for (Index i = 0; i < n; ++i) {
      double s = x(i, c);
      for (Index k = 0; k < i; ++k) s -= L(i, k) * x(k, c);
      x(i, c) = unit ? s : s / L(i, i);
    }
}

// X ← U⁻¹ X, U the upper triangle of F (transposed: Lᵀ of F's lower triangle, the Cholesky factor's)
template <class F, class X>
void upper_in_place(const F &U, X &x, bool transposed) {
  const Index n = U.rows();
  for (Index c = 0; c < x.cols(); ++c)
    for (Index i = n - 1; i >= 0; --i) {
      double s = x(i, c);
      for (Index k = i + 1; k < n; ++k) s -= (transposed ? U(k, i) : U(i, k)) * x(k, c);
      x(i, c) = s / U(i, i);
    }
}

// out = A⁻¹ B from the Cholesky factorization A = L Lᵀ (llt.info() == Success); out a matrix or a vector
template <class B, class Out>
void llt_solve(const Eigen::LLT<Mat> &llt, const B &b, Out &out) {
  const Mat &F = llt.matrixLLT();  // L in its lower triangle
  out = b;
  lower_in_place(F, out, false);
  upper_in_place(F, out, true);
}

// inv = A⁻¹ from the factorization P A = L U (A square and invertible): columns of U⁻¹ L⁻¹ P
inline void lu_inverse(const Eigen::PartialPivLU<Mat> &lu, Mat &inv) {
  const Mat &F = lu.matrixLU();
  inv = lu.permutationP() * Mat::Identity(F.rows(), F.cols());
  lower_in_place(F, inv, true);
  upper_in_place(F, inv, false);
}
}  // namespace pgpc::small_solve
