// Pinocchio algorithms called from their compiled copy in libpinocchio_default, not compiled here.
//
// libpinocchio_default holds explicit instantiations of Pinocchio's algorithms for double, VectorXd
// arguments and the default joint collection, and Pinocchio's headers declare them `extern template`.
// That does not stop GCC from compiling them again: a function template declared `inline` (as
// constraintDynamics, initConstraintDynamics and computeFrameJacobian are) is instantiated in every
// translation unit that calls it, extern template or not, and constraintDynamics pulls in the whole
// constrained-dynamics algorithm (Cholesky of the constraints, CRBA, the Delassus operator, and the
// geometry headers through them). Here they are declared only, with the template signature of
// Pinocchio's own declaration (so the mangled name is that of the library's instantiation), and a
// file that includes this header instead of pinocchio/algorithm/constrained-dynamics.hpp and
// frames.hpp has no body to instantiate: the call links to the library (`nm -C` on the object shows
// them undefined, `U`). Call them with exactly the argument types of the library's instantiations
// (Model, Data, VectorXd, Data::Matrix6x, the RigidConstraint{Model,Data}Vector of
// pinocchio/constraints.hpp): another type would need an instantiation the library lacks and the
// module would fail to import with an undefined symbol. In a unity unit where another file includes
// the real header, the body is visible again and compiled (harmless, only slower). The declarations
// lack Pinocchio's `inline`: the standard wants it on every declaration, GCC and Clang (Itanium ABI:
// the same mangled name) do not care. Build time: docs/performance.md#building-the-core.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "pinocchio/algorithm/proximal.hpp"
#include "pinocchio/constraints.hpp"
#include "pinocchio/macros.hpp"
#include "pinocchio/multibody.hpp"  // Model, Data (multibody/model.hpp is a deprecated alias of it in 4.x)

// RigidConstraintModelTpl is marked deprecated ("The API will change"): Pinocchio's own declaration
// silences that warning the same way
PINOCCHIO_COMPILER_DIAGNOSTIC_PUSH
PINOCCHIO_COMPILER_DIAGNOSTIC_IGNORED_DEPRECECATED_DECLARATIONS
namespace pinocchio {

// pinocchio/algorithm/constrained-dynamics.hpp
template <typename Scalar, int Options, template <typename, int> class JointCollectionTpl, class ConstraintModel,
          class ConstraintModelAllocator, class ConstraintData, class ConstraintDataAllocator>
void initConstraintDynamics(const ModelTpl<Scalar, Options, JointCollectionTpl> &model,
                            DataTpl<Scalar, Options, JointCollectionTpl> &data,
                            const std::vector<ConstraintModel, ConstraintModelAllocator> &contact_models,
                            const std::vector<ConstraintData, ConstraintDataAllocator> &contact_datas);

// pinocchio/algorithm/constrained-dynamics.hpp (with ProximalSettings)
template <typename Scalar, int Options, template <typename, int> class JointCollectionTpl, typename ConfigVectorType,
          typename TangentVectorType1, typename TangentVectorType2, class ConstraintModelAllocator,
          class ConstraintDataAllocator>
const typename DataTpl<Scalar, Options, JointCollectionTpl>::TangentVectorType &constraintDynamics(
    const ModelTpl<Scalar, Options, JointCollectionTpl> &model, DataTpl<Scalar, Options, JointCollectionTpl> &data,
    const Eigen::MatrixBase<ConfigVectorType> &q, const Eigen::MatrixBase<TangentVectorType1> &v,
    const Eigen::MatrixBase<TangentVectorType2> &tau,
    const std::vector<RigidConstraintModelTpl<Scalar, Options>, ConstraintModelAllocator> &contact_models,
    std::vector<RigidConstraintDataTpl<Scalar, Options>, ConstraintDataAllocator> &contact_datas,
    ProximalSettingsTpl<Scalar> &settings);

// pinocchio/algorithm/frames.hpp (with a reference frame)
template <typename Scalar, int Options, template <typename, int> class JointCollectionTpl, typename ConfigVectorType,
          typename Matrix6xLike>
void computeFrameJacobian(const ModelTpl<Scalar, Options, JointCollectionTpl> &model,
                          DataTpl<Scalar, Options, JointCollectionTpl> &data,
                          const Eigen::MatrixBase<ConfigVectorType> &q, const FrameIndex frame_id,
                          const ReferenceFrame reference_frame, const Eigen::MatrixBase<Matrix6xLike> &J);

}  // namespace pinocchio
PINOCCHIO_COMPILER_DIAGNOSTIC_POP
