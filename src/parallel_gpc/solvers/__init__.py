"""Square-root least squares of the GPC criterion and its QP back ends (DESIGN §3, §5).

The criterion (5) with square-root weights is ``J = ‖A v − b‖²`` with, eq. (15)–(16),

    A = [Qy·G; Qu],   b = [Qy·(w − f); 0].

* :class:`QRSolver` — the reference: Householder QR and back substitution, eq. (17)–(19)
  (the paper's (19) prints (R₁)ᵀ; it means R₁⁻¹). ``‖c_z‖² = J``. When A is rank-deficient
  (Qu = 0 with redundant drives) it returns the minimum-norm solution through a complete
  orthogonal decomposition — exactly "no drive fighting".
* :class:`QpsolversBackend` — ``qpsolvers.solve_qp`` for any installed solver, scaled, with
  drive torque limits (box on v, or linear inequalities ``u_lo ≤ u_base + L v ≤ u_hi``).
* :class:`OSQPBackend`, :class:`ProxQPBackend`, :class:`DAQPBackend` — persistent direct APIs
  (set up once, updated and warm-started every step).
* :class:`QRFirst` — solves by QR and calls the QP only when the QR solution violates a limit.

Every solve returns a :class:`SolveResult` (status, iterations, time, cost, active limits); a
failed solve is reported in the result, never swallowed.
"""

from __future__ import annotations

from ..errors import SolverNotFoundError
from .problem import LeastSquaresProblem, SolveResult, QP_REGULARIZATION, LIMIT_TOL, RANK_RTOL, FAST_QR_RCOND
from .qr import QRSolver, qr_least_squares
from .qpsolvers_ import QpsolversBackend, installed_qp_solvers
from .osqp_ import OSQPBackend
from .proxqp_ import ProxQPBackend
from .daqp_ import DAQPBackend
from .qr_first import QRFirst

__all__ = [
    "LeastSquaresProblem", "SolveResult", "QP_REGULARIZATION", "LIMIT_TOL", "RANK_RTOL", "FAST_QR_RCOND",
    "QRSolver", "qr_least_squares", "QpsolversBackend", "installed_qp_solvers", "OSQPBackend",
    "ProxQPBackend", "DAQPBackend", "QRFirst", "DIRECT_BACKENDS", "available_solvers", "make_solver",
]


#: Back-end names accepted by :func:`make_solver` besides ``qpsolvers:<name>``.
DIRECT_BACKENDS = {"qr": QRSolver, "osqp-direct": OSQPBackend, "proxqp-direct": ProxQPBackend,
                   "daqp-direct": DAQPBackend}


def available_solvers() -> list[str]:
    """Every name :func:`make_solver` accepts on this machine."""
    names = list(DIRECT_BACKENDS) + [f"qpsolvers:{s}" for s in installed_qp_solvers()]
    names += [f"qr-first:{n}" for n in names if n != "qr"]
    return names


def make_solver(name: str):
    """Back end by name: ``qr``, ``osqp-direct``, ``proxqp-direct``, ``daqp-direct``,
    ``qpsolvers:<solver>`` (or a bare installed qpsolvers name such as ``osqp``), each
    optionally prefixed ``qr-first:``.

    Raises:
        SolverNotFoundError: unknown or uninstalled name (the message lists the valid ones).
    """
    if not isinstance(name, str):
        raise SolverNotFoundError(f"solver name {name!r} must be a string; available: {available_solvers()}")
    if name.startswith("qr-first:"):
        inner = make_solver(name[len("qr-first:"):])
        if isinstance(inner, QRSolver):
            raise SolverNotFoundError("qr-first needs a QP back end, not 'qr'")
        return QRFirst(inner)
    if name in DIRECT_BACKENDS:
        try:
            return DIRECT_BACKENDS[name]()
        except ImportError as exc:  # its Python package is missing on this machine
            raise SolverNotFoundError(
                f"solver {name!r} is not installed ({exc}); available: {available_solvers()}") from None
    qp_name = name[len("qpsolvers:"):] if name.startswith("qpsolvers:") else name
    if qp_name in installed_qp_solvers():
        return QpsolversBackend(qp_name)
    raise SolverNotFoundError(f"unknown solver {name!r}; available: {available_solvers()}")
