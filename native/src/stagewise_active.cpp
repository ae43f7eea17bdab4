// The stage-wise primal-dual active set of solvers/stagewise_active.py (solve_active_set), compiled:
// per iteration one Riccati sweep of the LQ problem with the active rows' components fixed
// (v_j = σ (f − Fz z): affine in the state, substituted stage by stage; only the stages up to the
// last one whose set changed are factorized again; a set within SCHUR_MAX components of the last full
// sweep's taken from that sweep's factorization by Sweep::update, the Schur complement of its responses),
// one backward pass for the multipliers, the
// Hintermüller–Ito–Kunisch update of the set (a box row's limited arc left only at its edges) or, once
// that stops shrinking, the cautious one, stopped when the set repeats (KKT verified), cycles or
// reaches the cap. The Python module is the
// reference; this file follows it function by function (same names). One workspace serves every
// sweep of a solve and is kept from solve to solve (a controller's steps allocate nothing once the
// first has sized it); the sweep's and the multipliers' stage products are fixed-size for the stage
// sizes of the robots measured (with_stage_sizes), dynamic for the others. Two entry points:
// `stagewise_active` (any StageQP of input rows; one workspace per thread) and the class
// `RiccatiActive` (a form's limited step in one call: its stage models and criterion built here,
// gpc/stagewise.py; its own workspace).
#include <Eigen/Core>
#include <Eigen/LU>
#include <nanobind/eigen/dense.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/string.h>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "bindings.hpp"
#include "small_solve.hpp"
#include "stage_arrays.hpp"
#include "stage_model.hpp"
#include "zoh.hpp"

namespace pgpc {
namespace {
using stage_arrays::block, stage_arrays::CMap, stage_arrays::In1, stage_arrays::In2, stage_arrays::In3,
    stage_arrays::RowMat, stage_arrays::with_stage_sizes;
using InI = nb::ndarray<const int64_t, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using OutI = nb::ndarray<int64_t, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using Traj = std::vector<Vec>;
using Set = Eigen::Matrix<int64_t, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;  // (nd, m): row or −1

constexpr double TOL = 1e-10;     // AS_TOL
constexpr double ACCEPT = 1e-6;   // AS_ACCEPT
constexpr double ROUNDING = 1e-12;  // AS_ROUNDING
constexpr long ARC_MIN = 10;      // ARC_MIN_STAGES
constexpr long SCHUR_MAX = 6;     // SCHUR_MAX

struct Row {  // a used row of a stage: σ v_j + Fz_r z ≤ f_r
  long r, j;
  double sign, f;
  bool fz;  // Fz_r ≠ 0
  // Fz_r = coef·e_qᵀ, one nonzero entry (the incremental and nonlinear forms' torque rows: a selector of the
  // held input), q = −1 otherwise: the sweep's products with E take its rows as such (Sweep::sweep)
  long q = -1;
  double coef = 0.0;
};

using VMap = Eigen::Map<const Vec>;

// the used row r of a stage's rows (a row it names: the caller's set or parameter)
const Row &row_of(const std::vector<Row> &rows, long r) {
  return *std::find_if(rows.begin(), rows.end(), [r](const Row &row) { return row.r == r; });
}

// Fz_r z of a used row of a stage (Fz: that stage's rows) on its state z: a selector's one entry (its row of Fz
// not read: the passes over the rows touch the rows' few numbers, not Fz's N·k·nz)
template <class Z>
double row_times(const CMap &Fz, const Row &row, const Z &z) {
  return row.q >= 0 ? row.coef * z(row.q) : row.fz ? Fz.row(row.r).dot(z) : 0.0;
}

// out += l · Fz_rᵀ for a used row (as row_times)
template <class Out>
void add_row(const CMap &Fz, const Row &row, double l, Out &out) {
  if (row.q >= 0)
    out(row.q) += l * row.coef;
  else if (row.fz)
    out.noalias() += l * Fz.row(row.r).transpose();
}

struct QP {  // views of the caller's arrays (no copy)
  long N, nz, m, nd, k;
  std::vector<CMap> A, B, Q, Fz;
  std::vector<VMap> c, q;
  std::vector<std::vector<Row>> rows;  // per decision stage
  std::vector<long> row_comp;          // (nd, k): the component of a used row, −1 for the others
  std::vector<char> row_box;           // (nd, k): a used row on v alone (Fz_r = 0)
  Vec z0;
  Mat R;
  double f_scale = 1e-12;
};

// The temporaries of one sweep's stage: fixed-size (on the stack, products unrolled) for the stage
// sizes of the common robots (Sweep::run's table), dynamic otherwise (kept in the Sweep: no
// allocation once sized). NZ: the stage state's size, M: the inputs'.
template <int NZ, int M>
struct SweepTemps {
  using MZ = Eigen::Matrix<double, NZ, NZ>;
  using MZM = Eigen::Matrix<double, NZ, M>;
  using MMZ = Eigen::Matrix<double, M, NZ>;
  using MM = Eigen::Matrix<double, M, M>;
  using VZ = Eigen::Matrix<double, NZ, 1>;
  using VM = Eigen::Matrix<double, M, 1>;
  MZ P, Pz, PA;
  MZM PB;
  MM Hvv, Hww;  // Hww: the free inputs' Hessian, the fixed ones' rows and columns those of the identity
  MMZ Hvz, Hz, Hwz;
  VZ p, lin, w;
  VM gv, gw, vf;
  void resize(long nz, long m) {  // the dynamic ones' sizes (fixed: no-ops of the same size)
    P.resize(nz, nz), Pz.resize(nz, nz), PA.resize(nz, nz), PB.resize(nz, m), Hvv.resize(m, m);
    Hww.resize(m, m), Hvz.resize(m, nz), Hz.resize(m, nz), Hwz.resize(m, nz), p.resize(nz), lin.resize(nz);
    w.resize(nz), gv.resize(m), gw.resize(m), vf.resize(m);
  }
};

// The products of a sweep's stage with Ā = [[X, Y], [0, I]] and B̄ = [[W], [I]] (Sweep::held: X nx × nx,
// Y nx × m, W nx × m, I m × m; nx = NZ − M), block by block: the zero blocks left out, the identity's
// terms added (of the 10 × 10 stage of the incremental forms, 6 states and 4 inputs: PĀ and ĀᵀPĀ 600
// multiply-adds each instead of 1000, PB̄ 240 instead of 400). `on`: fixed sizes with NZ > M only.
template <int NZ, int M>
struct Held {
  static constexpr bool on = NZ != Eigen::Dynamic && M != Eigen::Dynamic && NZ > M;
  static constexpr int NX = on ? NZ - M : 1;
  // PA ← P Ā
  template <class AM, class PM, class OM>
  static void right_A(const AM &A, const PM &P, OM &PA) {
    if constexpr (on) {
      PA.template leftCols<NX>().noalias() = P.template leftCols<NX>().lazyProduct(A.template topLeftCorner<NX, NX>());
      PA.template rightCols<M>() = P.template rightCols<M>();
      PA.template rightCols<M>().noalias() += P.template leftCols<NX>().lazyProduct(A.template topRightCorner<NX, M>());
    }
  }
  // out += Āᵀ X (X: nz rows)
  template <class AM, class XM, class OM>
  static void add_At(const AM &A, const XM &X, OM &out) {
    if constexpr (on) {
      out.template topRows<NX>().noalias() +=
          A.template topLeftCorner<NX, NX>().transpose().lazyProduct(X.template topRows<NX>());
      out.template bottomRows<M>().noalias() +=
          A.template topRightCorner<NX, M>().transpose().lazyProduct(X.template topRows<NX>());
      out.template bottomRows<M>() += X.template bottomRows<M>();
    }
  }
  // PB ← P B̄
  template <class BM, class PM, class OM>
  static void right_B(const BM &B, const PM &P, OM &PB) {
    if constexpr (on) {
      PB = P.template rightCols<M>();
      PB.noalias() += P.template leftCols<NX>().lazyProduct(B.template topRows<NX>());
    }
  }
  // out += B̄ᵀ X (X: nz rows)
  template <class BM, class XM, class OM>
  static void add_Bt(const BM &B, const XM &X, OM &out) {
    if constexpr (on) {
      out.noalias() += B.template topRows<NX>().transpose().lazyProduct(X.template topRows<NX>());
      out += X.template bottomRows<M>();
    }
  }
  // out ← Ā x
  template <class AM, class XV, class OV>
  static void times_A(const AM &A, const XV &x, OV &out) {
    if constexpr (on) {
      out.resize(NZ);
      out.template head<NX>().noalias() = A.template topLeftCorner<NX, NX>().lazyProduct(x.template head<NX>());
      out.template head<NX>().noalias() += A.template topRightCorner<NX, M>().lazyProduct(x.template tail<M>());
      out.template tail<M>() = x.template tail<M>();
    }
  }
};

// The Riccati sweep of a fixed set (_sweep in the Python twin), its buffers kept from sweep to sweep
// and from solve to solve (part of a Workspace)
struct Sweep {
  const QP *qpp = nullptr;
  // per stage, one contiguous buffer each (column-major blocks): the gains v = K_i z + k_i of the free
  // components (zero rows on the fixed ones) and v = E_i z + e_i of the fixed ones (zero rows on the free
  // ones), (m, nz) and (m,) per decision stage; P_i (nz, nz) and p_i (nz) of the last sweep (N + 1): a sweep
  // redoes only the stages up to the last one whose set changed (the later ones' P, p and gains are the same)
  std::vector<double> K, k, E, e, Ps, ps;
  std::vector<long> n_free;  // the free components per decision stage
  std::vector<char> has_E;
  // per stage (this solve's): Ā_i = [[X, Y], [0, I]] and B̄_i = [[W], [I]] with I the m × m identity (the
  // held input of the incremental, delayed and nonlinear forms, stage_model::fill): the sweep's products
  // then skip the zero and identity blocks (the same sums; only their order differs)
  std::vector<char> held;
  // held stages whose B̄_i is Ā_i's last m columns (W = Y: the incremental and nonlinear forms, not the delayed
  // one): B̄ᵀPĀ, B̄ᵀPB̄ and B̄ᵀw are the last m rows (and columns) of ĀᵀPĀ and Āᵀw, which the sweep forms anyway
  std::vector<char> tail;
  // the base of the Schur updates (update): the plan of the last full sweep (its set: `last`) and the
  // Cholesky factors of its free inputs' Hessians Hww (m × m per decision stage, column-major), and the
  // responses of that plan computed against them so far in this solve (n_responses of `responses`)
  std::vector<double> L, zb, vb;  // zb (N + 1) × nz and vb nd × m, row-major: the base plan
  struct Response {
    long i = 0, j = 0, r = 0;          // component j of v(i); r < 0 an offset, else a force on row r
    std::vector<double> z, v, p;      // (N + 1) × nz, nd × m, (N + 1) × nz, row-major
  };
  std::vector<Response> responses;
  size_t n_responses = 0;
  // update's workspaces: the changed components (i, j), the parameters (i, j, r) and their responses' indices,
  // the equations G θ = −c0 and their solution, a costate (stationarity)
  std::vector<std::array<long, 2>> changed;
  std::vector<std::array<long, 3>> params;
  std::vector<size_t> resp;
  Mat G;
  Vec c0, theta, nu;
  long sized[4] = {-1, -1, -1, -1};  // (N, nd, nz, m) the buffers are sized for
  Set last;             // the set of the last sweep
  bool valid = false;   // Ps, ps and last belong to this solve
  SweepTemps<Eigen::Dynamic, Eigen::Dynamic> dyn;  // the temporaries of the sizes without a fixed-size sweep

