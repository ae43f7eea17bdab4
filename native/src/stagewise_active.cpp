// The stage-wise primal-dual active set of solvers/stagewise_active.py (solve_active_set), compiled:
// per iteration one Riccati sweep of the LQ problem with the active rows' components fixed
// (v_j = σ (f − Fz z): affine in the state, substituted stage by stage), one backward pass for the
// multipliers, the Hintermüller–Ito–Kunisch update of the set, stopped when the set repeats (KKT
// verified), cycles or reaches the cap. The Python module is the reference; this file follows it
// function by function (same names). One workspace serves every sweep of a solve.
#include <Eigen/Cholesky>
#include <nanobind/eigen/dense.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/string.h>
#include <algorithm>
#include <cmath>
#include <cstdio>
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
using InI = nb::ndarray<const int64_t, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using Traj = std::vector<Vec>;
using Set = Eigen::Matrix<int64_t, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;  // (nd, m): row or −1

constexpr double TOL = 1e-10;     // AS_TOL
constexpr double ACCEPT = 1e-6;   // AS_ACCEPT

struct Row {  // a used row of a stage: σ v_j + Fz_r z ≤ f_r
  long r, j;
  double sign, f;
  bool fz;  // Fz_r ≠ 0
};

using VMap = Eigen::Map<const Vec>;

struct QP {  // views of the caller's arrays (no copy)
  long N, nz, m, nd, k;
  std::vector<CMap> A, B, Q, Fz;
  std::vector<VMap> c, q;
  std::vector<std::vector<Row>> rows;  // per decision stage
  Vec z0;
  Mat R;
  double f_scale = 1e-12;
};

// The Riccati sweep of a fixed set (_sweep in the Python twin), its buffers kept from sweep to sweep
// (one per thread, kept from call to call: a controller's solves of one size allocate nothing here)
struct Sweep {
  const QP *qpp = nullptr;
  std::vector<Mat> K, E;
  Traj k, e;
  std::vector<std::vector<long>> free;
  std::vector<char> has_E;
  Mat P, Pz, PA, PB, Hvv, Hvz, Hz, Hww, Hwz;
  Vec p, lin, w, gv, gw, vf;
  Eigen::LLT<Mat> llt;

  // bind to qp, the per-stage buffers sized for it
  void prepare(const QP &qp) {
    qpp = &qp;
    if (long(E.size()) != qp.nd || (qp.nd && (E[0].rows() != qp.m || E[0].cols() != qp.nz))) {
      K.assign(qp.nd, Mat());
      E.assign(qp.nd, Mat::Zero(qp.m, qp.nz));
      k.assign(qp.nd, Vec());
      e.assign(qp.nd, Vec::Zero(qp.m));
      free.assign(qp.nd, {});
      has_E.assign(qp.nd, 1);  // E is zeroed on its first use
    }
  }

