// A new NumPy array of doubles that owns its buffer, for the bindings that fill their results in place
// (model_update.cpp, stage_jacobian.cpp).
#pragma once

#include <cstddef>
#include <initializer_list>

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

namespace pgpc {

using Array = nanobind::ndarray<nanobind::numpy, double>;

// shape's array (uninitialized), its buffer in *data
inline Array new_array(std::initializer_list<size_t> shape, double **data) {
  size_t n = 1;
  for (size_t d : shape) n *= d;
  double *buf = new double[n > 0 ? n : 1];
  nanobind::capsule owner(buf, [](void *p) noexcept { delete[] static_cast<double *>(p); });
  *data = buf;
  return Array(buf, shape.size(), shape.begin(), owner);
}

}  // namespace pgpc
