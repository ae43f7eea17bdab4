// One stage of the controller's stage models (gpc/riccati.py's stage_models), built from the step's
// (A_d, B_d, c_d): shared by the unconstrained recursion (riccati.cpp) and the torque-limited
// active set (stagewise_active.cpp). Forms: 0 absolute, 1 incremental, 2 delayed, 3 deviation.
#pragma once
#include <Eigen/Core>

namespace pgpc::stage_model {

// the stage state's size: n (absolute, Nu = N) or n + m (the input held in the state)
inline long state_size(int form, long n, long m, long N, long Nu) { return (form == 0 && Nu == N) ? n : n + m; }

// Ā_i (nz × nz), B̄_i (nz × m) and c̄_i (nz) of stage i from the row-major A (n × n), B (n × m) and
// c (n, or nullptr: c̄ left as it is); Ā_i, B̄_i and c̄_i may be matrices, maps or blocks
template <class MA, class MB, class VC>
void fill(int form, long n, long m, long Nu, long i, const double *A, const double *B, const double *c, MA &&Ai,
          MB &&Bi, VC &&ci) {
  using RM = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  using CM = Eigen::Map<const RM>;
  Ai.topLeftCorner(n, n) = CM(A, n, n);
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
}  // namespace pgpc::stage_model
