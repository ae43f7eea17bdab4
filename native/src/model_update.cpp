// The compiled model update: ReducedModel._factor_rows, discrete and simulate_factorized of
// model/dynamics.py in C++ (eq. (3), (4), (10)), and its nanobind binding.
#include "model_update.hpp"
#include "numpy_array.hpp"

#include <Eigen/Cholesky>
#include <nanobind/eigen/dense.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/array.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>
#include <stdexcept>

#include "bindings.hpp"
#include "model_io.hpp"
#include "small_solve.hpp"
#include "pinocchio/algorithm/rnea.hpp"

namespace pgpc {

ModelUpdate::ModelUpdate(const std::string &model_str, RobotConfig cfg_, nb::object handler, int threads_)
    : cfg(std::move(cfg_)), kin(load_model(model_str), cfg), threads(threads_), handler_(std::move(handler)),
      model_str_(model_str) {
  if (threads < 1) throw std::invalid_argument("ModelUpdate: threads must be >= 1");
  n_y = cfg.n_y;
  n_u = cfg.n_u;
  n_x = 2 * n_y;
  n_aug = n_x + n_u + 1;
  nv = kin.model.nv;
  n_z = static_cast<long>(cfg.z_idx.size());
  if (cfg.q_home.size() != kin.model.nq || cfg.branch.size() != static_cast<Index>(cfg.branch_q.size()))
    throw std::invalid_argument("ModelUpdate: q_home or branch signature of the wrong size");
  q_last = cfg.q_home;
  zero_v_ = Vec::Zero(nv);
  rhs_.setZero(nv, 2 * n_y + n_u + 1);
  for (Index j = 0; j < n_u; ++j) rhs_(cfg.drive_idx[j], 2 * n_y + j) = 1.0;  // Sᵀ, never changes
  aug_.setZero(n_x, n_aug);
  aug_.block(0, n_y, n_y, n_y).setIdentity();
  expm_.set_table(cfg.degree_norms);
  christoffel_ = christoffel_coriolis(kin.model);
}

ModelUpdate &ModelUpdate::worker(int k) {
  if (static_cast<int>(workers_.size()) <= k) workers_.resize(k + 1);
  if (!workers_[k]) workers_[k] = std::make_unique<ModelUpdate>(model_str_, cfg, handler_);
  return *workers_[k];
}

void ModelUpdate::reset() {
  q_last = cfg.q_home;
  warm_.reset();
  sim_warm_.clear();
}

void ModelUpdate::bias_rows(const Vec &v) {
  inertia_terms(v);  // M_, g_, DT_ = ∂h/∂v T; the Coriolis pass leaves the joint Jacobians' rates at (q, v)
  kin.jacobian_rate(q_, v, dPhi_, christoffel_);
  // ℓ_z(ẏ) = −Φ_z⁺ γ(T ẏ), γ bilinear in v: ∂ℓ_z/∂ẏ = −Φ_z⁺ (Φ̇_q(v) T + [Φ̇_q(T e_i) v]_i)
  // (the small products coefficient-wise: Eigen's blocked GEMM costs more than it saves here)
  W_.noalias() = pinv_.lazyProduct(dPhi_.lazyProduct(T_));
  if (!cfg.bias_symmetric) {
    W2_.resize(kin.rows, n_y);
    for (Index i = 0; i < n_y; ++i) {
      kin.jacobian_rate(q_, T_.col(i), col_);
      W2_.col(i).noalias() = col_ * v;
    }
    W2_ = (0.5 * (W_ + pinv_ * W2_)).eval();  // n_z × n_y from rows × n_y: a temporary
  }
  const Mat &Wb = cfg.bias_symmetric ? W_ : W2_;
  // K = M_z W̄ − ½ D T, M_z = M's dependent columns: one rank-1 update per column (no copy of M_z)
  K_ = -0.5 * DT_;
  for (Index i = 0; i < n_z; ++i) K_.noalias() += M_.col(cfg.z_idx[i]) * Wb.row(i);
}

void ModelUpdate::solve_reduced(const Eigen::Ref<const Mat> &A, const Eigen::Ref<const Mat> &B, Mat &out) {
  llt_.compute(A);
  if (llt_.info() == Eigen::Success) {
    small_solve::llt_solve(llt_, B, out);
    return;
  }
  // not numerically SPD: the Python solve (LU, or LinAlgError); a worker thread takes the GIL for it
  nb::gil_scoped_acquire gil;
  out = nb::cast<Mat>(handler_.attr("spd_solve")(Mat(A), Mat(B)));
}

const Mat &ModelUpdate::factor_here(const Vec &yd) {
  bias_rows(T_ * yd);
  // [M T | M_z W − ½ D T | Sᵀ | −g]; one product with Tᵀ gives [M_r | −C_r | B_r | −g_r]
  rhs_.leftCols(n_y).noalias() = M_.lazyProduct(T_);
  rhs_.middleCols(n_y, n_y) = K_;
  rhs_.col(rhs_.cols() - 1) = -g_;
  red_.noalias() = T_.transpose().lazyProduct(rhs_);
  solve_reduced(red_.leftCols(n_y), red_.rightCols(red_.cols() - n_y), Z_);
  return Z_;
}

const Mat &ModelUpdate::factor_rows(const Vec &X, const Warm *base) {
  const Vec y = X.head(n_y), yd = X.tail(n_y);
  kinematics(y, base);
  if (base != nullptr && base->has_z && base->y == y && base->yd == yd) {
    // the base's own state (a pre-simulation's, linearized along by stage_jacobians): its factorization,
    // computed at the same q, T, Φ_z⁺ and ẏ (the same numbers)
    Z_ = base->Z;
    M_ = base->M;
    red_ = base->red;
    g_ = base->g;
    W_ = base->W;
  } else {
    factor_here(yd);
  }
  Warm &w = *warm_;
  w.W = W_;
  w.yd = yd;
  w.has_w = true;
  w.Z = Z_;
  w.M = M_;
  w.red = red_;
  w.g = g_;
  w.has_z = true;
  return Z_;
}

const Mat &ModelUpdate::factor_rows_with(const Vec &q, const Mat &T, const Mat &pinv, const Vec &yd) {
  q_ = q;
  T_ = T;
  pinv_ = pinv;
  return factor_here(yd);
}

const Mat &ModelUpdate::factor_rates(const Vec &X, const Warm *base, Mat &rates) {
  factor_rows(X, base);
  // K is linear in ẏ: K(e_j) = M_z W̄(e_j) − ½ ∂h/∂v(T e_j) T = ∂K/∂ẏ_j at the same q (no assembly), with the
  // q-only parts (M_, g_, Φ_z⁺, T) of factor_rows computed once. h − g = b(v, v) is a symmetric bilinear form
  // in v, so ∂h/∂v(T e_j) T e_i = 2 b(T e_j, T e_i): n_y (n_y + 1) / 2 RNEA passes by polarization instead of
  // n_y RNEA derivatives; Φ̇_q(T e_i) (n_y passes) serves W(e_j) and the unsymmetric closure term alike
  auto &model = kin.model;
  auto &data = kin.data;
  const Index ny = n_y;
  Mat &P = rates_P_;  // column i·n_y + j: 2 b(T e_i, T e_j)
  P.resize(nv, ny * ny);
  if (christoffel_) {
    tangent_rates(P);  // the same from one kinematics pass
  } else {
    rate_dPhi_.resize(ny);
    for (Index i = 0; i < ny; ++i) kin.jacobian_rate(q_, T_.col(i), rate_dPhi_[i]);
    for (Index i = 0; i < ny; ++i)
      P.col(i * ny + i) = 2.0 * (pinocchio::rnea(model, data, q_, T_.col(i), zero_v_) - g_);
    for (Index i = 0; i < ny; ++i)
      for (Index j = i + 1; j < ny; ++j) {
        const Vec both = T_.col(i) + T_.col(j);
        P.col(i * ny + j) = pinocchio::rnea(model, data, q_, both, zero_v_) - g_ -
                            0.5 * (P.col(i * ny + i) + P.col(j * ny + j));
        P.col(j * ny + i) = P.col(i * ny + j);
      }
  }
  // block j of the right-hand side: M_z W̄(e_j) − ½ P_j, M_z = M's dependent columns (one rank-1 update per
  // column, no copy of M_z); the small products coefficient-wise (Eigen's blocked GEMM costs more here)
  Mat &rhs = rates_rhs_, &Wb = rates_Wb_;
  rhs.resize(nv, ny * ny);
  for (Index j = 0; j < ny; ++j) {
    rates_DT_.noalias() = rate_dPhi_[j].lazyProduct(T_);
    Wb.noalias() = pinv_.lazyProduct(rates_DT_);
    if (!cfg.bias_symmetric) {  // ½ (W + Φ_z⁺ [Φ̇_q(T e_i) T e_j]_i)
      W2_.resize(kin.rows, ny);
      for (Index i = 0; i < ny; ++i) W2_.col(i).noalias() = rate_dPhi_[i].lazyProduct(T_.col(j));
      Wb = 0.5 * (Wb + pinv_.lazyProduct(W2_));
    }
    auto block = rhs.middleCols(j * ny, ny);
    block = -0.5 * P.middleCols(j * ny, ny);
    for (Index i = 0; i < n_z; ++i) block.noalias() += M_.col(cfg.z_idx[i]) * Wb.row(i);
  }
  rates_red_.noalias() = T_.transpose().lazyProduct(rhs);
  solve_reduced(red_.leftCols(ny), rates_red_, rates);
  return Z_;
}

void ModelUpdate::zoh(const Mat &Z, double Ts) {
  aug_.block(0, n_y, n_y, n_y).diagonal().setConstant(Ts);
  aug_.bottomRightCorner(n_y, n_aug - n_y) = Z * Ts;
  if (!expm_.run(aug_, E_)) handler_.attr("nonfinite")();
}

void ModelUpdate::discrete(const Vec &X, double Ts, double *out) {
  zoh(factor_rows(X, nullptr), Ts);
  Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(out, n_x, n_aug) = E_;
}

void ModelUpdate::simulate(const Vec &X0, const double *u, long K, double Ts, const Vec *offset, double *Es,
                           double *Xs, RolloutProgress *progress) {
  Eigen::Map<RowMat> X(Xs, K + 1, n_x);
  X.row(0) = X0.transpose();
  // the warm starts of this run go into the storage of the run before last (copy-assigned at equal
  // sizes: no allocation), then the two swap
  sim_next_.resize(K);
  if (progress != nullptr) progress->warm.store(sim_next_.data(), std::memory_order_relaxed);  // done publishes it
  Vec x(n_x), xu(n_aug);
  xu[n_aug - 1] = 1.0;
  for (long i = 0; i < K; ++i) {
    x = X.row(i).transpose();
    // the previous simulation visited nearly the same states one index later (the last control step's
    // pre-simulation) or at the same index (a rollout of the same step: the NMPC line search)
    const Warm *base = nullptr;
    double nearest = 1e-8;
    for (long j = i; j <= i + 1 && j < static_cast<long>(sim_warm_.size()); ++j) {
      const double d2 = (x.head(n_y) - sim_warm_[j].y).squaredNorm();
      if (d2 < nearest) nearest = d2, base = &sim_warm_[j];
    }
    zoh(factor_rows(x, base), Ts);
    sim_next_[i] = *warm_;
    Eigen::Map<RowMat>(Es + i * n_x * n_aug, n_x, n_aug) = E_;
    xu.head(n_x) = x;
    xu.segment(n_x, n_u) = Eigen::Map<const Vec>(u + i * n_u, n_u);
    X.row(i + 1) = (E_ * xu).transpose();
    if (offset != nullptr) X.row(i + 1) += offset->transpose();
    if (progress != nullptr) progress->done.store(i + 1, std::memory_order_release);  // stage i: warm, X(i + 1)
  }
  sim_warm_.swap(sim_next_);
}

namespace {
void check_state(const ModelUpdate &self, const Vec &X) {
  if (X.size() != self.n_x) throw std::invalid_argument("the state X must have n_x = 2 n_y entries");
}

ModelUpdate *make(const std::string &model_str, std::vector<std::array<long, 2>> closure_frames,
                  std::vector<long> jac_rows, long n_y, long n_u, std::vector<long> y_q, std::vector<long> y_idx,
                  std::vector<long> z_idx, std::vector<long> drive_idx, long task_frame,
                  std::vector<long> task_rows, Eigen::Matrix3d R_ref, std::vector<long> branch_q, Vec branch,
                  Vec q_home, bool bias_symmetric, std::vector<std::array<long, 2>> universal,
                  std::vector<double> degree_norms, nb::object handler, int threads) {
  RobotConfig c;
  c.closure_frames = std::move(closure_frames);
  c.jac_rows = std::move(jac_rows);
  c.n_y = n_y;
  c.n_u = n_u;
  c.y_q = std::move(y_q);
  c.y_idx = std::move(y_idx);
  c.z_idx = std::move(z_idx);
  c.drive_idx = std::move(drive_idx);
  c.task_frame = task_frame;
  c.task_rows = std::move(task_rows);
  c.R_ref = R_ref;
  c.branch_q = std::move(branch_q);
  c.branch = std::move(branch);
  c.q_home = std::move(q_home);
  c.bias_symmetric = bias_symmetric;
  c.universal = std::move(universal);
  c.degree_norms = std::move(degree_norms);
  return new ModelUpdate(model_str, std::move(c), std::move(handler), threads);
}
// the instance holds a Python object (the validated path): let the cyclic GC see and break it
int traverse(PyObject *self, visitproc visit, void *arg) {
  Py_VISIT(Py_TYPE(self));
  if (!nb::inst_ready(self)) return 0;
  ModelUpdate *update = nb::inst_ptr<ModelUpdate>(self);
  Py_VISIT(update->handler().ptr());
  for (const auto &w : update->workers())  // each holds a reference of its own
    if (w) Py_VISIT(w->handler().ptr());
  return 0;
}

int clear(PyObject *self) {
  ModelUpdate *update = nb::inst_ptr<ModelUpdate>(self);
  update->handler() = nb::none();
  for (const auto &w : update->workers())
    if (w) w->handler() = nb::none();
  return 0;
}

PyType_Slot gc_slots[] = {{Py_tp_traverse, reinterpret_cast<void *>(traverse)},
                          {Py_tp_clear, reinterpret_cast<void *>(clear)},
                          {0, nullptr}};
}  // namespace

void bind_model_update(nb::module_ &m) {
  auto cls = nb::class_<ModelUpdate>(m, "ModelUpdate",
                                     "Compiled model update of one robot (see parallel_gpc.model.native_update)",
                                     nb::type_slots(gc_slots))
      .def(nb::new_(&make), nb::arg("model"), nb::arg("closure_frames"), nb::arg("jac_rows"), nb::arg("n_y"),
           nb::arg("n_u"), nb::arg("y_q"), nb::arg("y_idx"), nb::arg("z_idx"), nb::arg("drive_idx"),
           nb::arg("task_frame"), nb::arg("task_rows"), nb::arg("R_ref"), nb::arg("branch_q"),
           nb::arg("branch"), nb::arg("q_home"), nb::arg("bias_symmetric"), nb::arg("universal"),
           nb::arg("degree_norms"), nb::arg("handler"), nb::arg("threads") = 1)
      .def("factor_rows", [](ModelUpdate &self, const Vec &X) {
             check_state(self, X);
             return Mat(self.factor_rows(X, nullptr));
           },
           nb::arg("X"), "(n_y, n_y + n_u + 1) Z = M_r⁻¹ [−C_r | B_r | −g_r] at X = [y, ẏ]")
      .def("discrete",
           [](ModelUpdate &self, const Vec &X, double Ts) {
             check_state(self, X);
             double *buf;
             Array out = new_array({size_t(self.n_x), size_t(self.n_aug)}, &buf);
             self.discrete(X, Ts, buf);
             return out;
           },
           nb::arg("X"), nb::arg("Ts"), "(n_x, n_x + n_u + 1) top rows of the ZOH exponential at X")
      .def("simulate",
           [](ModelUpdate &self, const Vec &X0, In2 u, double Ts, std::optional<Vec> offset) {
             const long K = static_cast<long>(u.shape(0));
             if (u.shape(1) != size_t(self.n_u) || X0.size() != self.n_x)
               throw std::invalid_argument("simulate: X0 must be (n_x,) and u_seq (K, n_u)");
             if (offset && offset->size() != self.n_x) throw std::invalid_argument("simulate: offset must be (n_x,)");
             double *Es, *Xs;
             Array E = new_array({size_t(K), size_t(self.n_x), size_t(self.n_aug)}, &Es);
             Array X = new_array({size_t(K + 1), size_t(self.n_x)}, &Xs);
             self.simulate(X0, u.data(), K, Ts, offset ? &*offset : nullptr, Es, Xs);
             return nb::make_tuple(E, X);
           },
           nb::arg("X0"), nb::arg("u_seq"), nb::arg("Ts"), nb::arg("offset").none(),
           "(E (K, n_x, n_aug), X (K + 1, n_x)) of the pre-simulation (10)")
      .def("project",
           [](ModelUpdate &self, const Vec &q, const Vec &v, const Mat &pinv_hint) -> nb::object {
             if (q.size() != self.kin.model.nq || v.size() != self.nv)
               throw std::invalid_argument("project: q must be (nq,) and v (nv,)");
             if (pinv_hint.rows() != self.n_z || pinv_hint.cols() != self.kin.rows)
               throw std::invalid_argument("project: pinv_hint must be K⁺ (n_z, assembly rows)");
             Vec q_out, v_out;
             if (!self.project(q, v, &pinv_hint, q_out, v_out)) return nb::none();
             return nb::make_tuple(q_out, v_out, Mat(self.velocity_map()), Mat(self.pinv()));
           },
           nb::arg("q"), nb::arg("v"), nb::arg("pinv_hint"),
           "(q, v, T, K⁺) projected onto the closures keeping the output pose and velocity (the first "
           "Newton step preconditioned by pinv_hint, the previous K⁺), or None: take the validated path")
      .def("reset", &ModelUpdate::reset, "forget the warm starts (back to the home configuration)")
      .def_prop_ro("q_last", [](ModelUpdate &self) { return Vec(self.q_last); });
  bind_forward(cls);
}
}  // namespace pgpc
