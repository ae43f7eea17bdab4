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
}  // namespace pgpc
