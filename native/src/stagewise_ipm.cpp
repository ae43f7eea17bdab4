// The stage-wise interior point of solvers/stagewise_ipm.py (solve_stage_qp), compiled: Mehrotra's
// predictor-corrector with one Riccati factorization per iteration, Newton steps in delta form with
// iterative refinement, the objective scaled to unit curvature in v, and the active-set polish. The
// Python module is the reference; this file follows it function by function (same names), with one
// difference of form: the main loop keeps one Newton system bound to the iterate and its buffers.
#include <Eigen/Cholesky>
#include <nanobind/eigen/dense.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/optional.h>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "bindings.hpp"
#include "stage_arrays.hpp"
#include "zoh.hpp"

namespace pgpc {
namespace {
using stage_arrays::block, stage_arrays::CMap, stage_arrays::In1, stage_arrays::In2, stage_arrays::In3,
    stage_arrays::RowMat;
using InB = nb::ndarray<const bool, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using Arr = Eigen::ArrayXXd;  // (N, k) row quantities

constexpr double IPM_TOL = 1e-13, ACCEPT = 1e-6, PROGRESS = 0.5, REFINE_FORCING = 1e-3, POLISH_TOL = 1e-9,
                 POLISH_FLOOR = 1e-16, TAU = 0.995, FLOOR = 1e-9, SHIFT = 1e-14, SHIFT_MAX = 1e-8, WARM = 1e-3;
constexpr int MAX_ITER = 60, REFINE = 2, STALL = 3, POLISH_ROUNDS = 3, POLISH_STEPS = 2;

struct QP {
  long N, nz, m, nd, k;
  std::vector<Mat> A, B, Q, Fz, Fv;
  std::vector<char> fz_zero;  // per stage: Fz is all zero (input rows): its products are skipped
  std::vector<Vec> c, q;
  Vec z0;
  Mat R, S;
  bool has_S = false;
  Arr f;                                       // +inf on an unused row
  Arr f0;                                      // f with 0 on the unused rows (formed once, read by every iterate)
  Eigen::Array<bool, Eigen::Dynamic, Eigen::Dynamic> used, soft;
  double rho = 1.0, kappa = 1.0;
};

using Traj = std::vector<Vec>;

// The temporaries of one stage of a factorization: fixed-size (on the stack, products unrolled) for the
// stage sizes of stage_arrays::with_stage_sizes, dynamic otherwise (kept in the Riccati workspace)
template <int NZ, int M>
struct FactorTemps {
  Eigen::Matrix<double, NZ, NZ> P, Qi, PA, T;
  Eigen::Matrix<double, NZ, M> PB;
  Eigen::Matrix<double, M, M> Hvv;
  Eigen::Matrix<double, M, NZ> H;
  void resize(long nz, long m) {  // the dynamic ones' sizes (fixed: no-ops of the same size)
    P.resize(nz, nz), Qi.resize(nz, nz), PA.resize(nz, nz), T.resize(nz, nz), PB.resize(nz, m), Hvv.resize(m, m);
    H.resize(m, nz);
  }
};

// The Riccati factorization of one Newton system (row weights W) and its back-substitution. One
// workspace serves every factorization of a solve: the per-stage matrices are sized once, so the
// iterations allocate nothing here.
struct Riccati {
  const QP &qp;
  std::vector<Mat> Pn, Hvz, K;
  std::vector<Eigen::LLT<Mat>> llt;
  double h_max = 0.0;
  Mat WFz, WFv;
  FactorTemps<Eigen::Dynamic, Eigen::Dynamic> dyn;  // the temporaries of the sizes without a fixed-size factorization
  Traj kk;
  Vec p, w, tmp;

  explicit Riccati(const QP &qp)
      : qp(qp), Pn(qp.N, Mat(qp.nz, qp.nz)), Hvz(qp.nd, Mat(qp.m, qp.nz)), K(qp.nd, Mat(qp.m, qp.nz)),
        llt(qp.nd, Eigen::LLT<Mat>(qp.m)), WFz(qp.k, qp.nz), WFv(qp.k, qp.m), kk(qp.nd, Vec(qp.m)), p(qp.nz),
        w(qp.nz), tmp(qp.m) {
    dyn.resize(qp.nz, qp.m);
  }