  void run(const Set &fixed, Traj &z, Traj &v) {
    const QP &qp = *qpp;
    const long N = qp.N, nd = qp.nd, m = qp.m;
    P = qp.Q[N];
    p = qp.q[N];
    for (long i = N - 1; i >= 0; --i) {
      const CMap &A = qp.A[i];
      PA.noalias() = P.lazyProduct(A);
      w = p;
      w.noalias() += P.lazyProduct(qp.c[i]);
      Pz = qp.Q[i];
      Pz.noalias() += A.transpose().lazyProduct(PA);
      lin = qp.q[i];
      lin.noalias() += A.transpose().lazyProduct(w);
      if (i < nd) {
        const CMap &B = qp.B[i];
        PB.noalias() = P.lazyProduct(B);
        Hvv = qp.R;
        Hvv.noalias() += B.transpose().lazyProduct(PB);
        gv.noalias() = B.transpose().lazyProduct(w);
        Hvz.noalias() = PB.transpose().lazyProduct(A);
        // v = E z + e on the fixed components
        Mat &Ei = E[i];
        Vec &ei = e[i];
        if (has_E[i]) Ei.setZero();
        ei.setZero();
        has_E[i] = 0;
        bool any_fixed = false;
        for (const Row &row : qp.rows[i]) {
          if (fixed(i, row.j) != row.r) continue;
          any_fixed = true;
          ei(row.j) = row.sign * row.f;
          if (row.fz) {
            Ei.row(row.j) = -row.sign * qp.Fz[i].row(row.r);
            has_E[i] = 1;
          }
        }
        if (any_fixed) {
          lin.noalias() += Hvz.transpose().lazyProduct(ei);
          gv.noalias() += Hvv.lazyProduct(ei);
          if (has_E[i]) {
            Hz = Hvz;
            Hz.noalias() += Hvv.lazyProduct(Ei);
            Pz.noalias() += Ei.transpose().lazyProduct(Hvz);
            Pz.noalias() += Hz.transpose().lazyProduct(Ei);
            lin.noalias() += Ei.transpose().lazyProduct(gv);
          } else {
            Hz = Hvz;
          }
        } else {
          Hz = Hvz;
        }
        std::vector<long> &fr = free[i];
        fr.clear();
        for (long j = 0; j < m; ++j)
          if (fixed(i, j) < 0) fr.push_back(j);
        const long nf = long(fr.size());
        if (nf) {
          if (nf == m) {
            Hww = Hvv;
            Hwz = Hz;
            gw = gv;
          } else {
            Hww.resize(nf, nf);
            Hwz.resize(nf, qp.nz);
            gw.resize(nf);
            for (long a = 0; a < nf; ++a) {
              for (long b = 0; b < nf; ++b) Hww(a, b) = Hvv(fr[a], fr[b]);
              Hwz.row(a) = Hz.row(fr[a]);
              gw(a) = gv(fr[a]);
            }
          }
          if (!Hww.allFinite())
            throw std::runtime_error("stage-wise active set: the free inputs' Hessian at stage " + std::to_string(i) +
                                     " has non-finite entries (NaN or inf in the model, the weights or the limits)");
          llt.compute(Hww);
          if (llt.info() != Eigen::Success)
            throw std::runtime_error("stage-wise active set: the free inputs' Hessian R + BᵀPB at stage " +
                                     std::to_string(i) +
                                     " is not positive definite (the input weight Qu must be nonsingular)");
          K[i] = llt.solve(Hwz);
          K[i] *= -1.0;
          k[i] = llt.solve(gw);
          k[i] *= -1.0;
          Pz.noalias() += Hwz.transpose().lazyProduct(K[i]);
          lin.noalias() += Hwz.transpose().lazyProduct(k[i]);
        }
      }
      P = 0.5 * (Pz + Pz.transpose());
      p = lin;
    }
    z.resize(N + 1);
    v.resize(nd);
    z[0] = qp.z0;
    for (long i = 0; i < N; ++i) {
      z[i + 1].noalias() = qp.A[i].lazyProduct(z[i]);
      z[i + 1] += qp.c[i];
      if (i < nd) {
        v[i] = e[i];
        if (has_E[i]) v[i].noalias() += E[i].lazyProduct(z[i]);
        const std::vector<long> &fr = free[i];
        if (!fr.empty()) {
          vf = k[i];
          vf.noalias() += K[i].lazyProduct(z[i]);
          for (size_t a = 0; a < fr.size(); ++a) v[i](fr[a]) = vf(long(a));
        }
        z[i + 1].noalias() += qp.B[i].lazyProduct(v[i]);
      }
    }
  }
};

