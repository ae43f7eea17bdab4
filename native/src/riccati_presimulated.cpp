// The nonlinear form's unconstrained step in one call (gpc/riccati.py, RiccatiSolver.presimulated):
// the compiled pre-simulation (10) of a ModelUpdate (model_update.cpp), then the Riccati recursion of
// the deviation model along it (riccati.cpp, form 3) with the targets w − ŷ_sim formed in place. The
// Python path (simulate_factorized, then Riccati.solve or lq_tracking) is the reference. The limited step's
// pre-simulation, presimulated_stages: simulate_factorized's arrays and null(B_d(X0)) in one call.
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include <nanobind/eigen/dense.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/string.h>

#include "bindings.hpp"
#include "input_svd.hpp"
#include "model_update.hpp"
#include "riccati.hpp"

namespace pgpc {
namespace {
// (E (N, n_x, n_aug), X (N + 1, n_x), v (Nu·m), J, message, U (N, n_u), null): the pre-simulation from
// X0 along u_seq (N, n_u) with the offset, and the plan of the deviation model along it — Δu = v, the
// inputs U — and the null(B_d(X0)) rows (rank above null_rtol·σ_max); a failed recursion (R + BᵀPB not
// positive definite, v not finite) gives v = NaN, J = inf and its message, the pre-simulation kept
// null(B_d) at X0 of a pre-simulation's E (gpc/redundancy.py null_basis: the same rank rule): its rows,
// None when B_0 is not finite
nb::object first_null(const double *Es, long n, long m, long n_aug, double null_rtol) {
  try {
    const Eigen::Map<const RowMat, 0, Eigen::OuterStride<>> B0(Es + n, n, m, Eigen::OuterStride<>(n_aug));
    return nb::cast(RowMat(null_rows(B0, null_rtol)));
  } catch (const std::domain_error &) {
    return nb::none();
  }
}

nb::tuple riccati_presimulated(Riccati &ric, ModelUpdate &update, const Vec &X0, In2 u, double Ts,
                               std::optional<Vec> offset, In2 w, double null_rtol) {
  const long N = ric.N, n = ric.n, m = ric.m;
  if (ric.form != 3)
    throw std::invalid_argument("riccati_presimulated: the Riccati solve must be of the deviation form (3)");
  if (update.n_x != n || update.n_u != m)
    throw std::invalid_argument("riccati_presimulated: the model's n_x, n_u differ from the Riccati solve's");
  if (X0.size() != n || u.shape(0) != size_t(N) || u.shape(1) != size_t(m))
    throw std::invalid_argument("riccati_presimulated: X0 must be (n_x,) and u_seq (N, n_u)");
  if (offset && offset->size() != n) throw std::invalid_argument("riccati_presimulated: offset must be (n_x,)");
  if (w.shape(0) != size_t(N - ric.No) || w.shape(1) != size_t(ric.p))
    throw std::invalid_argument("riccati_presimulated: w must be (N − No, p)");
  double *Es, *Xs, *v;
  auto E = owned_array({size_t(N), size_t(n), size_t(update.n_aug)}, &Es);
  auto X = owned_array({size_t(N + 1), size_t(n)}, &Xs);
  auto V = owned_array({size_t(ric.Nu * m)}, &v);
  update.simulate(X0, u.data(), N, Ts, offset ? &*offset : nullptr, Es, Xs);  // its errors propagate
  double J;
  std::string message;
  try {
    J = ric.solve_deviation(Es, update.n_aug, Xs, w.data(), v);
  } catch (const std::runtime_error &exc) {
    message = exc.what();
    J = std::numeric_limits<double>::infinity();
    for (long i = 0; i < ric.Nu * m; ++i) v[i] = std::numeric_limits<double>::quiet_NaN();
  }
  // the plan's inputs u(i) = u_seq(i) + Σ_{l ≤ min(i, Nu−1)} Δu(l) (gpc/prediction.py cumulative_map)
  double *U;
  auto Uarr = owned_array({size_t(N), size_t(m)}, &U);
  Eigen::Map<RowMat> Um(U, N, m);
  Um = Eigen::Map<const RowMat>(u.data(), N, m);
  Vec sum = Vec::Zero(m);
  for (long i = 0; i < N; ++i) {
    if (i < ric.Nu) sum += Eigen::Map<const Vec>(v + i * m, m);
    Um.row(i) += sum.transpose();
  }
  return nb::make_tuple(E, X, V, J, message, Uarr, first_null(Es, n, m, update.n_aug, null_rtol));
}

// (A (N, n_x, n_x), B (N, n_x, n_u), c (N, n_x), X (N + 1, n_x), null): the pre-simulation (10) from X0 along
// u_seq (N, n_u) with the offset — simulate_factorized's arrays, each contiguous (the limited step's
// RiccatiActive reads A and B in place) — and the null(B_d(X0)) rows as riccati_presimulated's
nb::tuple presimulated_stages(ModelUpdate &update, const Vec &X0, In2 u, double Ts, std::optional<Vec> offset,
                              double null_rtol) {
  const long N = long(u.shape(0)), n = update.n_x, m = update.n_u, na = update.n_aug;
  if (X0.size() != n || u.shape(1) != size_t(m))
    throw std::invalid_argument("presimulated_stages: X0 must be (n_x,) and u_seq (N, n_u)");
  if (offset && offset->size() != n) throw std::invalid_argument("presimulated_stages: offset must be (n_x,)");
  std::vector<double> E(size_t(N * n * na));
  double *As, *Bs, *cs, *Xs;
  auto A = owned_array({size_t(N), size_t(n), size_t(n)}, &As);
  auto B = owned_array({size_t(N), size_t(n), size_t(m)}, &Bs);
  auto c = owned_array({size_t(N), size_t(n)}, &cs);
  auto X = owned_array({size_t(N + 1), size_t(n)}, &Xs);
  update.simulate(X0, u.data(), N, Ts, offset ? &*offset : nullptr, E.data(), Xs);  // its errors propagate
  const Eigen::Map<const RowMat> Em(E.data(), N * n, na);  // rows (i, r): [A_i | B_i | c_i] of row r
  Eigen::Map<RowMat>(As, N * n, n) = Em.leftCols(n);
  Eigen::Map<RowMat>(Bs, N * n, m) = Em.middleCols(n, m);
  Eigen::Map<Vec>(cs, N * n) = Em.col(na - 1);
  return nb::make_tuple(A, B, c, X, first_null(E.data(), n, m, na, null_rtol));
}
}  // namespace

void bind_riccati_presimulated(nb::module_ &m) {
  m.def("riccati_presimulated", &riccati_presimulated, nb::arg("riccati"), nb::arg("update"), nb::arg("X0"),
        nb::arg("u_seq"), nb::arg("Ts"), nb::arg("offset").none(), nb::arg("w"),
        nb::arg("null_rtol"),
        "(E (N, n_x, n_aug), X (N + 1, n_x), v (Nu·m,), J, message, U (N, n_u), null(B_d(X0)) rows or None) of a "
        "deviation-form Riccati and a ModelUpdate: the pre-simulation (10) and its plan in one call "
        "(see gpc/riccati.py)");
  m.def("presimulated_stages", &presimulated_stages, nb::arg("update"), nb::arg("X0"), nb::arg("u_seq"), nb::arg("Ts"),
        nb::arg("offset").none(), nb::arg("null_rtol"),
        "(A (N, n_x, n_x), B (N, n_x, n_u), c (N, n_x), X (N + 1, n_x), null(B_d(X0)) rows or None) of a "
        "ModelUpdate's pre-simulation (10), each contiguous: the nonlinear form's limited step (see gpc/riccati.py)");
}
}  // namespace pgpc
