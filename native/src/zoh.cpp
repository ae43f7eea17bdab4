// Taylor scaling-and-squaring exponential on the top rows (see zoh.hpp and discretization.expm).
#include "zoh.hpp"

#include <algorithm>
#include <cmath>

namespace pgpc {
namespace {
constexpr double EXPM_THETA = 0.5;  // discretization._EXPM_THETA
}

void TopRowsExpm::set_table(std::vector<double> degree_norms) {
  norms_ = std::move(degree_norms);
  inv_fact_.assign(norms_.size() + 2, 1.0);
  double fact = 1.0;  // exact up to 22!, the degrees used after scaling are far below
  for (size_t k = 1; k < inv_fact_.size(); ++k) {
    fact *= static_cast<double>(k);
    inv_fact_[k] = 1.0 / fact;
  }
}

bool TopRowsExpm::run(const Mat &M_top, Mat &E) {
  const Index m = M_top.rows(), n = M_top.cols();
  double norm = std::sqrt(M_top.squaredNorm());  // Frobenius norm (the zero rows add nothing)
  if (!std::isfinite(norm)) return false;
  int s = 0;
  M_ = M_top;
  if (norm > EXPM_THETA) {
    s = static_cast<int>(std::ceil(std::log2(norm / EXPM_THETA)));
    const double scale = std::ldexp(1.0, -s);
    M_ *= scale;
    norm *= scale;
  }
  const Index K = std::lower_bound(norms_.begin(), norms_.end(), norm) - norms_.begin() + 1;
  // E = Σ_k M^k / k!; the top rows of M^k = (top rows of M^(k-1))[:, :m] · M_top
  E.setZero(m, n);
  E.leftCols(m).setIdentity();
  P_ = M_;
  E += inv_fact_[1] * P_;
  for (Index k = 2; k <= K; ++k) {
    Pn_.noalias() = P_.leftCols(m) * M_;
    P_.swap(Pn_);
    E += inv_fact_[k] * P_;
  }
  for (int i = 0; i < s; ++i) {  // [[E₁, E₂], [0, I]]² = [[E₁ E₁, E₁ E₂ + E₂], [0, I]]
    E2_.noalias() = E.leftCols(m) * E;
    E2_.rightCols(n - m) += E.rightCols(n - m);
    E.swap(E2_);
  }
  return true;
}

void TopRowsExpmDerivative::set_table(std::vector<double> degree_norms) {
  norms_ = std::move(degree_norms);
  inv_fact_.assign(norms_.size() + 5, 1.0);
  double fact = 1.0;
  for (size_t k = 1; k < inv_fact_.size(); ++k) {
    fact *= static_cast<double>(k);
    inv_fact_[k] = 1.0 / fact;
  }
}

void TopRowsExpmDerivative::action(const Vec &u, Mat &out) {
  const Index m = A_.rows(), n_dir = static_cast<Index>(D_.size()), Kd = K_ + 2;
  R_.resize(Kd);
  // R_l (m, n_dir): column k = D_k A^l u; A^l u lives in the top m rows for l ≥ 1
  for (Index l = 0; l < Kd; ++l) {
    R_[l].resize(m, n_dir);
    if (l == 0) {
      for (Index k = 0; k < n_dir; ++k) R_[0].col(k).noalias() = D_[k] * u;
      w_.noalias() = A_ * u;
    } else {
      for (Index k = 0; k < n_dir; ++k) R_[l].col(k).noalias() = D_[k].leftCols(m) * w_;
      wn_.noalias() = A_.leftCols(m) * w_;
      w_.swap(wn_);
    }
  }
  // Σ_(i+l<Kd) A^i R_l / (i+l+1)!, Horner over i
  out = inv_fact_[Kd] * R_[0];
  for (Index i = Kd - 2; i >= 0; --i) {
    S_ = inv_fact_[i + 1] * R_[0];
    for (Index l = 1; l < Kd - i; ++l) S_ += inv_fact_[i + l + 1] * R_[l];
    Y_.noalias() = A_.leftCols(m) * out;
    out = S_ + Y_;
  }
}

bool TopRowsExpmDerivative::run(const Mat &M_top, const std::vector<Mat> &D, const Vec &xi, Mat &E, Mat &dE) {
  const Index m = M_top.rows(), n = M_top.cols();
  double norm = std::sqrt(M_top.squaredNorm());
  if (!std::isfinite(norm)) return false;
  int s = 0;
  if (norm > EXPM_THETA) s = static_cast<int>(std::ceil(std::log2(norm / EXPM_THETA)));
  const double scale = std::ldexp(1.0, -s);
  A_ = M_top * scale;
  D_.resize(D.size());
  for (size_t k = 0; k < D.size(); ++k) D_[k] = D[k] * scale;
  K_ = std::lower_bound(norms_.begin(), norms_.end(), norm * scale) - norms_.begin() + 1;
  F_.setZero(m, n);
  F_.leftCols(m).setIdentity();
  P_ = A_;
  F_ += P_;
  for (Index k = 2; k <= K_; ++k) {
    Pn_.noalias() = P_.leftCols(m) * A_;
    P_.swap(Pn_);
    F_ += inv_fact_[k] * P_;
  }
  u_ = xi;
  action(u_, dE);
  Mat acc;
  for (long r = 1; r < (1L << s); ++r) {  // d(F^p ξ) = Σ_r F^(p−1−r) dF F^r ξ, Horner over r
    wn_.noalias() = F_ * u_;
    u_.head(m) = wn_;
    action(u_, acc);
    Y_.noalias() = F_.leftCols(m) * dE;
    dE = Y_ + acc;
  }
  E = F_;
  for (int i = 0; i < s; ++i) {  // [[E₁, E₂], [0, I]]² = [[E₁ E₁, E₁ E₂ + E₂], [0, I]]
    E2_.noalias() = E.leftCols(m) * E;
    E2_.rightCols(n - m) += E.rightCols(n - m);
    E.swap(E2_);
  }
  return true;
}
}  // namespace pgpc
