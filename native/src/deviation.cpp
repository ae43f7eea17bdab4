// Condensing of the nonlinear form's deviation model, eq. (10)–(12): the compiled twin of the
// time-varying recursion that gpc/prediction.py simulative_prediction runs through condense (the
// reference). Along a pre-simulated (or re-simulated) trajectory, δX(i+1) = A_i δX(i) + B_i δu(i)
// with δu(i) = Σ_{l ≤ min(i, Nu−1)} Δu(l); G maps v = [Δu(0) … Δu(Nu−1)] to the penalized outputs
// C δX(j), j = No+1..N. The nonlinear MPC iterations (gpc/nmpc.py) condense with it where a step needs
// G, and take G v alone (deviation_response, one pass) where the Riccati recursion solves the step.
#include <algorithm>
#include <stdexcept>
#include <string>

#include <nanobind/eigen/dense.h>
#include <nanobind/ndarray.h>

#include "bindings.hpp"
#include "eigen_types.hpp"

namespace pgpc {
namespace {

// The sizes of a deviation model's arrays (N stages, n states, m inputs, p outputs), checked once
struct Sizes {
  long N, n, m, p;
};

Sizes checked_sizes(const char *who, const In3 &A, const In3 &B, const In2 &C, long No, long Nu) {
  const Sizes z{static_cast<long>(A.shape(0)), static_cast<long>(A.shape(1)), static_cast<long>(B.shape(2)),
                static_cast<long>(C.shape(0))};
  if (A.shape(2) != size_t(z.n) || B.shape(0) != size_t(z.N) || B.shape(1) != size_t(z.n) || C.shape(1) != size_t(z.n))
    throw std::invalid_argument(std::string(who) + ": A must be (N, n, n), B (N, n, m) and C (p, n)");
  if (No < 0 || No >= z.N || Nu < 1 || Nu > z.N)
    throw std::invalid_argument(std::string(who) + ": need 0 ≤ No < N and 1 ≤ Nu ≤ N");
  return z;
}

/// ((N − No)·p, Nu·m) G of ŷ = ŷ_sim + G v: S(i) = ∂δX(i)/∂v, S(0) = 0, S(i+1) = A_i S(i) + B_i in
/// every column block l ≤ min(i, Nu − 1); block row j − No − 1 of G is C S(j). S(i) is zero past its
/// first min(i, Nu) column blocks (causality), so step i multiplies those alone.
RowMat condense_deviation(In3 A, In3 B, In2 C, long No, long Nu) {
  const auto [N, n, m, p] = checked_sizes("condense_deviation", A, B, C, No, Nu);
  const Eigen::Map<const RowMat> Cm(C.data(), p, n);
  RowMat G = RowMat::Zero((N - No) * p, Nu * m);
  Mat S = Mat::Zero(n, Nu * m), T(n, Nu * m);
  for (long i = 0; i < N; ++i) {
    const Eigen::Map<const RowMat> Ai(A.data() + i * n * n, n, n), Bi(B.data() + i * n * m, n, m);
    const long cols = std::min(i, Nu) * m;  // the columns of S(i) that can be nonzero
    if (cols > 0) {
      T.leftCols(cols).noalias() = Ai * S.leftCols(cols);
      S.leftCols(cols) = T.leftCols(cols);
    }
    const long blocks = std::min(i + 1, Nu);
    for (long l = 0; l < blocks; ++l) S.middleCols(l * m, m) += Bi;
    if (i + 1 > No) G.block((i - No) * p, 0, p, blocks * m).noalias() = Cm * S.leftCols(blocks * m);
  }
  return G;
}

/// ((N − No)·p,) G v without G: the deviation model run once from δX(0) = 0 with δu(i) = Σ_{l ≤ min(i, Nu−1)}
/// Δu(l) (work O(N n²) instead of condensing's O(N² n² m)); the rows of G v are C δX(j), j = No+1..N.
Vec deviation_response(In3 A, In3 B, In2 C, In1 v, long No, long Nu) {
  const auto [N, n, m, p] = checked_sizes("deviation_response", A, B, C, No, Nu);
  if (v.shape(0) != size_t(Nu * m)) throw std::invalid_argument("deviation_response: v must be (Nu·m,)");
  const Eigen::Map<const RowMat> Cm(C.data(), p, n);
  Vec out((N - No) * p), x = Vec::Zero(n), next(n), du = Vec::Zero(m);
  for (long i = 0; i < N; ++i) {
    const Eigen::Map<const RowMat> Ai(A.data() + i * n * n, n, n), Bi(B.data() + i * n * m, n, m);
    if (i < Nu) du += Eigen::Map<const Vec>(v.data() + i * m, m);
    next.noalias() = Ai * x;
    next.noalias() += Bi * du;
    x.swap(next);
    if (i + 1 > No) out.segment((i - No) * p, p).noalias() = Cm * x;
  }
  return out;
}
}  // namespace

void bind_deviation(nb::module_ &m) {
  m.def("condense_deviation", &condense_deviation, nb::arg("A_seq"), nb::arg("B_seq"), nb::arg("C"), nb::arg("No"),
        nb::arg("Nu"),
        "((N − No)·p, Nu·m) G of the nonlinear form's deviation model (simulative_prediction): ŷ(k+No+1..k+N) = "
        "ŷ_sim + G [Δu(0) … Δu(Nu−1)] for the stage models A_seq (N, n, n), B_seq (N, n, m) and output matrix C (p, n)");
  m.def("deviation_response", &deviation_response, nb::arg("A_seq"), nb::arg("B_seq"), nb::arg("C"), nb::arg("v"),
        nb::arg("No"), nb::arg("Nu"),
        "((N − No)·p,) G v of condense_deviation's G without forming G: one pass of the deviation model (O(N))");
}
}  // namespace pgpc
