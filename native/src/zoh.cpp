// Taylor scaling-and-squaring exponential on the top rows (see zoh.hpp and discretization.expm).
//
// The kernels are plain loops over Eigen's column-major storage: the matrices are small (m ≤ 12 top rows,
// n ≤ 20 columns for the bundled robots) and Eigen's dynamic-size expressions (lazyProduct, `F += c * P`,
// setZero) spent more instructions on their size logic than on the arithmetic (roll14: 179 k of a 20-stage
// rollout's 231 k in the exponential). Each kernel is compiled for the row counts of the bundled robots
// (ROWS = 4, 6, 12: n_x of a 2- , 3- or 6-dof platform), so that its inner loops over a column are unrolled,
// and for any other count (ROWS = 0: m at run time); the numbers are the same whatever the instance.
#include "zoh.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <type_traits>

#include <nanobind/stl/vector.h>

#include "bindings.hpp"
#include "numpy_array.hpp"

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

// the leading columns of A (m rows, column-major) among its first `limit` that are zero
Index leading_zero_columns(const double *a, Index m, Index limit) {
  Index lead = 0;
  for (; lead < limit; ++lead)
    for (Index r = 0; r < m; ++r)
      if (a[lead * m + r] != 0.0) return lead;
  return lead;
}

// the row count of a kernel: ROWS when fixed at compile time, else m
template <int ROWS>
constexpr Index rows_of(Index m) {
  return ROWS > 0 ? ROWS : m;
}

// a column of ROWS doubles (ROWS = 0: of a size given at run time) over column-major storage
template <int ROWS>
using Column = Eigen::Matrix<double, (ROWS > 0 ? ROWS : Eigen::Dynamic), 1>;
template <int ROWS>
using ColumnMap = Eigen::Map<Column<ROWS>>;
template <int ROWS>
using ConstColumnMap = Eigen::Map<const Column<ROWS>>;

// out (m) = X[:, from..to) · y[from..to), X (m rows, column-major); a fixed row count keeps the sum in registers
template <int ROWS>
[[gnu::always_inline]] inline void product_column(const double *x, Index m_rt, const double *y, Index from, Index to, double *out) {
  const Index m = rows_of<ROWS>(m_rt);
  ColumnMap<ROWS> o(out, m);
  if constexpr (ROWS > 0) {
    Column<ROWS> acc = Column<ROWS>::Zero();
    for (Index t = from; t < to; ++t) acc += ConstColumnMap<ROWS>(x + t * m, m) * y[t];
    o = acc;
  } else {
    o.setZero();
    for (Index t = from; t < to; ++t) o += ConstColumnMap<ROWS>(x + t * m, m) * y[t];
  }
}

// F (m, n) = top rows of Σ_(k ≤ K) A^k / k!, A (m, n) the top rows of a matrix whose other rows are zero;
// the top rows of A^k = (top rows of A^(k−1))[:, :m] · A. A's leading columns that are zero (a robot's
// ZOH matrix: nothing depends on the positions, its first n_y columns) are zero in every A^k, k ≥ 1: the
// products skip them (their terms are exact zeros; half the work of a robot's Taylor sum). P, Pn: workspaces
// (only their columns lead.. are written and read)
template <int ROWS>
void taylor_top(const Mat &A, Index K, const std::vector<double> &inv_fact, Mat &F, Mat &P, Mat &Pn) {
  const Index m = rows_of<ROWS>(A.rows()), n = A.cols();
  const double *a = A.data();
  const Index lead = leading_zero_columns(a, m, m);
  F.resize(m, n);
  P.resize(m, n);
  Pn.resize(m, n);
  double *f = F.data();
  std::copy(a, a + m * n, f);
  for (Index i = 0; i < m; ++i) f[i * m + i] += 1.0;
  const double *prev = a;  // A^(k−1), its columns lead..
  double *next = P.data(), *spare = Pn.data();
  for (Index k = 2; k <= K; ++k) {
    const double c = inv_fact[k];
    for (Index j = lead; j < n; ++j) {
      double *out = next + j * m, *fj = f + j * m;
      product_column<ROWS>(prev, m, a + j * m, lead, m, out);
      ColumnMap<ROWS>(fj, m) += c * ConstColumnMap<ROWS>(out, m);
    }
    prev = next;
    std::swap(next, spare);
  }
}

