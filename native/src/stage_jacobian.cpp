// Jacobian ∂Φ/∂X of the stage map X(i+1) = Φ(X(i), u(i)) = E(X)·[X; u; 1] (the ZOH map of the
// pre-simulation, eq. (10)) along a trajectory, in one call: the compiled twin of
// ReducedModel.stage_jacobians (model/dynamics.py), which is the reference. ∂Φ/∂X_k = E[:, k] +
// (∂E/∂X_k)·[X; u; 1], the second term the Fréchet derivative of the exponential along Ts·∂Z/∂X_k
// applied to one vector (TopRowsExpmDerivative); ∂Z/∂ẏ exact (Z is linear in ẏ), ∂Z/∂y forward
// differences of the factor rows Z along the closures' tangent, the velocity map there to first order.
// The nonlinear MPC iterations (gpc/nmpc.py) linearize with it. The stages are independent given the
// trajectory and its pre-simulation: they run on the ModelUpdate's threads (thread_pool.hpp), the same
// numbers bit for bit whatever the split.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <exception>
#include <functional>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <thread>

#include <nanobind/eigen/dense.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/optional.h>

#include "bindings.hpp"
#include "model_update.hpp"
#include "numpy_array.hpp"
#include "thread_pool.hpp"
#include "pinocchio/algorithm/jacobian.hpp"

