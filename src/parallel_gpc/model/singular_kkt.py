"""Constrained dynamics of robots whose open-tree mass matrix is singular (massless moving bodies).

Published URDFs leave ``<inertial>`` out of some moving bodies (e.g. the cross link of a universal
joint written as two revolutes, or a distal link). The open tree's mass matrix M is then singular
while the closed chain is regular (M positive definite on the closures' null space), and
``pin.constraintDynamics`` (whose factorization needs M > 0) returns NaN. :class:`SingularMassKKT`
solves the same equations without M⁻¹:

    [M  Jᵀ] [ q̈]   [τ − h]
    [J  0 ] [−λ] = [ −γ  ]

(λ: the closure forces in ``RigidConstraintData.contact_force``'s convention, M q̈ = τ − h + Jᵀ λ),
densely by least squares (planar robots with CONTACT_3D closures have a rank-deficient J: the system
is consistent, q̈ is unique and the minimum-norm λ is returned). The closure acceleration −γ = J q̈
(J̇v and the Baumgarte terms) depends on q and v only, not on the inertias, so it is taken from
``pin.constraintDynamics`` on a twin model whose massless bodies get a unit-free small inertia:
the same γ the regular plant uses, computed by the same code.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

#: M counts as singular when its smallest eigenvalue is at most this fraction of its largest
SINGULAR_RATIO = 1e-10


def mass_matrix(model, data, q) -> np.ndarray:
    """(nv, nv) symmetric joint-space mass matrix M(q) (kg, kg·m, kg·m²) by ``pin.crba``."""
    M = pin.crba(model, data, q)
    return np.triu(M) + np.triu(M, 1).T


def singular_mass_matrix(robot, q) -> bool:
    """True when ``robot``'s open-tree mass matrix at q is singular (λ_min ≤ SINGULAR_RATIO λ_max)."""
    model = robot.model
    eig = np.linalg.eigvalsh(mass_matrix(model, model.createData(), q))
    return bool(eig[0] <= SINGULAR_RATIO * eig[-1])


def _regularized_twin(model):
    """A copy of ``model`` whose bodies without mass carry a small sphere (γ does not depend on it)."""
    twin = model.copy()
    masses = [twin.inertias[i].mass for i in range(1, twin.njoints)]
    m = 1e-3 * max(max(masses), 1.0)
    for i in range(1, twin.njoints):
        I = twin.inertias[i]
        if np.linalg.eigvalsh(I.matrix())[0] <= SINGULAR_RATIO * max(m, I.mass):
            twin.inertias[i] = I + pin.Inertia.FromSphere(m, 0.05)
    return twin


class SingularMassKKT:
    """KKT solve of the closed-chain dynamics for a singular open-tree mass matrix.

    Args:
        robot: the plant's :class:`~parallel_gpc.model.robot.ParallelRobot`.
        cms: the plant's ``pin.RigidConstraintModel`` closures (with their Baumgarte gains).
        q: a configuration to initialize Pinocchio's constraint data at.
        prox: the plant's ``pin.ProximalSettings`` (the twin's constraintDynamics uses the same).

    Attributes:
        forces: (3 k,) linear closure forces (N) of the last :meth:`accelerations` call.
    """

    def __init__(self, robot, cms, q, prox):
        self.model = robot.model
        self.data = self.model.createData()
        self.twin = _regularized_twin(self.model)
        self.twin_data = self.twin.createData()
        self.cms = cms
        self.cds = pin.StdVec_RigidConstraintData()
        for cm in cms:
            self.cds.append(cm.createData())
        pin.initConstraintDynamics(self.twin, self.twin_data, self.cms, self.cds)
        self.prox = prox
        # the linear rows of each closure (3 of a point closure's 3, of a weld's 6)
        self._linear = np.concatenate([np.arange(3 if cm.type == pin.ContactType.CONTACT_3D else 6) < 3
                                       for cm in cms])
        self.forces = np.zeros(int(self._linear.sum()))

    def accelerations(self, q, v, tau) -> np.ndarray:
        """(nv,) q̈ for joint torques tau at (q, v); sets :attr:`forces`."""
        a_twin = pin.constraintDynamics(self.twin, self.twin_data, q, v, tau, self.cms, self.cds, self.prox)
        J = pin.getConstraintsJacobian(self.twin, self.twin_data, self.cms, self.cds)
        M = mass_matrix(self.model, self.data, q)
        h = pin.nonLinearEffects(self.model, self.data, q, v)
        n, m = M.shape[0], J.shape[0]
        K = np.block([[M, J.T], [J, np.zeros((m, m))]])
        sol = np.linalg.lstsq(K, np.concatenate([tau - h, J @ a_twin]), rcond=None)[0]
        lam = -sol[n:]
        self.forces = lam[self._linear]
        return sol[:n]