  // stage i's input Hessian Hv factorized; regularize: see _cholesky in the Python twin
  template <class MH>
  void cholesky(long i, const MH &Hv, const Arr &W, bool regularize) {
    if (!Hv.allFinite())
      throw std::runtime_error("stage-wise IPM: the Newton system at stage " + std::to_string(i) +
                               " has non-finite entries (NaN or inf in the model, the weights or the limits)");
    const double top = Hv.diagonal().cwiseAbs().maxCoeff();
    llt[i].compute(Hv);
    double shift = SHIFT * top;
    while (llt[i].info() != Eigen::Success) {
      if (!regularize)
        throw std::runtime_error("stage-wise IPM: the input Hessian R + BᵀPB at stage " + std::to_string(i) +
                                 " is not positive definite (the input weight Qu must be nonsingular)");
      if (shift > SHIFT_MAX * top) {
        char buf[160];
        std::snprintf(buf, sizeof buf, "(row weights λ/t up to %.3g, the input Hessian's diagonal up to %.3g)",
                      W.rows() && W.cols() ? W.maxCoeff() : 0.0, top);
        throw std::runtime_error("stage-wise IPM: the Newton system at stage " + std::to_string(i) +
                                 " is singular to working precision " + buf +
                                 ": an ill-conditioned iterate, not the input weight");
      }
      Mat shifted = Hv;
      shifted.diagonal().array() += shift;
      llt[i].compute(shifted);
      shift *= 10.0;
    }
  }

  // the factorization, with the stage sizes fixed at compile time where with_stage_sizes knows them
  // (the same operations as the dynamic one; the sums of a product may round in another order)
  void factor(const Arr &W, bool regularize = false) {
    stage_arrays::with_stage_sizes(qp.nz, qp.m, [&](auto nz_, auto m_) {
      constexpr int NZ = decltype(nz_)::value, M = decltype(m_)::value;
      if constexpr (NZ == Eigen::Dynamic) {
        factor_sized(dyn, W, regularize);
      } else {
        FactorTemps<NZ, M> t;
        factor_sized(t, W, regularize);
      }
    });
  }

  template <int NZ, int M>
  void factor_sized(FactorTemps<NZ, M> &t, const Arr &W, bool regularize) {
    using MZ = Eigen::Matrix<double, NZ, NZ>;
    using MZM = Eigen::Matrix<double, NZ, M>;
    using MMZ = Eigen::Matrix<double, M, NZ>;
    const long nz = qp.nz, m = qp.m;
    h_max = 0.0;
    t.P = qp.Q[qp.N];
    for (long i = qp.N - 1; i >= 0; --i) {
      const Eigen::Map<const MZ> A(qp.A[i].data(), nz, nz);
      const Mat &Fz = qp.Fz[i];
      Pn[i] = t.P;
      // the matrices are small (a few rows): coefficient-wise products, no blocked-GEMM dispatch
      const bool fz = !qp.fz_zero[i];
      t.Qi = qp.Q[i];
      if (fz) {
        WFz.noalias() = W.row(i).matrix().asDiagonal() * Fz;
        t.Qi.noalias() += Fz.transpose().lazyProduct(WFz);
      }
      t.PA.noalias() = t.P.lazyProduct(A);
      if (i < qp.nd) {
        const Eigen::Map<const MZM> B(qp.B[i].data(), nz, m);
        const Mat &Fv = qp.Fv[i];
        t.PB.noalias() = t.P.lazyProduct(B);
        WFv.noalias() = W.row(i).matrix().asDiagonal() * Fv;
        t.Hvv = qp.R;
        t.Hvv.noalias() += Fv.transpose().lazyProduct(WFv);
        t.Hvv.noalias() += B.transpose().lazyProduct(t.PB);
        t.H.noalias() = t.PB.transpose().lazyProduct(A);
        if (fz) t.H.noalias() += Fv.transpose().lazyProduct(WFz);
        if (qp.has_S) t.H += qp.S;
        h_max = std::max(h_max, t.Hvv.diagonal().maxCoeff());
        cholesky(i, t.Hvv, W, regularize);
        Hvz[i] = t.H;
        K[i] = llt[i].solve(t.H);
        K[i] *= -1.0;
        const Eigen::Map<const MMZ> Ki(K[i].data(), m, nz);
        t.P = t.Qi;
        t.P.noalias() += A.transpose().lazyProduct(t.PA);
        t.P.noalias() += t.H.transpose().lazyProduct(Ki);
      } else {
        t.P = t.Qi;
        t.P.noalias() += A.transpose().lazyProduct(t.PA);
      }
      t.T = t.P.transpose();
      t.P = 0.5 * (t.P + t.T);
    }
  }

