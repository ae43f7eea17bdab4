"""State and output constraints of the GPC problem, stage-wise over the horizon (issue 22).

The prediction ŷ = f + G v (:mod:`parallel_gpc.gpc.prediction`) is affine in the decision
variables v, so every limit on the predicted motion is a set of rows ``G_c v ≤ h_c``:

* ``output_box``: y_lo ≤ ŷ(k+i) ≤ y_hi on the predicted steps i = No+1..N;
* ``output_velocity``: |ŷ(k+i) − ŷ(k+i−1)| ≤ v·Ts (the mean velocity over each sample; the
  first difference from the measured y(k) when No = 0);
* ``drive_position``: q_lo ≤ q_a(ŷ(k+i)) ≤ q_hi, linearized along the poses the controller
  expects, ȳ(k+i) (the previous plan's prediction: f + G v_warm, the nonlinear form's
  pre-simulated trajectory): q_a(ŷ) ≈ q_a(ȳ) + J(ȳ)(ŷ − ȳ), J = ∂q_a/∂y the drive rows of the
  velocity map (q̇ = T ẏ);
* ``drive_rate``: |J̄ᵢ (ŷ(k+i) − ŷ(k+i−1))| ≤ r·Ts, J̄ᵢ = (J(ȳ(k+i)) + J(ȳ(k+i−1)))/2 (the
  trapezoid rule: q_a(ŷ(k+i)) − q_a(ŷ(k+i−1)) to second order; ȳ(k) = y(k)). This bounds the
  mean drive rate over each sample; within a sample the rate can exceed it (a sampled input
  that alternates makes it ring), so leave margin when the instantaneous rate matters;
* ``joint_position``: q_lo ≤ q_j(ŷ(k+i)) ≤ q_hi for each named passive one-DOF joint, linearized
  like the drive positions through the joint's row of the velocity map (q_j = q_j(y) through
  the closure solution; a universal joint is two revolute joints, two ranges). A spherical
  joint's cone limit is not supported (our robot files cut their loops at the spherical joints,
  which then have no coordinate).

Soft kinds (``Limits.soft``) get one slack variable per bound pair and step (exact L1 penalty,
:func:`~parallel_gpc.solvers.problem.with_inequalities`); hard ones are plain rows. A kind whose
bounds are all infinite adds no row; with no state limit the problem is returned unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import AssemblyError, InvalidParameterError, SingularPoseError
from ..limits import KINEMATIC_KINDS, SOFT_QUADRATIC, STATE_KINDS, Limits
from ..solvers import LeastSquaresProblem, SolveResult, with_equalities, with_inequalities
from .prediction import Prediction

__all__ = ["DriveKinematics", "ConstraintRows", "OutputRows", "output_rows", "ConstraintReport", "stage_constraints",
           "terminal_rows", "constrain", "linearization_points",
           "report", "report_at", "split", "hard_violation", "hard_excess", "STATE_TOL"]

#: a row counts as active when its (slack-relaxed) value is within this of its bound (units of the limit).
ACTIVE_TOL = 1e-7
#: a solution whose hard state rows are violated by more than this (m, rad, m/s, …) is not applied.
STATE_TOL = 1e-7


class DriveKinematics:
    """Drive positions q_a(y), the positions of named passive joints q_j(y), and their Jacobians
    ∂q/∂y of a robot (rows of the velocity map q̇ = T ẏ), warm-started pose to pose.

    Args:
        robot: a :class:`~parallel_gpc.model.ParallelRobot` (assembly, velocity map, drive indices).
        joints: names of passive one-DOF joints whose positions are wanted too (joint ranges).

    Raises:
        InvalidParameterError: a joint name that is not a passive one-DOF joint of the robot
            (naming it and the valid names).
    """

    def __init__(self, robot, joints=()):
        self.robot = robot
        self._q = robot.q_home.copy()
        self.joints = tuple(joints)
        found = robot.passive_joints if self.joints else {}
        for name in self.joints:
            if name not in found:
                drive = name in robot.description.drive_joints
                raise InvalidParameterError(
                    f"joint_position names joint {name!r}, which is " + ("a drive (limit it by drive_position)"
                                                                          if drive else "not a passive one-DOF joint "
                                                                          f"of {robot.name}") +
                    f"; valid joint names: {list(found)}")
        idx = [found[n] for n in self.joints]
        self._iq = np.concatenate([robot.drive_q_indices, np.array([i for i, _ in idx], dtype=int)]).astype(int)
        self._iv = np.concatenate([np.asarray(robot.drive_idx), np.array([i for _, i in idx], dtype=int)]).astype(int)

    def __call__(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """((n_u + n_j,) drive then joint positions (m or rad), (n_u + n_j, n_y) Jacobian ∂q/∂y)
        at pose y (m, rad); n_j = len(joints).

        Raises:
            AssemblyError, SingularPoseError: y cannot be assembled on the robot's branch.
        """
        r = self.robot
        out = r.assemble_warm(np.asarray(y, dtype=float), self._q)
        if out is None:
            q = r.assemble(y, self._q)
            T, _ = r.velocity_map_nocopy(q)
        else:
            q, T, _ = out
        self._q = q
        return q[self._iq], T[self._iv]

    @classmethod
    def of(cls, model, joints=()) -> "DriveKinematics | None":
        """The drive (and ``joints``') kinematics of a controller's model (a robot's reduced model), or None."""
        robot = getattr(model, "robot", None)
        return None if robot is None or not hasattr(robot, "assemble_warm") else cls(robot, joints)

    @classmethod
    def needed(cls, model, limits: Limits) -> "DriveKinematics | None":
        """The kinematics ``limits`` need (drive_position, drive_rate, joint_position), None when they need none.

        Raises:
            InvalidParameterError: such limits on a model that is not a robot's, or an unknown joint name.
        """
        if not limits.has_kinematic_limits:
            return None
        joints = tuple(limits.joint_position or ())
        kin = cls.of(model, joints)
        if kin is None:
            raise InvalidParameterError(f"{', '.join(k for k in KINEMATIC_KINDS if getattr(limits, k) is not None)} "
                                        f"limits need a robot's model (drive and joint kinematics); "
                                        f"{type(model).__name__} has none")
        return kin


@dataclass
class ConstraintRows:
    """One step's state/output constraints as one-sided rows ``G v ≤ h``.

    Attributes:
        G: (k, n); h: (k,). kind: (k,) the kind of each row (names of
        :data:`~parallel_gpc.limits.STATE_KINDS`). slack_of: (k,) slack index, −1 for a hard row.
        n_slack: number of slack variables.
    """

    G: np.ndarray
    h: np.ndarray
    kind: np.ndarray
    slack_of: np.ndarray
    n_slack: int = 0


@dataclass(frozen=True)
class ConstraintReport:
    """What the state/output constraints did in one step.

    Attributes:
        active: the kinds with a row at its (relaxed) bound, sorted.
        slack: the largest slack used per soft kind (units of the limit: m, rad, m/s, …); 0 when
            the constraint holds.
    """

    active: tuple[str, ...] = ()
    slack: dict = field(default_factory=dict)

    @property
    def max_slack(self) -> float:
        return max(self.slack.values(), default=0.0)


@dataclass(frozen=True)
class OutputRows:
    """One state kind's rows over the predicted steps, written on the outputs (the one definition
    both layouts use: :func:`stage_constraints` condenses it, :func:`~parallel_gpc.gpc.stagewise.stage_problem`
    places it on the stages):

        lo(j) ≤ cur(j) ŷ(k+i) + prev(j) ŷ(k+i−1) + offset(j) ≤ hi(j),   i = first + j,

    ŷ(k) being the measured y(k) (a first difference from it when No = 0).

    Attributes:
        kind: a name of :data:`~parallel_gpc.limits.STATE_KINDS`. first: the predicted step of row block 0.
        cur: (n_i, k, p) and prev: (n_i, k, p) or None (no ŷ(k+i−1) term) coefficients; offset: (n_i, k)
            (units of the limit); lo, hi: (n_i, k) bounds (±inf: that side is unused). soft: relaxed by slacks.
    """

    kind: str
    first: int
    cur: np.ndarray
    prev: np.ndarray | None
    offset: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    soft: bool


def _steps(H, differenced: bool) -> tuple[int, int]:
    """(first predicted step, number of steps) of a kind on ŷ(k+i) (i = No+1..N) or, ``differenced``,
    on ŷ(k+i) − ŷ(k+i−1) (from i = No+2, or i = 1 from the measured y(k) when No = 0)."""
    first = H.No + 1 if not differenced or H.No == 0 else H.No + 2
    return first, H.N - first + 1


def output_rows(limits: Limits, H, Ts: float, p: int) -> list[OutputRows]:
    """The rows of the kinds written on the outputs alone (``output_box``, ``output_velocity``):
    y_lo ≤ ŷ(k+i) ≤ y_hi, i = No+1..N, and −v·Ts ≤ ŷ(k+i) − ŷ(k+i−1) ≤ v·Ts (see the module docstring).

    Args:
        limits: sized to the outputs. H: the horizons. Ts: sample time (s). p: number of outputs.
    """
    out, eye = [], np.eye(p)
    if limits.output_box is not None:
        first, n = _steps(H, False)
        box = limits.output_box
        out.append(OutputRows("output_box", first, np.broadcast_to(eye, (n, p, p)), None, np.zeros((n, p)),
                              np.broadcast_to(box[:, 0], (n, p)), np.broadcast_to(box[:, 1], (n, p)),
                              limits.is_soft("output_box")))
    if limits.output_velocity is not None:
        first, n = _steps(H, True)
        vmax = np.broadcast_to(limits.output_velocity * Ts, (n, p))
        out.append(OutputRows("output_velocity", first, np.broadcast_to(eye, (n, p, p)),
                              np.broadcast_to(-eye, (n, p, p)), np.zeros((n, p)), -vmax, vmax,
                              limits.is_soft("output_velocity")))
    return out


def stage_constraints(pred: Prediction, limits: Limits, Ts: float, y_now: np.ndarray,
                      y_lin: np.ndarray | None = None, drives: DriveKinematics | None = None) -> ConstraintRows | None:
    """The rows of every state limit of ``limits`` for one step (the condensed layout of :class:`OutputRows`).

    Args:
        pred: the prediction ŷ = f + G v (outputs k+No+1..k+N, p each).
        limits: sized to the drives and outputs (:meth:`~parallel_gpc.limits.Limits.for_drives`).
        Ts: sample time (s). y_now: (p,) measured output y(k) (m, rad).
        y_lin: (n_rows·p,) poses the drive limits are linearized at (default f).
        drives: the robot's :class:`DriveKinematics` (needed by drive_position and drive_rate).

    Returns:
        The rows, or None when no state limit is set.

    Raises:
        InvalidParameterError: a drive limit without drive kinematics (a model that is not a robot's).
    """
    if not limits.has_state_limits:
        return None
    H = pred.horizons
    y_now = np.asarray(y_now, dtype=float)
    p = len(y_now)
    n_rows, n = H.n_rows, pred.G.shape[1]
    # ŷ(k+No+j) = fe[j] + Ge[j] v, j = 0..n_rows; j = 0 is y(k) itself (used only when No = 0)
    Ge = np.concatenate([np.zeros((1, p, n)), pred.G.reshape(n_rows, p, n)])
    fe = np.concatenate([y_now[None], pred.f.reshape(n_rows, p)])
    # rows in the order the two producers write them: output_box, output_velocity, drive_position,
    # joint_position, drive_rate
    blocks = output_rows(limits, H, Ts, p)
    if limits.has_kinematic_limits:
        blocks += _kinematic_rows(limits, H, Ts, y_now, fe[1:], y_lin, drives)
    G_rows, h_rows, kinds, slack_of = [], [], [], []
    n_slack = 0
    for b in blocks:
        j = np.arange(b.first, b.first + len(b.cur)) - H.No  # indices into Ge, fe
        k = b.cur.shape[0] * b.cur.shape[1]  # rows of this block (explicit: n may be 0, a trajectory's own rows)
        M = np.einsum("ikp,ipn->ikn", b.cur, Ge[j]).reshape(k, n)
        value = np.einsum("ikp,ip->ik", b.cur, fe[j]) + b.offset
        if b.prev is not None:
            M += np.einsum("ikp,ipn->ikn", b.prev, Ge[j - 1]).reshape(k, n)
            value = value + np.einsum("ikp,ip->ik", b.prev, fe[j - 1])
        value, lo, hi = value.reshape(-1), np.reshape(b.lo, -1), np.reshape(b.hi, -1)
        has_hi, has_lo = np.isfinite(hi), np.isfinite(lo)
        used = has_hi | has_lo
        index = np.full(len(M), -1)
        if b.soft:
            index[used] = n_slack + np.arange(int(used.sum()))
            n_slack += int(used.sum())
        for mask, sign, bound in ((has_hi, 1.0, hi), (has_lo, -1.0, lo)):
            G_rows.append(sign * M[mask])
            h_rows.append(sign * (bound[mask] - value[mask]))
            kinds += [b.kind] * int(mask.sum())
            slack_of.append(index[mask])
    return ConstraintRows(np.vstack(G_rows), np.concatenate(h_rows), np.array(kinds, dtype=object),
                          np.concatenate(slack_of).astype(int), n_slack)


def linearization_points(drives: DriveKinematics, poses: np.ndarray, y_now: np.ndarray):
    """The poses the kinematic limits are linearized at, and the drive kinematics there.

    A predicted pose is a point of a linear (or pre-simulated) prediction: far along a long horizon it may
    lie beyond the workspace or at a singular pose, where no assembly exists. Such a row is linearized at
    the last pose before it that assembles (the row before, or the measured pose y_now for the first):
    q(ŷ) ≈ q(ȳ) + J(ȳ)(ŷ − ȳ), a first-order extension of the limit past the workspace's edge, re-linearized
    at every step as the prediction comes back.

    Args:
        drives: the robot's :class:`DriveKinematics`. poses: (n_rows, p) predicted poses (m, rad).
        y_now: (p,) measured pose (m, rad).

    Returns:
        ((n_rows, p) linearization points, [(positions, Jacobian)] per row as ``drives`` gives them).

    Raises:
        AssemblyError, SingularPoseError: y_now itself cannot be assembled (needed only when the first
            predicted pose cannot).
    """
    points, out, last = np.array(poses, dtype=float), [], None
    for i, y in enumerate(points):
        try:
            last = (y, drives(y))
        except (AssemblyError, SingularPoseError):
            if last is None:
                last = (np.asarray(y_now, dtype=float), drives(np.asarray(y_now, dtype=float)))
            points[i] = last[0]
        out.append(last[1])
    return points, out


def _kinematic_rows(limits: Limits, H, Ts: float, y_now, f_rows, y_lin, drives) -> list[OutputRows]:
    """The :class:`OutputRows` of drive_position, joint_position and drive_rate, linearized at the
    poses y_lin ((n_rows·p,), default the free response f_rows (n_rows, p)) through ``drives``."""
    if drives is None:
        raise InvalidParameterError("drive_position, drive_rate and joint_position limits need the robot's "
                                    "kinematics (a controller of a robot's reduced model); this model has none")
    joints = tuple(limits.joint_position or ())
    if joints and drives.joints != joints:
        raise InvalidParameterError(f"the kinematics give the joints {list(drives.joints)}; the joint_position "
                                    f"limits name {list(joints)}")
    n_rows, p = f_rows.shape
    ybar, qj = linearization_points(drives, (f_rows if y_lin is None else np.asarray(y_lin, dtype=float)).reshape(
        n_rows, p), y_now)
    qall = np.array([a for a, _ in qj])
    jall = np.array([J for _, J in qj])  # (n_rows, n_u + n_j, p)
    n_u = qall.shape[1] - len(drives.joints)
    out = []
    first, _ = _steps(H, False)

    def tiled(bounds):  # (k, 2) → (n_rows, k) lower and upper
        shape = (n_rows, len(bounds))
        return np.broadcast_to(bounds[:, 0], shape), np.broadcast_to(bounds[:, 1], shape)

    if limits.drive_position is not None:  # q_a(ŷ) ≈ q̄ + J (ŷ − ȳ)
        jac = jall[:, :n_u]
        offset = qall[:, :n_u] - np.einsum("imp,ip->im", jac, ybar)
        out.append(OutputRows("drive_position", first, jac, None, offset, *tiled(limits.drive_position),
                              limits.is_soft("drive_position")))
    if limits.joint_position is not None:
        sel = [drives.joints.index(name) for name in joints]
        Jj = jall[:, n_u:][:, sel]
        offset = qall[:, n_u:][:, sel] - np.einsum("imp,ip->im", Jj, ybar)
        ranges = np.array([limits.joint_position[name] for name in joints])
        out.append(OutputRows("joint_position", first, Jj, None, offset, *tiled(ranges),
                              limits.is_soft("joint_position")))
    if limits.drive_rate is not None:  # J̄ (ŷ(k+i) − ŷ(k+i−1)), J̄ the trapezoid of the two poses' Jacobians
        jac = jall[:, :n_u]
        if H.No == 0:  # the first difference is from y(k): its Jacobian too
            J_now = drives(np.asarray(y_now, dtype=float))[1][:n_u]
            J = 0.5 * (jac + np.concatenate([J_now[None], jac[:-1]]))
        else:
            J = 0.5 * (jac[1:] + jac[:-1])
        first_d, n_d = _steps(H, True)
        rmax = np.broadcast_to(limits.drive_rate * Ts, (n_d, n_u))
        out.append(OutputRows("drive_rate", first_d, J, -J, np.zeros((n_d, n_u)), -rmax, rmax,
                              limits.is_soft("drive_rate")))
    return out


def terminal_rows(pred: Prediction, w: np.ndarray, terminal: str | None) -> tuple[np.ndarray, np.ndarray] | None:
    """The terminal equality rows ``E v = e`` of one step, or None.

    Args:
        pred: the prediction ŷ = f + G v. w: (n_rows, p) or (n_rows·p,) reference (m, rad).
        terminal: None, ``"pose"`` (ŷ(k+N) = w(k+N)) or ``"stop"`` (also ŷ(k+N) = ŷ(k+N−1):
            zero mean velocity over the last predicted sample; needs two predicted rows).

    Returns:
        (E (k, n), e (k,)), k = p (pose) or 2p (stop); None without a terminal equality.
    """
    if terminal is None:
        return None
    w = np.asarray(w, dtype=float).reshape(-1)
    p = len(w) // pred.horizons.n_rows
    E, e = [pred.G[-p:]], [w[-p:] - pred.f[-p:]]
    if terminal == "stop":
        E.append(pred.G[-p:] - pred.G[-2 * p:-p])
        e.append(pred.f[-2 * p:-p] - pred.f[-p:])
    return np.vstack(E), np.concatenate(e)


def constrain(problem: LeastSquaresProblem, rows: ConstraintRows | None, limits: Limits,
              terminal: tuple[np.ndarray, np.ndarray] | None = None) -> LeastSquaresProblem:
    """``problem`` with the state constraint ``rows`` added (slack variables for the soft ones) and
    the hard terminal equality rows ``terminal`` = (E, e) (:func:`terminal_rows`)."""
    if rows is not None and len(rows.h):
        problem = with_inequalities(problem, rows.G, rows.h, rows.slack_of, limits.penalty,
                                    limits.penalty * SOFT_QUADRATIC)
    if terminal is not None:
        problem = with_equalities(problem, *terminal)
    return problem


def report(problem: LeastSquaresProblem, rows: ConstraintRows | None, x: np.ndarray) -> ConstraintReport | None:
    """Which kinds are active at the full solution x = [v; s] and the slack each used."""
    if rows is None or not len(rows.h):
        return None
    n = problem.n_decision
    s = x[n:] * (1.0 if problem.slack_unit is None else problem.slack_unit)  # in the limits' units
    return report_at(rows, rows.G @ x[:n], s)


def report_at(rows: ConstraintRows | None, Gv: np.ndarray, s: np.ndarray) -> ConstraintReport | None:
    """Which kinds are active where the rows' left sides are Gv = G v (k,), and the slack each used,
    s (n_s,) the slack in the limits' units (m, rad, m/s, …); None without rows."""
    if rows is None or not len(rows.h):
        return None
    relaxed = rows.h + np.where(rows.slack_of >= 0, s[np.maximum(rows.slack_of, 0)] if s.size else 0.0, 0.0)
    gap = relaxed - Gv
    active = sorted({str(k) for k in rows.kind[gap <= ACTIVE_TOL * (1.0 + np.abs(rows.h))]})
    slack = {}
    for kind in STATE_KINDS:
        sel = (rows.kind == kind) & (rows.slack_of >= 0)
        if sel.any():
            slack[kind] = float(max(0.0, np.max(s[rows.slack_of[sel]])))
    return ConstraintReport(tuple(active), slack)


def hard_violation(problem: LeastSquaresProblem, rows: ConstraintRows | None, x: np.ndarray) -> float:
    """The largest violation of a hard row at x = [v; s] (units of the limit: m, rad, m/s, …; 0 when kept)."""
    if rows is None or not len(rows.h):
        return 0.0
    return hard_excess(rows, rows.G @ x[:problem.n_decision])


def hard_excess(rows: ConstraintRows | None, Gv: np.ndarray) -> float:
    """The largest violation of a hard row where the rows' left sides are Gv = G v (k,) (units of
    the limit: m, rad, m/s, …; 0 when kept or without rows)."""
    if rows is None or not len(rows.h):
        return 0.0
    hard = rows.slack_of < 0
    if not hard.any():
        return 0.0
    return float(max(0.0, np.max(Gv[hard] - rows.h[hard])))


def split(problem: LeastSquaresProblem, result: SolveResult) -> tuple[SolveResult, np.ndarray]:
    """The result with v the decision variables proper, and the slack (n_s,) in the limits' units."""
    n = problem.n_decision
    if not problem.n_slack:
        return result, np.zeros(0)
    x = result.v
    return replace(result, v=x[:n].copy()), x[n:] * problem.slack_unit
