// parallel_gpc._native: the compiled hot paths. Each source file of native/src registers its part
// through one bind_* function declared in bindings.hpp.
#include "bindings.hpp"

NB_MODULE(_native, m) {
  m.doc() = "parallel-gpc compiled core (Pinocchio C++ API); the Python modules are the reference";
  m.attr("pinocchio_version") = PGPC_PINOCCHIO_VERSION;
  pgpc::bind_model_update(m);
  pgpc::bind_stage_jacobian(m);
  pgpc::bind_plant(m);
  pgpc::bind_riccati(m);
  pgpc::bind_riccati_presimulated(m);
  pgpc::bind_stagewise_ipm(m);
  pgpc::bind_stagewise_active(m);
  pgpc::bind_kalman(m);
  pgpc::bind_input_svd(m);
  pgpc::bind_deviation(m);
  pgpc::bind_zoh(m);  // zoh15
}
