// The Eigen matrix and nanobind array types the native sources share (one declaration each).
#pragma once

#include <Eigen/Core>
#include <initializer_list>
#include <nanobind/ndarray.h>

namespace pgpc {
namespace nb = nanobind;

using Mat = Eigen::MatrixXd;  // column-major, Eigen's default
using Vec = Eigen::VectorXd;
using Index = Eigen::Index;
using RowMat = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;  // a NumPy C-order matrix
using Mat3x = Eigen::Matrix<double, 3, Eigen::Dynamic>;  // three rows of a frame Jacobian (linear or angular)
using Mat6x = Eigen::Matrix<double, 6, Eigen::Dynamic>;  // a frame Jacobian, (6, nv)
using Vec6 = Eigen::Matrix<double, 6, 1>;  // a spatial motion [linear; angular] (a frame Jacobian's column)

// C-contiguous float64 NumPy arrays on the CPU: read-only inputs of D dimensions, writable outputs
template <int D>
using In = nb::ndarray<const double, nb::ndim<D>, nb::c_contig, nb::device::cpu>;
template <int D>
using Out = nb::ndarray<double, nb::ndim<D>, nb::c_contig, nb::device::cpu>;
using In1 = In<1>;
using In2 = In<2>;
using In3 = In<3>;
using Out1 = Out<1>;
using Out2 = Out<2>;
// a read-only float64 array of any shape (nanobind converts another dtype or layout)
using Floats = nb::ndarray<const double, nb::c_contig, nb::device::cpu>;

// a new NumPy float64 array of `shape` owning its buffer, written through *data
inline nb::ndarray<nb::numpy, double> owned_array(std::initializer_list<size_t> shape, double **data) {
  size_t size = 1;
  for (size_t s : shape) size *= s;
  double *buf = new double[size > 0 ? size : 1];
  nb::capsule owner(buf, [](void *p) noexcept { delete[] static_cast<double *>(p); });
  *data = buf;
  return nb::ndarray<nb::numpy, double>(buf, shape.size(), shape.begin(), owner);
}
}  // namespace pgpc
