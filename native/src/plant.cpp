// Compiled plant step: RK4 sub-steps of Pinocchio's constraintDynamics over one sample.
//
// The reference is parallel_gpc.model.plant.ConstrainedPlant (Python): the same legacy
// RigidConstraintModel closures (CONTACT_3D / CONTACT_6D, LOCAL, Baumgarte Kp/Kd), the same
// ProximalSettings, the same RK4 on the configuration manifold (q ⊕ h v by pinocchio::integrate when
// nq ≠ nv, q + h v otherwise), the same order of operations. The projection onto the closures after
// the sample stays in Python (it is the robot's assembly, compiled elsewhere).
#include "bindings.hpp"
#include "eigen_types.hpp"
#include "model_io.hpp"

#include <cmath>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include <nanobind/eigen/dense.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <pinocchio/algorithm/joint-configuration.hpp>
#include <pinocchio/spatial.hpp>

#include "pinocchio_compiled.hpp"  // constraintDynamics & co. from libpinocchio_default, not compiled here

namespace pgpc {
namespace {

namespace pin = pinocchio;
// The argument types of Pinocchio's precompiled constraintDynamics (libpinocchio_default): with them
// the call links to the library instead of instantiating the algorithm here (build time, CMakeLists.txt)
using ConstraintModels = pin::RigidConstraintModelVector;
using ConstraintDatas = pin::RigidConstraintDataVector;
using CRef = nb::DRef<const Vec>;

/// A force f on a task-space output y = rows of [p; log3(R_refᵀ R)] of one frame acts as Hᵀ f
/// (H = ∂y/∂v, the rows of the frame Jacobian in LOCAL_WORLD_ALIGNED, the angular rows mapped by
/// Jlog3(R_refᵀ R) Rᵀ), as parallel_gpc.model.outputs.TaskOutput.jacobian.
struct TaskForce {
  pin::FrameIndex frame = 0;
  std::vector<int> rows;  // indices in [x, y, z, rx, ry, rz]
  Eigen::Matrix3d R_ref = Eigen::Matrix3d::Identity();
  pin::Data::Matrix6x J;

  /// tau += Hᵀ f at q (updates the placements in data).
  void add(const pin::Model &model, pin::Data &data, const Vec &q, const CRef &f, Vec &tau) {
    J.setZero(6, model.nv);
    pin::computeFrameJacobian(model, data, q, frame, pin::LOCAL_WORLD_ALIGNED, J);
    const Eigen::Matrix3d &R = data.oMf[frame].rotation();
    Eigen::Matrix3d Jlog;
    pin::Jlog3(Eigen::Matrix3d(R_ref.transpose() * R), Jlog);
    const Mat3x H_ang = Jlog * (R.transpose() * J.bottomRows<3>());
    for (std::size_t i = 0; i < rows.size(); ++i) {
      const int r = rows[i];
      if (r < 3) {
        tau.noalias() += J.row(r).transpose() * f[Index(i)];
      } else {
        tau.noalias() += H_ang.row(r - 3).transpose() * f[Index(i)];
      }
    }
  }
};

class Plant {
 public:
  Plant(const std::string &model_text, const std::vector<int> &dims, const std::vector<int> &joints_a,
        const std::vector<Eigen::Matrix4d> &placements_a, const std::vector<int> &joints_b,
        const std::vector<Eigen::Matrix4d> &placements_b, double kp, double kd, double accuracy, double mu,
        int max_iter)
      : model_(load_model(model_text)), data_(model_), prox_(accuracy, mu, max_iter) {
    flat_ = model_.nq == model_.nv;
    const std::size_t n = dims.size();
    if (joints_a.size() != n || placements_a.size() != n || joints_b.size() != n || placements_b.size() != n) {
      throw nb::value_error("Plant: dims, joints_a, placements_a, joints_b, placements_b must have one entry per closure");
    }
    const pin::BaumgarteCorrectorParametersTpl<double> baumgarte(kp, kd);
    for (std::size_t k = 0; k < n; ++k) {
      if (dims[k] != 3 && dims[k] != 6) {
        throw nb::value_error(("Plant: closure " + std::to_string(k) + " has dimension " + std::to_string(dims[k]) +
                               "; valid: 3 (point) or 6 (weld)").c_str());
      }
      for (int j : {joints_a[k], joints_b[k]}) {
        if (j < 0 || j >= model_.njoints) {
          throw nb::value_error(("Plant: closure " + std::to_string(k) + " names joint " + std::to_string(j) +
                                 ", outside [0, " + std::to_string(model_.njoints) + ")").c_str());
        }
      }
      pin::RigidConstraintModel cm(dims[k] == 3 ? pin::CONTACT_3D : pin::CONTACT_6D, model_,
                                   pin::JointIndex(joints_a[k]), to_se3(placements_a[k]),
                                   pin::JointIndex(joints_b[k]), to_se3(placements_b[k]), pin::LOCAL);
      cm.setBaumgarteCorrectorParameters(baumgarte);
      cms_.push_back(cm);
    }
    for (const auto &cm : cms_) cds_.push_back(pin::RigidConstraintData(cm));
    pin::initConstraintDynamics(model_, data_, cms_, cds_);
  }