  // the back-substitution of the last factorization (fixed stage sizes as in factor)
  void solve(const Traj &gz, const Traj &gv, bool homogeneous, Traj &z, Traj &v) {
    stage_arrays::with_stage_sizes(qp.nz, qp.m, [&](auto nz_, auto m_) {
      solve_sized<decltype(nz_)::value, decltype(m_)::value>(gz, gv, homogeneous, z, v);
    });
  }

  template <int NZ, int M>
  void solve_sized(const Traj &gz, const Traj &gv, bool homogeneous, Traj &z, Traj &v) {
    using MZ = Eigen::Matrix<double, NZ, NZ>;
    using MZM = Eigen::Matrix<double, NZ, M>;
    using MMZ = Eigen::Matrix<double, M, NZ>;
    const long N = qp.N, nd = qp.nd, nz = qp.nz, m = qp.m;
    p = gz[N];
    for (long i = N - 1; i >= 0; --i) {
      const Eigen::Map<const MZ> A(qp.A[i].data(), nz, nz);
      w = p;
      if (!homogeneous) w.noalias() += Eigen::Map<const MZ>(Pn[i].data(), nz, nz).lazyProduct(qp.c[i]);
      if (i < nd) {
        const Eigen::Map<const MZM> B(qp.B[i].data(), nz, m);
        tmp = gv[i];
        tmp.noalias() += B.transpose().lazyProduct(w);
        kk[i] = llt[i].solve(tmp);
        kk[i] *= -1.0;
        p = gz[i];
        p.noalias() += A.transpose().lazyProduct(w);
        p.noalias() += Eigen::Map<const MMZ>(Hvz[i].data(), m, nz).transpose().lazyProduct(kk[i]);
      } else {
        p = gz[i];
        p.noalias() += A.transpose().lazyProduct(w);
      }
    }
    z.resize(N + 1);
    v.resize(nd);
    if (homogeneous) z[0].setZero(nz); else z[0] = qp.z0;
    for (long i = 0; i < N; ++i) {
      z[i + 1].noalias() = Eigen::Map<const MZ>(qp.A[i].data(), nz, nz).lazyProduct(z[i]);
      if (i < nd) {
        v[i].noalias() = Eigen::Map<const MMZ>(K[i].data(), m, nz).lazyProduct(z[i]);
        v[i] += kk[i];
        z[i + 1].noalias() += Eigen::Map<const MZM>(qp.B[i].data(), nz, m).lazyProduct(v[i]);
      }
      if (!homogeneous) z[i + 1] += qp.c[i];
    }
  }
};

// F [z; v] per stage into out (N, k), its storage kept
void rows_times(const QP &qp, const Traj &z, const Traj &v, Arr &out) {
  out.resize(qp.N, qp.k);
  for (long i = 0; i < qp.N; ++i) {
    auto r = out.row(i).matrix().transpose();
    if (qp.fz_zero[i]) r.setZero(); else r.noalias() = qp.Fz[i].lazyProduct(z[i]);
    if (i < qp.nd) r.noalias() += qp.Fv[i].lazyProduct(v[i]);
  }
}

Arr rows_times(const QP &qp, const Traj &z, const Traj &v) {
  Arr out;
  rows_times(qp, z, v, out);
  return out;
}

// (gz, gv) = Fᵀ y stage by stage; the outputs keep their storage from call to call
void rows_transpose(const QP &qp, const Arr &y, Traj &gz, Traj &gv) {
  gz.resize(qp.N + 1);
  gv.resize(qp.nd);
  for (long i = 0; i < qp.N; ++i) {
    if (qp.fz_zero[i]) gz[i].setZero(qp.nz);
    else gz[i].noalias() = qp.Fz[i].transpose().lazyProduct(y.row(i).matrix().transpose());
    if (i < qp.nd) gv[i].noalias() = qp.Fv[i].transpose().lazyProduct(y.row(i).matrix().transpose());
  }
  gz[qp.N].setZero(qp.nz);
}

// ν and the v-gradient (costates in the Python module); linear = false: without q
// (the buffers are per thread and keep their storage: no allocation once the sizes are seen)
void costates(const QP &qp, const Traj &z, const Traj &v, const Arr &lam, bool linear, Traj &nu, Traj &rv) {
  thread_local Traj gz, gv;
  rows_transpose(qp, lam, gz, gv);
  const long N = qp.N, nd = qp.nd;
  nu.resize(N + 1);
  for (long i = N; i >= 0; --i) {  // ν(i) = g(i) + Aᵀ ν(i+1), g the stage gradient; ν(0) unused (0)
    if (i == 0) {
      nu[0].setZero(qp.nz);
      break;
    }
    Vec &g = nu[i];
    g.noalias() = qp.Q[i].lazyProduct(z[i]);
    g += gz[i];
    if (linear) g += qp.q[i];
    if (qp.has_S && i < nd) g.noalias() += qp.S.transpose().lazyProduct(v[i]);
    if (i < N) g.noalias() += qp.A[i].transpose().lazyProduct(nu[i + 1]);
  }
  rv.resize(nd);
  for (long i = 0; i < nd; ++i) {
    rv[i].noalias() = qp.R.lazyProduct(v[i]);
    rv[i] += gv[i];
    rv[i].noalias() += qp.B[i].transpose().lazyProduct(nu[i + 1]);
    if (qp.has_S) rv[i].noalias() += qp.S.lazyProduct(z[i]);
  }
}

double max_abs(const Traj &x) {
  double out = 0.0;
  for (const Vec &e : x) if (e.size()) out = std::max(out, e.cwiseAbs().maxCoeff());
  return out;
}

struct Point {
  Traj z, v;
  Arr t, lam, s, pi;
};

using Mask = Eigen::Array<bool, Eigen::Dynamic, Eigen::Dynamic>;

// mask ? a : other, coefficient-wise (an expression: evaluated where it is assigned, no temporary)
template <class E>
auto where(const Mask &mask, const E &a, double other) {
  return mask.select(a, Arr::Constant(a.rows(), a.cols(), other));
}

// the rows the iterate pt deems active: λ and t each against its own scale (the polish's first set, the
// crossover's multipliers; the Python twin's _deemed_active)
Mask deemed_active(const Point &pt, const Mask &used, double scale, double f_scale) {
  return used && (pt.lam * f_scale > pt.t * scale);
}

// The Newton system of the iterate pt (a reference: an iteration moves pt and evaluates again,
// every buffer keeping its storage)
struct Newton {
  const QP &qp;
  const Mask &used, &soft;
  double scale, f_scale;
  const Point &pt;  // the iterate (outlives this system)
  const Arr &f;  // qp.f0
  Arr Fx, r_t, r_s, d, sp, a, W;
  double mu = 0.0, merit = 0.0, refine_above = 0.0;
  Traj nu, rv;
  Riccati *ric = nullptr;  // the solve's workspace, once factorized for this system

