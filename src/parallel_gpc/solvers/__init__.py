"""Square-root least squares and its QP back ends (eq. (15)–(19)); knows nothing about GPC.

A problem is ``min ‖A v − b‖²`` with optional box and linear limits (:class:`LeastSquaresProblem`,
with named structure hints that its builder fills in).

* :class:`QRSolver` — the reference: Householder QR and back substitution, eq. (17)–(19)
  (the paper's (19) prints (R₁)ᵀ; it means R₁⁻¹). ``‖c_z‖² = J``. When A is rank-deficient
  it returns the minimum-norm solution (or the minimizer of ``‖M v + offset‖``, see
  :class:`MinNormOf`) through a complete orthogonal decomposition.
* :class:`QpsolversBackend` — ``qpsolvers.solve_problem`` for any installed solver, scaled.
* :class:`OSQPBackend`, :class:`ProxQPBackend`, :class:`DAQPBackend` — persistent direct APIs
  (set up once, updated and warm-started every step).
* :class:`NormalEquationsSolver` — Cholesky of the normal equations when their condition
  estimate allows it (else QR): the cheaper unconstrained solve.
* :class:`BVLSSolver` — bounded-variable least squares (Lawson & Hanson ch. 23): an active set
  on the QR form for box limits, no QP Hessian.
* :class:`QRFirst` — solves by QR and calls the QP only when the QR solution violates a limit.
* :func:`~parallel_gpc.solvers.riccati.lq_tracking` — the Riccati recursion of an unconstrained
  linear-quadratic tracking problem over stages (not a back end of a condensed problem: the
  controller's ``solver="riccati"`` path, :mod:`parallel_gpc.gpc.riccati`, calls it).

Every QP back end's solution goes through one KKT check (:mod:`parallel_gpc.solvers.kkt`,
:func:`kkt_residuals` against :data:`KKT_TOL`): the status is ``"optimal"`` only when the primal,
stationarity and complementarity residuals pass, ``"inaccurate"`` (not ``ok``) otherwise.

Back ends register themselves (qpsolvers' style): each module is imported inside
``try/except ImportError`` and only those whose package imports are listed by
:func:`available_solvers`. Every solve returns a :class:`SolveResult` (status, iterations,
time, cost, active limits); a failed solve is reported in the result, never swallowed.
"""

from __future__ import annotations

from ..errors import SolverNotFoundError
from .problem import (
    FAST_QR_RCOND,
    LIMIT_TOL,
    QP_REGULARIZATION,
    RANK_RTOL,
    LeastSquaresProblem,
    MinNormOf,
    SolveResult,
    from_cumulative,
    with_equalities,
    with_inequalities,
)
from .riccati import lq_tracking
from .stagewise_ipm import CROSSOVER, StageQP, StageQPSolution, StageStart, solve_stage_qp, stopped_short
from .stagewise_active import (AS_MAX_ITER, AS_WARM_MAX_ITER, ActiveSetSolution, InputRowMap, active_set_of, input_rows_of, shift_active_set,
                               solve_active_set)
from .kkt import KKT_TOL, KKTResiduals, KKTTolerance, kkt_residuals, verified
from .bvls import BVLSSolver
from .normal import NormalEquationsSolver
from .qr import QRSolver, qr_least_squares
from .qr_first import QRFirst

__all__ = [
    "from_cumulative", "with_inequalities", "with_equalities", "lq_tracking", "StageQP", "StageQPSolution", "StageStart",
    "solve_stage_qp", "stopped_short", "CROSSOVER", "ActiveSetSolution", "InputRowMap", "input_rows_of", "shift_active_set", "active_set_of",
    "solve_active_set", "AS_MAX_ITER", "AS_WARM_MAX_ITER",
    "LeastSquaresProblem", "MinNormOf", "SolveResult", "QP_REGULARIZATION", "LIMIT_TOL", "RANK_RTOL",
    "FAST_QR_RCOND", "BVLSSolver", "NormalEquationsSolver", "QRSolver", "qr_least_squares", "QRFirst", "DIRECT_BACKENDS", "KNOWN_DIRECT_BACKENDS",
    "available_solvers", "installed_qp_solvers", "make_solver",
    "KKT_TOL", "KKTResiduals", "KKTTolerance", "kkt_residuals", "verified",
]

