// Compiled model update of a closed-chain robot: the C++ twin of ReducedModel._factor_rows and
// everything under it (src/parallel_gpc/model/{assembly,closures,outputs,universal,dynamics}.py).
// The Python modules are the reference; each function here names the Python function it ports.
#pragma once

#include <array>
#include <atomic>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <nanobind/nanobind.h>

#include "zoh.hpp"
// the types only: the algorithms are included by the files that call them (build time, CMakeLists.txt)
#include "pinocchio/multibody.hpp"  // Model, Data (multibody/model.hpp is a deprecated alias of it in 4.x)

namespace pgpc {
namespace nb = nanobind;

// What ParallelRobot knows about the robot (model/robot.py, _setup_outputs/_setup_fast_paths).
struct RobotConfig {
  std::vector<std::array<long, 2>> closure_frames;  // (frame a, frame b) per closure
  std::vector<long> jac_rows;   // rows kept of the stacked 6-D frame differences (robot._jac_rows)
  long n_y = 0, n_u = 0;
  std::vector<long> y_q;        // q indices of the output joints (joint outputs)
  std::vector<long> y_idx;      // v indices of the output joints (joint outputs)
  std::vector<long> z_idx;      // v indices of the dependent coordinates
  std::vector<long> drive_idx;  // v indices of the drives
  long task_frame = -1;         // output frame of a task-space output, -1: joint outputs
  std::vector<long> task_rows;  // kept axes of [x y z rx ry rz]
  Eigen::Matrix3d R_ref = Eigen::Matrix3d::Identity();
  std::vector<long> branch_q;   // q indices of the branch joints
  Vec branch;                   // home branch signature (signs of sin q)
  Vec q_home;
  bool bias_symmetric = true;
  std::vector<std::array<long, 2>> universal;  // (joint id, first v index) of universal joints
  std::vector<double> degree_norms;            // discretization._DEGREE_NORMS
};

// One evaluated configuration: the Newton predictor of the next one (ReducedModel._warm).
struct Warm {
  Vec q, y;
  Mat T, pinv;
  bool has_w = false;
  Mat W;
  Vec yd;
  // the factorization at (y, ẏ = yd) when has_z (factor_rows): Z, the full mass matrix M, [M_r | Tᵀ rhs] and
  // the gravity torques g; a later factor_rows at this very state takes them instead of recomputing
  bool has_z = false;
  Mat Z, M, red;
  Vec g;
};

// Kinematics of the assembly rows Ψ = [Φ; h − y] (closures.py, outputs.py, universal.py).
class Kinematics {
 public:
  Kinematics(pinocchio::Model model, const RobotConfig &cfg);
  Kinematics(const Kinematics &) = delete;  // never copied: no copy of Model/Data compiled
  Kinematics &operator=(const Kinematics &) = delete;
  // Ψ(q) + [0; y] and ∂Ψ/∂v (ClosureMixin._eval); fills res_, jac_
  void eval(const Vec &q);
  // eval at the configuration whose joint placements and world Jacobians data already holds (any of
  // computeJointJacobians, computeJointJacobiansTimeVariation, computeCoriolisMatrix at it): no kinematics pass
  void eval_placed();
  // Ψ̇_q at (q, v) (constraint_jacobian_derivative), into out (rows × nv); fresh: data already holds the
  // joint placements, Jacobians and their rates at (q, v) (computeJointJacobiansTimeVariation's
  // oMi, v, ov, J, dJ, which computeCoriolisMatrix leaves too, by the same formulas)
  void jacobian_rate(const Vec &q, const Vec &v, Mat &out, bool fresh = false);
  // ∂h/∂v · T by RNEA polarization (UniversalJoints.bias_derivative)
  void universal_bias_derivative(const Vec &q, const Vec &v, const Mat &T, Mat &out);
  Vec integrate(const Vec &q, const Vec &dv) const;

  pinocchio::Model model;
  pinocchio::Data data, data_u;
  const RobotConfig &cfg;
  bool flat, task, task_rotation;
  bool mimic = false;  // stage15: a mimic joint (nvExtended > nv): the closure rows from getFrameJacobian
  long n_c = 0, rows = 0;  // closure rows, assembly rows (closures + task outputs)
  Vec res_;
  Mat jac_;