  Newton(const QP &qp, const Point &point, const Mask &used, const Mask &soft, double scale, double f_scale,
         Riccati *factor)
      : qp(qp), used(used), soft(soft), scale(scale), f_scale(f_scale), pt(point), f(qp.f0) {
    evaluate();
    if (factor) factorize(factor, false);
  }

  // the residuals, μ and the merit of pt
  void evaluate() {
    rows_times(qp, pt.z, pt.v, Fx);
    r_t = where(used, Fx - pt.s + pt.t - f, 0.0);
    r_s = where(soft, qp.rho + qp.kappa * pt.s - pt.lam - pt.pi, 0.0);
    const double n_ineq = std::max(1.0, double(used.count() + soft.count()));
    mu = (where(used, pt.t * pt.lam, 0.0).sum() + where(soft, pt.s * pt.pi, 0.0).sum()) / n_ineq;
    costates(qp, pt.z, pt.v, pt.lam, true, nu, rv);
    const double res = std::max(max_abs(rv), r_s.abs().maxCoeff()) / scale;
    merit = std::max({mu / (scale * f_scale), r_t.abs().maxCoeff() / f_scale, res});
    refine_above = std::max(1e-15, REFINE_FORCING * merit) * scale;  // an inexact Newton step (see the Python twin)
  }

  // the row weights and their Riccati factorization (into the solve's workspace)
  void factorize(Riccati *workspace, bool regularize) {
    ric = workspace;
    d = where(used, pt.lam / pt.t, 0.0);
    sp = where(soft, pt.pi / where(soft, pt.s, 1.0), 0.0);
    a = where(soft, qp.kappa + d + sp, 1.0);
    W = soft.select(d * (qp.kappa + sp) / a, d);
    ric->factor(W, regularize);
  }