// λ (N, k), the free components' v-gradient (nd, m) and the gradient's scale (_multipliers)
double multipliers(const QP &qp, const Set &fixed, const Traj &z, const Traj &v, RowMat &lam, RowMat &grad) {
  const long N = qp.N, nd = qp.nd;
  lam.setZero(N, qp.k);
  grad.setZero(nd, qp.m);
  double scale = 0.0;
  thread_local Vec nu, nxt, g, Rv;  // storage kept from call to call
  nu.noalias() = qp.Q[N] * z[N];
  nu += qp.q[N];
  for (long i = N - 1; i >= 0; --i) {
    nxt.noalias() = qp.A[i].transpose().lazyProduct(nu);
    if (i < nd) {
      Rv.noalias() = qp.R.lazyProduct(v[i]);
      g.noalias() = qp.B[i].transpose().lazyProduct(nu);
      scale = std::max({scale, Rv.cwiseAbs().maxCoeff(), g.cwiseAbs().maxCoeff()});
      g += Rv;
      for (long j = 0; j < qp.m; ++j)
        if (fixed(i, j) < 0) grad(i, j) = g(j);
      for (const Row &row : qp.rows[i]) {
        if (fixed(i, row.j) != row.r) continue;
        const double l = -row.sign * g(row.j);
        lam(i, row.r) = l;
        if (row.fz) nxt.noalias() += l * qp.Fz[i].row(row.r).transpose();
      }
    }
    if (i > 0) {
      nu.noalias() = qp.Q[i] * z[i];
      nu += qp.q[i];
      nu += nxt;
    }
  }
  return scale;
}

struct Outcome {
  Traj z, v;
  RowMat lam;
  Set fixed;
  int iterations = 0;
  bool ok = false;
  double residual = 0.0;
  std::string message;
};

// a start's entries that name no used row on their component: free (as in the Python twin)
void sanitize(const QP &qp, Set &fixed) {
  for (long i = 0; i < qp.nd; ++i)
    for (long j = 0; j < qp.m; ++j) {
      if (fixed(i, j) < 0) continue;
      bool found = false;
      for (const Row &row : qp.rows[i]) found = found || (row.r == fixed(i, j) && row.j == j);
      if (!found) fixed(i, j) = -1;
    }
}

Outcome solve_active_set(const QP &qp, Set fixed, int max_iter) {
  const long nd = qp.nd, m = qp.m;
  thread_local Sweep sweep;
  sweep.prepare(qp);
  Outcome out;
  RowMat grad;
  std::vector<Set> seen;
  Set next(nd, m);
  std::vector<double> worst(m);
  char buf[200];
  for (int it = 1; it <= max_iter; ++it) {
    sweep.run(fixed, out.z, out.v);
    const double scale = std::max(multipliers(qp, fixed, out.z, out.v, out.lam, grad), 1e-300);
    const double tol_f = TOL * qp.f_scale, tol_l = TOL * scale;
    double broken = 0.0;
    for (long i = 0; i < nd; ++i) {  // the next set (_update)
      std::fill(worst.begin(), worst.end(), 0.0);
      for (long j = 0; j < m; ++j) next(i, j) = -1;
      for (const Row &row : qp.rows[i]) {
        double Fx = row.sign * out.v[i](row.j);
        if (row.fz) Fx += qp.Fz[i].row(row.r).dot(out.z[i]);
        const double gap = Fx - row.f;
        broken = std::max(broken, gap);
        if (gap - tol_f > worst[row.j]) {
          worst[row.j] = gap - tol_f;
          next(i, row.j) = row.r;
        }
      }
      for (long j = 0; j < m; ++j)
        if (next(i, j) < 0 && fixed(i, j) >= 0 && out.lam(i, fixed(i, j)) >= -tol_l) next(i, j) = fixed(i, j);
    }
    out.residual = std::max({broken / qp.f_scale, std::max(-out.lam.minCoeff(), 0.0) / scale,
                             grad.size() ? grad.cwiseAbs().maxCoeff() / scale : 0.0});
    out.iterations = it;
    if (next == fixed) {
      out.fixed = fixed;
      out.ok = out.residual <= ACCEPT;
      if (!out.ok) {
        std::snprintf(buf, sizeof buf, "stage-wise active set: the set settled with a KKT residual %.3g above %g",
                      out.residual, ACCEPT);
        out.message = buf;
      }
      return out;
    }
    for (const Set &s : seen)
      if (s == next) {
        out.fixed = fixed;
        out.message = "stage-wise active set: the active set cycles after " + std::to_string(it) + " sweeps";
        return out;
      }
    seen.push_back(fixed);
    fixed = next;
  }
  out.fixed = fixed;
  std::snprintf(buf, sizeof buf, "stage-wise active set: not converged in %d sweeps (KKT residual %.3g)", max_iter,
                out.residual);
  out.message = buf;
  return out;
}

}  // namespace

