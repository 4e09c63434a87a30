"""Affine kinematics: every node of the network at x = F X (``solver.kinematics = "affine"``).

The classical affine network model: the cross-links follow the macroscopic deformation, so no
equilibrium is solved and the fiber stretches are those of F alone (docs/model.md section 4).
It is an upper bound of the stiffness of the equilibrated network with the same law, and the
kinematics of the authors' worked example (``data/authors``). The plastic flow still needs time
steps: a loading program runs through the same march (:mod:`espin.mechanics.march`) as the
equilibrated one, each attempt updating the fiber law at the affine stretches.

Under mixed control the free components f_k of F = F_prescribed + sum_k f_k G_k are the only
unknowns: Newton's method on their stress equations P : G_k = 0 (or the lateral stress target,
:class:`~espin.mechanics.loading.LateralStress`) with the affine tangent
dP_iJ / dF_kL = (1 / V0) sum_e [dT/dl a_i a_k + T / l (delta_ik - a_i a_k)] dX_J dX_L.
The recorded residual is the largest force imbalance of an inner node [uN]: how far the affine
state is from equilibrium.
"""

from __future__ import annotations

import numpy as np

from espin.core.errors import InadmissibleState, StepFailureKind, StepNotConverged
from espin.mechanics.equilibrium import EquilibriumSolver, StepResult, StepState
from espin.mechanics.fiber_law import LawState, axial_force_and_stiffness, update
from espin.mechanics.loading import LateralStress, LoadProgram

__all__ = ["AffineSteps"]

_MAX_ITERATIONS = 50
_MAX_HALVINGS = 30


