// Pinocchio's text deserialization of a model, instantiated here only (see model_io.hpp).
#include "model_io.hpp"

#include "pinocchio/serialization.hpp"

namespace pgpc {
pinocchio::Model load_model(const std::string &text) {
  pinocchio::Model model;
  model.loadFromString(text);
  return model;
}
}  // namespace pgpc