void bind_stagewise_active(nb::module_ &m) {
  m.def(
      "stagewise_active",
      [](In3 A, In3 B, In2 c, In1 z0, In3 Q, In2 q, In2 R, long n_decide, In3 Fz, In2 f, InI comp, In2 sign,
         std::optional<InI> start, int max_iter) {
        QP qp;
        stage_arrays::read_lq(qp, A, B, c, z0, Q, q, R, n_decide, Fz, f, "stagewise_active");
        if (long(comp.shape(0)) != qp.N || long(comp.shape(1)) != qp.k || long(sign.shape(0)) != qp.N ||
            long(sign.shape(1)) != qp.k)
          throw std::invalid_argument("stagewise_active: inconsistent stage shapes");
        qp.rows.resize(qp.nd);
        for (long i = 0; i < qp.N; ++i)
          for (long r = 0; r < qp.k; ++r) {
            const long j = long(comp.data()[i * qp.k + r]);
            if (j < 0) continue;
            if (i >= qp.nd || j >= qp.m)
              throw std::invalid_argument("stagewise_active: a row on a stage without decision or a component ≥ m");
            const double fr = f.data()[i * qp.k + r];
            qp.rows[i].push_back({r, j, sign.data()[i * qp.k + r], fr, !qp.Fz[i].row(r).isZero(0.0)});
            qp.f_scale = std::max(qp.f_scale, std::abs(fr));
          }
        Set fixed = Set::Constant(qp.nd, qp.m, -1);
        if (start) {
          if (long(start->shape(0)) != qp.nd || long(start->shape(1)) != qp.m)
            throw std::invalid_argument("stagewise_active: the start must be (n_decide, m)");
          fixed = Eigen::Map<const Set>(start->data(), qp.nd, qp.m);
          sanitize(qp, fixed);
        }
        if (max_iter < 1) throw std::invalid_argument("stagewise_active: max_iter must be ≥ 1");
        Outcome res = solve_active_set(qp, fixed, max_iter);
        RowMat vout(qp.nd, qp.m), zout(qp.N + 1, qp.nz);
        for (long i = 0; i < qp.nd; ++i) vout.row(i) = res.v[i].transpose();
        for (long i = 0; i <= qp.N; ++i) zout.row(i) = res.z[i].transpose();
        return nb::make_tuple(vout, zout, res.lam, res.fixed, res.iterations, res.ok, res.residual, res.message);
      },
      nb::arg("A"), nb::arg("B"), nb::arg("c"), nb::arg("z0"), nb::arg("Q"), nb::arg("q"), nb::arg("R"),
      nb::arg("n_decide"), nb::arg("Fz"), nb::arg("f"), nb::arg("comp"), nb::arg("sign"),
      nb::arg("start") = nb::none(), nb::arg("max_iter") = 30,
      "(v, z, λ, fixed, iterations, ok, residual, message): solvers.stagewise_active.solve_active_set compiled "
      "(see that module); comp and sign: its InputRowMap; start (n_decide, m) int64 or None; max_iter: its "
      "AS_MAX_ITER (cold) or AS_WARM_MAX_ITER (from a start)");
}
}  // namespace pgpc