  // not copyable nor movable: nanobind then compiles no copy/move of the instance (nor of Pinocchio's
  // Model, Data and constraint vectors inside it), which the Python side never makes (build time)
  Plant(const Plant &) = delete;
  Plant &operator=(const Plant &) = delete;

  void set_task_output(int frame, const std::vector<int> &rows, const Eigen::Matrix3d &R_ref) {
    if (frame < 0 || frame >= int(model_.nframes)) {
      throw nb::value_error(("Plant.set_task_output: frame " + std::to_string(frame) + " outside [0, " +
                             std::to_string(model_.nframes) + ")").c_str());
    }
    for (int r : rows) {
      if (r < 0 || r > 5) throw nb::value_error("Plant.set_task_output: rows must lie in [0, 5] (x, y, z, rx, ry, rz)");
    }
    task_.frame = pin::FrameIndex(frame);
    task_.rows = rows;
    task_.R_ref = R_ref;
    has_task_ = true;
  }

  /// q̈ (nv,) of the constrained dynamics for the generalized force tau (+ Hᵀ f_task).
  Vec accelerations(CRef q, CRef v, CRef tau, CRef f_task) {
    check_sizes(q, v, tau, f_task);
    return acc(Vec(q), Vec(v), tau, f_task);
  }

  /// One sample of length Ts: `substeps` RK4 steps with tau (and f_task) held; returns (q, v).
  std::pair<Vec, Vec> integrate(CRef q0, CRef v0, CRef tau, CRef f_task, double Ts, int substeps) {
    check_sizes(q0, v0, tau, f_task);
    if (!(Ts > 0.0) || substeps < 1) {
      throw nb::value_error(("Plant.integrate: Ts = " + std::to_string(Ts) + " s and substeps = " +
                             std::to_string(substeps) + "; valid: Ts > 0 and substeps >= 1").c_str());
    }
    Vec q = q0, v = v0;
    const double h = Ts / substeps;
    {
      nb::gil_scoped_release release;  // pure C++ from here on: other Python threads may run
      for (int s = 0; s < substeps; ++s) rk4(q, v, tau, f_task, h);
    }
    return {std::move(q), std::move(v)};
  }

  /// Closure forces of the last dynamics call: the linear part of each contact force, stacked (3 k,).
  Vec contact_forces() const {
    Vec out(3 * Index(cds_.size()));
    for (std::size_t k = 0; k < cds_.size(); ++k) out.segment<3>(3 * Index(k)) = cds_[k].contact_force.linear();
    return out;
  }

  int nq() const { return model_.nq; }
  int nv() const { return model_.nv; }

 private:
  static pin::SE3 to_se3(const Eigen::Matrix4d &M) {
    return pin::SE3(Eigen::Matrix3d(M.topLeftCorner<3, 3>()), Eigen::Vector3d(M.topRightCorner<3, 1>()));
  }

  void check_sizes(const CRef &q, const CRef &v, const CRef &tau, const CRef &f_task) const {
    if (q.size() != model_.nq || v.size() != model_.nv || tau.size() != model_.nv) {
      throw nb::value_error(("Plant: q, v, tau have sizes " + std::to_string(q.size()) + ", " + std::to_string(v.size()) +
                             ", " + std::to_string(tau.size()) + "; the model needs nq = " + std::to_string(model_.nq) +
                             ", nv = " + std::to_string(model_.nv) + ", nv")
                                .c_str());
    }
    if (f_task.size() != 0 && (!has_task_ || f_task.size() != Index(task_.rows.size()))) {
      throw nb::value_error("Plant: f_task must be empty, or have one entry per task-space output row (set_task_output)");
    }
  }

