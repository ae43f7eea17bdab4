// The small systems of every pre-simulated stage and Riccati step (M_r of a model update, 3×3 … 12×12; the
// assembly's K, 8×8 … 24×24; R + BᵀPB, m×m, also the active set's free inputs' block) solved by plain loops: Eigen's triangular solve and LU of a
// dynamic matrix block and pack their operands for large systems, which at these sizes is most of their
// instructions (callgrind, docs/performance.md#the-nonlinear-step). The arithmetic is the same
// substitution and elimination (Eigen's LLT factor; the LU's pivots as PartialPivLU's); only the order
// of a row's sum may differ (rounding).
#pragma once

#include <Eigen/Cholesky>
#include <cmath>
#include <utility>
#include <vector>

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

// X ← A⁻¹ X from the Cholesky factor L of A = L Lᵀ (the lower triangle of F); X a matrix or a vector
template <class F, class X>
void llt_solve_in_place(const F &L, X &x) {
  lower_in_place(L, x, false);
  upper_in_place(L, x, true);
}

// out = A⁻¹ B from the Cholesky factorization A = L Lᵀ (llt.info() == Success); out a matrix or a vector
template <class B, class Out>
void llt_solve(const Eigen::LLT<Mat> &llt, const B &b, Out &out) {
  out = b;
  llt_solve_in_place(llt.matrixLLT(), out);  // L in its lower triangle
}

// F ← the Cholesky factor L of the symmetric positive definite F (its lower triangle read and written:
// A = L Lᵀ, Eigen's LLT factor); false (F left part-way) when a pivot is not positive (or NaN). Plain loops:
// at a few inputs, with the size known at compile time, unrolled (the stage-wise active set's R + BᵀPB).
template <class F>
bool cholesky_in_place(F &L) {
  const Index n = L.rows();
  for (Index j = 0; j < n; ++j) {
    double t = L(j, j);
    for (Index c = 0; c < j; ++c) t -= L(j, c) * L(j, c);
    if (!(t > 0.0)) return false;
    const double l = std::sqrt(t);
    L(j, j) = l;
    for (Index r = j + 1; r < n; ++r) {
      double x = L(r, j);
      for (Index c = 0; c < j; ++c) x -= L(r, c) * L(j, c);
      L(r, j) = x / l;
    }
  }
  return true;
}

// inv = A⁻¹ (A square) by Gaussian elimination with partial pivoting (the largest |entry| of the column,
// as Eigen's PartialPivLU), in the workspace F: P A = L U, then the columns of U⁻¹ L⁻¹ P. A singular A
// gives inf or NaN entries (the caller's finiteness test decides)
inline void lu_inverse(const Mat &A, Mat &F, Mat &inv) {
  const Index n = A.rows();
  thread_local std::vector<Index> perm;
  F = A;
  perm.resize(n);
  for (Index i = 0; i < n; ++i) perm[i] = i;
  for (Index k = 0; k < n; ++k) {
    Index p = k;
    for (Index i = k + 1; i < n; ++i)
      if (std::abs(F(i, k)) > std::abs(F(p, k))) p = i;
    if (p != k) {
      F.row(k).swap(F.row(p));
      std::swap(perm[k], perm[p]);
    }
    const double pivot = F(k, k);
    for (Index i = k + 1; i < n; ++i) {
      const double l = F(i, k) / pivot;
      F(i, k) = l;
      for (Index j = k + 1; j < n; ++j) F(i, j) -= l * F(k, j);
    }
  }
  inv.setZero(n, n);
  for (Index i = 0; i < n; ++i) inv(i, perm[i]) = 1.0;  // P: row i of P A is row perm[i] of A
  lower_in_place(F, inv, true);
  upper_in_place(F, inv, false);
}
}  // namespace pgpc::small_solve