  // (dz, dv, dt, dλ, ds, dπ)
  void direction(const Arr &r_tl, const Arr &r_sp, Point &step) const {
    thread_local Traj gz, gv, dz, dv, zero_z, nu1, rv1, cz, cv;  // storage kept from call to call
    thread_local Arr s_safe, gam, beta, w0, Fdx, lam1;
    s_safe = where(soft, pt.s, 1.0);
    gam = where(used, (-r_tl + pt.lam * r_t) / pt.t, 0.0);
    beta = where(soft, -r_s + gam - r_sp / s_safe, 0.0);
    w0 = soft.select((gam * (qp.kappa + sp) + d * (r_s + r_sp / s_safe)) / a, gam);
    rows_transpose(qp, w0, gz, gv);
    for (long i = 0; i < qp.nd; ++i) gv[i] += rv[i];
    ric->solve(gz, gv, true, dz, dv);
    zero_z.resize(qp.N + 1);
    for (Vec &e : zero_z) e.setZero(qp.nz);
    for (int r = 0; r < REFINE; ++r) {
      rows_times(qp, dz, dv, Fdx);
      lam1 = W * Fdx + w0;
      costates(qp, dz, dv, lam1, false, nu1, rv1);
      for (long i = 0; i < qp.nd; ++i) rv1[i] += rv[i];
      if (!(max_abs(rv1) > refine_above)) break;
      ric->solve(zero_z, rv1, true, cz, cv);
      for (long i = 0; i <= qp.N; ++i) dz[i] += cz[i];
      for (long i = 0; i < qp.nd; ++i) dv[i] += cv[i];
    }
    rows_times(qp, dz, dv, Fdx);
    step.z.swap(dz);
    step.v.swap(dv);
    step.s = where(soft, (beta + d * Fdx) / a, 0.0);
    step.lam = where(used, W * Fdx + w0, 0.0);
    step.t = where(used, -r_t - Fdx + step.s, 0.0);
    step.pi = where(soft, (-r_sp - pt.pi * step.s) / s_safe, 0.0);
  }

  double max_step(const Point &st, double frac) const {
    double alpha = 1.0;
    auto limit = [&](const Arr &x, const Arr &dx, const Mask &mask) {
      for (long i = 0; i < x.rows(); ++i)
        for (long j = 0; j < x.cols(); ++j)
          if (mask(i, j) && dx(i, j) < 0) alpha = std::min(alpha, frac * (-x(i, j) / dx(i, j)));
    };
    limit(pt.t, st.t, used);
    limit(pt.lam, st.lam, used);
    limit(pt.s, st.s, soft);
    limit(pt.pi, st.pi, soft);
    return alpha;
  }

  // the iterate moved by alpha along st, into out (its storage kept)
  void moved(const Point &st, double alpha, Point &out) const {
    out.z.resize(qp.N + 1);
    out.v.resize(qp.nd);
    for (long i = 0; i <= qp.N; ++i) out.z[i] = pt.z[i] + alpha * st.z[i];
    for (long i = 0; i < qp.nd; ++i) out.v[i] = pt.v[i] + alpha * st.v[i];
    out.t = where(used, pt.t + alpha * st.t, 1.0);
    out.lam = where(used, pt.lam + alpha * st.lam, 0.0);
    out.s = where(soft, pt.s + alpha * st.s, 0.0);
    out.pi = where(soft, pt.pi + alpha * st.pi, 1.0);
  }

