// A Pinocchio model from its serialization (Model.saveToString() on the Python side).
// One translation unit instantiates Pinocchio's Boost.Serialization of the model (model_io.cpp):
// the heaviest templates of the core, compiled once instead of in every file that needs a model.
#pragma once

#include <string>

#include "pinocchio/multibody.hpp"  // Model (multibody/model.hpp is a deprecated alias of it in 4.x)

namespace pgpc {
// The model serialized as text by pinocchio::Model::saveToString (same Pinocchio version).
pinocchio::Model load_model(const std::string &text);
}  // namespace pgpc
