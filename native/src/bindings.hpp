// Registration functions of the parts of parallel_gpc._native (one per source file).
#pragma once
#include <nanobind/nanobind.h>

namespace pgpc {
namespace nb = nanobind;
void bind_model_update(nb::module_ &m);  // model_update.cpp
void bind_plant(nb::module_ &m);         // plant.cpp
void bind_riccati(nb::module_ &m);       // riccati.cpp
void bind_riccati_presimulated(nb::module_ &m);  // riccati_presimulated.cpp (after bind_riccati, bind_model_update)
void bind_stage_jacobian(nb::module_ &m);  // stage_jacobian.cpp (after bind_model_update)
void bind_stagewise_ipm(nb::module_ &m); // stagewise_ipm.cpp
void bind_stagewise_active(nb::module_ &m);  // stagewise_active.cpp
void bind_kalman(nb::module_ &m);        // kalman.cpp
void bind_input_svd(nb::module_ &m);     // input_svd.cpp
void bind_deviation(nb::module_ &m);     // deviation.cpp
void bind_zoh(nb::module_ &m);           // zoh.cpp (zoh15: the exponential kernels' test entry points)
}  // namespace pgpc
