// Matrix exponential of the augmented ZOH matrix [[A, B, c], [0, 0, 0]]: the C++ twin of
// model/discretization.py expm (same degree table, scaling and squaring).
#pragma once

#include <vector>

#include <Eigen/Core>

#include "eigen_types.hpp"

namespace pgpc {

// exp(M) of an (n, n) matrix whose rows n_top.. are zero, computed on the n_top top rows only
// (the other rows of exp(M) are those of the identity). Workspaces are kept between calls.
class TopRowsExpm {
 public:
  // degree_norms: discretization._DEGREE_NORMS (largest norm of each Taylor degree K = 1, 2, ...)
  void set_table(std::vector<double> degree_norms);
  // E (n_top, n) = top rows of exp(M) for M_top = the top rows of M; false if M has NaN/inf
  bool run(const Mat &M_top, Mat &E);

 private:
  std::vector<double> norms_, inv_fact_;
  Mat M_, P_, Pn_, E2_;
};

// The derivatives of e^M ξ along directions D_k, M and each D_k with only their top m rows nonzero, each D_k
// only on the rows row0..row0+nr (discretization.expm_derivative_action, the reference): the Fréchet derivative
// of the exponential applied to one vector, by Horner on the Taylor polynomial of the block matrix
// [[M/2^s, D_k], [0, M/2^s]] applied to [0; ξ] and on the squarings of e^(M/2^s) — or, where 2^s − 1 > n
// (frechet_by_squaring: a stiff ZOH matrix), that polynomial's derivative on all n columns and the product
// rule at each squaring (O(s) products instead of 2^s − 1 actions).
class TopRowsExpmDerivative {
 public:
  void set_table(std::vector<double> degree_norms);
  // E (m, n) = top rows of e^M, dE (m, n_dir): column k = d/dt e^(M + t D_k) ξ at t = 0 (top rows); M_top (m, n);
  // G (n_dir·nr, n): rows k·nr.. = rows row0..row0+nr of D_k (its other rows zero); false if M has NaN/inf;
  // std::invalid_argument if the sizes do not fit
  bool run(const Mat &M_top, const Mat &G, Index row0, Index nr, const Vec &xi, Mat &E, Mat &dE);

 private:
  // dF u / 2^-s for every direction D_k (m, n_dir), F = e^A, A = M/2^s (dF along 2^-s D_k: linear in D_k);
  // ROWS: m fixed at compile time, or 0 (zoh.cpp)
  template <int ROWS>
  void action(const Vec &u, Mat &out);
  std::vector<double> norms_, inv_fact_;
  const Mat *G_ = nullptr;  // run's directions, while it runs
  Index row0_ = 0, nr_ = 0, lead_ = 0, glead_ = 0;  // G's rows; A's and G's leading zero columns
  Mat A_, P_, Pn_, F_, E2_, S_, acc_;
  Vec u_, w_, wn_, g_, ab_, gb_, Fu_;
  Index K_ = 0;
  // the derivative through the squarings (frechet_by_squaring): L_k (m, n) per direction, the next ones, a column
  std::vector<Mat> L_, Ln_;
  Mat col_;
};

// discretization.frechet_by_squaring: the derivative through the squarings (n actions, then O(s) matrix products)
// rather than along the vector (2^s − 1 more actions) — when 2^s − 1 > n
inline bool frechet_by_squaring(int s, Index n) { return s >= 62 || (1L << s) - 1 > n; }
}  // namespace pgpc
