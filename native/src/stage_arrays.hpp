// The stage-wise solvers' view of their numpy arguments (stagewise_ipm.cpp, stagewise_active.cpp):
// C-contiguous float64 arrays and the per-stage blocks of an (N, a, b) array.
#pragma once
#include <nanobind/eigen/dense.h>
#include <nanobind/ndarray.h>

#include "bindings.hpp"

namespace pgpc::stage_arrays {
using RowMat = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using CMap = Eigen::Map<const RowMat>;
using In1 = nb::ndarray<const double, nb::ndim<1>, nb::c_contig, nb::device::cpu>;
using In2 = nb::ndarray<const double, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using In3 = nb::ndarray<const double, nb::ndim<3>, nb::c_contig, nb::device::cpu>;

// stage i of an (N, a, b) row-major array, a view (no copy)
template <class T>
CMap block(const T &arr, long i) {
  const long a = long(arr.shape(1)), b = long(arr.shape(2));
  return CMap(arr.data() + i * a * b, a, b);
}
}  // namespace pgpc::stage_arrays