  // bind to qp (a new solve: nothing of the last sweep kept), the per-stage buffers sized for it
  void prepare(const QP &qp) {
    qpp = &qp;
    valid = false;
    n_responses = 0;
    if (sized[0] != qp.N || sized[1] != qp.nd || sized[2] != qp.nz || sized[3] != qp.m) {
      Ps.assign(size_t((qp.N + 1) * qp.nz * qp.nz), 0.0);
      ps.assign(size_t((qp.N + 1) * qp.nz), 0.0);
      K.assign(size_t(qp.nd * qp.m * qp.nz), 0.0);
      E.assign(K.size(), 0.0);
      k.assign(size_t(qp.nd * qp.m), 0.0);
      e.assign(k.size(), 0.0);
      n_free.assign(size_t(qp.nd), 0);
      has_E.assign(size_t(qp.nd), 0);  // E_i is zero
      L.assign(size_t(qp.nd * qp.m * qp.m), 0.0);
      sized[0] = qp.N, sized[1] = qp.nd, sized[2] = qp.nz, sized[3] = qp.m;
    }
    held.assign(size_t(qp.N), 0);
    tail.assign(size_t(qp.N), 0);
    const long m = qp.m, nx = qp.nz - qp.m;
    if (nx > 0)
      for (long i = 0; i < qp.N; ++i) {
        held[i] = qp.A[i].bottomLeftCorner(m, nx).isZero(0.0) &&
                  qp.A[i].bottomRightCorner(m, m).isIdentity(0.0) && qp.B[i].bottomRows(m).isIdentity(0.0);
        tail[i] = held[i] && qp.B[i].topRows(nx) == qp.A[i].topRightCorner(nx, m);
      }
  }

  [[noreturn]] static void not_definite(long i) {
    throw std::runtime_error("stage-wise active set: the free inputs' Hessian R + BᵀPB at stage " + std::to_string(i) +
                             " is not positive definite (the input weight Qu must be nonsingular)");
  }

  // the gains of a stage with nf < m free inputs from their own nf × nf block (the fixed ones' rows and columns of
  // Hww, Hwz and gw are the identity's and zero, so the bordered system's factor and solutions are the free block's
  // with zero rows; the same numbers at a fraction of the work: planar_4rrr, incremental, N = 160, 1 or 2 free
  // inputs of 4 on every stage): K, k written whole (zero rows on the fixed), Pz += Hwzᵀ K and lin += Hwzᵀ k,
  // and Hww ← its bordered Cholesky factor (the free block's factor at the free entries, L of the updates)
  template <int NZ, int M>
  void gains_of_free(long i, long nf, const Set &fixed, Eigen::Matrix<double, M, M> &Hww,
                     const Eigen::Matrix<double, M, NZ> &Hwz, const Eigen::Matrix<double, M, 1> &gw,
                     Eigen::Matrix<double, NZ, NZ> &Pz, Eigen::Matrix<double, NZ, 1> &lin,
                     Eigen::Map<Eigen::Matrix<double, M, NZ>> &Ki, Eigen::Map<Eigen::Matrix<double, M, 1>> &ki) {
    const long nz = Hwz.cols();
    long fr[M];
    for (long j = 0, a = 0; j < M; ++j)
      if (fixed(i, j) < 0) fr[a++] = j;
    Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, M, M> Hf(nf, nf);
    Eigen::Matrix<double, Eigen::Dynamic, NZ, 0, M, NZ> Hfz(nf, nz), Kf(nf, nz);
    Eigen::Matrix<double, Eigen::Dynamic, 1, 0, M, 1> kf(nf);
    for (long a = 0; a < nf; ++a) {
      for (long b = 0; b < nf; ++b) Hf(a, b) = Hww(fr[a], fr[b]);
      Hfz.row(a) = Hwz.row(fr[a]);
      kf(a) = -gw(fr[a]);
    }
    if (!small_solve::cholesky_in_place(Hf)) not_definite(i);
    Kf = -Hfz;
    small_solve::llt_solve_in_place(Hf, Kf);
    small_solve::llt_solve_in_place(Hf, kf);
    Pz.noalias() += Hfz.transpose().lazyProduct(Kf);
    lin.noalias() += Hfz.transpose().lazyProduct(kf);
    Ki.setZero();
    ki.setZero();
    for (long a = 0; a < nf; ++a) {
      Ki.row(fr[a]) = Kf.row(a);
      ki(fr[a]) = kf(a);
      for (long b = 0; b <= a; ++b) Hww(fr[a], fr[b]) = Hf(a, b);
    }
  }

  // the sweep, with the stage sizes (nz, m) of the robots measured fixed at compile time (the same
  // operations as the dynamic sweep; the sums of a product may round in another order)
  void run(const Set &fixed, Traj &z, Traj &v) {
    with_stage_sizes(qpp->nz, qpp->m, [&](auto nz_, auto m_) { run_sized<nz_(), m_()>(fixed, z, v); });
  }

  template <int NZ, int M>
  void run_sized(const Set &fixed, Traj &z, Traj &v) {
    if constexpr (NZ == Eigen::Dynamic) {
      dyn.resize(qpp->nz, qpp->m);
      sweep<NZ, M>(dyn, fixed, z, v);
    } else {
      SweepTemps<NZ, M> t;
      sweep<NZ, M>(t, fixed, z, v);
    }
  }

