// Placeholder of the compiled model update (filled in by the model-update work).
#include "bindings.hpp"

namespace pgpc {
void bind_model_update(nb::module_ &m) { m.attr("has_model_update") = false; }
}  // namespace pgpc