// E ← E^(2^s) on the top rows: [[E₁, E₂], [0, I]]² = [[E₁ E₁, E₁ E₂ + E₂], [0, I]]. E2: workspace
template <int ROWS>
void square_top(Mat &E, int s, Mat &E2) {
  const Index m = rows_of<ROWS>(E.rows()), n = E.cols();
  E2.resize(m, n);
  for (int i = 0; i < s; ++i) {
    const double *e = E.data();
    double *e2 = E2.data();
    for (Index j = 0; j < n; ++j) {
      double *out = e2 + j * m;
      product_column<ROWS>(e, m, e + j * m, 0, m, out);
      if (j >= m) ColumnMap<ROWS>(out, m) += ConstColumnMap<ROWS>(e + j * m, m);
    }
    E.swap(E2);
  }
}

// calls f(std::integral_constant<int, ROWS>) with ROWS = m for the compiled row counts, else 0
template <class F>
void dispatch_rows(Index m, F &&f) {
  switch (m) {
    case 4: f(std::integral_constant<int, 4>()); break;
    case 6: f(std::integral_constant<int, 6>()); break;
    case 12: f(std::integral_constant<int, 12>()); break;
    default: f(std::integral_constant<int, 0>()); break;
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
  const Index K = degree(norms_, norm * scale);
  dispatch_rows(M_.rows(), [&](auto rows) {
    taylor_top<decltype(rows)::value>(M_, K, inv_fact_, E, P_, Pn_);
    square_top<decltype(rows)::value>(E, s, E2_);
  });
  return true;
}

void TopRowsExpmDerivative::set_table(std::vector<double> degree_norms) {
  norms_ = std::move(degree_norms);
  inv_fact_ = inverse_factorials(norms_.size() + 5);
}

template <int ROWS>
void TopRowsExpmDerivative::action(const Vec &u, Mat &out) {
  // dF u is the upper block of p([[A, D_k], [0, A]]) [0; u], p = Σ_(k ≤ Kd) B^k / k! (the Fréchet derivative of
  // the Taylor polynomial: Σ_(i+l<Kd) A^i D_k A^l u / (i+l+1)!). Horner on the block vector [h₁; h₂]:
  // h₁ ← A h₁ + D_k h₂, h₂ ← c_k u + A h₂ (h₂ the same for every direction: the directions' h₁ side by side in
  // out, their D_k h₂ one product with the stack G). h₂'s rows m.. stay c_k u[m..]: their products with A and
  // G are c_k times those of u, made once. A's columns < lead_ and G's < glead_ are zero: skipped
  const Mat &G = *G_;
  const Index m = rows_of<ROWS>(A_.rows()), n = A_.cols(), Kd = K_ + 2, nr = nr_, n_dir = G.rows() / nr;
  const double *a = A_.data();
  ab_.noalias() = A_.rightCols(n - m) * u.tail(n - m);
  gb_.noalias() = G.rightCols(n - m) * u.tail(n - m);
  out.resize(m, n_dir);
  S_.resize(m, n_dir);
  w_.resize(m);
  wn_.resize(m);
  double *h1 = out.data(), *h1n = S_.data(), *h2 = w_.data(), *h2n = wn_.data();
  const double *uu = u.data();
  double c = inv_fact_[Kd];
  ColumnMap<ROWS>(h2, m) = c * ConstColumnMap<ROWS>(uu, m);
  for (Index k = Kd - 1; k >= 0; --k) {
    // D h₂ for every direction: G [h₂[:m]; c u[m:]] (c: h₂'s coefficient at this step)
    g_ = c * gb_;
    for (Index t = glead_; t < m; ++t) g_ += h2[t] * G.col(t);
    // h₁ ← A h₁ + D h₂ (h₁ = 0 at the first step)
    for (Index d = 0; d < n_dir; ++d) {
      double *o = h1n + d * m;
      if (k == Kd - 1)
        ColumnMap<ROWS>(o, m).setZero();
      else
        product_column<ROWS>(a, m, h1 + d * m, lead_, m, o);
      Eigen::Map<Vec>(o + row0_, nr) += g_.segment(d * nr, nr);
    }
    std::swap(h1, h1n);
    if (k == 0) break;
    // h₂ ← c_k u + A h₂ = c_k u + A[:, :m] h₂[:m] + c A[:, m:] u[m:]
    product_column<ROWS>(a, m, h2, lead_, m, h2n);
    const double ck = inv_fact_[k];
    ColumnMap<ROWS>(h2n, m) += ck * ConstColumnMap<ROWS>(uu, m) + c * ConstColumnMap<ROWS>(ab_.data(), m);
    std::swap(h2, h2n);
    c = ck;
  }
  if (h1 != out.data()) out.swap(S_);  // the last h₁ is in S_'s storage
}

bool TopRowsExpmDerivative::run(const Mat &M_top, const Mat &G, Index row0, Index nr, const Vec &xi, Mat &E,
                                Mat &dE) {
  const Index m = M_top.rows(), n = M_top.cols();
  if (nr <= 0 || row0 < 0 || row0 + nr > m || G.rows() % nr != 0 || G.cols() != n || xi.size() != n)
    throw std::invalid_argument("TopRowsExpmDerivative: the directions must be (n_dir·nr, n) with rows row0.. + nr ≤ m");
  const double norm = std::sqrt(M_top.squaredNorm());
  if (!std::isfinite(norm)) return false;
  const int s = squarings(norm);
  const double scale = std::ldexp(1.0, -s);
  A_ = M_top * scale;
  K_ = degree(norms_, norm * scale);
  // the derivative is linear in the directions: run on G and scale the sum once (no scaled copy of G)
  G_ = &G;
  row0_ = row0;
  nr_ = nr;
  lead_ = leading_zero_columns(A_.data(), m, m);
  glead_ = leading_zero_columns(G.data(), G.rows(), m);
  dispatch_rows(m, [&](auto rows) {
    constexpr int ROWS = decltype(rows)::value;
    taylor_top<ROWS>(A_, K_, inv_fact_, F_, P_, Pn_);
    if (!frechet_by_squaring(s, n)) {
      u_ = xi;
      action<ROWS>(u_, dE);
      for (long r = 1; r < (1L << s); ++r) {  // d(F^p ξ) = Σ_r F^(p−1−r) dF F^r ξ, Horner over r
        Fu_.noalias() = F_.lazyProduct(u_);
        u_.head(m) = Fu_;
        action<ROWS>(u_, acc_);
        acc_.noalias() += F_.leftCols(m).lazyProduct(dE);
        dE.swap(acc_);
      }
      dE *= scale;
      E = F_;
      square_top<ROWS>(E, s, E2_);
      return;
    }
    // L_k = dF[D_k] on every column (n actions, scaled once), then at each squaring of E = [[E₁, E₂], [0, I]]:
    // [[L₁, L₂], [0, 0]] → [[L₁ E₁ + E₁ L₁, L₁ E₂ + E₁ L₂ + L₂], [0, 0]]; dE[:, k] = L_k ξ
    const Index n_dir = G.rows() / nr;
    L_.resize(n_dir);
    Ln_.resize(n_dir);
    for (Index d = 0; d < n_dir; ++d) L_[d].resize(m, n);
    u_.setZero(n);
    for (Index j = 0; j < n; ++j) {
      u_[j] = 1.0;
      action<ROWS>(u_, col_);
      u_[j] = 0.0;
      for (Index d = 0; d < n_dir; ++d) L_[d].col(j) = col_.col(d) * scale;
    }
    E = F_;
    for (int i = 0; i < s; ++i) {
      for (Index d = 0; d < n_dir; ++d) {
        Ln_[d].noalias() = E.leftCols(m) * L_[d];
        Ln_[d].leftCols(m).noalias() += L_[d].leftCols(m) * E.leftCols(m);
        Ln_[d].rightCols(n - m).noalias() += L_[d].leftCols(m) * E.rightCols(n - m);
        Ln_[d].rightCols(n - m) += L_[d].rightCols(n - m);
        L_[d].swap(Ln_[d]);
      }
      square_top<ROWS>(E, 1, E2_);
    }
    dE.resize(m, n_dir);
    for (Index d = 0; d < n_dir; ++d) dE.col(d).noalias() = L_[d] * xi;
  });
  G_ = nullptr;
  return true;
}

// BIND_BEGIN (the test entry points of the kernels)
namespace {
// E (m, n) of TopRowsExpm on M_top (m, n), the top rows of an (n, n) matrix whose other rows are zero
Eigen::MatrixXd expm_top(const Mat &M_top, std::vector<double> degree_norms) {
  if (M_top.rows() > M_top.cols()) throw std::invalid_argument("expm_top: M_top must be (m, n), m ≤ n");
  TopRowsExpm expm;
  expm.set_table(std::move(degree_norms));
  Mat E;
  if (!expm.run(M_top, E)) throw std::invalid_argument("expm_top: M_top has NaN or inf entries");
  return E;
}

// (E, dE) of TopRowsExpmDerivative (discretization.expm_derivative_action's arguments and results): the
// directions D (n_dir, m, n) stacked on the rows between their first and last nonzero row
nb::tuple expm_derivative_action(const Mat &M_top, In3 D, const Vec &xi, std::vector<double> degree_norms) {
  const Index m = M_top.rows(), n = M_top.cols(), n_dir = static_cast<Index>(D.shape(0));
  if (m > n || D.shape(1) != size_t(m) || D.shape(2) != size_t(n) || xi.size() != n || n_dir == 0)
    throw std::invalid_argument("expm_derivative_action: M_top (m, n), m ≤ n, D (n_dir ≥ 1, m, n) and xi (n,)");
  const auto at = [&](Index k, Index r, Index j) { return D.data()[(k * m + r) * n + j]; };
  Index first = m, last = -1;
  for (Index k = 0; k < n_dir; ++k)
    for (Index r = 0; r < m; ++r)
      for (Index j = 0; j < n; ++j)
        if (at(k, r, j) != 0.0) first = std::min(first, r), last = std::max(last, r);
  if (last < 0) first = 0, last = 0;  // all zero: one row of zeros
  const Index nr = last - first + 1;
  Mat G(n_dir * nr, n);
  for (Index k = 0; k < n_dir; ++k)
    for (Index t = 0; t < nr; ++t)
      for (Index j = 0; j < n; ++j) G(k * nr + t, j) = at(k, first + t, j);
  TopRowsExpmDerivative expm;
  expm.set_table(std::move(degree_norms));
  Mat E, dE;
  if (!expm.run(M_top, G, first, nr, xi, E, dE))
    throw std::invalid_argument("expm_derivative_action: M_top has NaN or inf entries");
  return nb::make_tuple(Eigen::MatrixXd(E), Eigen::MatrixXd(dE));
}
}  // namespace

void bind_zoh(nb::module_ &m) {
  m.def("expm_top", &expm_top, nb::arg("M_top"), nb::arg("degree_norms"),
        "(m, n) top rows of exp(M), M (n, n) with only its top m rows M_top nonzero (the ZOH exponential of the "
        "rollout); degree_norms: discretization.DEGREE_NORMS");
  m.def("expm_derivative_action", &expm_derivative_action, nb::arg("M_top"), nb::arg("D"), nb::arg("xi"),
        nb::arg("degree_norms"),
        "(E (m, n), dE (m, n_dir)): the top rows of exp(M) and dE[:, k] = d/dt exp(M + t D_k) xi at t = 0, the top "
        "rows of the stage Jacobians' derivative (discretization.expm_derivative_action)");
}
}  // namespace pgpc
