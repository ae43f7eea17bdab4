// One stage of the controller's stage models (gpc/riccati.py's stage_models), built from the step's
// (A_d, B_d, c_d): shared by the unconstrained recursion (riccati.cpp) and the torque-limited
// active set (stagewise_active.cpp). Forms: 0 absolute, 1 incremental, 2 delayed, 3 deviation.
#pragma once
#include <Eigen/Core>
#include <stdexcept>
#include <string>

#include "eigen_types.hpp"

namespace pgpc::stage_model {

// the stage state's size: n (absolute, Nu = N) or n + m (the input held in the state)
inline long state_size(int form, long n, long m, long N, long Nu) { return (form == 0 && Nu == N) ? n : n + m; }

// Ā_i (nz × nz), B̄_i (nz × m) and c̄_i (nz) of stage i from the row-major A (n × n), B (n × m) and
// c (n, or nullptr: c̄_i = 0; the deviation form has none); Ā_i, B̄_i and c̄_i may be matrices, maps or
// blocks, reused from step to step (c̄_i written whole: nothing of the last step's c is kept; Ā_i's
// bottom-left block is never written and must start at zero)
template <class MA, class MB, class VC>
void fill(int form, long n, long m, long Nu, long i, const double *A, const double *B, const double *c, MA &&Ai,
          MB &&Bi, VC &&ci) {
  using RM = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  using CM = Eigen::Map<const RM>;
  Ai.topLeftCorner(n, n) = CM(A, n, n);
  ci.setZero();
  if (c && form != 3) ci.head(n) = Eigen::Map<const Eigen::VectorXd>(c, n);
  if (Ai.rows() == n) {
    Bi = CM(B, n, m);
    return;
  }
  const bool held = form != 0 || i >= Nu;  // the input memory feeds x
  if (held) Ai.topRightCorner(n, m) = CM(B, n, m); else Ai.topRightCorner(n, m).setZero();
  if (held) Ai.bottomRightCorner(m, m).setIdentity(); else Ai.bottomRightCorner(m, m).setZero();
  if (form == 2) Bi.topRows(n).setZero(); else Bi.topRows(n) = CM(B, n, m);
  Bi.bottomRows(m).setIdentity();
}

// the stages a step's argument holds: 1 (one model for every stage) or N
struct StepShape {
  long nA, nB, nc;  // nc: 0 (no c), 1 or N
};

// the shapes of a step's (A (n or N·n, n), B (n or N·n, m), c (n or N·n entries; also 0 when not
// `c_required`), x0 (n), u0 (m), r (N − No, p)) checked (`who` names the caller in the error)
inline StepShape check_step(const char *who, long n, long m, long p, long N, long No, const In2 &A, const In2 &B,
                            long c_size, bool c_required, const In1 &x0, const In1 &u0, const In2 &r) {
  // the message built only when a check fails (a string per call otherwise)
  auto fail = [who](const char *what) { throw std::invalid_argument(std::string(who) + what); };
  if (A.shape(0) % size_t(n) != 0 || B.shape(0) % size_t(n) != 0) fail(": bad rows of A or B");
  const long nA = long(A.shape(0)) / n, nB = long(B.shape(0)) / n;
  if (A.shape(1) != size_t(n) || B.shape(1) != size_t(m) || (nA != 1 && nA != N) || (nB != 1 && nB != N))
    fail(": A must be (n or N·n, n), B (n or N·n, m)");
  if (c_size != n && c_size != N * n && (c_required || c_size != 0))
    fail(c_required ? ": c must have n or N·n entries" : ": c must have 0, n or N·n entries");
  if (x0.shape(0) != size_t(n) || u0.shape(0) != size_t(m) || r.shape(0) != size_t(N - No) || r.shape(1) != size_t(p))
    fail(": x0 (n,), u0 (m,), r (N − No, p)");
  return {nA, nB, c_size == 0 ? 0 : c_size == n ? 1 : N};
}
}  // namespace pgpc::stage_model
