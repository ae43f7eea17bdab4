// The null(B) basis of input_svd.cpp, for the compiled callers that hold B themselves (the nonlinear
// form's fused step, riccati_presimulated.cpp): one rank rule, one implementation.
#pragma once

#include <Eigen/SVD>
#include <stdexcept>

#include "eigen_types.hpp"

namespace pgpc {

// (m − rank, m) orthonormal rows spanning null(B) of an (n, m) B (rank: singular values above
// rtol·σ_max), an empty (0, m) at full column rank; B not finite: std::domain_error (ValueError)
template <class MatB>
Mat null_rows(const MatB &B, double rtol) {
  const Index m = B.cols();
  if (!B.allFinite()) throw std::domain_error("null_basis: B contains NaN or inf");
  if (B.size() == 0) return Mat::Identity(m, m);
  Eigen::JacobiSVD<Mat> svd(B, Eigen::ComputeFullV);
  const Vec &s = svd.singularValues();
  Index rank = 0;
  if (s[0] > 0.0)
    for (Index i = 0; i < s.size(); ++i) rank += s[i] > rtol * s[0] ? 1 : 0;
  return svd.matrixV().rightCols(m - rank).transpose();
}
}  // namespace pgpc
