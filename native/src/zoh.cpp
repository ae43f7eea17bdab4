// Taylor scaling-and-squaring exponential on the top rows (see zoh.hpp and discretization.expm).
#include "zoh.hpp"

#include <algorithm>
#include <cmath>

namespace pgpc {
namespace {
constexpr double EXPM_THETA = 0.5;  // discretization._EXPM_THETA

// 1/k!, k = 0..n−1 (exact up to 22!, the degrees used after scaling are far below)
std::vector<double> inverse_factorials(size_t n) {
  std::vector<double> inv(n, 1.0);
  double fact = 1.0;
  for (size_t k = 1; k < n; ++k) {
    fact *= static_cast<double>(k);
    inv[k] = 1.0 / fact;
  }
  return inv;
}

// the squarings s with ‖M‖/2^s ≤ θ (Frobenius norm of the top rows: the zero rows add nothing)
int squarings(double norm) { return norm > EXPM_THETA ? static_cast<int>(std::ceil(std::log2(norm / EXPM_THETA))) : 0; }

// the smallest Taylor degree K whose table norm covers `norm` (discretization.DEGREE_NORMS)
Index degree(const std::vector<double> &norms, double norm) {
  return std::lower_bound(norms.begin(), norms.end(), norm) - norms.begin() + 1;
}

// F (m, n) = top rows of Σ_(k ≤ K) A^k / k!, A (m, n) the top rows of a matrix whose other rows are zero;
// the top rows of A^k = (top rows of A^(k−1))[:, :m] · A. A's leading columns that are zero (a robot's
// ZOH matrix: nothing depends on the positions, its first n_y columns) are zero in every A^k, k ≥ 1: the
// products skip them (their terms are exact zeros; half the work of a robot's Taylor sum). P, Pn: workspaces
void taylor_top(const Mat &A, Index K, const std::vector<double> &inv_fact, Mat &F, Mat &P, Mat &Pn) {
  const Index m = A.rows(), n = A.cols();
  Index lead = 0;  // leading zero columns among A's first m
  while (lead < m && (A.col(lead).array() == 0.0).all()) ++lead;
  const Index live = m - lead;
  F.setZero(m, n);
  F.leftCols(m).setIdentity();
  P = A;
  F += P;
  for (Index k = 2; k <= K; ++k) {
    Pn.noalias() = P.middleCols(lead, live).lazyProduct(A.middleRows(lead, live));
    P.swap(Pn);
    F += inv_fact[k] * P;
  }
}

// E ← E^(2^s) on the top rows: [[E₁, E₂], [0, I]]² = [[E₁ E₁, E₁ E₂ + E₂], [0, I]]. E2: workspace
void square_top(Mat &E, int s, Mat &E2) {
  const Index m = E.rows(), n = E.cols();
  for (int i = 0; i < s; ++i) {
    E2.noalias() = E.leftCols(m).lazyProduct(E);
    E2.rightCols(n - m) += E.rightCols(n - m);
    E.swap(E2);
  }
}
}  // namespace

void TopRowsExpm::set_table(std::vector<double> degree_norms) {
  norms_ = std::move(degree_norms);
  inv_fact_ = inverse_factorials(norms_.size() + 2);
}

bool TopRowsExpm::run(const Mat &M_top, Mat &E) {
  const double norm = std::sqrt(M_top.squaredNorm());
  if (!std::isfinite(norm)) return false;
  const int s = squarings(norm);
  const double scale = std::ldexp(1.0, -s);
  M_ = M_top * scale;
  taylor_top(M_, degree(norms_, norm * scale), inv_fact_, E, P_, Pn_);
  square_top(E, s, E2_);
  return true;
}

void TopRowsExpmDerivative::set_table(std::vector<double> degree_norms) {
  norms_ = std::move(degree_norms);
  inv_fact_ = inverse_factorials(norms_.size() + 5);
}

void TopRowsExpmDerivative::stack(const std::vector<Mat> &D) {
  // the rows that are nonzero in some direction (a robot's ZOH directions move only the ẏ rows): the
  // others give exact zeros in every D_k A^l u, so they are left out of the products
  const Index m = A_.rows(), n = A_.cols(), n_dir = static_cast<Index>(D.size());
  live_.clear();
  for (Index r = 0; r < m; ++r) {
    bool zero = true;
    for (Index k = 0; k < n_dir && zero; ++k) zero = (D[k].row(r).array() == 0.0).all();
    if (!zero) live_.push_back(r);
  }
  const Index nr = static_cast<Index>(live_.size());
  G_.resize(n_dir * nr, n);
  for (Index k = 0; k < n_dir; ++k)
    for (Index t = 0; t < nr; ++t) G_.row(k * nr + t) = D[k].row(live_[t]);
}

void TopRowsExpmDerivative::action(Index n_dir, const Vec &u, Mat &out) {
  const Index m = A_.rows(), Kd = K_ + 2, nr = static_cast<Index>(live_.size());
  R_.resize(Kd);
  // R_l (m, n_dir): column k = D_k A^l u (the directions stacked in G_: one product for all); A^l u lives
  // in the top m rows for l ≥ 1. Coefficient-wise products: Eigen's GEMV/GEMM cost more than they save here
  for (Index l = 0; l < Kd; ++l) {
    if (l == 0) {
      g_.noalias() = G_.lazyProduct(u);
      w_.noalias() = A_.lazyProduct(u);
    } else {
      g_.noalias() = G_.leftCols(m).lazyProduct(w_);
      wn_.noalias() = A_.leftCols(m).lazyProduct(w_);
      w_.swap(wn_);
    }
    R_[l].setZero(m, n_dir);
    for (Index k = 0; k < n_dir; ++k)
      for (Index t = 0; t < nr; ++t) R_[l](live_[t], k) = g_[k * nr + t];
  }
  // Σ_(i+l<Kd) A^i R_l / (i+l+1)!, Horner over i
  out = inv_fact_[Kd] * R_[0];
  for (Index i = Kd - 2; i >= 0; --i) {
    S_ = inv_fact_[i + 1] * R_[0];
    for (Index l = 1; l < Kd - i; ++l) S_ += inv_fact_[i + l + 1] * R_[l];
    S_.noalias() += A_.leftCols(m).lazyProduct(out);
    out.swap(S_);
  }
}

bool TopRowsExpmDerivative::run(const Mat &M_top, const std::vector<Mat> &D, const Vec &xi, Mat &E, Mat &dE) {
  const Index m = M_top.rows();
  const double norm = std::sqrt(M_top.squaredNorm());
  if (!std::isfinite(norm)) return false;
  const int s = squarings(norm);
  const double scale = std::ldexp(1.0, -s);
  A_ = M_top * scale;
  K_ = degree(norms_, norm * scale);
  taylor_top(A_, K_, inv_fact_, F_, P_, Pn_);
  // the derivative is linear in the directions: run on D and scale the sum once (no scaled copies of D)
  stack(D);
  const Index n_dir = static_cast<Index>(D.size());
  u_ = xi;
  action(n_dir, u_, dE);
  for (long r = 1; r < (1L << s); ++r) {  // d(F^p ξ) = Σ_r F^(p−1−r) dF F^r ξ, Horner over r
    wn_.noalias() = F_.lazyProduct(u_);
    u_.head(m) = wn_;
    action(n_dir, u_, acc_);
    acc_.noalias() += F_.leftCols(m).lazyProduct(dE);
    dE.swap(acc_);
  }
  dE *= scale;
  E = F_;
  square_top(E, s, E2_);
  return true;
}
}  // namespace pgpc