  Point moved(const Point &st, double alpha) const {
    Point out;
    moved(st, alpha, out);
    return out;
  }
};

struct Result {
  Point pt;
  Traj nu;
  double merit;
  int iterations;
  bool ok;
};

bool polish(const QP &qp, Riccati &ric, const Point &point, const Mask &used, const Mask &soft, double scale,
            double f_scale, double merit, Result &out) {
  Mask active = deemed_active(point, used, scale, f_scale);
  const Arr &f = qp.f0;
  Point cur;
  Mask keep_soft;
  Arr gap;
  bool settled = false;
  for (int round = 0; round < POLISH_ROUNDS; ++round) {
    keep_soft = soft && active;
    cur = point;
    for (int k = 0; k < POLISH_STEPS; ++k) {
      const double tf = POLISH_FLOOR * f_scale, lf = POLISH_FLOOR * scale;
      Point start;
      start.z = cur.z;
      start.v = cur.v;
      start.t = where(active, cur.t.max(tf), 1.0);
      start.lam = where(active, cur.lam.max(lf), 0.0);
      start.s = where(keep_soft, cur.s.max(tf), 0.0);
      start.pi = where(keep_soft, cur.pi.max(lf), 1.0);
      try {
        Newton newton(qp, start, active, keep_soft, scale, f_scale, &ric);
        newton.refine_above = 1e-15 * scale;  // the polish is the last word: refined to the rounding floor
        Point step;
        newton.direction(where(active, start.t * start.lam, 0.0), where(keep_soft, start.s * start.pi, 0.0), step);
        cur = newton.moved(step, 1.0);
      } catch (const std::runtime_error &) {
        break;
      }
    }
    gap = f + cur.s - rows_times(qp, cur.z, cur.v);
    Mask broken = used && (!active) && (gap < -POLISH_TOL * f_scale);
    Mask negative = active && ((cur.lam < -POLISH_TOL * scale) || (keep_soft && (cur.s < -POLISH_TOL * f_scale)));
    if (!broken.any() && !negative.any()) {
      settled = true;
      break;
    }
    active = (active && !negative) || broken;
  }
  if (!settled || (used && (gap < -POLISH_TOL * f_scale)).any()) return false;
  Point pt = cur;
  pt.t = where(used, gap.max(0.0), 1.0);
  Mask dropped_soft = soft && !keep_soft;
  pt.pi = dropped_soft.select(qp.rho + qp.kappa * cur.s - cur.lam, cur.pi);
  pt.lam = cur.lam.max(0.0);
  pt.s = cur.s.max(0.0);
  pt.pi = where(soft, pt.pi.max(0.0), 1.0);
  Newton polished(qp, pt, used, soft, scale, f_scale, nullptr);
  if (!(polished.merit <= std::max(merit, IPM_TOL))) return false;
  out.pt = pt;
  out.nu = polished.nu;
  out.merit = polished.merit;
  return true;
}

// the states of the plan v: the dynamics rows held exactly
Traj simulate(const QP &qp, const Traj &v) {
  Traj z(qp.N + 1);
  z[0] = qp.z0;
  for (long i = 0; i < qp.N; ++i) {
    z[i + 1].noalias() = qp.A[i].lazyProduct(z[i]);
    z[i + 1] += qp.c[i];
    if (i < qp.nd) z[i + 1].noalias() += qp.B[i].lazyProduct(v[i]);
  }
  return z;
}

struct Start {  // a warm start's row multipliers (scaled) and slacks (N, k)
  Arr lam, s;
};

Result solve_scaled(const QP &qp, Traj z, Traj v, const Start *start, double crossover) {
  Riccati ric(qp);  // one workspace for every factorization of the solve
  Mask used = qp.used, soft = qp.soft && qp.used;
  const Arr &f = qp.f0;
  const double n_ineq = double(used.count() + soft.count());
  Traj zero_v(qp.nd, Vec::Zero(qp.m)), nu0, rv0;
  costates(qp, z, zero_v, Arr::Zero(qp.N, qp.k), true, nu0, rv0);
  const double scale = std::max({max_abs(rv0), soft.any() ? qp.rho : 0.0, 1e-300});
  double f_scale = 0.0;
  for (long i = 0; i < qp.N; ++i)
    for (long j = 0; j < qp.k; ++j)
      if (used(i, j)) f_scale = std::max(f_scale, std::abs(f(i, j)));
  f_scale = std::max(f_scale, 1e-12);
  Arr Fx = rows_times(qp, z, v);
  Point pt;
  pt.z = z;
  pt.v = v;
  pt.s = where(soft, (Fx - f).max(0.0) + f_scale, 0.0);
  pt.t = where(used, (f + pt.s - Fx).max(f_scale), 1.0);
  // λ0 = scale·N²: see the Python twin
  pt.lam = where(used, Arr::Constant(qp.N, qp.k, scale * double(qp.N) * double(qp.N)), 0.0);
  pt.pi = where(soft, Arr::Constant(qp.N, qp.k, scale), 1.0);
  if (start) {  // kept off the boundary (see the Python twin)
    const double th_t = WARM * f_scale, th_l = WARM * scale;
    pt.s = where(soft, start->s.max(Fx - f).max(0.0) + th_t, 0.0);
    pt.t = where(used, (f + pt.s - Fx).max(th_t), 1.0);
    pt.lam = where(used, start->lam.max(th_l), 0.0);
    pt.pi = where(soft, (qp.rho + qp.kappa * pt.s - pt.lam).max(th_l), 1.0);
  }
  Result best{pt, {}, std::numeric_limits<double>::infinity(), 0, false};
  bool have = false;
  double marked = std::numeric_limits<double>::infinity();  // merit and iteration of the last marked improvement
  int marked_it = 0;
  Newton sys(qp, pt, used, soft, scale, f_scale, nullptr);  // bound to pt: evaluated again as pt moves
  Newton *newton = &sys;
  Point next, aff, step;  // storage kept from iteration to iteration
  for (int it = 0; it <= MAX_ITER; ++it) {
    if (it) newton->evaluate();
    if (newton->merit <= crossover) {  // the caller's crossover: this iterate (not polished), see the Python twin
      Result out{pt, newton->nu, newton->merit, it, newton->merit <= ACCEPT};
      out.pt.lam = where(deemed_active(pt, used, scale, f_scale), pt.lam, 0.0);
      out.pt.s = where(soft, pt.s, 0.0);
      return out;
    }
    const bool improved = !have || newton->merit < best.merit;
    if (improved) {
      best.pt = pt;  // assignments: the best iterate's storage is reused
      best.nu = newton->nu;
      best.merit = newton->merit;
      best.iterations = it;
      have = true;
    }
    if (newton->merit < PROGRESS * marked) {
      marked = newton->merit;
      marked_it = it;
    }
    if (newton->merit <= IPM_TOL || it == MAX_ITER) break;
    // the rounding floor: keep the best iterate (the stopping iterate is never factorized)
    if ((it - marked_it >= STALL && best.merit <= ACCEPT) || (!improved && best.merit <= FLOOR)) break;
    try {
      newton->factorize(&ric, true);
    } catch (const std::runtime_error &) {
      if (best.merit <= ACCEPT) break;  // row weights beyond the factorization's precision
      throw;
    }
    newton->direction(where(used, pt.t * pt.lam, 0.0), where(soft, pt.s * pt.pi, 0.0), aff);
    double alpha = newton->max_step(aff, 1.0);
    const double mu_aff = (where(used, (pt.t + alpha * aff.t) * (pt.lam + alpha * aff.lam), 0.0).sum() +
                           where(soft, (pt.s + alpha * aff.s) * (pt.pi + alpha * aff.pi), 0.0).sum()) / n_ineq;
    const double sigma = std::pow(mu_aff / newton->mu, 3);
    newton->direction(where(used, pt.t * pt.lam + aff.t * aff.lam - sigma * newton->mu, 0.0),
                      where(soft, pt.s * pt.pi + aff.s * aff.pi - sigma * newton->mu, 0.0), step);
    newton->moved(step, newton->max_step(step, TAU), next);
    std::swap(pt, next);  // the contents: newton stays bound to pt
  }
  if (best.merit <= ACCEPT) {
    Result polished = best;
    if (polish(qp, ric, best.pt, used, soft, scale, f_scale, best.merit, polished)) best = polished;
  }
  best.ok = best.merit <= ACCEPT;
  best.pt.s = where(soft, best.pt.s, 0.0);
  return best;
}

}  // namespace

void bind_stagewise_ipm(nb::module_ &m) {
  m.def(
      "stagewise_ipm",
      [](In3 A, In3 B, In2 c, In1 z0, In3 Q, In2 q, In2 R, long n_decide, In3 Fz, In3 Fv, In2 f, InB soft, double rho,
         double kappa, nb::ndarray<const double, nb::c_contig, nb::device::cpu> S, std::optional<In2> v0,
         std::optional<In2> lam0, std::optional<In2> s0, double crossover) {
        QP qp;
        stage_arrays::read_lq(qp, A, B, c, z0, Q, q, R, n_decide, Fz, f, "stagewise_ipm");
        if (long(soft.shape(0)) != qp.N || long(soft.shape(1)) != qp.k || long(Fv.shape(0)) != qp.N)
          throw std::invalid_argument("stagewise_ipm: inconsistent stage shapes");
        for (long i = 0; i < qp.N; ++i) {
          qp.fz_zero.push_back(qp.Fz[i].isZero(0.0));
          qp.Fv.push_back(block(Fv, i));
        }
        qp.has_S = S.size() == size_t(qp.m * qp.nz);
        if (qp.has_S) qp.S = Eigen::Map<const RowMat>(S.data(), qp.m, qp.nz);
        qp.f = Eigen::Map<const RowMat>(f.data(), qp.N, qp.k).array();
        qp.used = qp.f.isFinite();
        qp.f0 = where(qp.used, qp.f, 0.0);
        qp.soft.resize(qp.N, qp.k);
        for (long i = 0; i < qp.N; ++i)
          for (long j = 0; j < qp.k; ++j) qp.soft(i, j) = soft.data()[i * qp.k + j];
        qp.rho = rho;
        qp.kappa = kappa;
        // the unconstrained plan, the scale σ of the curvature in v, then the scaled problem
        Riccati free(qp);
        free.factor(Arr::Zero(qp.N, qp.k));
        Traj z, v;
        Traj qz(qp.q.begin(), qp.q.end()), zero_v(qp.nd, Vec::Zero(qp.m));
        free.solve(qz, zero_v, false, z, v);
        const double sigma = free.h_max > 0.0 && std::isfinite(free.h_max) ? free.h_max : 1.0;
        Result res{{z, v, Arr::Ones(qp.N, qp.k), Arr::Zero(qp.N, qp.k), Arr::Zero(qp.N, qp.k),
                    Arr::Ones(qp.N, qp.k)}, {}, 0.0, 0, true};
        if (qp.used.any()) {
          for (auto &x : qp.Q) x /= sigma;
          for (auto &x : qp.q) x /= sigma;
          qp.R /= sigma;
          if (qp.has_S) qp.S /= sigma;
          qp.rho /= sigma;
          qp.kappa /= sigma;
          std::optional<Start> start;
          if (lam0 && s0) {
            if (long(lam0->shape(0)) != qp.N || long(lam0->shape(1)) != qp.k || long(s0->shape(0)) != qp.N ||
                long(s0->shape(1)) != qp.k)
              throw std::invalid_argument("stagewise_ipm: the warm start's λ and s must be (N, k)");
            start = Start{Eigen::Map<const RowMat>(lam0->data(), qp.N, qp.k).array() / sigma,
                          Eigen::Map<const RowMat>(s0->data(), qp.N, qp.k).array()};
          }
          if (v0) {
            if (long(v0->shape(0)) != qp.nd || long(v0->shape(1)) != qp.m)
              throw std::invalid_argument("stagewise_ipm: the warm start's v must be (n_decide, m)");
            for (long i = 0; i < qp.nd; ++i) v[i] = Eigen::Map<const Vec>(v0->data() + i * qp.m, qp.m);
            z = simulate(qp, v);
          }
          res = solve_scaled(qp, z, v, start ? &*start : nullptr, crossover);
          res.pt.lam *= sigma;
        }
        RowMat vout(qp.nd, qp.m), zout(qp.N + 1, qp.nz);
        for (long i = 0; i < qp.nd; ++i) vout.row(i) = res.pt.v[i].transpose();
        for (long i = 0; i <= qp.N; ++i) zout.row(i) = res.pt.z[i].transpose();
        RowMat sout = res.pt.s.matrix(), lout = res.pt.lam.matrix();
        return nb::make_tuple(Mat(vout), Mat(zout), Mat(sout), Mat(lout), res.iterations, res.ok, res.merit);
      },
      nb::arg("A"), nb::arg("B"), nb::arg("c"), nb::arg("z0"), nb::arg("Q"), nb::arg("q"), nb::arg("R"),
      nb::arg("n_decide"), nb::arg("Fz"), nb::arg("Fv"), nb::arg("f"), nb::arg("soft"), nb::arg("rho"),
      nb::arg("kappa"), nb::arg("S"), nb::arg("v0") = nb::none(), nb::arg("lam0") = nb::none(),
      nb::arg("s0") = nb::none(), nb::arg("crossover") = 0.0,
      "(v, z, s, λ, iterations, ok, merit): solvers.stagewise_ipm.solve_stage_qp compiled (see that module); "
      "v0 (n_decide, m) or None, lam0 and s0 (N, k): its StageStart (a warm start), or all None");
}
}  // namespace pgpc