class AffineSteps:
    """A loading program on one network with affine kinematics, as a
    :class:`~espin.mechanics.march.StepProblem`.

    Parameters
    ----------
    solver
        The network's solver: its network, fiber law, tolerances (``solver.rtol``, ``atol``)
        and local time error; no equilibrium is solved with it.
    program
        The loading program.
    lateral
        The lateral stress target of the one free component, or None.
    """

    iteration_limit = None  # steps grow by the time error alone

    def __init__(self, solver: EquilibriumSolver, program: LoadProgram, lateral: LateralStress | None) -> None:
        self.solver, self.program, self.lateral = solver, program, lateral
        self.directions = program.free_directions
        network = solver.network
        self.reference = solver.asm.reference
        self.dX = network.element_vector
        n = network.n_elements
        F0 = program.prescribed_F(0.0)
        self.state = StepState(
            0.0,
            self.reference[: network.n_inner] @ F0.T,
            np.zeros(len(self.directions)),
            F0,
            network.initial_plastic_stretch,
            np.zeros(n),
        )

    def _evaluate(
        self, free: np.ndarray, F_prescribed: np.ndarray, dt: float, guess: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, LawState, np.ndarray, np.ndarray]:
        """F, the nodes at F X, the law, the element forces and stiffnesses at free values ``free``."""
        F = F_prescribed + np.tensordot(free, self.directions, axes=1) if len(free) else F_prescribed
        if not (np.all(np.isfinite(F)) and np.linalg.det(F) > 0.0):
            raise InadmissibleState("the free components of F left the admissible states (det F <= 0)")
        solver = self.solver
        x = self.reference @ F.T
        stretch = solver.asm.kinematics(x).length / solver.l0
        law = update(solver.law, stretch, self.state.plastic_stretch, solver.tortuosity, dt, guess)
        force, stiffness = axial_force_and_stiffness(law, solver.area, solver.l0)
        return F, x, law, force, stiffness

    def _free_residual(self, F: np.ndarray, x: np.ndarray, force: np.ndarray) -> tuple[np.ndarray, float]:
        """P : G_k minus the stress each free component is held at, and max |P| [MPa]."""
        kin = self.solver.asm.kinematics(x)
        P = np.einsum("e,ei,eJ->iJ", force, kin.unit, self.dX) / self.solver.network.reference_volume
        residual = np.einsum("iJ,kiJ->k", P, self.directions)
        if self.lateral is not None:
            residual[0] -= self.lateral.nominal(float(np.vdot(F, self.directions[0])))[0]
        return residual, float(np.max(np.abs(P)))

    def _jacobian(self, F: np.ndarray, x: np.ndarray, force: np.ndarray, stiffness: np.ndarray) -> np.ndarray:
        """d(free residual)_k / d f_l [MPa] from the affine tangent (module docstring)."""
        kin = self.solver.asm.kinematics(x)
        transverse = np.where(kin.length > 0.0, force / np.maximum(kin.length, np.finfo(float).tiny), 0.0)
        aa = np.einsum("ei,ek->eik", kin.unit, kin.unit)
        K = (stiffness - transverse)[:, None, None] * aa + transverse[:, None, None] * np.eye(2)
        A = np.einsum("eik,eJ,eL->iJkL", K, self.dX, self.dX) / self.solver.network.reference_volume
        jacobian = np.einsum("kiJ,iJmL,lmL->kl", self.directions, A, self.directions)
        if self.lateral is not None:
            jacobian[0, 0] -= self.lateral.nominal(float(np.vdot(F, self.directions[0])))[1]
        return jacobian

    def attempt(self, start: float, end: float) -> StepResult:
        """The affine state at ``end`` [s] from the committed one; the free components of F by
        Newton's method with a halving line search on the residual's norm.

        Raises
        ------
        StepNotConverged
            When the free components' stress equations are not met in 50 iterations, or no
            shorter Newton step lowers their residual.
        """
        solver, dt = self.solver, end - start
        F_prescribed = self.program.prescribed_F(end)
        free = self.state.free.copy()
        F, x, law, force, stiffness = self._evaluate(free, F_prescribed, dt, None)
        iterations = 0
        history: list[float] = []
        if len(free):
            # as the equilibrium's free rows: |P : G_k - target| <= rtol max |P| + atol E_t phi;
            # the history in uN (V0 times the stress over L / 2, as the equilibrium's)
            to_force = 2.0 * solver.network.reference_volume / solver.network.size
            residual, P_scale = self._free_residual(F, x, force)
            while True:
                norm = float(np.max(np.abs(residual)))
                history.append(norm * to_force)
                if norm <= solver.config.rtol * P_scale + solver.stress_tolerance_abs:
                    break
                if iterations == _MAX_ITERATIONS:
                    raise StepNotConverged(
                        f"the free components of F did not converge in {_MAX_ITERATIONS} iterations",
                        history=history,
                        iterations=iterations,
                    )
                iterations += 1
                step = np.linalg.solve(self._jacobian(F, x, force, stiffness), -residual)
                for _ in range(_MAX_HALVINGS):
                    try:
                        trial = self._evaluate(free + step, F_prescribed, dt, law.plastic_stretch)
                    except InadmissibleState:
                        step = 0.5 * step
                        continue
                    trial_residual, trial_scale = self._free_residual(trial[0], trial[1], trial[3])
                    if np.max(np.abs(trial_residual)) < norm:
                        break
                    step = 0.5 * step
                else:
                    raise StepNotConverged(
                        "no shorter step along the Newton direction lowered the free components' stress residual",
                        StepFailureKind.UPHILL,
                        history=history,
                        iterations=iterations,
                    )
                free = free + step
                F, x, law, force, stiffness = trial
                residual, P_scale = trial_residual, trial_scale
        kin = solver.asm.kinematics(x)
        imbalance = solver.asm.gradient(force, kin)[: 2 * solver.n_inner]
        residual_force = float(np.max(np.abs(imbalance))) if len(imbalance) else 0.0
        state = StepState(end, x[: solver.n_inner].copy(), free, F, law.plastic_stretch, law.stress)
        return StepResult(state, law, force, kin, iterations, 0, residual_force, history)

    def error(self, trial: StepResult) -> float:
        """Relative local time error of the plastic update (as for the equilibrated network)."""
        return self.solver.time_error(self.state, trial)

    def commit(self, trial: StepResult) -> None:
        self.state = trial.state

    def rollback(self) -> None:
        pass

    def new_segment(self) -> None:
        """Nothing is extrapolated across segments."""
