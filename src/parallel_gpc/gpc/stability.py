"""Poles of the unconstrained closed loop of a GPC controller on its own model, held at one state.

Without limits every linear form's step is a linear law of its augmented state (the reference
aside): v = argmin ‖Qy(f(x̄) + G v − w)‖² + ‖Qu v‖², f linear in x̄, minimum-norm where G leaves
freedom (the QR reference's choice), and only v's first block is applied. On the model's ZOH
matrices (A_d, B_d) at X the loop is then x̄(k+1) = A_cl x̄(k) + const:

* absolute (x̄ = X, u(k) = K x̄):                          A_cl = A_d + B_d K;
* incremental (x̄ = [X; u(k−1)], u(k) = u(k−1) + K x̄):   A_cl = Ā + [B_d; I] K;
* incremental-delayed (x̄ = [X; u(k)], u(k+1) = u(k) + K x̄, the paper's (8) as printed):
  A_cl = Ā + [0; I] K,

Ā = [[A_d, B_d], [0, P]]. K is taken column by column from the criterion's own least-squares
problem and the QR reference back end (the controller's law, not a re-derivation). With redundant
drives the incremental forms add the increments to u without its null(B_d) component (the
controller's no-drive-fighting rule, without a Δu limit): the u block enters through the projector
P = I − NᵀN onto the complement of null(B_d) (N :func:`~parallel_gpc.gpc.redundancy.null_basis`),
so inputs that move nothing give poles at 0, not 1.

What it shows: with Qu = 0 (the paper's tracking setting) every form is the same dead-beat law
(docs/controller.md), which inverts the sampled plant. A robot's ZOH model at rest is a double integrator
per output, whose zero at z = −1 the dead-beat law cancels: a pole on the unit circle at −1, an
undamped oscillation at the Nyquist frequency 1/(2 Ts) in the inputs and velocities that the
sampled outputs do not show (measured on a prismatic two-drive robot: the delayed form's drive
forces grow from ±16 N to the 120 N limit within 0.9 s while the sampled error stays 0.25 µm;
any Qu ≥ 1e-6 damps it: ρ = 0.60). :func:`spectral_radius` ≥ 1 − 1e-9 says the loop is not
asymptotically stable at that state.

Scope: the loop on the controller's own model, linearized and held at X (its state-dependent
factorization at X; the Coriolis terms enter through the velocity in X), without the limits and
without the disturbance estimate (whose error is zero on the controller's own model). The
nonlinear form's law depends on its previous plan as well; it is not a function of x̄ alone and
is refused.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidParameterError
from ..solvers.qr import QRSolver
from ..validation import finite_vector
from .criterion import Criterion
from .prediction import absolute_prediction, incremental_prediction
from .redundancy import null_basis

__all__ = ["closed_loop_poles", "spectral_radius", "STABLE_MARGIN"]

#: a spectral radius at or above 1 − STABLE_MARGIN counts as not asymptotically stable.
STABLE_MARGIN = 1e-9

#: the forms whose unconstrained step is a linear law of the augmented state.
LINEAR_FORMS = ("absolute", "incremental", "incremental-delayed")


def closed_loop_poles(controller, X) -> np.ndarray:
    """Eigenvalues of the unconstrained closed loop of ``controller`` on its own model at X.

    Args:
        controller: a :class:`~parallel_gpc.gpc.GPCController` of form absolute, incremental or
            incremental-delayed (its horizons, weights, form and model; its limits are left out).
        X: (n_x,) state the model is linearized and held at (a robot: [y, ẏ] in m, rad, m/s, rad/s).

    Returns:
        (n_x,) poles of the absolute form, (n_x + m,) of the incremental ones (complex).

    Raises:
        InvalidParameterError: the nonlinear form (its law depends on its previous plan).
        ShapeError, NonFiniteError: X of the wrong size or not finite.
    """
    form = controller.form
    if form not in LINEAR_FORMS:
        raise InvalidParameterError(f"closed-loop poles: form {form!r} is not a linear law of its state; "
                                    f"valid: {', '.join(LINEAR_FORMS)} (the nonlinear form's law at rest along a "
                                    f"held plan is the incremental one's at Qu = 0)")
    model = controller.model
    n, m = model.n_x, model.n_u
    X = finite_vector("X", X, n)
    H, C = controller.horizons, model.C
    Ad, Bd, _ = model.discrete(X, controller.Ts)
    criterion = Criterion(controller.weights, H, model.n_y, m)
    w = np.zeros(H.n_rows * model.n_y)
    solver = QRSolver()
    n_aug = n if form == "absolute" else n + m

    def first_move(x_aug: np.ndarray) -> np.ndarray:
        if form == "absolute":
            pred = absolute_prediction(Ad, Bd, None, C, x_aug, H)
        else:
            pred = incremental_prediction(Ad, Bd, None, C, x_aug[:n], x_aug[n:], H,
                                          delayed=form == "incremental-delayed")
        result = solver.solve_unconstrained(criterion.problem(pred, w))
        return result.v[:m]

    origin = first_move(np.zeros(n_aug))  # zero: the law is linear; subtracted all the same
    K = np.column_stack([first_move(e) - origin for e in np.eye(n_aug)])
    if form == "absolute":
        return np.linalg.eigvals(Ad + Bd @ K)
    basis = null_basis(Bd, native=False)
    P = np.eye(m) if basis is None else np.eye(m) - basis.T @ basis  # u's part that moves the model
    # the law and the next input see the u block through P (the increments add to u without null(B_d))
    K[:, n:] = K[:, n:] @ P
    A_aug = np.block([[Ad, Bd @ P], [np.zeros((m, n)), P]])
    B_aug = np.vstack([Bd if form == "incremental" else np.zeros((n, m)), np.eye(m)])
    return np.linalg.eigvals(A_aug + B_aug @ K)


def spectral_radius(poles: np.ndarray) -> float:
    """Largest |pole| (1 or more: not asymptotically stable; compare with 1 − :data:`STABLE_MARGIN`)."""
    return float(np.abs(np.asarray(poles)).max(initial=0.0))
