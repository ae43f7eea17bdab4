// The inertia terms of one model update: the mass matrix M, the gravity torques g and ∂h/∂v · T of
// the bias forces h(q, v) = τ(q, v, 0) (ReducedModel._bias_rows in model/dynamics.py takes all three
// from computeRNEADerivatives and computeGeneralizedGravity).
//
// h − g = b(v, v) with b symmetric bilinear, so ∂h/∂v(v) · w = 2 b(v, w). When every joint has one
// degree of freedom (revolute, prismatic, helical: v = q̇ and a motion subspace constant in the joint's
// frame), Pinocchio's C(q, v), built from the body-level factorization B_i = ½ Y_i.variation(v_i) +
// ½ (Y_i v_i)×* (rnea.hxx), is the Christoffel-consistent one (Echeandia and Wensing 2021):
// C(q, v) w = b(v, w), so ∂h/∂v · T = 2 C T exactly, without the ∂/∂q half and the second recursion of
// the RNEA derivatives (docs/performance.md). M and g come from what the same pass leaves in Data: the
// world-frame joint Jacobian J and Ag = Ycrb J (Ycrb the composite inertias), so M = Jᵀ Ag on each
// joint's subtree (crba's own WORLD formula) and g = Jᵀ Ycrb (−a_g) = −Agᵀ a_g: no CRBA and no gravity
// recursion. A joint of several degrees of freedom (spherical: its angular velocity is no coordinate
// rate; universal) breaks the symmetry (measured on the suite's RPS robot: 2 C − ∂h/∂v up to 0.4 of ∂h/∂v's largest entry):
// those robots keep the RNEA derivatives, and universal joints the polarization of
// Kinematics::universal_bias_derivative. Oracle: tests/test_native.py (the velocity block against a
// difference of the Python reference's accelerations, which is exact for the quadratic form).
#include "model_update.hpp"

#include "pinocchio/algorithm/rnea-derivatives.hpp"
#include "pinocchio/algorithm/rnea.hpp"

namespace pgpc {

bool ModelUpdate::christoffel_coriolis(const pinocchio::Model &model) {
  for (pinocchio::JointIndex i = 1; i < static_cast<pinocchio::JointIndex>(model.njoints); ++i) {
    const std::string kind = model.joints[i].shortname();
    if (model.joints[i].nv() != 1 || kind.find("Composite") != std::string::npos ||
        kind.find("Mimic") != std::string::npos)
      return false;
  }
  return true;
}

void ModelUpdate::inertia_terms(const Vec &v) {
  const auto &model = kin.model;
  auto &data = kin.data;
  if (!christoffel_) {
    pinocchio::computeRNEADerivatives(model, data, q_, v, zero_v_);  // data.dtau_dv = ∂h/∂v, data.M
    M_ = data.M;
    M_.triangularView<Eigen::StrictlyLower>() = M_.transpose().triangularView<Eigen::StrictlyLower>();
    if (!cfg.universal.empty())
      kin.universal_bias_derivative(q_, v, T_, DT_);
    else
      DT_.noalias() = data.dtau_dv * T_;
    g_ = pinocchio::computeGeneralizedGravity(model, data, q_);
    return;
  }
  pinocchio::computeCoriolisMatrix(model, data, q_, v);
  M_.setZero(nv, nv);
  for (pinocchio::JointIndex i = 1; i < static_cast<pinocchio::JointIndex>(model.njoints); ++i) {
    const Index iv = model.joints[i].idx_v(), n = model.joints[i].nv(), sub = data.nvSubtree[i];
    M_.block(iv, iv, n, sub).noalias() =
        data.J.middleCols(iv, n).transpose().lazyProduct(data.Ag.middleCols(iv, sub));
  }
  M_.triangularView<Eigen::StrictlyLower>() = M_.transpose().triangularView<Eigen::StrictlyLower>();
  g_.noalias() = -(data.Ag.transpose() * model.gravity.toVector());
  DT_.noalias() = 2.0 * data.C.lazyProduct(T_);
}
}  // namespace pgpc