  template <int NZ, int M>
  void sweep(SweepTemps<NZ, M> &t, const Set &fixed, Traj &z, Traj &v) {
    using AM = Eigen::Map<const Eigen::Matrix<double, NZ, NZ, Eigen::RowMajor>>;
    using BM = Eigen::Map<const Eigen::Matrix<double, NZ, M, Eigen::RowMajor>>;
    using ZV = Eigen::Map<const Eigen::Matrix<double, NZ, 1>>;
    using ZZ = Eigen::Map<Eigen::Matrix<double, NZ, NZ>>;   // P_i
    using ZW = Eigen::Map<Eigen::Matrix<double, NZ, 1>>;    // p_i
    using GM = Eigen::Map<Eigen::Matrix<double, M, NZ>>;    // K_i, E_i
    using GV = Eigen::Map<Eigen::Matrix<double, M, 1>>;     // k_i, e_i
    const QP &qp = *qpp;
    const long N = qp.N, nd = qp.nd, m = qp.m, nz = qp.nz;
    auto &P = t.P, &Pz = t.Pz, &PA = t.PA;
    auto &PB = t.PB;
    auto &Hvv = t.Hvv, &Hww = t.Hww;
    auto &Hvz = t.Hvz, &Hz = t.Hz, &Hwz = t.Hwz;
    auto &p = t.p, &lin = t.lin, &w = t.w;
    auto &gv = t.gv, &gw = t.gw;
    auto Pi = [&](long i) { return ZZ(Ps.data() + i * nz * nz, nz, nz); };
    auto pi = [&](long i) { return ZW(ps.data() + i * nz, nz); };
    long top = N - 1;  // the last stage to redo
    if (valid) {
      top = -1;
      for (long i = nd - 1; i >= 0 && top < 0; --i)
        if (fixed.row(i) != last.row(i)) top = i;
    } else {
      Pi(N) = qp.Q[N];
      pi(N) = qp.q[N];
    }
    if (top >= 0) {
      P = Pi(top + 1);
      p = pi(top + 1);
    }
    for (long i = top; i >= 0; --i) {
      const AM A(qp.A[i].data(), nz, nz);
      w = p;
      w.noalias() += P.lazyProduct(ZV(qp.c[i].data(), nz));
      const bool blocks = Held<NZ, M>::on && held[i];
      const bool from_tail = blocks && tail[i] && i < nd;  // B̄ᵀPĀ, B̄ᵀPB̄, B̄ᵀw: blocks of ĀᵀPĀ, Āᵀw
      if (from_tail) {  // ĀᵀPĀ and Āᵀw alone first, their last m rows read, then Q and q added (whatever their rows)
        if constexpr (Held<NZ, M>::on) {
          Held<NZ, M>::right_A(A, P, PA);
          Pz.setZero();
          Held<NZ, M>::add_At(A, PA, Pz);
          Hvz = Pz.template bottomRows<M>();
          Pz += AM(qp.Q[i].data(), nz, nz);
          lin.setZero();
          Held<NZ, M>::add_At(A, w, lin);
          gv = lin.template bottomRows<M>();
          lin += ZV(qp.q[i].data(), nz);
        }
      } else if (blocks) {
        Pz = AM(qp.Q[i].data(), nz, nz);
        lin = ZV(qp.q[i].data(), nz);
        Held<NZ, M>::right_A(A, P, PA);
        Held<NZ, M>::add_At(A, PA, Pz);
        Held<NZ, M>::add_At(A, w, lin);
      } else {
        Pz = AM(qp.Q[i].data(), nz, nz);
        lin = ZV(qp.q[i].data(), nz);
        PA.noalias() = P.lazyProduct(A);
        Pz.noalias() += A.transpose().lazyProduct(PA);
        lin.noalias() += A.transpose().lazyProduct(w);
      }
      if (i < nd) {
        const BM B(qp.B[i].data(), nz, m);
        Hvv = qp.R;
        if (from_tail) {
          if constexpr (Held<NZ, M>::on) Hvv += Hvz.template rightCols<M>();
        } else if (blocks) {
          Held<NZ, M>::right_B(B, P, PB);
          Held<NZ, M>::add_Bt(B, PB, Hvv);
          gv.setZero();
          Held<NZ, M>::add_Bt(B, w, gv);
          Hvz.setZero();
          Held<NZ, M>::add_Bt(B, PA, Hvz);
        } else {
          PB.noalias() = P.lazyProduct(B);
          Hvv.noalias() += B.transpose().lazyProduct(PB);
          gv.noalias() = B.transpose().lazyProduct(w);
          Hvz.noalias() = B.transpose().lazyProduct(PA);  // (PB)ᵀA: P is symmetric
        }
        // v = E z + e on the fixed components
        GM Ei(E.data() + i * m * nz, m, nz);
        GV ei(e.data() + i * m, m);
        if (has_E[i]) Ei.setZero();
        ei.setZero();
        has_E[i] = 0;
        bool any_fixed = false, selectors = true;  // selectors: every row of E_i one entry (Row::q)
        for (const Row &row : qp.rows[i]) {
          if (fixed(i, row.j) != row.r) continue;
          any_fixed = true;
          ei(row.j) = row.sign * row.f;
          if (row.q >= 0) {  // Ei zero here: its row j one entry
            Ei(row.j, row.q) = -row.sign * row.coef;
            has_E[i] = 1;
          } else if (row.fz) {  // a row of several entries: E_i taken whole below
            Ei.row(row.j) = -row.sign * qp.Fz[i].row(row.r);
            has_E[i] = 1;
            selectors = false;
          }
        }
        Hz = Hvz;
        if (any_fixed) {
          lin.noalias() += Hvz.transpose().lazyProduct(ei);
          gv.noalias() += Hvv.lazyProduct(ei);
          if (has_E[i] && selectors) {  // E_i's row j = c_j e_qᵀ: Hvv E_i, E_iᵀ Hvz, Hzᵀ E_i and E_iᵀ gv a column or row each
            for (const Row &row : qp.rows[i])
              if (fixed(i, row.j) == row.r && row.fz) Hz.col(row.q) -= (row.sign * row.coef) * Hvv.col(row.j);
            for (const Row &row : qp.rows[i])
              if (fixed(i, row.j) == row.r && row.fz) {
                const double c = -row.sign * row.coef;
                Pz.row(row.q) += c * Hvz.row(row.j);
                Pz.col(row.q) += c * Hz.row(row.j).transpose();
                lin(row.q) += c * gv(row.j);
              }
          } else if (has_E[i]) {
            Hz.noalias() += Hvv.lazyProduct(Ei);
            Pz.noalias() += Ei.transpose().lazyProduct(Hvz);
            Pz.noalias() += Hz.transpose().lazyProduct(Ei);
            lin.noalias() += Ei.transpose().lazyProduct(gv);
          }
        }
        // v = K z + k on the free ones: the system of all m inputs with the fixed ones' rows and columns
        // those of the identity and their right-hand sides 0 (its factor is the free block's, bordered by the
        // identity: the same numbers, and zero gains on the fixed components), at a size known at compile time
        long nf = 0;
        for (long j = 0; j < m; ++j) nf += fixed(i, j) < 0;
        n_free[i] = nf;
        if (nf) {
          Hww = Hvv;
          Hwz = Hz;
          gw = gv;
          if (nf < m)
            for (long j = 0; j < m; ++j)
              if (fixed(i, j) >= 0) {
                Hww.row(j).setZero();
                Hww.col(j).setZero();
                Hww(j, j) = 1.0;
                Hwz.row(j).setZero();
                gw(j) = 0.0;
              }
          if (!Hww.allFinite())
            throw std::runtime_error("stage-wise active set: the free inputs' Hessian at stage " + std::to_string(i) +
                                     " has non-finite entries (NaN or inf in the model, the weights or the limits)");
          GM Ki(K.data() + i * m * nz, m, nz);
          GV ki(k.data() + i * m, m);
          bool compact = false;
          if constexpr (M != Eigen::Dynamic) compact = nf < m;
          if (compact) {
            if constexpr (M != Eigen::Dynamic) gains_of_free<NZ, M>(i, nf, fixed, Hww, Hwz, gw, Pz, lin, Ki, ki);
          } else {
            if (!small_solve::cholesky_in_place(Hww)) not_definite(i);
            Ki = -Hwz;  // K = −Hww⁻¹ Hwz, k = −Hww⁻¹ gw
            small_solve::llt_solve_in_place(Hww, Ki);
            ki = -gw;
            small_solve::llt_solve_in_place(Hww, ki);
            Pz.noalias() += Hwz.transpose().lazyProduct(Ki);
            lin.noalias() += Hwz.transpose().lazyProduct(ki);
          }
          std::copy(Hww.data(), Hww.data() + m * m, L.data() + i * m * m);
        }
      }
      for (long a = 0; a < nz; ++a)  // P = (Pz + Pzᵀ) / 2, each pair once
        for (long b = 0; b <= a; ++b) P(a, b) = P(b, a) = 0.5 * (Pz(a, b) + Pz(b, a));
      p = lin;
      Pi(i) = P;
      pi(i) = p;
    }
    last = fixed;
    valid = true;
    z.resize(N + 1);
    v.resize(nd);
    z[0] = qp.z0;
    auto &vf = t.vf;
    for (long i = 0; i < N; ++i) {
      const AM A(qp.A[i].data(), nz, nz);
      if (Held<NZ, M>::on && held[i])
        Held<NZ, M>::times_A(A, z[i], z[i + 1]);
      else
        z[i + 1].noalias() = A.lazyProduct(z[i]);
      z[i + 1] += qp.c[i];
      if (i < nd) {
        v[i] = GV(e.data() + i * m, m);
        if (has_E[i]) v[i].noalias() += GM(E.data() + i * m * nz, m, nz).lazyProduct(z[i]);
        if (n_free[i]) {  // the free components (0 on the fixed ones: their v stays E z + e)
          vf = GV(k.data() + i * m, m);
          vf.noalias() += GM(K.data() + i * m * nz, m, nz).lazyProduct(z[i]);
          v[i] += vf;
        }
        z[i + 1].noalias() += BM(qp.B[i].data(), nz, m).lazyProduct(v[i]);
      }
    }
    zb.resize(size_t((N + 1) * nz));
    vb.resize(size_t(nd * m));
    for (long i = 0; i <= N; ++i) Eigen::Map<Vec>(zb.data() + i * nz, nz) = z[i];
    for (long i = 0; i < nd; ++i) Eigen::Map<Vec>(vb.data() + i * m, m) = v[i];
    n_responses = 0;
  }