  // q, v, tau_ as Vec (Eigen::VectorXd): Pinocchio's precompiled instantiation (see ConstraintModels)
  const Vec &acc(const Vec &q, const Vec &v, const CRef &tau, const CRef &f_task) {
    tau_ = tau;
    if (f_task.size() != 0) task_.add(model_, data_, q, f_task, tau_);
    return pin::constraintDynamics(model_, data_, q, v, tau_, cms_, cds_, prox_);
  }

  void step_q(const Vec &q, const Vec &dv, Vec &out) const {
    if (flat_) {
      out = q + dv;
    } else {
      out.resize(model_.nq);
      pin::integrate(model_, q, dv, out);
    }
  }

  /// One classical RK4 step of (q̇, v̇) = (v, q̈) on the configuration manifold, in place.
  void rk4(Vec &q, Vec &v, const CRef &tau, const CRef &f_task, double h) {
    a1_ = acc(q, v, tau, f_task);
    v2_ = v + 0.5 * h * a1_;
    dv_ = 0.5 * h * v;
    step_q(q, dv_, qi_);
    a2_ = acc(qi_, v2_, tau, f_task);
    v3_ = v + 0.5 * h * a2_;
    dv_ = 0.5 * h * v2_;
    step_q(q, dv_, qi_);
    a3_ = acc(qi_, v3_, tau, f_task);
    v4_ = v + h * a3_;
    dv_ = h * v3_;
    step_q(q, dv_, qi_);
    a4_ = acc(qi_, v4_, tau, f_task);
    dv_ = (h / 6.0) * (v + 2 * v2_ + 2 * v3_ + v4_);
    step_q(q, dv_, qi_);
    q.swap(qi_);
    v = v + (h / 6.0) * (a1_ + 2 * a2_ + 2 * a3_ + a4_);
  }

  pin::Model model_;
  pin::Data data_;
  ConstraintModels cms_;
  ConstraintDatas cds_;
  pin::ProximalSettings prox_;
  bool flat_ = true;
  bool has_task_ = false;
  TaskForce task_;
  Vec a1_, a2_, a3_, a4_, v2_, v3_, v4_, qi_, dv_, tau_;  // work vectors (no allocation per sample)
};

}  // namespace

void bind_plant(nb::module_ &m) {
  nb::class_<Plant>(m, "Plant",
                    "RK4 sub-steps of pinocchio::constraintDynamics over one sample (the compiled step of "
                    "parallel_gpc.model.plant.ConstrainedPlant; the projection stays in Python).")
      .def(nb::init<const std::string &, const std::vector<int> &, const std::vector<int> &,
                    const std::vector<Eigen::Matrix4d> &, const std::vector<int> &,
                    const std::vector<Eigen::Matrix4d> &, double, double, double, double, int>(),
           nb::arg("model"), nb::arg("dims"), nb::arg("joints_a"), nb::arg("placements_a"), nb::arg("joints_b"),
           nb::arg("placements_b"), nb::arg("kp"), nb::arg("kd"), nb::arg("accuracy"), nb::arg("mu"),
           nb::arg("max_iter"),
           "model: Model.saveToString(); per closure: dimension 3 (point) or 6 (weld), parent joint and 4x4 "
           "placement of its two frames; Baumgarte gains Kp (1/s²), Kd (1/s); ProximalSettings(accuracy, mu, "
           "max_iter).")
      .def("set_task_output", &Plant::set_task_output, nb::arg("frame"), nb::arg("rows"), nb::arg("R_ref"),
           "Task-space output (frame id, rows of [x, y, z, rx, ry, rz], home rotation) on which f_task acts.")
      .def("accelerations", &Plant::accelerations, nb::arg("q"), nb::arg("v"), nb::arg("tau"), nb::arg("f_task"),
           "(nv,) q̈ for the generalized force tau (N·m, N) plus Hᵀ f_task (f_task empty: none).")
      .def("integrate", &Plant::integrate, nb::arg("q"), nb::arg("v"), nb::arg("tau"), nb::arg("f_task"),
           nb::arg("Ts"), nb::arg("substeps"), "(q, v) after one sample Ts (s) of `substeps` RK4 steps, tau held.")
      .def("contact_forces", &Plant::contact_forces, "(3 k,) linear closure forces (N) of the last dynamics call.")
      .def_prop_ro("nq", &Plant::nq)
      .def_prop_ro("nv", &Plant::nv);
}

}  // namespace pgpc
