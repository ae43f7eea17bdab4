// The stage-wise solvers' view of their numpy arguments (stagewise_ipm.cpp, stagewise_active.cpp):
// C-contiguous float64 arrays, the per-stage blocks of an (N, a, b) array, and the LQ part of a
// StageQP (models, criterion, row bounds' shape) both read.
#pragma once
#include <nanobind/eigen/dense.h>
#include <nanobind/ndarray.h>

#include <stdexcept>
#include <string>
#include <type_traits>

#include "bindings.hpp"
#include "zoh.hpp"

namespace pgpc::stage_arrays {
using pgpc::RowMat;
using CMap = Eigen::Map<const RowMat>;
using pgpc::In1, pgpc::In2, pgpc::In3;

// stage i of an (N, a, b) row-major array, a view (no copy)
template <class T>
CMap block(const T &arr, long i) {
  const long a = long(arr.shape(1)), b = long(arr.shape(2));
  return CMap(arr.data() + i * a * b, a, b);
}

// qp's sizes (N, nz, m, nd, k) and its A, B, Fz, c (N stages), Q, q (N + 1), z0, R from the arrays
// (stored as the QP's containers hold them: copies or views); `who` names the caller in the error
template <class QP>
void read_lq(QP &qp, const In3 &A, const In3 &B, const In2 &c, const In1 &z0, const In3 &Q, const In2 &q,
             const In2 &R, long n_decide, const In3 &Fz, const In2 &f, const char *who) {
  qp.N = long(A.shape(0));
  qp.nz = long(A.shape(1));
  qp.m = long(B.shape(2));
  qp.nd = n_decide;
  qp.k = long(f.shape(1));
  if (qp.nd < 1 || qp.nd > qp.N || long(Q.shape(0)) != qp.N + 1 || long(Fz.shape(0)) != qp.N ||
      long(f.shape(0)) != qp.N)
    throw std::invalid_argument(std::string(who) + ": inconsistent stage shapes");
  for (long i = 0; i < qp.N; ++i) {
    qp.A.push_back(block(A, i));
    qp.B.push_back(block(B, i));
    qp.Fz.push_back(block(Fz, i));
    qp.c.push_back(Eigen::Map<const Vec>(c.data() + i * qp.nz, qp.nz));
  }
  for (long i = 0; i <= qp.N; ++i) {
    qp.Q.push_back(block(Q, i));
    qp.q.push_back(Eigen::Map<const Vec>(q.data() + i * qp.nz, qp.nz));
  }
  qp.z0 = Eigen::Map<const Vec>(z0.data(), qp.nz);
  qp.R = CMap(R.data(), qp.m, qp.m);
}

// f(std::integral_constant<int, NZ>, std::integral_constant<int, M>) with the stage sizes (nz, m) fixed
// at compile time where they are those of the benchmark's robot (the state without / with the input
// held in it: planar_4rrr (6, 4), (10, 4)), else Dynamic: the active set's sweep and the interior point's
// factorization. Each fixed pair costs ~14 s of compile time (stagewise_active.cpp: 22 s dynamic only,
// 63-78 s with four pairs, which put the core's build past 2.5 min on 2 cores); the 3-drive robots'
// (6, 3), (9, 3) were dropped for that.
template <class F>
decltype(auto) with_stage_sizes(long nz, long m, F &&f) {
  using std::integral_constant;
  if (nz == 6 && m == 4) return f(integral_constant<int, 6>(), integral_constant<int, 4>());
  if (nz == 10 && m == 4) return f(integral_constant<int, 10>(), integral_constant<int, 4>());
  return f(integral_constant<int, Eigen::Dynamic>(), integral_constant<int, Eigen::Dynamic>());
}

}  // namespace pgpc::stage_arrays