  // the response (R.z, R.v, R.p: the change of the base plan's z, v and p) per unit parameter at component j
  // of v(i) (_response in the Python twin): r < 0 an offset, v_j(i) = E z + e + θ (j fixed in the base set);
  // r ≥ 0 a force, θ (σ_r v_j(i) + Fz_r z_i) added to the cost. The base sweep's gains and factors, vectors only
  template <int NZ, int M>
  void response_sized(Response &R) {
    using AM = Eigen::Map<const Eigen::Matrix<double, NZ, NZ, Eigen::RowMajor>>;
    using BM = Eigen::Map<const Eigen::Matrix<double, NZ, M, Eigen::RowMajor>>;
    using ZZ = Eigen::Map<const Eigen::Matrix<double, NZ, NZ>>;
    using GM = Eigen::Map<const Eigen::Matrix<double, M, NZ>>;
    using LM = Eigen::Map<const Eigen::Matrix<double, M, M>>;
    using ZV = Eigen::Map<Eigen::Matrix<double, NZ, 1>>;
    using MV = Eigen::Map<Eigen::Matrix<double, M, 1>>;
    const QP &qp = *qpp;
    const long N = qp.N, nd = qp.nd, nz = qp.nz, m = qp.m, i = R.i, j = R.j;
    R.z.assign(size_t((N + 1) * nz), 0.0);
    R.v.assign(size_t(nd * m), 0.0);
    R.p.assign(size_t((N + 1) * nz), 0.0);
    Eigen::Matrix<double, NZ, 1> w = Eigen::Matrix<double, NZ, 1>::Zero(nz), lin(nz), Pb(nz);
    Eigen::Matrix<double, M, 1> gv(m), gw(m);
    for (long s = i; s >= 0; --s) {
      const AM A(qp.A[s].data(), nz, nz);
      const BM B(qp.B[s].data(), nz, m);
      lin.noalias() = A.transpose().lazyProduct(w);
      gv.noalias() = B.transpose().lazyProduct(w);
      if (s == i && R.r >= 0) {
        gv(j) += row_of(qp.rows[i], R.r).sign;
        add_row(qp.Fz[i], row_of(qp.rows[i], R.r), 1.0, lin);
      } else if (s == i) {  // Hvv e_j and Hvzᵀ e_j of the base's stage: R e_j + BᵀP B e_j, AᵀP B e_j
        Pb.noalias() = ZZ(Ps.data() + (s + 1) * nz * nz, nz, nz).lazyProduct(B.col(j));
        gv += qp.R.col(j);
        gv.noalias() += B.transpose().lazyProduct(Pb);
        lin.noalias() += A.transpose().lazyProduct(Pb);
      }
      if (has_E[s]) lin.noalias() += GM(E.data() + s * m * nz, m, nz).transpose().lazyProduct(gv);
      MV kd(R.v.data() + s * m, m);  // v(s) holds k's change until the forward pass
      if (n_free[s]) {
        gw = gv;
        for (long c = 0; c < m; ++c)
          if (last(s, c) >= 0) gw(c) = 0.0;
        lin.noalias() += GM(K.data() + s * m * nz, m, nz).transpose().lazyProduct(gw);
        const LM Ls(L.data() + s * m * m, m, m);
        small_solve::llt_solve_in_place(Ls, gw);
        kd = -gw;
      }
      ZV(R.p.data() + s * nz, nz) = lin;
      w = lin;
    }
    Eigen::Matrix<double, M, 1> vs(m);
    for (long s = 0; s < N; ++s) {
      const ZV zs(R.z.data() + s * nz, nz);
      ZV zn(R.z.data() + (s + 1) * nz, nz);
      zn.noalias() = AM(qp.A[s].data(), nz, nz).lazyProduct(zs);
      if (s < nd) {
        MV v(R.v.data() + s * m, m);
        vs = s <= i ? Eigen::Matrix<double, M, 1>(v) : Eigen::Matrix<double, M, 1>::Zero(m);
        if (s == i && R.r < 0) vs(j) += 1.0;
        if (has_E[s]) vs.noalias() += GM(E.data() + s * m * nz, m, nz).lazyProduct(zs);
        if (n_free[s]) vs.noalias() += GM(K.data() + s * m * nz, m, nz).lazyProduct(zs);
        v = vs;
        zn.noalias() += BM(qp.B[s].data(), nz, m).lazyProduct(vs);
      }
    }
  }

  // the v-gradient of component j of v(i) on a plan (z, v) with p (N + 1 rows of nz): R_j v(i) + B_iᵀ(P_{i+1} z(i+1) +
  // p(i+1)), ν(i+1) = P z + p of the base's stage i + 1
  double stationarity(long i, long j, const double *z, const double *v, const double *p) {
    const QP &qp = *qpp;
    const long nz = qp.nz, m = qp.m;
    const Eigen::Map<const Mat> P(Ps.data() + (i + 1) * nz * nz, nz, nz);
    nu = Eigen::Map<const Vec>(p + (i + 1) * nz, nz);
    nu.noalias() += P * Eigen::Map<const Vec>(z + (i + 1) * nz, nz);
    return qp.R.row(j).dot(Eigen::Map<const Vec>(v + i * m, m)) + qp.B[i].col(j).dot(nu);
  }

  // σ_r v_j(i) + Fz_r z(i) on a plan (z, v)
  double row_value(long i, long j, long r, const double *z, const double *v) const {
    const QP &qp = *qpp;
    const Row &row = row_of(qp.rows[i], r);
    return row.sign * v[i * qp.m + j] + row_times(qp.Fz[i], row, Eigen::Map<const Vec>(z + i * qp.nz, qp.nz));
  }

