// The two singular value decompositions of every control step, compiled: the condition number of
// the input gain (gpc/protocol.py condition_number) and the null(B_d) basis that keeps the drives
// from fighting (gpc/redundancy.py null_basis). The Python functions (LAPACK gesdd through scipy)
// are the reference; on the robots' 3×4 … 12×8 matrices a call there is mostly the wrapper's
// overhead (array conversion, workspace). Eigen only (no Pinocchio): this file compiles on its own.
#include <Eigen/SVD>
#include <cmath>
#include <limits>
#include <nanobind/eigen/dense.h>
#include <nanobind/ndarray.h>
#include <stdexcept>

#include "bindings.hpp"
#include "input_svd.hpp"

namespace pgpc {
namespace {
// any float64 2-D array, strided views included (a slice of the pre-simulation's stack): read in
// place, no conversion to a column-major copy (which costs more than the SVD at these sizes)
using In2 = nb::ndarray<const double, nb::ndim<2>, nb::device::cpu>;
using Strided = Eigen::Map<const Mat, 0, Eigen::Stride<Eigen::Dynamic, Eigen::Dynamic>>;

Strided view(const In2 &a) {
  return Strided(a.data(), Index(a.shape(0)), Index(a.shape(1)),
                 Eigen::Stride<Eigen::Dynamic, Eigen::Dynamic>(a.stride(1), a.stride(0)));
}

// σ_max/σ_min of G (min(p, m) singular values); inf when G is empty, not finite or singular
double condition_number(const In2 &array) {
  const Strided G = view(array);
  const double inf = std::numeric_limits<double>::infinity();
  if (G.size() == 0 || !G.allFinite()) return inf;
  Eigen::JacobiSVD<Mat> svd(G);
  const Vec &s = svd.singularValues();
  const double smin = s[s.size() - 1];
  if (!(smin > 0.0)) return inf;
  const double cond = s[0] / smin;
  return std::isfinite(cond) ? cond : inf;
}

// null_rows (input_svd.hpp) of an array, read in place
Mat null_basis(const In2 &array, double rtol) { return null_rows(view(array), rtol); }
}  // namespace

void bind_input_svd(nb::module_ &m) {
  m.def("condition_number", &condition_number, nb::arg("G"),
        "σ_max/σ_min of G (inf when empty, not finite or singular): gpc.protocol.condition_number");
  m.def("null_basis", &null_basis, nb::arg("B"), nb::arg("rtol"),
        "(m − rank, m) orthonormal rows spanning null(B), rank counted above rtol·σ_max; (0, m) at full "
        "column rank: gpc.redundancy.null_basis");
}
}  // namespace pgpc
