// The Riccati recursion of the controller's unconstrained problems (riccati.cpp), declared here so
// that the nonlinear form's fused step (riccati_presimulated.cpp: the compiled pre-simulation, then
// this recursion, in one call) reaches it from the translation unit that knows the model update.
#pragma once

#include <Eigen/Cholesky>
#include <vector>

#include "eigen_types.hpp"

namespace pgpc {

class Riccati {
 public:
  // C (p, n), Wy (p, p), Wu (m, m) square-root weights, horizons N, No, Nu, form 0..3 (gpc/riccati.py)
  Riccati(const Mat &C, const Mat &Wy, const Mat &Wu, long N, long No, long Nu, int form);

  // A (N·n or n, n), B (N·n or n, m), c (N·n or n, or null), x0 (n), u0 (m), r (N − No, p), all
  // row-major; nA, nB, nc: stages held (1: one model for every stage) → v (Nu·m); returns J
  double solve(const double *A, long nA, const double *B, long nB, const double *c, long nc, const double *x0,
               const double *u0, const double *r, double *v);

  // the deviation form (3) along a pre-simulation: E (N, n, ld) row-major holds A_i in its first n
  // columns and B_i in the next m (the model update's ZOH rows [A_d | B_d | c_d], ld = n + m + 1),
  // X (N + 1, n) the pre-simulated states, w (N − No, p) the reference rows; the targets
  // w − C X(No+1..N) are formed here → v (Nu·m); returns J
  double solve_deviation(const double *E, long ld, const double *X, const double *w, double *v);

  long n, m, p, N, No, Nu, nz;
  int form;

 private:
  int kind(long i) const;
  void right_A(const Mat &P, long i, Mat &out) const;
  void left_AT(const Mat &Y, long i, Mat &out) const;
  void stage(long i, const double *A, const double *B, const double *c);
  double recursion(const double *x0, const double *u0, const double *r, double *v);

  Mat C_, Wy_, CQ_, CQC_, R_, PA_, M_, T_, BPA_, PB_, H_;
  Vec s_, g_, z_, zn_, e_;
  RowMat Ai_, Bi_, r_;  // one stage's A and B gathered from a strided E; the deviation targets
  std::vector<Mat> An_, Bn_, Abar_, Bbar_, K_;
  std::vector<Vec> cbar_, k_;
  Eigen::LLT<Mat> llt_;
};

}  // namespace pgpc