  // the plan of the set `fixed` from the base (the last full sweep of this solve) when it differs from the base's
  // set `last` in 1..SCHUR_MAX components (_sweep_update in the Python twin): one parameter per changed
  // component fixed in the base (an offset) and one per changed component fixed by a row now (a force on it), the
  // rows' equations and the freed components' stationarity solved for them; false: not applicable (a full sweep:
  // more changes, more than 2·SCHUR_MAX responses against this base, or a singular system)
  bool update(const Set &fixed, Traj &z, Traj &v) {
    if (!valid) return false;
    const QP &qp = *qpp;
    const long N = qp.N, nd = qp.nd, nz = qp.nz, m = qp.m;
    changed.clear();
    for (long i = 0; i < nd; ++i)
      for (long j = 0; j < m; ++j)
        if (fixed(i, j) != last(i, j)) {
          if (long(changed.size()) >= SCHUR_MAX) return false;
          changed.push_back({i, j});
        }
    if (changed.empty()) return false;
    params.clear();
    for (const auto &c : changed)
      if (last(c[0], c[1]) >= 0) params.push_back({c[0], c[1], -1});
    for (const auto &c : changed)
      if (fixed(c[0], c[1]) >= 0) params.push_back({c[0], c[1], long(fixed(c[0], c[1]))});
    const long n = long(params.size());
    // the index of a parameter's response against this base, n_responses when it has none yet
    const auto response_of = [this](const std::array<long, 3> &q) {
      size_t a = 0;
      while (a < n_responses && (responses[a].i != q[0] || responses[a].j != q[1] || responses[a].r != q[2])) ++a;
      return a;
    };
    size_t fresh = 0;
    for (const auto &q : params) fresh += response_of(q) == n_responses;
    if (n_responses + fresh > size_t(2 * SCHUR_MAX)) return false;  // about one sweep's cost: a full sweep
    resp.assign(size_t(n), 0);
    for (long b = 0; b < n; ++b) {
      const size_t a = response_of(params[b]);
      if (a == n_responses) {  // not computed against this base yet
        if (n_responses == responses.size()) responses.emplace_back();
        Response &R = responses[n_responses++];
        R.i = params[b][0], R.j = params[b][1], R.r = params[b][2];
        with_stage_sizes(nz, m, [&](auto nz_, auto m_) { response_sized<nz_(), m_()>(R); });
      }
      resp[b] = a;
    }
    G.setZero(n, n);
    c0.setZero(n);
    long eq = 0;
    for (const auto &c : changed) {
      const long i = c[0], j = c[1];
      if (last(i, j) >= 0) {  // stationary in v_j(i), with the force on its new row
        c0(eq) = stationarity(i, j, zb.data(), vb.data(), ps.data());
        for (long b = 0; b < n; ++b) {
          G(eq, b) = stationarity(i, j, responses[resp[b]].z.data(), responses[resp[b]].v.data(), responses[resp[b]].p.data());
          if (params[b][0] == i && params[b][1] == j && params[b][2] >= 0) G(eq, b) += row_of(qp.rows[i], params[b][2]).sign;
        }
        ++eq;
      }
      if (fixed(i, j) >= 0) {
        const long r = long(fixed(i, j));
        c0(eq) = row_value(i, j, r, zb.data(), vb.data()) - row_of(qp.rows[i], r).f;
        for (long b = 0; b < n; ++b) G(eq, b) = row_value(i, j, r, responses[resp[b]].z.data(), responses[resp[b]].v.data());
        ++eq;
      }
    }
    theta = G.partialPivLu().solve(-c0);
    if (!theta.allFinite()) return false;
    z.resize(N + 1);
    v.resize(nd);
    for (long s = 0; s <= N; ++s) {
      z[s] = Eigen::Map<const Vec>(zb.data() + s * nz, nz);
      for (long b = 0; b < n; ++b) z[s] += theta(b) * Eigen::Map<const Vec>(responses[resp[b]].z.data() + s * nz, nz);
    }
    for (long s = 0; s < nd; ++s) {
      v[s] = Eigen::Map<const Vec>(vb.data() + s * m, m);
      for (long b = 0; b < n; ++b) v[s] += theta(b) * Eigen::Map<const Vec>(responses[resp[b]].v.data() + s * m, m);
    }
    return true;
  }
};

// λ (N, k), the free components' v-gradient (nd, m) and the gradient's scale (costates with the active set, in
// solvers/stagewise_ipm.py)
template <int NZ, int M>
struct Costates {  // the buffers of multipliers() (fixed-size, or dynamic and kept in the Workspace)
  Eigen::Matrix<double, NZ, 1> nu, nxt;
  Eigen::Matrix<double, M, 1> g, Rv;
};

template <int NZ, int M>
double multipliers_sized(const QP &qp, const std::vector<char> &held, const Set &fixed, const Traj &z,
                         const Traj &v, RowMat &lam, RowMat &grad, Costates<NZ, M> &buf) {
  using AM = Eigen::Map<const Eigen::Matrix<double, NZ, NZ, Eigen::RowMajor>>;
  using BM = Eigen::Map<const Eigen::Matrix<double, NZ, M, Eigen::RowMajor>>;
  using ZV = Eigen::Map<const Eigen::Matrix<double, NZ, 1>>;
  const long N = qp.N, nd = qp.nd, nz = qp.nz, m = qp.m;
  lam.setZero(N, qp.k);
  grad.setZero(nd, qp.m);
  double scale = 0.0;
  auto &nu = buf.nu, &nxt = buf.nxt;
  auto &g = buf.g, &Rv = buf.Rv;
  nu.noalias() = AM(qp.Q[N].data(), nz, nz).lazyProduct(z[N]);
  nu += ZV(qp.q[N].data(), nz);
  for (long i = N - 1; i >= 0; --i) {
    const bool blocks = Held<NZ, M>::on && held[i];
    if (blocks) {
      nxt.setZero();
      Held<NZ, M>::add_At(AM(qp.A[i].data(), nz, nz), nu, nxt);
    } else {
      nxt.noalias() = AM(qp.A[i].data(), nz, nz).transpose().lazyProduct(nu);
    }
    if (i < nd) {
      Rv.noalias() = qp.R.lazyProduct(v[i]);
      if (blocks) {
        g.setZero();
        Held<NZ, M>::add_Bt(BM(qp.B[i].data(), nz, m), nu, g);
      } else {
        g.noalias() = BM(qp.B[i].data(), nz, m).transpose().lazyProduct(nu);
      }
      scale = std::max({scale, Rv.cwiseAbs().maxCoeff(), g.cwiseAbs().maxCoeff()});
      g += Rv;
      for (long j = 0; j < qp.m; ++j)
        if (fixed(i, j) < 0) grad(i, j) = g(j);
      for (const Row &row : qp.rows[i]) {
        if (fixed(i, row.j) != row.r) continue;
        const double l = -row.sign * g(row.j);
        lam(i, row.r) = l;
        add_row(qp.Fz[i], row, l, nxt);
      }
    }
    if (i > 0) {
      nu.noalias() = AM(qp.Q[i].data(), nz, nz).lazyProduct(z[i]);
      nu += ZV(qp.q[i].data(), nz);
      nu += nxt;
    }
  }
  return scale;
}

// multipliers_sized with the stage sizes of with_stage_sizes; held: Sweep::held; buf: the dynamic sizes' buffers
double multipliers(const QP &qp, const std::vector<char> &held, const Set &fixed, const Traj &z, const Traj &v,
                   RowMat &lam, RowMat &grad, Costates<Eigen::Dynamic, Eigen::Dynamic> &buf) {
  return with_stage_sizes(qp.nz, qp.m, [&](auto nz_, auto m_) {
    constexpr int NZ = nz_(), M = m_();
    if constexpr (NZ == Eigen::Dynamic) {
      return multipliers_sized(qp, held, fixed, z, v, lam, grad, buf);
    } else {
      Costates<NZ, M> local;
      return multipliers_sized(qp, held, fixed, z, v, lam, grad, local);
    }
  });
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

// everything a solve writes, kept from solve to solve (sized by the first solve of a problem size)
struct Workspace {
  Sweep sweep;
  Costates<Eigen::Dynamic, Eigen::Dynamic> costates;
  Outcome out;
  RowMat grad;
  Set fixed, next, brk;  // the set of a sweep (the start on entry), the next one, each component's most broken row
  Set arc;               // the length of the run of stages each entry of `fixed` lies in (arc_lengths)
  std::vector<Set> seen;  // the sets swept so far: the first n_seen entries
  size_t n_seen = 0;
  std::vector<double> worst;
  std::vector<std::pair<double, long>> negative;  // (λ, i·m + j) of the fixed components with λ < 0
  std::vector<long> inner_kept;  // i·m + j of the components with λ < 0 the full update kept inside a box arc
};

// the largest term the v-gradient R v(i) + Bᵢᵀ ν(i+1) sums, in absolute values (_terms_scale in the Python twin): |R||v|
// and |Bᵢ|ᵀ ν̄(i+1), ν̄ the costates' recursion on absolute values; only when a settled set's KKT residual is above ACCEPT
double terms_scale(const QP &qp, const Traj &z, const Traj &v, const RowMat &lam) {
  const long N = qp.N, nd = qp.nd;
  Vec nb = qp.Q[N].cwiseAbs() * z[N].cwiseAbs() + qp.q[N].cwiseAbs();
  double scale = 0.0;
  const Mat Rabs = qp.R.cwiseAbs();
  for (long i = 0; i < nd; ++i) scale = std::max(scale, (Rabs * v[i].cwiseAbs()).maxCoeff());
  for (long i = N - 1; i >= 0; --i) {
    if (i < nd) scale = std::max(scale, (qp.B[i].cwiseAbs().transpose() * nb).maxCoeff());
    Vec next = qp.Q[i].cwiseAbs() * z[i].cwiseAbs() + qp.q[i].cwiseAbs();
    next.noalias() += qp.A[i].cwiseAbs().transpose() * nb;
    next.noalias() += qp.Fz[i].cwiseAbs().transpose() * lam.row(i).cwiseAbs().transpose();
    nb.swap(next);
  }
  return scale;
}

// a start's entries that name no used row on their component: free (as in the Python twin)
void sanitize(const QP &qp, Set &fixed) {
  for (long i = 0; i < qp.nd; ++i)
    for (long j = 0; j < qp.m; ++j) {
      const int64_t r = fixed(i, j);
      if (r >= 0 && (r >= qp.k || qp.row_comp[i * qp.k + r] != j)) fixed(i, j) = -1;
    }
}

// qp.rows (per decision stage) and qp.f_scale from the InputRowMap (comp, sign) and the bounds f
void read_rows(QP &qp, const InI &comp, const In2 &sign, const In2 &f, const char *who) {
  if (long(comp.shape(0)) != qp.N || long(comp.shape(1)) != qp.k || long(sign.shape(0)) != qp.N ||
      long(sign.shape(1)) != qp.k)
    throw std::invalid_argument(std::string(who) + ": inconsistent stage shapes");
  qp.rows.assign(qp.nd, {});
  qp.row_comp.assign(qp.nd * qp.k, -1);
  qp.row_box.assign(qp.nd * qp.k, 0);
  for (long i = 0; i < qp.N; ++i)
    for (long r = 0; r < qp.k; ++r) {
      const long j = long(comp.data()[i * qp.k + r]);
      if (j < 0) continue;
      if (i >= qp.nd || j >= qp.m)
        throw std::invalid_argument(std::string(who) + ": a row on a stage without decision or a component ≥ m");
      const double fr = f.data()[i * qp.k + r];
      qp.rows[i].push_back({r, j, sign.data()[i * qp.k + r], fr, !qp.Fz[i].row(r).isZero(0.0)});
      Row &row = qp.rows[i].back();
      for (long c = 0; c < qp.nz; ++c)
        if (qp.Fz[i](r, c) != 0.0) {
          if (row.q >= 0) {  // a second nonzero: not a selector
            row.q = -1;
            break;
          }
          row.q = c, row.coef = qp.Fz[i](r, c);
        }
      qp.row_comp[i * qp.k + r] = j;
      qp.row_box[i * qp.k + r] = !row.fz;
      qp.f_scale = std::max(qp.f_scale, std::abs(fr));
    }
}

// component j of v(i) held by a box row (on v alone) that also holds the stages i − 1 and i + 1, in an arc
// of at least ARC_MIN stages (arc: each component's run length, arc_lengths): inside a limited arc, kept
// whatever its multiplier (_inside_box_arcs in the Python twin: only the arc's edges leave)
bool inside_box_arc(const QP &qp, const Set &fixed, const Set &arc, long i, long j) {
  const int64_t r = fixed(i, j);
  return r >= 0 && i > 0 && i + 1 < qp.nd && qp.row_box[i * qp.k + r] && fixed(i - 1, j) == r &&
         fixed(i + 1, j) == r && arc(i, j) >= ARC_MIN;
}

// arc (nd, m) ← the length of the run of equal entries of `fixed` each entry lies in, per component
void arc_lengths(const Set &fixed, Set &arc) {
  const long nd = fixed.rows(), m = fixed.cols();
  arc.resize(nd, m);
  for (long j = 0; j < m; ++j)
    for (long s = 0, e; s < nd; s = e) {
      for (e = s + 1; e < nd && fixed(e, j) == fixed(s, j); ++e) {
      }
      for (long i = s; i < e; ++i) arc(i, j) = e - s;
    }
}

// from the start ws.fixed (nd, m); warm: a start was given (the cautious update also when the changes
// stop shrinking, as in the Python twin). The outcome is ws.out.
const Outcome &solve_active_set(const QP &qp, Workspace &ws, int max_iter, bool warm) {
  const long nd = qp.nd, m = qp.m;
  Sweep &sweep = ws.sweep;
  sweep.prepare(qp);
  Outcome &out = ws.out;
  out.iterations = 0;
  out.ok = false;
  out.residual = 0.0;
  out.message.clear();
  RowMat &grad = ws.grad;
  Set &fixed = ws.fixed, &next = ws.next, &brk = ws.brk;
  next.resize(nd, m);
  brk.resize(nd, m);  // −1 where no row of the component is broken
  std::vector<double> &worst = ws.worst;
  worst.resize(m);
  std::vector<std::pair<double, long>> &negative = ws.negative;
  std::vector<Set> &seen = ws.seen;
  ws.n_seen = 0;
  char buf[200];
  long fewest = nd * m + 1, frees = 0;  // frees: 0 while the full update runs
  bool freed = false;
  auto was_seen = [&ws](const Set &s) {
    for (size_t a = 0; a < ws.n_seen; ++a)
      if (ws.seen[a] == s) return true;
    return false;
  };
  for (int it = 1; it <= max_iter; ++it) {
    if (!sweep.update(fixed, out.z, out.v)) sweep.run(fixed, out.z, out.v);
    const double scale =
        std::max(multipliers(qp, sweep.held, fixed, out.z, out.v, out.lam, grad, ws.costates), 1e-300);
    const double tol_f = TOL * qp.f_scale, tol_l = TOL * scale;
    double broken = 0.0;
    bool any_broken = false;
    ws.inner_kept.clear();
    arc_lengths(fixed, ws.arc);
    for (long i = 0; i < nd; ++i) {  // the next set (_update)
      std::fill(worst.begin(), worst.end(), 0.0);
      for (long j = 0; j < m; ++j) brk(i, j) = -1;
      for (const Row &row : qp.rows[i]) {
        const double Fx = row.sign * out.v[i](row.j) + row_times(qp.Fz[i], row, out.z[i]);
        const double gap = Fx - row.f;
        broken = std::max(broken, gap);
        if (gap - tol_f > worst[row.j]) {
          worst[row.j] = gap - tol_f;
          brk(i, row.j) = row.r;
        }
      }
      for (long j = 0; j < m; ++j) {
        any_broken = any_broken || brk(i, j) >= 0;
        if (brk(i, j) >= 0) {
          next(i, j) = brk(i, j);
        } else if (fixed(i, j) >= 0 && out.lam(i, fixed(i, j)) >= -tol_l) {
          next(i, j) = fixed(i, j);
        } else if (inside_box_arc(qp, fixed, ws.arc, i, j)) {
          next(i, j) = fixed(i, j);
          ws.inner_kept.push_back(i * m + j);
        } else {
          next(i, j) = -1;
        }
      }
    }
    // _next_set: the rule would keep the set (the arcs' edges hold, their inside does not): freed as without it
    if (!ws.inner_kept.empty() && next == fixed)
      for (long c : ws.inner_kept) next(c / m, c % m) = -1;
    // the rows' excess, λ's negative part and the free gradient, the last two over a gradient scale
    const auto kkt_residual = [&](double gradient_scale) {
      return std::max({broken / qp.f_scale, std::max(-out.lam.minCoeff(), 0.0) / gradient_scale,
                       grad.size() ? grad.cwiseAbs().maxCoeff() / gradient_scale : 0.0});
    };
    out.residual = kkt_residual(scale);
    out.iterations = it;
    if (next == fixed) {
      out.fixed = fixed;
      if (out.residual > ACCEPT)  // or rounding: the gradient's scale at least ROUNDING / ACCEPT of its terms'
        out.residual = kkt_residual(std::max(scale, ROUNDING / ACCEPT * terms_scale(qp, out.z, out.v, out.lam)));
      out.ok = out.residual <= ACCEPT;
      if (!out.ok) {
        std::snprintf(buf, sizeof buf, "stage-wise active set: the set settled with a KKT residual %.3g above %g",
                      out.residual, ACCEPT);
        out.message = buf;
      }
      return out;
    }
    // the full update while it proposes no set seen before and (from a start) fewer changes each sweep,
    // then the cautious one: one component freed per sweep, twice as many after frees that broke no
    // row, half as many after frees that did
    const long n_changed = long((next.array() != fixed.array()).count());
    if (frees == 0 && ((warm && n_changed >= fewest) || was_seen(next))) frees = 1;
    fewest = std::min(fewest, n_changed);
    if (frees > 0) {
      if (freed) frees = any_broken ? std::max(1L, frees / 2) : 2 * frees;
      if (any_broken) {  // the broken components fixed, the others kept
        for (long i = 0; i < nd; ++i)
          for (long j = 0; j < m; ++j) next(i, j) = brk(i, j) >= 0 ? brk(i, j) : fixed(i, j);
      } else {  // the `frees` most negative multipliers' components freed
        next = fixed;
        negative.clear();
        for (int with_inner = 0; with_inner < 2 && negative.empty(); ++with_inner)  // _next_set: inner ones last
          for (long i = 0; i < nd; ++i)
            for (long j = 0; j < m; ++j)
              if (fixed(i, j) >= 0 && out.lam(i, fixed(i, j)) < -tol_l &&
                  (with_inner || !inside_box_arc(qp, fixed, ws.arc, i, j)))
                negative.push_back({out.lam(i, fixed(i, j)), i * m + j});
        std::stable_sort(negative.begin(), negative.end(),
                         [](const auto &a, const auto &b) { return a.first < b.first; });
        for (size_t a = 0; a < negative.size() && long(a) < frees; ++a) next(negative[a].second / m, negative[a].second % m) = -1;
      }
      freed = !any_broken;
      if (was_seen(next)) {
        out.fixed = fixed;
        out.ok = out.residual <= ACCEPT;  // _unsettled: the last sweep accepted when its KKT conditions hold
        if (!out.ok) out.message = "stage-wise active set: the active set cycles after " + std::to_string(it) + " sweeps";
        return out;
      }
    }
    if (ws.n_seen < seen.size()) seen[ws.n_seen] = fixed; else seen.push_back(fixed);
    ++ws.n_seen;
    out.fixed = fixed;  // the set of the last sweep
    fixed.swap(next);  // next is overwritten before it is read again
  }
  out.ok = out.residual <= ACCEPT;
  if (!out.ok) {
    std::snprintf(buf, sizeof buf, "stage-wise active set: not converged in %d sweeps (KKT residual %.3g)", max_iter,
                  out.residual);
    out.message = buf;
  }
  return out;
}


// out ← a step's set (nd, m) shifted by one stage, the last stage repeated (shift_active_set without `before`)
void shift_set(const Set &fixed, Set &out) {
  const long nd = fixed.rows();
  out.resize(nd, fixed.cols());
  if (nd == 0) return;
  out.topRows(nd - 1) = fixed.bottomRows(nd - 1);
  out.row(nd - 1) = fixed.row(nd - 1);
}

// out (`fixed` shifted, shift_set) with every moved edge moved again: _extrapolate_edges of
// solvers/stagewise_active.py, its twin (the reference; same runs, same order). was: the set of the step
// before, shifted. A run: consecutive stages of one component where `fixed` differs from `was`, all one value r;
// an edge when next on one side only to a stage holding r in both; moved again by the run's length in the same
// direction over the stages (of the shifted frame) holding what lay beyond it.
void extrapolate_edges(const Set &fixed, const Set &was, Set &out) {
  const long nd = fixed.rows(), m = fixed.cols();
  for (long j = 0; j < m; ++j)
    for (long i = 0; i < nd;) {
      if (fixed(i, j) == was(i, j)) {
        ++i;
        continue;
      }
      const long s = i;
      const int64_t r = fixed(s, j);
      long e = s;
      while (e + 1 < nd && fixed(e + 1, j) != was(e + 1, j) && fixed(e + 1, j) == r) ++e;
      i = e + 1;
      const long length = e - s + 1;
      const bool grew_later = s > 0 && fixed(s - 1, j) == r && was(s - 1, j) == r;
      const bool grew_earlier = e + 1 < nd && fixed(e + 1, j) == r && was(e + 1, j) == r;
      if (grew_later == grew_earlier) continue;  // no side or both: not an edge
      if (grew_later) {  // the next stages after the run (at s − 1 … e − 1 once shifted)
        if (e + 1 >= nd) continue;
        const int64_t beyond = fixed(e + 1, j);
        for (long t = e; t < std::min(e + length, nd) && out(t, j) == beyond; ++t) out(t, j) = r;
      } else {
        if (s == 0) continue;
        const int64_t beyond = fixed(s - 1, j);
        for (long t = s - 2; t > std::max(s - 2 - length, -1L) && out(t, j) == beyond; --t) out(t, j) = r;
      }
    }
}

// The controller's torque/Δu-limited problem of a form (0 absolute, 1 incremental, 2 delayed, 3 the
// nonlinear form's deviation model) in one call per step: the stage models (stage_model.hpp) and the
// criterion's linear terms built here from the step's (A_d, B_d, c_d, x0, u0, targets; form 3: A_i,
// B_i along the pre-simulation, z0 = 0), the rows (Fz, comp, sign: the controller's StageQP template,
// the same every step) kept from construction with their bounds f, which a step may replace (the
// nonlinear form's move with the pre-simulated inputs), then solve_active_set and J. It keeps the controller's
// last set (keep) and starts a warm step from it (solve with warm): StagewiseSolver._next_start, _plain_after and
// _keep_set of gpc/stagewise.py, compiled (the Python path's rule, its reference; moves_edges: EDGE_FORMS there).
class RiccatiActive {
 public:
  RiccatiActive(const Mat &C, const Mat &Wy, const Mat &Wu, long N, long No, long Nu, int form, In3 Fz, In2 f,
                InI comp, In2 sign, bool moves_edges)
      : n(C.cols()), m(Wu.rows()), p(C.rows()), N(N), No(No), Nu(Nu), form(form), moves_edges_(moves_edges) {
    if (form < 0 || form > 3) throw std::invalid_argument("RiccatiActive: form must be 0..3");
    if (N < 1 || No < 0 || No >= N || Nu < 1 || Nu > N) throw std::invalid_argument("RiccatiActive: bad horizons");
    if (Wy.rows() != p || Wy.cols() != p || Wu.cols() != m) throw std::invalid_argument("RiccatiActive: weights");
    nz = stage_model::state_size(form, n, m, N, Nu);
    const long k = long(f.shape(1));
    if (long(Fz.shape(0)) != N || long(Fz.shape(1)) != k || long(Fz.shape(2)) != nz || long(f.shape(0)) != N ||
        long(comp.shape(0)) != N || long(comp.shape(1)) != k || long(sign.shape(0)) != N ||
        long(sign.shape(1)) != k)
      throw std::invalid_argument("RiccatiActive: rows Fz (N, k, nz), f, comp, sign (N, k)");
    C_ = C;
    Wy_ = Wy;
    Wu_ = Wu;
    Mat Cz = Mat::Zero(p, nz);
    Cz.leftCols(n) = C;
    CQ2_ = 2.0 * Cz.transpose() * (Wy.transpose() * Wy);
    Q2_ = CQ2_ * Cz;
    zero_ = RowMat::Zero(nz, nz);
    Ab_.assign(N, RowMat::Zero(nz, nz));
    Bb_.assign(N, RowMat::Zero(nz, m));
    cb_ = RowMat::Zero(N, nz);
    q_ = RowMat::Zero(N + 1, nz);
    Fz_ = Eigen::Map<const RowMat>(Fz.data(), N * k, nz);
    qp_.N = N;
    qp_.nz = nz;
    qp_.m = m;
    qp_.nd = Nu;
    qp_.k = k;
    for (long i = 0; i < N; ++i) {
      qp_.A.emplace_back(Ab_[i].data(), nz, nz);
      qp_.B.emplace_back(Bb_[i].data(), nz, m);
      qp_.Fz.emplace_back(Fz_.data() + i * k * nz, k, nz);
      qp_.c.emplace_back(cb_.data() + i * nz, nz);
    }
    for (long i = 0; i <= N; ++i) {
      qp_.Q.emplace_back(i > No ? Q2_.data() : zero_.data(), nz, nz);  // Q2_ symmetric: either layout
      qp_.q.emplace_back(q_.data() + i * nz, nz);
    }
    qp_.R = 2.0 * Wu.transpose() * Wu;
    qp_.z0 = Vec::Zero(nz);  // with nz == n, qp_.A, B and c are re-seated on each step's arrays (solve)
    read_rows(qp_, comp, sign, f, "RiccatiActive");
  }

  // the used rows' bounds from f (N, k), row-major (the unused rows' entries are not read); checked
  // whole before any is kept
  void set_bounds(const double *f) {
    for (long i = 0; i < qp_.nd; ++i)
      for (const Row &row : qp_.rows[i])
        if (!std::isfinite(f[i * qp_.k + row.r]))
          throw std::invalid_argument("RiccatiActive.solve: the bound f[" + std::to_string(i) + ", " +
                                      std::to_string(row.r) + "] of a used row is not finite (" +
                                      std::to_string(f[i * qp_.k + row.r]) +
                                      "); the rows in use are fixed at construction");
    qp_.f_scale = 1e-12;
    for (long i = 0; i < qp_.nd; ++i)
      for (Row &row : qp_.rows[i]) {
        row.f = f[i * qp_.k + row.r];
        qp_.f_scale = std::max(qp_.f_scale, std::abs(row.f));
      }
  }

  // A (N·n or n, n), B (N·n or n, m), c (N·n or n entries), x0 (n), u0 (m) (forms 1, 2; none: zeros;
  // form 3: neither read), r (N − No, p), start (Nu, m) or none (warm: from the kept set, warm_start's; else
  // cold), f (N, k) or none (the bounds kept) → the Outcome (v, z, λ, set; valid until the next solve) and J
  // of the criterion (5)
  const Outcome &solve(const double *A, long nA, const double *B, long nB, const double *c, long nc,
                       const double *x0, const double *u0, const double *r, const int64_t *start, bool warm,
                       int max_iter, const double *f, double &J) {
    if (f) set_bounds(f);
    if (nz == n) {  // Ā_i = A_i, B̄_i = B_i, c̄_i = c_i (absolute, Nu = N): read in place, no copy
      for (long i = 0; i < N; ++i) {
        new (&qp_.A[i]) CMap(A + (nA == 1 ? 0 : i) * n * n, n, n);
        new (&qp_.B[i]) CMap(B + (nB == 1 ? 0 : i) * n * m, n, m);
        new (&qp_.c[i]) VMap(c ? c + (nc == 1 ? 0 : i) * n : cb_.data() + i * nz, n);  // cb_: zeros
      }
    } else if (nA == 1 && nB == 1 && nc <= 1) {
      // one model for every stage (the absolute and incremental forms' step at X): the stages of the two kinds
      // (deciding, i < Nu; after Nu) filled once and every stage's view seated on its kind's, so that the sweeps
      // read one block (cached) instead of N copies of it (planar_4rrr, incremental, N = 160: 180 kB a call)
      stage_model::fill(form, n, m, Nu, 0, A, B, c, Ab_[0], Bb_[0], cb_.row(0));
      if (Nu < N) stage_model::fill(form, n, m, Nu, Nu, A, B, c, Ab_[Nu], Bb_[Nu], cb_.row(Nu));
      for (long i = 0; i < N; ++i) seat(i, i < Nu ? 0 : Nu);
    } else {
      for (long i = 0; i < N; ++i) {
        stage_model::fill(form, n, m, Nu, i, A + (nA == 1 ? 0 : i) * n * n, B + (nB == 1 ? 0 : i) * n * m,
                          c ? c + (nc == 1 ? 0 : i) * n : nullptr, Ab_[i], Bb_[i], cb_.row(i));
        seat(i, i);
      }
    }
    if (form != 3) qp_.z0.head(n) = VMap(x0, n);  // the deviation model starts at 0
    if (form == 1 || form == 2) {
      if (u0)
        qp_.z0.tail(m) = VMap(u0, m);
      else
        qp_.z0.tail(m).setZero();
    }
    Eigen::Map<const RowMat> W(r, N - No, p);
    q_.bottomRows(N - No).noalias() = -W.lazyProduct(CQ2_.transpose());  // small: no blocked product
    Set &fixed = ws_.fixed;
    starts_ = 0;
    const bool moved = warm && warm_start();  // the start is the moved edges' (else the plain shift)
    if (warm) {
      fixed = moved ? moved_ : plain_;
      sanitize(qp_, fixed);
    } else if (start) {
      fixed = Eigen::Map<const Set>(start, Nu, m);
      sanitize(qp_, fixed);
    } else {
      fixed.setConstant(Nu, m, -1);
    }
    const Outcome &out = solve_active_set(qp_, ws_, max_iter, start != nullptr || warm);
    if (!out.ok && moved && moved_ != plain_) {  // _plain_after: a moved start that did not settle, the plain shift
      const int swept = out.iterations;
      fixed = plain_;
      sanitize(qp_, fixed);
      solve_active_set(qp_, ws_, max_iter, true);  // the same Outcome, written again
      ws_.out.iterations += swept;
    }
    active_ = out.fixed.size() > 0 && out.fixed.maxCoeff() >= 0;
    J = 0.0;
    for (long i = 0; i < Nu; ++i) {
      wu_.noalias() = Wu_.lazyProduct(out.v[i]);
      J += wu_.squaredNorm();
    }
    for (long i = No + 1; i <= N; ++i) {
      y_.noalias() = C_.lazyProduct(out.z[i].head(n));
      y_ -= W.row(i - No - 1).transpose();
      wy_.noalias() = Wy_.lazyProduct(y_);
      J += wy_.squaredNorm();
    }
    return out;
  }

  // keep `fixed` ((Nu, m) row-major, or none) as the next warm step's set, the last one as the set before (warm:
  // a step after the last; else none), and whether the next warm step starts from the moved edges: when this
  // step's set is at most half as far (components differing) from its moved start as from the plain shift
  // (StagewiseSolver._keep_set, whose docstring says why)
  void keep(const int64_t *fixed, bool warm) {
    edges_ = false;
    if (fixed && warm && starts_ == 2) {
      const Eigen::Map<const Set> set(fixed, Nu, m);
      const long off_moved = long((moved_.array() != set.array()).count());
      const long off_plain = long((plain_.array() != set.array()).count());
      edges_ = off_plain > 0 && 2 * off_moved <= off_plain;
    }
    has_before_ = warm && has_kept_;
    if (has_before_) before_.swap(kept_);
    has_kept_ = fixed != nullptr;
    if (has_kept_) kept_ = Eigen::Map<const Set>(fixed, Nu, m);
    starts_ = 0;
  }
  bool has_kept() const { return has_kept_; }

  long n, m, p, N, No, Nu, nz;
  int form;
  long k() const { return qp_.k; }
  bool active() const { return active_; }           // a row of the last solve's set binds
  double f_scale() const { return qp_.f_scale; }  // the largest bound of the used rows, at least 1e-12

  // how many models the step's A, B or c holds (A: (n, n), or one per stage (N, n, n) or (N·n, n); B
  // likewise with m columns; c (n,), (N·n,) or (N, n)): 1 or N, 0 for an empty c
  long models_in(const char *name, const Floats &a, long cols) const {
    const bool vec = cols == 0;  // c
    const long size = long(a.size()), nd = long(a.ndim()), last = nd ? long(a.shape(nd - 1)) : 0;
    const long one = vec ? n : n * cols;
    if (vec && size == 0) return 0;
    const bool shaped = vec ? (nd == 1 || (nd == 2 && last == n)) : ((nd == 2 || nd == 3) && last == cols);
    if (shaped && (size == one || size == N * one)) return size == one ? 1 : N;
    std::string got;
    for (long d = 0; d < nd; ++d) got += (d ? ", " : "") + std::to_string(a.shape(d));
    throw std::invalid_argument("RiccatiActive.solve: " + std::string(name) +
                                " must be one model or one per stage (n = " + std::to_string(n) +
                                ", m = " + std::to_string(m) + ", N = " + std::to_string(N) + "): " +
                                (vec ? "(n,), (N·n,), (N, n) or empty" : cols == m ? "(n, m), (N·n, m) or (N, n, m)"
                                                                                   : "(n, n), (N·n, n) or (N, n, n)") +
                                "; got (" + got + ")");
  }


 private:
  // stage i's views of the stage models on those of stage s (Ab_, Bb_, cb_; the views of a step's own arrays when
  // nz == n are seated in solve)
  void seat(long i, long s) {
    new (&qp_.A[i]) CMap(Ab_[s].data(), nz, nz);
    new (&qp_.B[i]) CMap(Bb_[s].data(), nz, m);
    new (&qp_.c[i]) VMap(cb_.data() + s * nz, nz);
  }

  QP qp_;
  Mat C_, Wy_, Wu_, CQ2_;
  RowMat Q2_, zero_, cb_, q_, Fz_;
  std::vector<RowMat> Ab_, Bb_;
  Workspace ws_;
  Vec wu_, y_, wy_;  // J's terms
  bool active_ = false;
  // the warm start (keep, warm_start): the kept set and the one before, whether the next warm step starts from the
  // moved edges, this step's starts (the plain shift, the moved edges', the set before shifted) and which were made
  // (0 none, 1 the plain shift, 2 both)
  bool moves_edges_, has_kept_ = false, has_before_ = false, edges_ = false;
  Set kept_, before_, plain_, moved_, was_;
  int starts_ = 0;

  // this warm step's starts from the kept set (StagewiseSolver._next_start): the plain shift, and with moves_edges
  // and a set before, the moved edges' (shift_active_set with `before`); true when the moved one starts
  bool warm_start() {
    shift_set(kept_, plain_);
    starts_ = 1;
    if (!moves_edges_ || !has_before_) return false;
    shift_set(before_, was_);
    moved_ = plain_;
    extrapolate_edges(kept_, was_, moved_);
    starts_ = 2;
    return edges_;
  }
};

// (v (nd, m), z (N + 1, nz), λ, set, iterations, ok, residual, message) of an Outcome, as numpy
nb::tuple outcome_tuple(const QP &qp, const Outcome &res) {
  RowMat vout(qp.nd, qp.m), zout(qp.N + 1, qp.nz);
  for (long i = 0; i < qp.nd; ++i) vout.row(i) = res.v[i].transpose();
  for (long i = 0; i <= qp.N; ++i) zout.row(i) = res.z[i].transpose();
  return nb::make_tuple(vout, zout, res.lam, res.fixed, res.iterations, res.ok, res.residual, res.message);
}
}  // namespace

void bind_stagewise_active(nb::module_ &m) {
  m.def(
      "stagewise_active",
      [](In3 A, In3 B, In2 c, In1 z0, In3 Q, In2 q, In2 R, long n_decide, In3 Fz, In2 f, InI comp, In2 sign,
         std::optional<InI> start, int max_iter) {
        QP qp;
        stage_arrays::read_lq(qp, A, B, c, z0, Q, q, R, n_decide, Fz, f, "stagewise_active");
        read_rows(qp, comp, sign, f, "stagewise_active");
        thread_local Workspace ws;  // one per thread, kept from call to call
        Set &fixed = ws.fixed;
        if (start) {
          if (long(start->shape(0)) != qp.nd || long(start->shape(1)) != qp.m)
            throw std::invalid_argument("stagewise_active: the start must be (n_decide, m)");
          fixed = Eigen::Map<const Set>(start->data(), qp.nd, qp.m);
          sanitize(qp, fixed);
        } else {
          fixed.setConstant(qp.nd, qp.m, -1);
        }
        if (max_iter < 1) throw std::invalid_argument("stagewise_active: max_iter must be ≥ 1");
        return outcome_tuple(qp, solve_active_set(qp, ws, max_iter, bool(start)));
      },
      nb::arg("A"), nb::arg("B"), nb::arg("c"), nb::arg("z0"), nb::arg("Q"), nb::arg("q"), nb::arg("R"),
      nb::arg("n_decide"), nb::arg("Fz"), nb::arg("f"), nb::arg("comp"), nb::arg("sign"),
      nb::arg("start") = nb::none(), nb::arg("max_iter") = 30,
      "(v, z, λ, fixed, iterations, ok, residual, message): solvers.stagewise_active.solve_active_set compiled "
      "(see that module); comp and sign: its InputRowMap; start (n_decide, m) int64 or None; max_iter: its "
      "AS_MAX_ITER (cold) or AS_WARM_MAX_ITER (from a start)");

  m.def(
      "shift_active_set",
      [](InI fixed, std::optional<InI> before) {
        const Eigen::Map<const Set> set(fixed.data(), long(fixed.shape(0)), long(fixed.shape(1)));
        Set out;
        shift_set(set, out);
        if (before && long(before->shape(0)) == set.rows() && long(before->shape(1)) == set.cols() && set.rows()) {
          Set was;
          shift_set(Eigen::Map<const Set>(before->data(), set.rows(), set.cols()), was);
          extrapolate_edges(set, was, out);
        }
        return out;
      },
      nb::arg("fixed"), nb::arg("before").none() = nb::none(),
      "solvers.stagewise_active.shift_active_set compiled (the set the compiled limited step starts from, "
      "RiccatiActive.solve with warm): fixed, before (n_decide, m) int64");

  nb::class_<RiccatiActive>(m, "RiccatiActive",
                            "the torque/Δu-limited problem of a linear form, one call per step (see gpc/stagewise.py)")
      .def(nb::init<const Mat &, const Mat &, const Mat &, long, long, long, int, In3, In2, InI, In2, bool>(),
           nb::arg("C"), nb::arg("Wy"), nb::arg("Wu"), nb::arg("N"), nb::arg("No"), nb::arg("Nu"), nb::arg("form"),
           nb::arg("Fz"), nb::arg("f"), nb::arg("comp"), nb::arg("sign"), nb::arg("moves_edges") = false)
      .def(
          "solve",
          [](RiccatiActive &self, Floats A, Floats B, std::optional<Floats> c, In1 x0, std::optional<In1> u0, In2 r,
             std::optional<InI> start, int max_iter, std::optional<In2> f, bool warm, std::optional<Out2> v_out,
             std::optional<Out2> lam_out, std::optional<OutI> set_out) {
            // the step's arrays read in place (nanobind converts another dtype or layout on the way in)
            const long m = self.m;
            const long nA = self.models_in("A", A, self.n), nB = self.models_in("B", B, m),
                       nc = c ? self.models_in("c", *c, 0) : 0;
            if (long(x0.shape(0)) != self.n || (u0 && long(u0->shape(0)) != m) || long(r.shape(0)) != self.N - self.No ||
                long(r.shape(1)) != self.p)
              throw std::invalid_argument("RiccatiActive.solve: x0 must be (n,) = (" + std::to_string(self.n) +
                                          ",), u0 (m,) = (" + std::to_string(m) + ",) or None, r (N − No, p) = (" +
                                          std::to_string(self.N - self.No) + ", " + std::to_string(self.p) + ")");
            if (start && (long(start->shape(0)) != self.Nu || long(start->shape(1)) != m))
              throw std::invalid_argument("RiccatiActive.solve: the start must be (Nu, m)");
            if (warm && (start || !self.has_kept()))
              throw std::invalid_argument("RiccatiActive.solve: warm starts from the kept set (keep), without a start");
            if (max_iter < 1) throw std::invalid_argument("RiccatiActive.solve: max_iter must be ≥ 1");
            if (f && (long(f->shape(0)) != self.N || long(f->shape(1)) != self.k()))
              throw std::invalid_argument("RiccatiActive.solve: the bounds f must be (N, k) as at construction");
            const bool outs = v_out || lam_out || set_out;
            if (outs && !(v_out && lam_out && set_out && long(v_out->shape(0)) == self.Nu &&
                          long(v_out->shape(1)) == m && long(lam_out->shape(0)) == self.N &&
                          long(lam_out->shape(1)) == self.k() && long(set_out->shape(0)) == self.Nu &&
                          long(set_out->shape(1)) == m))
              throw std::invalid_argument("RiccatiActive.solve: v_out (Nu, m), lam_out (N, k) and set_out (Nu, m) "
                                          "go together (Nu = " + std::to_string(self.Nu) + ", m = " +
                                          std::to_string(m) + ", N = " + std::to_string(self.N) + ", k = " +
                                          std::to_string(self.k()) + ")");
            double J = 0.0;
            const Outcome &res = self.solve(A.data(), nA, B.data(), nB, nc ? c->data() : nullptr, nc, x0.data(),
                                           u0 ? u0->data() : nullptr, r.data(), start ? start->data() : nullptr, warm,
                                           max_iter, f ? f->data() : nullptr, J);
            if (outs) {  // written into the caller's arrays, which are returned (no new array to hand over)
              Eigen::Map<RowMat> v(v_out->data(), self.Nu, m);
              for (long i = 0; i < self.Nu; ++i) v.row(i) = res.v[i].transpose();
              Eigen::Map<RowMat>(lam_out->data(), self.N, self.k()) = res.lam;
              Eigen::Map<Set>(set_out->data(), self.Nu, m) = res.fixed;
              return nb::make_tuple(*v_out, J, *lam_out, *set_out, res.iterations, res.ok, res.residual, res.message);
            }
            RowMat vout(self.Nu, m);
            for (long i = 0; i < self.Nu; ++i) vout.row(i) = res.v[i].transpose();
            return nb::make_tuple(vout, J, res.lam, res.fixed, res.iterations, res.ok, res.residual, res.message);
          },
          nb::arg("A"), nb::arg("B"), nb::arg("c").none(), nb::arg("x0"), nb::arg("u0").none(), nb::arg("r"),
          nb::arg("start") = nb::none(), nb::arg("max_iter") = 30, nb::arg("f") = nb::none(), nb::arg("warm") = false,
          nb::arg("v_out") = nb::none(), nb::arg("lam_out") = nb::none(), nb::arg("set_out") = nb::none(),
          "(v (Nu, m), J, λ (N, k), set (Nu, m), iterations, ok, residual, message): the active set of "
          "solvers/stagewise_active.py on the step's stage models; A, B, c: one model or one per stage, "
          "(N, n, n) or (N·n, n) etc., read in place; start: a set to start from as it is, or None (warm: the kept "
          "set's warm start, see keep; else cold); "
          "f: this step's bounds (N, k) of the rows (the used ones stay the construction's), or None: the last; "
          "v_out, lam_out, set_out (float64, float64, int64): arrays to write v, λ and the set into (returned; "
          "cheaper than new ones), or None")
      .def(
          "keep",
          [](RiccatiActive &self, std::optional<InI> fixed, bool warm) {
            if (fixed && (long(fixed->shape(0)) != self.Nu || long(fixed->shape(1)) != self.m))
              throw std::invalid_argument("RiccatiActive.keep: the set must be (Nu, m)");
            self.keep(fixed ? fixed->data() : nullptr, warm);
          },
          nb::arg("fixed").none(), nb::arg("warm"),
          "keep a step's set (Nu, m) int64, or None, for the next warm solve (StagewiseSolver._keep_set): the last "
          "kept one becomes the set before (warm: a step after it; else none), and the next warm solve starts from "
          "the moved edges (moves_edges) when this step's set is at most half as far from them as from the plain "
          "shift; warm=True solves start from the plain shift or the moved edges, then the plain shift when the "
          "moved start does not settle (iterations added)")
      .def_prop_ro("active", &RiccatiActive::active, "a row of the last solve's set binds")
      .def_prop_ro("f_scale", &RiccatiActive::f_scale,
                   "the largest bound of the used rows (the last bounds given), at least 1e-12: the scale of the "
                   "residual's row excess");
}
}  // namespace pgpc