namespace pgpc {

void ModelUpdate::tangent_rates(Mat &P) {
  // computeJointJacobiansTimeVariation and RNEA without their kinematics passes: with the world Jacobian J
  // at q, a joint's world velocity at v is ov_k = ov_parent + J_k v_k and dJ_k = ov_k × J_k (Pinocchio's
  // formulas, jacobian.hxx); b(v, w) is the polarized world-frame RNEA of rnea-derivatives.hxx with zero
  // q̈ and gravity: a_k = a_parent + ½ (ov_k(v) × J_k w_k + ov_k(w) × J_k v_k),
  // f_k = oY_k a_k + ½ (ov_k(v) ×* oY_k ov_k(w) + ov_k(w) ×* oY_k ov_k(v)), τ_k = J_kᵀ Σ_subtree f
  // (exact for joints without a bias c_J, which christoffel_ ensures: every joint one degree of freedom)
  using pinocchio::Force;
  using pinocchio::Motion;
  const auto &model = kin.model;
  auto &data = kin.data;
  const int nj = model.njoints;
  const Index ny = n_y;
  pinocchio::computeJointJacobians(model, data, q_);  // oMi and J at q_ (eval_placed reads them too)
  if (static_cast<Index>(tangent_ov_.size()) != ny) {  // sized once (a fill value per call would allocate)
    tangent_ov_.assign(ny, std::vector<Motion>(nj, Motion::Zero()));
    tangent_oh_.assign(ny, std::vector<Force>(nj, Force::Zero()));
    tangent_dJ_.assign(ny, std::vector<Motion>(nj, Motion::Zero()));
  }
  tangent_oY_.resize(nj);
  rate_dPhi_.resize(ny);
  for (int k = 1; k < nj; ++k) tangent_oY_[k] = data.oMi[k].act(model.inertias[k]);
  for (Index i = 0; i < ny; ++i) {
    auto &ov = tangent_ov_[i];
    for (int k = 1; k < nj; ++k) {
      const Index c = model.joints[k].idx_v();
      ov[k] = ov[model.parents[k]] + Motion(data.J.col(c) * T_(c, i));
      data.ov[k] = ov[k];
      tangent_dJ_[i][k] = ov[k].cross(Motion(data.J.col(c)));
      data.dJ.col(c) = tangent_dJ_[i][k].toVector();
      tangent_oh_[i][k] = tangent_oY_[k] * ov[k];
    }
    kin.jacobian_rate(q_, T_.col(i), rate_dPhi_[i], true);
  }
  std::vector<Motion> &a = tangent_a_;
  std::vector<Force> &f = tangent_f_;
  a.assign(nj, Motion::Zero());
  f.resize(nj);
  for (Index i = 0; i < ny; ++i)
    for (Index j = i; j < ny; ++j) {
      const auto &vi = tangent_ov_[i], &vj = tangent_ov_[j];
      const auto &hi = tangent_oh_[i], &hj = tangent_oh_[j];
      const auto &ci = tangent_dJ_[i], &cj = tangent_dJ_[j];
      for (int k = 1; k < nj; ++k) {
        const Index c = model.joints[k].idx_v();
        a[k] = a[model.parents[k]] + (ci[k] * T_(c, j) + cj[k] * T_(c, i)) * 0.5;
        f[k] = tangent_oY_[k] * a[k] + (vi[k].cross(hj[k]) + vj[k].cross(hi[k])) * 0.5;
      }
      for (int k = nj - 1; k > 0; --k) {
        const Index c = model.joints[k].idx_v();
        P(c, i * ny + j) = 2.0 * data.J.col(c).dot(f[k].toVector());
        if (model.parents[k] > 0) f[model.parents[k]] += f[k];
      }
      P.col(j * ny + i) = P.col(i * ny + j);
    }
}

namespace {

// One thread's workspaces of the stage loop: assigned at equal sizes from its second stage on (no allocation).
struct StageWork {
  StageWork(const ModelUpdate &self, double Ts)
      : M_top(Mat::Zero(self.n_x, self.n_aug)),
        D(Mat::Zero(self.n_x * self.n_y, self.n_aug)),
        xi(self.n_aug), x(self.n_x), yd(self.n_y), dT(self.n_y), dP(self.n_y) {
    expm.set_table(self.cfg.degree_norms);
    M_top.block(0, self.n_y, self.n_y, self.n_y).diagonal().setConstant(Ts);
    xi[self.n_aug - 1] = 1.0;
  }
  TopRowsExpmDerivative expm;
  Mat M_top, rates, E, dE;
  // Ts·∂(ZOH matrix)/∂X_k, its ẏ rows n_y..n_x (the others do not move), stacked: rows k·n_y.. (TopRowsExpmDerivative)
  Mat D;
  Vec xi, x, q, yd;
  std::vector<Mat> dT, dP;
  Mat Zc, T, P, T_s, P_s;
};

/// ∂Φ/∂X at (x, u) into out (n_x × n_x, row-major), on the model update self (its assembly, Pinocchio data and
/// workspaces: one per thread); base: x's warm start (the pre-simulation's at x) or null. With a base the
/// result depends on (x, u, base) alone, not on the stages self computed before: any split of the stages
/// over threads gives the same numbers.
void stage_jacobian(ModelUpdate &self, const Warm *base, StageWork &w, const double *x_in, const double *u_in,
                    double Ts, double step, double *out) {
  const long n = self.n_x, m = self.n_u, ny = self.n_y, na = self.n_aug;
  Vec &x = w.x;
  x = Eigen::Map<const Vec>(x_in, n);
  w.Zc = self.factor_rates(x, base, w.rates);
  w.M_top.bottomRightCorner(ny, na - ny) = w.Zc * Ts;
  for (long j = 0; j < ny; ++j) w.D.block((ny + j) * ny, ny, ny, ny) = w.rates.middleCols(j * ny, ny) * Ts;
  // forward differences along the closures' tangent q + T e_j h (not assembled: the line has the
  // closures' first derivative; ReducedModel._factor_derivatives), with the first-order velocity map
  // T + h Ṫ_j, K⁺ + h K̇⁺_j there (Ṫ_j, K̇⁺_j from the rates Φ̇_q(T e_j) that factor_rates left) instead of
  // a kinematics pass and a factorization of the assembly Jacobian per step
  w.q = self.q_last;  // X's assembly (factor_rates) and its velocity map
  w.yd = x.tail(ny);
  w.T = self.velocity_map();
  w.P = self.pinv();
  self.kin.eval_placed();  // Ψ_q at q: factor_rates' rate passes left q's kinematics in the data
  self.velocity_map_rates(self.kin.jac_, w.T, w.P, self.rate_jacobians(), w.dT, w.dP);
  for (long j = 0; j < ny; ++j) {
    const double h = step * std::max(1.0, std::abs(x[j]));
    w.T_s = w.T + h * w.dT[j];
    w.P_s = w.P + h * w.dP[j];
    w.D.block(j * ny, ny, ny, na - ny) =
        (self.factor_rows_with(self.kin.integrate(w.q, w.T.col(j) * h), w.T_s, w.P_s, w.yd) - w.Zc) * (Ts / h);
  }
  w.xi.head(n) = x;
  w.xi.segment(n, m) = Eigen::Map<const Vec>(u_in, m);
  if (!w.expm.run(w.M_top, w.D, ny, ny, w.xi, w.E, w.dE)) {
    nb::gil_scoped_acquire gil;  // a worker thread's too
    self.handler().attr("nonfinite")();
  }
  Eigen::Map<RowMat>(out, n, n) = w.E.leftCols(n) + w.dE;
}

/// Threads for the stages start..K−1: no more than the stages, nor helpers than the machine has free cores now
/// (ThreadPool::free_cores), nor than self.threads.
int stage_threads(const ModelUpdate &self, long stages) {
  return static_cast<int>(std::min<long>({self.threads, stages, 1L + std::max(0, ThreadPool::free_cores())}));
}

/// Stages start..K−1 one after the other on self (the base of stage i: base(i)).
template <class Base>
void stages_serial(ModelUpdate &self, const Base &base, const double *X, const double *u, double Ts, double step,
                   long start, long K, double *out) {
  const long n = self.n_x, m = self.n_u;
  StageWork work(self, Ts);
  for (long i = start; i < K; ++i)
    stage_jacobian(self, base(i), work, X + i * n, u + i * m, Ts, step, out + (i - start) * n * n);
}

/// Stages start..K−2 on self and its workers, threads at once (each its own model update), stage K−1 last on
/// self (which ends as after the loop on one thread: its warm start is the last stage's); the GIL released.
/// The stages are handed out one at a time (a thread the machine delays takes fewer); returns the exception of the
/// earliest failing stage (the one the loop on one thread would meet), caught while all run, or null.
/// base(i): stage i's warm start. lead (or null): run by the calling thread (slot 0) before it takes stages, e.g.
/// the rollout that produces them; false: no stage is computed by it. ready(i) (or null): called by a pool thread
/// before stage i, waits until the stage can be computed; false: it never will (the thread stops).
template <class Base>
std::exception_ptr stages_threaded(ModelUpdate &self, const Base &base, const double *X, const double *u, double Ts,
                                   double step, long start, long K, int threads, double *out,
                                   const std::function<bool()> &lead = nullptr,
                                   const std::function<bool(long)> &ready = nullptr) {
  const long n = self.n_x, m = self.n_u;
  std::vector<ModelUpdate *> updates{&self};
  for (int k = 0; k + 1 < threads; ++k) updates.push_back(&self.worker(k));  // the GIL held: made on first use
  std::atomic<long> next{start};
  std::mutex failed;
  long first_failure = K;
  std::exception_ptr error;
  const auto fail = [&](long i) {  // i: the stage, start − 1 for a thread's set-up
    std::lock_guard<std::mutex> lock(failed);
    if (i < first_failure) first_failure = i, error = std::current_exception();
  };
  const auto one = [&](ModelUpdate &update, StageWork &work, long i) {
    try {
      stage_jacobian(update, base(i), work, X + i * n, u + i * m, Ts, step, out + (i - start) * n * n);
    } catch (...) {
      fail(i);
    }
  };
  const std::function<void(int)> task = [&](int slot) {
    try {
      if (slot == 0 && lead && !lead()) return;
      ModelUpdate &update = *updates[slot];
      StageWork work(update, Ts);
      for (long i = next++; i < K - 1; i = next++) {
        if (slot != 0 && ready && !ready(i)) return;
        one(update, work, i);
      }
      if (slot == 0) one(update, work, K - 1);
    } catch (...) {
      fail(start - 1);
    }
  };
  {
    nb::gil_scoped_release release;  // a helper's nonfinite/spd_solve takes the GIL: free while the caller waits
    ThreadPool::shared().run(threads - 1, task);
  }
  return error;
}

/// ((K − start)·n_x, n_x): rows (i − start)·n_x … hold ∂Φ/∂X at (X(i), u(i)), i = start..K−1; the y-columns
/// of ∂Z by forward differences along the tangent with step h_j = step·max(1, |y_j(i)|) (the Python rule).
/// On self.threads threads when every stage has its base in the last pre-simulation (then the stages are
/// independent) and the machine has cores free for them, else one after the other on one (a stage without a
/// base starts its assembly's Newton from the stage before).
RowMat stage_jacobians(ModelUpdate &self, In2 X, In2 u, double Ts, double step, long start) {
  const long K = static_cast<long>(u.shape(0)), n = self.n_x, m = self.n_u, ny = self.n_y;
  if (u.shape(1) != size_t(m) || X.shape(1) != size_t(n) || X.shape(0) < size_t(K))
    throw std::invalid_argument("stage_jacobians: X_seq must be (>= K, n_x) and u_seq (K, n_u)");
  if (!(Ts > 0.0) || !(step > 0.0))
    throw std::invalid_argument("stage_jacobians: Ts and step must be > 0");
  if (start < 0 || start > K) throw std::invalid_argument("stage_jacobians: start must be in 0..K");
  RowMat J((K - start) * n, n);
  const std::vector<Warm> &sim = self.simulation_warm();  // usually at these very states
  std::vector<const Warm *> bases(K - start, nullptr);
  bool all = true;
  for (long i = start; i < K; ++i) {
    const Eigen::Map<const Vec> y(X.data() + i * n, ny);
    if (i < static_cast<long>(sim.size()) && sim[i].y == y) bases[i - start] = &sim[i];
    all = all && bases[i - start] != nullptr;
  }
  const auto base = [&](long i) { return bases[i - start]; };
  const int threads = stage_threads(self, K - start);
  if (all && threads > 1) {
    if (const auto error = stages_threaded(self, base, X.data(), u.data(), Ts, step, start, K, threads, J.data()))
      std::rethrow_exception(error);
  } else {
    stages_serial(self, base, X.data(), u.data(), Ts, step, start, K, J.data());
  }
  return J;
}

/// The rollout of simulate (Es, Xs as ModelUpdate::simulate) and the stage Jacobians of its states start..K−1 (J,
/// rows as stage_jacobians) in one call: the calling thread runs the rollout stage by stage (the GIL held, as
/// simulate: its handler calls need it), the pool's threads compute the Jacobians of the stages it has finished
/// meanwhile (each stage's state, input and warm start published by the rollout's progress), then the calling
/// thread, the GIL released, takes the stages left and stage K−1 last on self (which ends as after the two calls).
/// A stage's Jacobian depends on (X(i), u(i), its warm start) alone: the same numbers bit for bit as simulate then
/// stage_jacobians. An exception of the rollout is the call's (the Jacobians computed meanwhile are dropped);
/// else the earliest failing stage's. On one thread (or no free core): the two calls one after the other.
void simulate_linearized(ModelUpdate &self, const Vec &X0, const double *u, long K, double Ts, const Vec *offset,
                         double step, long start, double *Es, double *Xs, double *J) {
  const int threads = stage_threads(self, K - start);
  if (threads <= 1) {
    self.simulate(X0, u, K, Ts, offset, Es, Xs);
    const std::vector<Warm> &sim = self.simulation_warm();
    stages_serial(self, [&](long i) { return &sim[i]; }, Xs, u, Ts, step, start, K, J);
    return;
  }
  RolloutProgress progress;
  std::exception_ptr rollout_error;
  const auto lead = [&] {
    nb::gil_scoped_acquire gil;  // the rollout's handler calls (assembly fallback, nonfinite) as in simulate
    try {
      self.simulate(X0, u, K, Ts, offset, Es, Xs, &progress);
      return true;
    } catch (...) {
      rollout_error = std::current_exception();
      progress.failed.store(true, std::memory_order_release);
      return false;
    }
  };
  // stage i once the rollout has finished it (its warm start, and X(i) written by stage i − 1); false: it never will
  const auto ready = [&](long i) {
    for (;;) {
      if (progress.done.load(std::memory_order_acquire) > i) return true;
      if (progress.failed.load(std::memory_order_acquire)) return false;
      std::this_thread::yield();
    }
  };
  // published with done (read after ready's acquire, or by the calling thread after its rollout)
  const auto base = [&](long i) { return progress.warm.load(std::memory_order_relaxed) + i; };
  const auto error = stages_threaded(self, base, Xs, u, Ts, step, start, K, threads, J, lead, ready);
  if (rollout_error) std::rethrow_exception(rollout_error);  // the rollout's first, as the two calls would
  if (error) std::rethrow_exception(error);
}
}  // namespace

void bind_stage_jacobian(nb::module_ &m) {
  m.def("adapt_threads", &ThreadPool::adapt, nb::arg("on"),
        "True (the default): the per-stage loops run on no more helper threads than the machine has free cores "
        "at the call (/proc/loadavg); False: on the threads asked, whatever the load (tests, benchmarks)");
  m.def("stage_jacobians", &stage_jacobians, nb::arg("update"), nb::arg("X_seq"), nb::arg("u_seq"), nb::arg("Ts"),
        nb::arg("step"), nb::arg("start") = 0,
        "((K − start)·n_x, n_x) ∂Φ/∂X of the ZOH stage map of a ModelUpdate at (X_seq[i], u_seq[i]), start ≤ i < K: the Fréchet "
        "derivative of the exponential, ẏ-derivatives of the factor rows exact, y-derivatives by forward "
        "differences along the closures' tangent with step·max(1, |y_j|)");
  m.def(
      "simulate_linearized",
      [](ModelUpdate &self, const Vec &X0, In2 u, double Ts, std::optional<Vec> offset, double step, long start) {
        const long K = static_cast<long>(u.shape(0)), n = self.n_x;
        if (u.shape(1) != size_t(self.n_u) || X0.size() != n)
          throw std::invalid_argument("simulate_linearized: X0 must be (n_x,) and u_seq (K, n_u)");
        if (offset && offset->size() != n) throw std::invalid_argument("simulate_linearized: offset must be (n_x,)");
        if (!(Ts > 0.0) || !(step > 0.0)) throw std::invalid_argument("simulate_linearized: Ts and step must be > 0");
        if (start < 0 || start > K) throw std::invalid_argument("simulate_linearized: start must be in 0..K");
        double *Es, *Xs, *Js;
        Array E = new_array({size_t(K), size_t(n), size_t(self.n_aug)}, &Es);
        Array X = new_array({size_t(K + 1), size_t(n)}, &Xs);
        Array J = new_array({size_t(K - start), size_t(n), size_t(n)}, &Js);
        simulate_linearized(self, X0, u.data(), K, Ts, offset ? &*offset : nullptr, step, start, Es, Xs, Js);
        return nb::make_tuple(E, X, J);
      },
      nb::arg("update"), nb::arg("X0"), nb::arg("u_seq"), nb::arg("Ts"), nb::arg("offset").none(), nb::arg("step"),
      nb::arg("start") = 0,
      "(E (K, n_x, n_aug), X (K + 1, n_x), J (K − start, n_x, n_x)): ModelUpdate.simulate and stage_jacobians of its "
      "states in one call, the Jacobians of the finished stages on the pool's threads while the rollout goes on");
}
}  // namespace pgpc
