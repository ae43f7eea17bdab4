// The Riccati recursion of solvers/riccati.py (lq_tracking) for the controller's unconstrained
// problems, with the stage models of gpc/riccati.py built here from (A_d, B_d, c_d): one call per
// control step, workspaces kept between calls. Forms (see gpc/riccati.py):
//   0 absolute     z = x (Nu = N) or [x; u_held] (Nu < N), v = u held after Nu
//   1 incremental  z = [x; u(k−1)], v = Δu, B̄ = [B; I], Δu = 0 after Nu
//   2 delayed      z = [x; u(k)],   v = Δu, B̄ = [0; I]
//   3 deviation    the nonlinear form's deviation model along the pre-simulation: per-stage
//                  A_i, B_i, z = [δx; δu] from 0, no affine term, targets w − ŷ_sim
#include <Eigen/Cholesky>
#include <nanobind/eigen/dense.h>
#include <nanobind/ndarray.h>
#include <stdexcept>
#include <vector>

#include "bindings.hpp"
#include "riccati.hpp"
#include "small_solve.hpp"
#include "stage_model.hpp"

namespace pgpc {
namespace {
using CMap = Eigen::Map<const RowMat>;
using VMap = Eigen::Map<const Vec>;
using SMap = Eigen::Map<const RowMat, 0, Eigen::OuterStride<>>;  // a block of a row-major array
}  // namespace

Riccati::Riccati(const Mat &C, const Mat &Wy, const Mat &Wu, long N, long No, long Nu, int form)
    : n(C.cols()), m(Wu.rows()), p(C.rows()), N(N), No(No), Nu(Nu), form(form) {
  if (form < 0 || form > 3) throw std::invalid_argument("Riccati: form must be 0..3");
  if (N < 1 || No < 0 || No >= N || Nu < 1 || Nu > N) throw std::invalid_argument("Riccati: bad horizons");
  if (Wy.rows() != p || Wy.cols() != p || Wu.cols() != m) throw std::invalid_argument("Riccati: weight shapes");
  nz = stage_model::state_size(form, n, m, N, Nu);
  Mat Cz = Mat::Zero(p, nz);
  Cz.leftCols(n) = C;
  CQ_ = Cz.transpose() * (Wy.transpose() * Wy);
  CQC_ = CQ_ * Cz;
  R_ = Wu.transpose() * Wu;
  C_ = C;
  Wy_ = Wy;
  Abar_.assign(N, Mat::Zero(nz, nz));
  Bbar_.assign(N, Mat::Zero(nz, m));
  cbar_.assign(N, Vec::Zero(nz));
  An_.assign(N, Mat::Zero(n, n));
  Bn_.assign(N, Mat::Zero(n, m));
  PA_.setZero(nz, nz);
  M_.setZero(nz, nz);
  T_.setZero(nz, nz);
  K_.assign(Nu, Mat::Zero(m, nz));
  k_.assign(Nu, Vec::Zero(m));
}

double Riccati::solve(const double *A, long nA, const double *B, long nB, const double *c, long nc,
                      const double *x0, const double *u0, const double *r, double *v) {
  for (long i = 0; i < N; ++i) stage(i, A + (nA == 1 ? 0 : i) * n * n, B + (nB == 1 ? 0 : i) * n * m,
                                     c ? c + (nc == 1 ? 0 : i) * n : nullptr);
  return recursion(x0, u0, r, v);
}

double Riccati::solve_deviation(const double *E, long ld, const double *X, const double *w, double *v) {
  if (form != 3) throw std::logic_error("Riccati.solve_deviation: the deviation form (3) only");
  for (long i = 0; i < N; ++i) {  // stage_model::fill reads contiguous blocks: gather A_i, B_i first
    Ai_ = SMap(E + i * n * ld, n, n, Eigen::OuterStride<>(ld));
    Bi_ = SMap(E + i * n * ld + n, n, m, Eigen::OuterStride<>(ld));
    stage(i, Ai_.data(), Bi_.data(), nullptr);
  }
  r_.noalias() = CMap(X + (No + 1) * n, N - No, n) * C_.transpose();  // ŷ_sim(No+1..N)
  r_ = CMap(w, N - No, p) - r_;
  return recursion(nullptr, nullptr, r_.data(), v);
}

double Riccati::recursion(const double *x0, const double *u0, const double *r, double *v) {
  CMap W(r, N - No, p);
  Mat P = CQC_;
  Vec q = CQ_ * W.row(N - No - 1).transpose();
  // forms 1 and 3: B̄_i = [B_i; I] is Ā_i's last m columns, so B̄ᵀPĀ and B̄ᵀPB̄ are blocks of ĀᵀPĀ
  const bool tail = form == 1 || form == 3;
  for (long i = N - 1; i >= 0; --i) {
    const Mat &Ai = Abar_[i];
    right_A(P, i, PA_);  // P Ā_i, with Ā_i's structure
    if (form == 3) {  // no affine term: s = P c̄ − q = −q
      s_ = -q;
    } else {
      s_.noalias() = P.lazyProduct(cbar_[i]);
      s_ -= q;
    }
    if (i < Nu) {
      const Mat &Bi = Bbar_[i];
      if (tail) {  // B̄ᵀPĀ = the last m rows of ĀᵀPĀ (left_AT's)
        BPA_ = PA_.bottomRows(m);
        BPA_.noalias() += Bn_[i].transpose().lazyProduct(PA_.topRows(n));
        H_ = R_ + BPA_.rightCols(m);
      } else {
        BPA_.noalias() = Bi.transpose().lazyProduct(PA_);
        PB_.noalias() = P.lazyProduct(Bi);
        H_ = R_;
        H_.noalias() += Bi.transpose().lazyProduct(PB_);
        left_AT(PA_, i, M_);
      }
      llt_.compute(H_);
      if (llt_.info() != Eigen::Success) throw std::runtime_error("Riccati: R + BᵀPB is not positive definite");
      small_solve::llt_solve(llt_, BPA_, K_[i]);
      if (tail) {  // B̄ᵀ s = Bᵀ s_x + s_u, which are also Āᵀ s's last m rows (B̄ is Ā's last m columns)
        g_.noalias() = Bn_[i].transpose().lazyProduct(s_.head(n));
        g_ += s_.tail(m);
      } else {
        g_.noalias() = Bi.transpose().lazyProduct(s_);
      }
      small_solve::llt_solve(llt_, g_, k_[i]);
      if (tail) {  // P ← ĀᵀPĀ − B̄ᵀPĀᵀ K, symmetric: its lower triangle (ĀᵀPĀ's top-left block AᵀPA, its last
        // m rows B̄ᵀPĀ), then the upper one mirrored (no averaging below: exactly symmetric)
        P.topLeftCorner(n, n).triangularView<Eigen::Lower>() = An_[i].transpose().lazyProduct(PA_.topLeftCorner(n, n));
        P.bottomRows(m) = BPA_;
        P.triangularView<Eigen::Lower>() -= BPA_.transpose().lazyProduct(K_[i]);
        for (Index c = 1; c < nz; ++c)
          for (Index r = 0; r < c; ++r) P(r, c) = P(c, r);
      } else {
        P = M_;
        P.noalias() -= BPA_.transpose().lazyProduct(K_[i]);
      }
      q.noalias() = BPA_.transpose().lazyProduct(k_[i]);
      if (tail) {  // Āᵀ s = [Aᵀ s_x; B̄ᵀ s]
        q.head(n).noalias() -= An_[i].transpose().lazyProduct(s_.head(n));
        q.tail(m) -= g_;
      } else {
        q.noalias() -= Ai.transpose().lazyProduct(s_);
      }
    } else {
      left_AT(PA_, i, P);
      q.noalias() = -(Ai.transpose().lazyProduct(s_));
    }
    if (!tail || i >= Nu) {  // the rounding's asymmetry averaged out
      T_ = P.transpose();
      P += T_;
      P *= 0.5;
    }
    if (i > No) {
      P += CQC_;
      q.noalias() += CQ_.lazyProduct(W.row(i - No - 1).transpose());
    }
  }
  z_.setZero(nz);
  if (form != 3) z_.head(n) = VMap(x0, n);
  if (form == 1 || form == 2) z_.tail(m) = VMap(u0, m);
  double J = 0.0;
  Eigen::Map<Vec> out(v, Nu * m);
  for (long i = 0; i < N; ++i) {
    if (i < Nu) {
      auto vi = out.segment(i * m, m);
      vi.noalias() = -K_[i] * z_;
      vi -= k_[i];
      J += (vi.transpose() * R_ * vi).value();
      zn_.noalias() = Abar_[i] * z_ + Bbar_[i] * vi;
    } else {
      zn_.noalias() = Abar_[i] * z_;
    }
    z_ = zn_ + cbar_[i];
    if (i + 1 > No) {
      e_.noalias() = C_ * z_.head(n);
      e_ -= W.row(i - No).transpose();
      J += (Wy_ * e_).squaredNorm();
    }
  }
  if (!out.allFinite()) throw std::runtime_error("Riccati: the solution is not finite");
  return J;
}

// Ā_i: 0 = A (nz = n), 1 = [[A, B], [0, I]] (input held in the state), 2 = [[A, 0], [0, 0]]
// (the absolute form deciding while Nu < N)
int Riccati::kind(long i) const { return nz == n ? 0 : (form == 0 && i < Nu) ? 2 : 1; }

// out = P Ā_i (nz × nz) from the blocks of Ā_i: n·nz·(n + m) multiplications instead of nz³
void Riccati::right_A(const Mat &P, long i, Mat &out) const {
  const Mat &A = An_[i], &B = Bn_[i];
  const int k = kind(i);
  if (k == 0) {
    out.noalias() = P.lazyProduct(A);
    return;
  }
  out.leftCols(n).noalias() = P.leftCols(n).lazyProduct(A);
  if (k == 2) {
    out.rightCols(m).setZero();
    return;
  }
  out.rightCols(m) = P.rightCols(m);
  out.rightCols(m).noalias() += P.leftCols(n).lazyProduct(B);
}

// out = Ā_iᵀ Y (nz × nz), likewise
void Riccati::left_AT(const Mat &Y, long i, Mat &out) const {
  const Mat &A = An_[i], &B = Bn_[i];
  const int k = kind(i);
  if (k == 0) {
    out.noalias() = A.transpose().lazyProduct(Y);
    return;
  }
  out.topRows(n).noalias() = A.transpose().lazyProduct(Y.topRows(n));
  if (k == 2) {
    out.bottomRows(m).setZero();
    return;
  }
  out.bottomRows(m) = Y.bottomRows(m);
  out.bottomRows(m).noalias() += B.transpose().lazyProduct(Y.topRows(n));
}

void Riccati::stage(long i, const double *A, const double *B, const double *c) {
  An_[i] = CMap(A, n, n);
  Bn_[i] = CMap(B, n, m);
  stage_model::fill(form, n, m, Nu, i, A, B, c, Abar_[i], Bbar_[i], cbar_[i]);
}

void bind_riccati(nb::module_ &m) {
  nb::class_<Riccati>(m, "Riccati", "Riccati recursion of the unconstrained GPC problem (see parallel_gpc.gpc.riccati)")
      .def(nb::init<const Mat &, const Mat &, const Mat &, long, long, long, int>(), nb::arg("C"), nb::arg("Wy"),
           nb::arg("Wu"), nb::arg("N"), nb::arg("No"), nb::arg("Nu"), nb::arg("form"))
      .def("solve",
           [](Riccati &self, In2 A, In2 B, nb::ndarray<const double, nb::c_contig, nb::device::cpu> c, In1 x0,
              In1 u0, In2 r) {
             const long m = self.m;
             const stage_model::StepShape step = stage_model::check_step(
                 "Riccati.solve", self.n, m, self.p, self.N, self.No, A, B, long(c.size()), self.form != 3, x0, u0, r);
             double *buf;
             auto v = owned_array({size_t(self.Nu * m)}, &buf);
             const double J = self.solve(A.data(), step.nA, B.data(), step.nB, step.nc ? c.data() : nullptr,
                                         step.nc, x0.data(), u0.data(), r.data(), buf);
             return nb::make_tuple(v, J);
           },
           nb::arg("A"), nb::arg("B"), nb::arg("c"), nb::arg("x0"), nb::arg("u0"), nb::arg("r"),
           "(v (Nu·m,), J): the plan and its input cost (see gpc/riccati.py)");
}
}  // namespace pgpc