#: every direct back-end name this package knows, installed or not (for error messages).
KNOWN_DIRECT_BACKENDS = ("qr", "cholesky", "bvls", "osqp-direct", "proxqp-direct", "daqp-direct")
#: Back ends whose Python package imported on this machine, by :func:`make_solver` name.
DIRECT_BACKENDS: dict[str, type] = {"qr": QRSolver, "cholesky": NormalEquationsSolver, "bvls": BVLSSolver}

try:
    from .osqp_ import OSQPBackend

    DIRECT_BACKENDS["osqp-direct"] = OSQPBackend
    __all__.append("OSQPBackend")
except ImportError:
    pass

try:
    from .proxqp_ import ProxQPBackend

    DIRECT_BACKENDS["proxqp-direct"] = ProxQPBackend
    __all__.append("ProxQPBackend")
except ImportError:
    pass

try:
    from .daqp_ import DAQPBackend

    DIRECT_BACKENDS["daqp-direct"] = DAQPBackend
    __all__.append("DAQPBackend")
except ImportError:
    pass

try:
    from .qpsolvers_ import QpsolversBackend, installed_qp_solvers

    __all__.append("QpsolversBackend")
except ImportError:
    QpsolversBackend = None

    def installed_qp_solvers() -> list[str]:
        """QP solvers available through qpsolvers: none (qpsolvers is not installed)."""
        return []


def available_solvers() -> list[str]:
    """Every name :func:`make_solver` accepts on this machine (only back ends that imported)."""
    names = list(DIRECT_BACKENDS) + [f"qpsolvers:{s}" for s in installed_qp_solvers()]
    names += [f"qr-first:{n}" for n in names if n not in ("qr", "cholesky")]
    return names


def make_solver(name: str):
    """Back end by name: ``qr``, ``cholesky``, ``bvls``, ``osqp-direct``, ``proxqp-direct``, ``daqp-direct``,
    ``qpsolvers:<solver>`` (or a bare installed qpsolvers name such as ``osqp``), each
    optionally prefixed ``qr-first:``.

    Raises:
        SolverNotFoundError: unknown or uninstalled name (the message lists the valid ones).
    """
    if not isinstance(name, str):
        raise SolverNotFoundError(f"solver name {name!r} must be a string; available: {available_solvers()}")
    if name.startswith("qr-first:"):
        inner = make_solver(name[len("qr-first:"):])
        if isinstance(inner, (QRSolver, NormalEquationsSolver)):
            raise SolverNotFoundError(f"qr-first needs a back end that enforces limits, not {inner.name!r}")
        return QRFirst(inner)
    if name == "riccati":
        raise SolverNotFoundError(
            "'riccati' is a path of the GPC controller (GPCController.build(..., solver='riccati'), track --solver riccati): "
            "it solves the unconstrained problem from the model without condensing, it is not a back end of a "
            f"condensed least-squares problem; use 'qr' here (available: {available_solvers()})")
    if name in DIRECT_BACKENDS:
        return DIRECT_BACKENDS[name]()
    if name in KNOWN_DIRECT_BACKENDS:
        raise SolverNotFoundError(f"solver {name!r} is not installed (its Python package did not import); "
                                  f"available: {available_solvers()}")
    qp_name = name[len("qpsolvers:"):] if name.startswith("qpsolvers:") else name
    if qp_name in installed_qp_solvers():
        return QpsolversBackend(qp_name)
    raise SolverNotFoundError(f"unknown solver {name!r}; available: {available_solvers()}")