 private:
  void place_frames();  // data.oMf of the closure and output frames (from data.oMi)
  void closure_rows();  // stage15: the closure rows of jac_ from data.J and data.oMf (no mimic joint)
  void frame_rate(long frame, const Vec &v, Eigen::Matrix<double, 6, Eigen::Dynamic> &dJ);
  std::vector<long> frames_;                 // closure frames, then the output frame
  std::vector<std::vector<long>> uni_cols_;  // per frame id: v columns of universal joints moving it
  std::vector<Eigen::Matrix<double, 6, Eigen::Dynamic>> Ja_, Jb_;
  Eigen::Matrix<double, 6, Eigen::Dynamic> Jt_, dJt_;
};

struct ForwardSolver;  // forward kinematics from drive readings (forward.cpp)

// A simulate run as another thread sees it while it goes on (pipe14: the fused rollout and linearization,
// stage_jacobian.cpp): warm = the run's warm starts (one per stage, valid until the next simulate), done = the
// stages finished (their warm start and the next state written; stored with release, read with acquire)
struct RolloutProgress {
  std::atomic<const Warm *> warm{nullptr};
  std::atomic<long> done{0};
  std::atomic<bool> failed{false};  // set by the driver when the run threw: nothing more is coming
};

class ModelUpdate {
  friend struct ForwardSolver;

 public:
  // threads: the threads of the per-stage loops (stage_jacobians), ≥ 1 (validated by the caller,
  // model/native_update.py: PARALLEL_GPC_THREADS)
  ModelUpdate(const std::string &model_str, RobotConfig cfg, nb::object handler, int threads = 1);
  // not copyable nor movable: nanobind then compiles no copy/move of the instance (and of Pinocchio's
  // Model and Data inside it), which the Python side never makes (build time, CMakeLists.txt)
  ModelUpdate(const ModelUpdate &) = delete;
  ModelUpdate &operator=(const ModelUpdate &) = delete;
  // ReducedModel._factor_rows: Z = M_r⁻¹ [−C_r | B_r | −g_r] at X; base: explicit warm start or null
  const Mat &factor_rows(const Vec &X, const Warm *base);
  // factor_rows at X and the exact ẏ-derivatives of its first block −M_r⁻¹ C_r (linear in ẏ): rates
  // (n_y, n_y·n_y), block j = ∂Z[:, :n_y]/∂ẏ_j (ReducedModel._factor_derivatives); the warm start is X's
  // base: an explicit warm start (a pre-simulation's at X: its assembly is reused) or null
  const Mat &factor_rates(const Vec &X, const Warm *base, Mat &rates);
  // factor_rows at a configuration q that need not be assembled, with a given velocity map T and K⁺ (the
  // Jacobian's difference steps: their first-order values, stage_jacobian.cpp) and platform velocity ẏ:
  // ReducedModel._factor_at; the warm start is not changed
  const Mat &factor_rows_with(const Vec &q, const Mat &T, const Mat &pinv, const Vec &yd);
  // Φ̇_q(T e_i), i < n_y, at the state of the last factor_rates
  const std::vector<Mat> &rate_jacobians() const { return rate_dPhi_; }
  // (Ṫ_j, K̇⁺_j) of the velocity map (T, K⁺) of map_from along motions δ_j: jac = Ψ_q at q, dPsi[j] = Ψ̇_q(q, δ_j);
  // exact for K = Ψ_q's dependent columns of full column rank (AssemblyMixin.velocity_map_rate)
  void velocity_map_rates(const Mat &jac, const Mat &T, const Mat &pinv, const std::vector<Mat> &dPsi,
                          std::vector<Mat> &dT, std::vector<Mat> &dP);
  // the warm starts of the last pre-simulation, one per state X_sim(0..K−1)
  const std::vector<Warm> &simulation_warm() const { return sim_warm_; }
  // exp of the ZOH matrix at X, the n_x top rows (n_x × (n_x + n_u + 1)), row-major out
  void discrete(const Vec &X, double Ts, double *out);
  // ReducedModel.simulate_factorized: Es (K, n_x, n_aug) and Xs (K+1, n_x), row-major; progress (or null):
  // where another thread follows the run stage by stage (the fused rollout and linearization, pipe14,
  // stage_jacobian.cpp)
  void simulate(const Vec &X0, const double *u, long K, double Ts, const Vec *offset, double *Es, double *Xs,
                RolloutProgress *progress = nullptr);
  // ConstrainedPlant._project: (q, v) onto Ψ = 0 keeping the output pose, v = T ẏ keeping ẏ;
  // pinv_hint: K⁺ of the previous projection (or null). False when the warm Newton meets anything
  // unusual (the caller takes the validated path); else T and K⁺ at q_out in velocity_map/pinv
  bool project(const Vec &q, const Vec &v, const Mat *pinv_hint, Vec &q_out, Vec &v_out);
  const Mat &velocity_map() const { return T_; }
  const Mat &pinv() const { return pinv_; }
  void reset();
  nb::object &handler() { return handler_; }  // for the cyclic GC (tp_traverse / tp_clear)
  // the k-th worker (k < threads − 1): a model update of the same robot with its own Pinocchio data and
  // workspaces, for one thread's share of the independent stages (stage_jacobian.cpp); made on first use
  // (the GIL held: it shares the handler)
  ModelUpdate &worker(int k);
  const std::vector<std::unique_ptr<ModelUpdate>> &workers() const { return workers_; }

  RobotConfig cfg;
  Kinematics kin;
  long n_y, n_u, n_x, n_aug, nv, n_z;
  int threads;
  Vec q_last;
  std::shared_ptr<ForwardSolver> forward_;  // forward kinematics' workspace (forward.cpp), made on first use

 private:
  // ReducedModel._kinematics: (q, T, K⁺) at pose y from the warm start; sets warm_
  void kinematics(const Vec &y, const Warm *base);
  // AssemblyMixin.assemble_warm; false when anything is unusual
  bool assemble_warm(const Vec &pose, Vec q, const Mat *pinv_hint, bool near);
  // AssemblyMixin._map_from into T_, pinv_; exact: decide the rank by SVD (as Python) only
  bool map_from(const Mat &jac, bool exact);
  void lstsq_z(const Mat &jac, const Vec &res, Vec &out);
  void step(Vec &q, const Vec &dz) const;  // ClosureMixin._step
  void fallback(const Vec &y);             // the validated Python path (raises the package errors)
  void zoh(const Mat &Z, double Ts);       // exp of the augmented ZOH matrix, top rows into E_
  // ReducedModel._bias_rows at q_, T_, pinv_ and v = T ẏ: K_ (nv × n_y) = M_z W − ½ ∂h/∂v T with
  // Tᵀ K = −C_r(ẏ); sets W_ (the Newton predictor's curvature, unaveraged), M_ (full) and g_
  void bias_rows(const Vec &v);
  // M_ (full), the gravity torques g_ and ∂h/∂v · T_ into DT_ at (q_, v) (bias_terms.cpp): one pass of
  // Pinocchio's Coriolis matrix algorithm when christoffel_, else RNEA derivatives
  void inertia_terms(const Vec &v);
  // factor_rates' passes at q_ along the directions T e_i from one kinematics pass (stage_jacobian.cpp):
  // Φ̇_q(T e_i) into rate_dPhi_ and P's columns i·n_y + j = 2 b(T e_i, T e_j), b the bilinear form of
  // h − g; only when christoffel_ (one degree of freedom per joint: no joint bias c_J)
  void tangent_rates(Mat &P);
  // every joint has one degree of freedom: Pinocchio's C(q, v) is Christoffel-consistent (bias_terms.cpp)
  static bool christoffel_coriolis(const pinocchio::Model &model);
  // A⁻¹ B into out, A = M_r (LLT, else the Python solve)
  void solve_reduced(const Eigen::Ref<const Mat> &A, const Eigen::Ref<const Mat> &B, Mat &out);
  const Mat &factor_here(const Vec &yd);          // Z_ at q_, T_, pinv_ and ẏ (sets W_)

  nb::object handler_;
  std::string model_str_;  // the model in Pinocchio's serialization: the workers load it
  std::vector<std::unique_ptr<ModelUpdate>> workers_;
  std::optional<Warm> warm_;
  std::vector<Warm> sim_warm_, sim_next_;
  Vec q_, zero_v_, g_;
  bool christoffel_ = false;  // christoffel_coriolis(kin.model), decided once
  std::vector<Mat> rate_dPhi_;  // Φ̇_q(T e_i), i < n_y (factor_rates)
  std::vector<std::vector<pinocchio::Motion>> tangent_ov_;  // world velocities of the joints at T e_i (tangent_rates)
  std::vector<std::vector<pinocchio::Force>> tangent_oh_;   // their momenta oY ov
  std::vector<std::vector<pinocchio::Motion>> tangent_dJ_;  // the joints' Jacobian rates ov × J at T e_i
  std::vector<pinocchio::Inertia> tangent_oY_;              // world inertias at q_
  std::vector<pinocchio::Motion> tangent_a_;                // tangent_rates' polarized accelerations
  std::vector<pinocchio::Force> tangent_f_;                 // and forces (workspaces)
  Mat rates_P_, rates_rhs_, rates_Wb_, rates_DT_, rates_red_;  // factor_rates' workspaces
  Mat T_, pinv_, dPhi_, W_, W2_, col_, rhs_, red_, Z_, DT_, M_, K_;
  Eigen::LLT<Mat> llt_;
  Mat aug_, E_;
  TopRowsExpm expm_;
  // velocity_map_rates' workspaces (zoh15: kept between calls, no allocation per stage Jacobian)
  struct MapRatesWork {
    std::vector<Index> rows;  // the rows of K that are not zero in K and every K̇
    struct {
      Mat K, Ps, dK, dKP, dPs, Q, N, dKtN, Ky, dKy, dTz;
    } mats;
  } map_rates_;
};

// the forward-kinematics methods of the ModelUpdate class (forward.cpp)
void bind_forward(nb::class_<ModelUpdate> &cls);

}  // namespace pgpc
