"""Equilibrium of the network over one load step (paper 3.1.4; docs/model.md section 4).

Unknowns: the inner node positions x_I and, under mixed control, the free components f_k of
F = F_prescribed + sum_k f_k G_k. Border nodes follow x = F X (X relative to the RVE centre).
The step minimizes the incremental potential

    Phi(x_I, f) = sum_e A_e l0_e * integral from lambda_n to lambda of t_alg(lambda') dlambda'

(each element's algorithmic stress depends on its own stretch only, so Phi exists for the
plastic step too); its gradient is the residual [g_I, V0 P : G_k] and its Hessian the
consistent tangent. A lateral stress target (:class:`~espin.mechanics.loading.LateralStress`)
adds -V0 s F'22 (nominal) or -V0 s ln F'22 (Kirchhoff) to Phi, so its free row is
V0 (P'22 - s) or V0 (P'22 - s / F'22). Newton's method with:

* the exact tangent when the factorization's inertia shows it positive definite, else the
  tangent without the negative geometric stiffness of compressed elements (positive
  semi-definite by construction); after an indefinite exact tangent the next few iterations
  use the clipped one directly;
* a chord step: an iteration whose residual ratio r_k / r_k-1, repeated once, brings the
  residual within the tolerance lends its factorization to the next one (no new
  factorization), as long as that gives a descent direction;
* with the exact tangent, a semismooth correction at the slack/taut kink (modulus x1000 at
  e = lambda_r): the elements whose recruitment at the full Newton step (foreseen from their
  lengths there, without the fiber law) differs from the one the factorized tangent was
  built with are linearized on the side the step puts them (their force about the kink, on
  that side), a low-rank change solved with the same factorization
  (Sherman-Morrison-Woodbury, :mod:`espin.mechanics.kink_correction`), repeated while that
  set changes; the corrected direction is kept when its full step passes the line search's
  slope test with a smaller residual than the iterate's (the plain direction is searched
  otherwise);
* after each line search, a local Newton step on the few inner nodes whose force residual is
  still over the tolerance (at most :data:`_RELAX_MAX_NODES` and :data:`_RELAX_MAX_SHARE` of
  the inner nodes, without fiber joints) and
  their neighbours (:data:`_RELAX_RINGS` elements away, at most :data:`_RELAX_MAX_BLOCK`
  nodes): the exact tangent's block of those nodes (their elements' 2 x 2 blocks, the rest of the
  network held) solved densely, up to :data:`_RELAX_ROUNDS` rounds (one residual evaluation
  each, the fiber law updated on those nodes' elements only; no factorization), and the
  round with the lowest largest force residual kept if it is below the iterate's. After the
  first Newton iterations the residual often sits at one or two nodes held by very short,
  stiff elements (plla: a node tied to the border by two elements of 0.05 um), where the
  flow's nonlinearity costs Newton a whole iteration and factorization;
* a line search on Phi along the Newton direction (:mod:`espin.mechanics.line_search`)
  through its exact derivative (the residual projected on the direction, one residual
  evaluation per trial); where the residual grew,
  the increment of Phi from the current iterate to the trial is checked, by Simpson's rule
  on that derivative along the line (never as a difference of two large totals);
* convergence when max |g_I| <= rtol max_e |T_e| + atol E_t mean(A_e) and, under mixed
  control, |P : G_k| <= rtol max |P| + atol E_t phi (phi: fiber volume over V0);
* with fiber bending on (``fiber.bending_modulus_MPa`` > 0, :mod:`espin.mechanics.bending`),
  the joints' springs add to Phi, its gradient and its Hessian (the clipped tangent keeps
  their positive semi-definite part), and a node's force tolerance grows by the precision its
  joints' forces are known to (:meth:`~espin.mechanics.bending.FiberJoints.force_resolution`:
  next to an element of 1e-6 D the rounding of the positions alone exceeds the tolerance); so
  do the springs of fused crossings (``fiber.fused_crossing_fraction`` > 0,
  :mod:`espin.mechanics.crossings`), appended to them;
* with a compression limit (``fiber.compression_limit`` > 0,
  :mod:`espin.mechanics.compression_limit`), its contact force adds to the axial force of
  each element compressed below it, and its stiffness to dT/dl;
* with a trust region (``solver.max_move_ratio`` = m > 0), a Newton direction that moves any
  inner node by more than m D (D the mean fiber diameter) beyond the affine motion of the
  free components of F is shortened to that along its direction (before the line search).
  Where a floppy state has near-null directions (lateral ``free``: buckling chains, folding
  joints), the full Newton step can throw nodes tens of micrometres, and Newton then wanders;
  the shortened step costs iterations, never the solution (the residual is the true one);
* when Newton fails, a continuation in the slack modulus before the driver cuts the step:
  the step is solved with E_b raised 100-fold (capped at E_t / 2), then 10-fold, then with
  the true E_b, each solve starting from the equilibrium of the one before. Slack and
  compressed fibers (E_b = E_t / 1000 for plla) make a network nearly a mechanism, where
  Newton from the step's predictor does not find the basin of the solution; a stiffer E_b
  leads it there. The last solve is the true model, so the result is exact.

A step that does not converge raises :class:`~espin.core.errors.StepNotConverged` with the
residual history (the fiber law and the linear solver raise its kinds ``inadmissible`` and
``singular``); the march cuts the step. Any other exception is a bug and goes through.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from contextlib import nullcontext
from dataclasses import dataclass, field, replace
from functools import cache, partial

import numpy as np
import scipy.sparse as sp
from scipy.linalg import cho_solve
from threadpoolctl import ThreadpoolController, threadpool_info

from espin.core.config import Config, SolverConfig
from espin.core.errors import InadmissibleState, StepNotConverged
from espin.geometry.network import Network
from espin.mechanics.assembly import Kinematics, NetworkAssembler
from espin.mechanics.bending import FiberJoints, fiber_joints
from espin.mechanics.compression_limit import CompressionLimit
from espin.mechanics.crossings import crossing_joints, with_crossings
from espin.mechanics.fiber_law import STRETCH_FLOOR, FiberLaw, LawState, axial_force_and_stiffness, update
from espin.mechanics.kink_correction import KinkColumns
from espin.mechanics.line_search import SLOPE_RATIO, line_search
from espin.mechanics.linear_solvers import Factorization, LinearSolver
from espin.mechanics.loading import LateralStress
from espin.mechanics.time_steps import local_error

__all__ = ["StepState", "StepResult", "EquilibriumSolver"]

_MAX_ITERATIONS = 200  # default per step: plla seed 6 needs 75 at its first step (kink cycling)
_MAX_ITERATIONS_MIXED = 500  # under mixed control: buckling chains need hundreds
_CLIPPED_AFTER_INDEFINITE = 3
_SLACK_CONTINUATION = (100.0, 10.0, 1.0)  # E_b factors of the fallback, ending at the true law
_NEWTON_FORCING = 1e-4  # relative residual a Newton direction's linear solve may leave (single precision)
_KINK_ROUNDS = 3  # semismooth rounds of the kink correction per Newton iteration
_KINK_MAX = 100  # more crossing elements than this: no correction (m solves would cost a factorization)
_KINK_FIXED_POINT = 3  # iterations of lambda = lambda_r lambda_p(lambda) for the kink's stretch
_KINK_SIDE = 1e-9  # relative offset of the stretch that evaluates one side of the kink
_RELAX_MAX_NODES = 200  # more nodes over the tolerance: the residual is not local, no node relaxation
_RELAX_MAX_SHARE = 0.1  # nor when they are more than this share of the inner nodes (a small RVE)
_RELAX_ROUNDS = 10  # local Newton steps on those nodes per Newton iteration
_RELAX_RINGS = 2  # the nodes' neighbours up to this many elements away relax with them
_RELAX_MAX_BLOCK = 200  # most nodes in one local (dense) block
_ELEMENTS_PER_THREAD = 10_000  # fewer per thread: the threads cost more than they save


@dataclass(frozen=True, eq=False)
class StepState:
    """Converged state at the end of a step (the start of the next).

    Attributes
    ----------
    time : float [s]
    inner : (n_inner, 2) float64 [um]
        Inner node positions.
    free : (n_free,) float64
        Values f_k of the free components of F.
    F : (2, 2) float64
        Deformation gradient.
    plastic_stretch : (n_elements,) float64
        lambda_p.
    stress : (n_elements,) float64 [MPa]
        Element stress t (it starts the next step's local time error).
    """

    time: float
    inner: np.ndarray
    free: np.ndarray
    F: np.ndarray
    plastic_stretch: np.ndarray
    stress: np.ndarray


@dataclass(frozen=True, eq=False)
class StepResult:
    """A converged step: new state, element results and solver statistics."""

    state: StepState
    law: LawState
    force: np.ndarray
    kinematics: Kinematics
    iterations: int
    factorizations: int
    residual: float
    residual_history: list[float] = field(default_factory=list)


@dataclass(eq=False)
class _Point:
    """Everything evaluated at one iterate."""

    z: np.ndarray
    F: np.ndarray
    x: np.ndarray  # node positions
    kin: Kinematics
    stretch: np.ndarray
    law: LawState
    force: np.ndarray
    stiffness: np.ndarray
    gradient: np.ndarray  # full gradient over all DOF
    residual: np.ndarray  # [g_I, V0 P : G_k]


@dataclass(frozen=True, eq=False)
class _Step:
    """What one load step's iterations share."""

    start: StepState
    dt: float
    F_prescribed: np.ndarray
    directions: np.ndarray
    modes: np.ndarray  # (n_free, 2 n_border): d x_B / d f_k = G_k X_B
    weight: np.ndarray  # residual row scales for norms (all rows in uN)
    law: FiberLaw  # the law this solve uses (the continuation's stages soften E_b)
    lateral: LateralStress | None  # the stress target of the one free component, if any


@dataclass(frozen=True, eq=False)
class _Tangent:
    """A factorized tangent and what its elements entered it with."""

    factorization: Factorization
    axial: np.ndarray  # (n_elements,) dT/dl in the matrix [uN/um]
    recruited: np.ndarray  # (n_elements,) bool: taut at the point it was built
    clipped: bool  # the positive semi-definite tangent (an indefinite exact one was refused)
    kin: Kinematics  # the geometry it was built with
    kink: KinkColumns = field(init=False)
    """b_e = d l_e / d z at ``kin`` and K^-1 b_e of the elements met at the kink so far."""

    def __post_init__(self) -> None:
        # The corrected step is evaluated, so its columns need no backward-error check.
        object.__setattr__(self, "kink", KinkColumns(partial(self.factorization.solve, rtol=np.inf)))


@dataclass
class _TangentChoice:
    """Which tangent the next Newton iterations factorize: the exact one while it is positive
    definite; after an indefinite one, the clipped tangent for the next few iterations."""

    clipped_left: int = 0


class _ThreadedLaw:
    """The fiber law update of all elements, in contiguous chunks on a few threads.

    The return mapping is element by element and numpy releases the GIL inside its loops,
    so chunks on two threads take about 0.6 of the time of one call on a 2-core machine.
    The thread count is what the BLAS / OpenMP pools may use now (1 inside ensemble workers,
    which limit them), at most one thread per 10,000 elements. The result does not depend
    on it.
    """

    def __init__(self, tortuosity: np.ndarray) -> None:
        self.tortuosity = tortuosity
        n = len(tortuosity)
        available = max((int(pool["num_threads"]) for pool in threadpool_info()), default=1)
        threads = max(1, min(available, n // _ELEMENTS_PER_THREAD))
        bounds = np.linspace(0, n, threads + 1).astype(int)
        self.chunks = [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]
        self.pool = ThreadPoolExecutor(threads) if threads > 1 else None

    def __call__(
        self, law: FiberLaw, stretch: np.ndarray, plastic_old: np.ndarray, dt: float, guess: np.ndarray | None
    ) -> LawState:
        """:func:`~espin.mechanics.fiber_law.update` of every element."""

        def chunk(c: slice) -> LawState:
            return update(law, stretch[c], plastic_old[c], self.tortuosity[c], dt, None if guess is None else guess[c])

        if self.pool is None:
            return chunk(self.chunks[0])
        parts = list(self.pool.map(chunk, self.chunks))
        return LawState(*(np.concatenate([getattr(part, name) for part in parts]) for name in _LAW_FIELDS))

    def patched(
        self,
        law: FiberLaw,
        stretch: np.ndarray,
        plastic_old: np.ndarray,
        dt: float,
        near: _Point,
        elements: np.ndarray,
    ) -> LawState:
        """``near``'s law state with the update of the ``elements`` (indices) alone, started
        to first order from ``near``'s, on this thread: the others' stretches are those
        ``near`` was evaluated at."""
        guess = _first_order_plastic_stretch(near, stretch, elements)
        part = update(law, stretch[elements], plastic_old[elements], self.tortuosity[elements], dt, guess)
        fields = {name: getattr(near.law, name).copy() for name in _LAW_FIELDS}
        for name, values in fields.items():
            values[elements] = getattr(part, name)
        return LawState(**fields)


_LAW_FIELDS = ("stress", "plastic_stretch", "tangent", "recruited", "plastic_rate")


def _first_order_plastic_stretch(
    near: _Point, stretch: np.ndarray, elements: np.ndarray | slice = slice(None)
) -> np.ndarray:
    """lambda_p of the ``elements`` at ``stretch``, to first order from ``near``'s state."""
    return near.law.plastic_stretch[elements] + near.law.plastic_rate[elements] * (
        stretch[elements] - near.stretch[elements]
    )


def _each_once(indices: np.ndarray, size: int) -> np.ndarray:
    """The distinct ``indices`` (all in [0, size)), sorted: np.unique through a mask."""
    mask = np.zeros(size, dtype=bool)
    mask[indices] = True
    return np.flatnonzero(mask)


@cache
def _openblas_pools() -> ThreadpoolController:
    """The process's OpenBLAS thread pools, found once: a ThreadpoolController scans every
    loaded library (about 2 ms), and solves of small RVEs call this for every step."""
    return ThreadpoolController().select(internal_api="openblas")


class EquilibriumSolver:
    """Solves load steps of one network with one fiber law.

    Parameters
    ----------
    network
        The network.
    law
        The fiber law.
    config
        Tolerances and limits.
    linear_solver
        Object with ``factorize(K) -> factorization``; the factorization has ``solve(b)``
        and ``n_negative`` (int, or None when the backend cannot tell).
    bending_modulus_MPa
        E of the fibers' bending stiffness across their nodes [MPa]; 0: none
        (:mod:`espin.mechanics.bending`).
    fused_crossing_fraction, crossing_seed, crossing_stiffness_ratio
        Fraction phi of fused crossings, the seed of their draw and their springs' stiffness
        relative to a fiber joint's; phi > 0 (with
        ``bending_modulus_MPa`` > 0) adds their springs to the joints
        (:mod:`espin.mechanics.crossings`).
    compression_limit
        lambda_c of the elements' compression limit; 0: none
        (:mod:`espin.mechanics.compression_limit`).
    """

    def __init__(
        self,
        network: Network,
        law: FiberLaw,
        config: SolverConfig,
        linear_solver,
        bending_modulus_MPa: float = 0.0,
        fused_crossing_fraction: float = 0.0,
        crossing_seed: int = 0,
        crossing_stiffness_ratio: float = 1.0,
        compression_limit: float = 0.0,
    ) -> None:
        self.network = network
        self.law = law
        self.config = config
        self.linear = linear_solver
        self.joints: FiberJoints | None = (
            fiber_joints(network, bending_modulus_MPa) if bending_modulus_MPa > 0 else None
        )
        if fused_crossing_fraction > 0 and bending_modulus_MPa > 0:
            self.joints = with_crossings(
                self.joints,
                crossing_joints(
                    network, bending_modulus_MPa, fused_crossing_fraction, crossing_seed, crossing_stiffness_ratio
                ),
            )
        self.limit = CompressionLimit(compression_limit, law.taut_modulus) if compression_limit > 0 else None
        self.max_move = config.max_move_ratio * float(np.mean(network.element_diameter))  # 0: no trust region
        self.asm = NetworkAssembler(network, self.joints)
        self.l0 = network.element_length
        self.area = network.element_area
        self.tortuosity = network.element_tortuosity
        self._law_update = _ThreadedLaw(self.tortuosity)
        self.n_inner = network.n_inner
        # The elements of each node (CSR by node over the element ends), for the relaxation.
        ends = network.element_nodes.ravel()
        order = np.argsort(ends, kind="stable")
        self._node_start = np.searchsorted(ends[order], np.arange(self.asm.n_dof // 2 + 1))
        self._node_elements_list = order // 2
        self.border_reference = self.asm.reference[network.n_inner :]
        self.force_tolerance_abs = config.atol * law.taut_modulus * float(np.mean(self.area))
        fiber_fraction = float(np.sum(self.area * network.element_contour_length)) / network.reference_volume
        self.stress_tolerance_abs = config.atol * law.taut_modulus * fiber_fraction
        self._guess: tuple[_Step, _Point] | None = None  # kept by predicted_error for solve

    @classmethod
    def from_config(cls, network: Network, config: Config, linear_solver: LinearSolver) -> EquilibriumSolver:
        """The solver of a run's config: its fiber law (with bending and fused crossings, drawn
        from the RVE's seed) and solver settings."""
        return cls(
            network,
            FiberLaw.from_config(config.fiber),
            config.solver,
            linear_solver,
            config.fiber.bending_modulus_MPa,
            config.fiber.fused_crossing_fraction,
            config.rve.seed,
            config.fiber.fused_crossing_stiffness_ratio,
            config.fiber.compression_limit,
        )

    # -- evaluation ---------------------------------------------------------------------------
    def _context(
        self, start: StepState, time: float, F_prescribed, directions, law: FiberLaw, lateral: LateralStress | None
    ) -> _Step:
        X = self.border_reference
        modes = np.stack([(X @ G.T).ravel() for G in directions]) if len(directions) else np.zeros((0, 2 * len(X)))
        # Residual rows are forces [uN] for inner DOF and V0 P : G_k [uN um] for free
        # components; dividing the latter by L / 2 puts both in uN for norms.
        weight = np.r_[np.ones(2 * self.n_inner), np.full(len(directions), 2.0 / self.network.size)]
        return _Step(start, time - start.time, F_prescribed, directions, modes, weight, law, lateral)

    def _evaluate(
        self, z: np.ndarray, step: _Step, near: _Point | None = None, moved: np.ndarray | None = None
    ) -> _Point:
        """Everything at the iterate ``z``; an inadmissible state raises :class:`InadmissibleState`.

        ``near``: an evaluated iterate of the same step whose plastic stretches, extrapolated
        to first order in the stretch, start the return mapping (a warm start: same result,
        fewer iterations of the fiber law).
        ``moved``: the elements whose stretch differs from ``near``'s (indices; ``near``
        required): the fiber law is updated for those alone and ``near``'s kept for the rest.
        """
        n = 2 * self.n_inner
        F, x = self._deformation(z, step)
        kin = self.asm.kinematics(x)
        stretch = kin.length / self.l0
        if near is None:
            law = self._law_update(step.law, stretch, step.start.plastic_stretch, step.dt, None)
        elif moved is None:
            guess = _first_order_plastic_stretch(near, stretch)
            law = self._law_update(step.law, stretch, step.start.plastic_stretch, step.dt, guess)
        else:
            law = self._law_update.patched(step.law, stretch, step.start.plastic_stretch, step.dt, near, moved)
        force, stiffness = self.element_forces(law, stretch)
        gradient = self.asm.gradient(force, kin)
        if self.joints is not None:
            gradient += self.joints.gradient(x, self.asm.n_dof)
        residual = np.concatenate([gradient[:n], step.modes @ gradient[n:]])
        if step.lateral is not None:  # the one free component F'22 = F : G holds a stress target
            target, _ = step.lateral.nominal(float(np.vdot(F, step.directions[0])))
            residual[n] -= self.network.reference_volume * target
        return _Point(z, F, x, kin, stretch, law, force, stiffness, gradient, residual)

    def _deformation(self, z: np.ndarray, step: _Step) -> tuple[np.ndarray, np.ndarray]:
        """F and the node positions [um] at the iterate ``z``; :class:`InadmissibleState`
        where ``z`` is not finite or det F <= 0."""
        n = 2 * self.n_inner
        free = z[n:]
        F = step.F_prescribed + np.tensordot(free, step.directions, axes=1) if len(free) else step.F_prescribed
        if not (np.all(np.isfinite(z)) and np.linalg.det(F) > 0.0):
            raise InadmissibleState("the iterate left the admissible states (non-finite, or det F <= 0)")
        return F, self.asm.positions(z[:n], F)

    def _recruited_at(self, z: np.ndarray, step: _Step, near: _Point) -> np.ndarray:
        """Whether each element is taut (e >= lambda_r) at the iterate ``z``, foreseen
        without the fiber law: its plastic stretch there to first order from ``near``'s."""
        _, x = self._deformation(z, step)
        stretch = self.asm.lengths(x) / self.l0
        plastic = _first_order_plastic_stretch(near, stretch)
        return np.maximum(stretch, STRETCH_FLOOR) / plastic >= np.maximum(self.tortuosity, 1.0)

    def element_forces(self, law: LawState, stretch: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Axial force T [uN] and dT/dl [uN / um] of every element: the fiber law's, plus the
        compression limit's contact where it is on."""
        force, stiffness = axial_force_and_stiffness(law, self.area, self.l0)
        if self.limit is None:
            return force, stiffness
        return self.limit.add(force, stiffness, stretch, self.area, self.l0)

    def _converged(self, p: _Point, n_free: int) -> tuple[bool, float, float]:
        n = 2 * self.n_inner
        g = p.residual[:n]
        force_norm = float(np.max(np.abs(g))) if n else 0.0
        tolerance = self.config.rtol * float(np.max(np.abs(p.force), initial=0.0)) + self.force_tolerance_abs
        if self.joints is None:
            ok = force_norm <= tolerance
        else:  # the joints' forces are known only to the rounding of the positions (bending module notes)
            ok = bool(np.all(np.abs(g) <= tolerance + self.joints.force_resolution(p.x, self.asm.n_dof)[:n]))
        if n_free:
            V0 = self.network.reference_volume
            stress = np.abs(p.residual[n:]) / V0
            P_scale = float(np.max(np.abs(p.gradient[n:].reshape(-1, 2).T @ self.border_reference))) / V0
            ok &= bool(np.all(stress <= self.config.rtol * P_scale + self.stress_tolerance_abs))
        return ok, force_norm, tolerance

    # -- tangent ------------------------------------------------------------------------------
    def _stiffness(self, force, stiffness, kin: Kinematics, clipped: bool) -> tuple[np.ndarray, np.ndarray]:
        """Axial dT/dl and transverse T/l stiffness of every element [uN/um].

        No geometric term for an element below the length floor. ``clipped`` drops what can
        make the tangent indefinite: T/l of compressed elements and a negative dT/dl (a
        compressed, flowing element with c_p > 0 softens), so the result is positive
        semi-definite.
        """
        floor = STRETCH_FLOOR * self.l0
        transverse = np.where(kin.length > floor, force / np.maximum(kin.length, floor), 0.0)
        if clipped:
            return np.maximum(stiffness, 0.0), np.maximum(transverse, 0.0)
        return stiffness, transverse

    def _joint_blocks(self, x: np.ndarray, clipped: bool) -> np.ndarray | None:
        """The joints' Hessians (their positive semi-definite part if ``clipped``); None
        without bending."""
        return None if self.joints is None else self.joints.blocks(x, exact=not clipped)

    def _hessian(self, p: _Point, step: _Step, clipped: bool) -> sp.csr_matrix:
        axial, transverse = self._stiffness(p.force, p.stiffness, p.kin, clipped)
        joints = self._joint_blocks(p.x, clipped)
        modes = step.modes
        if not len(modes):
            return self.asm.tangent("II", axial, transverse, p.kin, joints)
        K_II, K_IB, K_BB = self.asm.tangents(("II", "IB", "BB"), axial, transverse, p.kin, joints)
        coupling = sp.csr_matrix(K_IB @ modes.T)
        corner = modes @ (K_BB @ modes.T)
        if step.lateral is not None:
            _, slope = step.lateral.nominal(float(np.vdot(p.F, step.directions[0])))
            corner[0, 0] -= self.network.reference_volume * slope
        return sp.bmat([[K_II, coupling], [coupling.T, sp.csr_matrix(corner)]], format="csr")

    def _direction(
        self, p: _Point, step: _Step, chord: _Tangent | None, choice: _TangentChoice
    ) -> tuple[np.ndarray, _Tangent]:
        """Newton direction and the tangent used, solved to :data:`_NEWTON_FORCING`.

        ``chord``: a tangent to reuse (a chord step, no factorization) if it gives a
        descent direction. ``choice`` is updated: an indefinite exact tangent makes the next
        few iterations take the clipped one directly.
        """
        if chord is not None:
            direction = chord.factorization.solve(-p.residual, _NEWTON_FORCING)
            if np.dot(direction, p.residual) < 0.0:
                return direction, chord
        if choice.clipped_left == 0:
            fact = self.linear.factorize(self._hessian(p, step, clipped=False))
            # Perturbed pivots mean a (nearly) singular tangent: not usable as exact.
            indefinite = bool(fact.n_negative) or fact.n_perturbed > 0
            if not indefinite:
                direction = fact.solve(-p.residual, _NEWTON_FORCING)
                if np.dot(direction, p.residual) < 0.0:
                    return direction, _Tangent(fact, p.stiffness, p.law.recruited, False, p.kin)
            choice.clipped_left = _CLIPPED_AFTER_INDEFINITE
        choice.clipped_left -= 1
        fact = self.linear.factorize(self._hessian(p, step, clipped=True))
        tangent = _Tangent(fact, np.maximum(p.stiffness, 0.0), p.law.recruited, True, p.kin)
        return fact.solve(-p.residual, _NEWTON_FORCING), tangent

    def _element_modes(self, elements: np.ndarray, kin: Kinematics, step: _Step) -> np.ndarray:
        """(n_unknowns, m) d l_e / d z of the given elements: -a at their first node, +a at
        their second, border DOF mapped onto the free components by the step's modes."""
        n = 2 * self.n_inner
        columns = np.zeros((self.asm.n_dof, len(elements)))
        a = kin.unit[elements]
        nodes = self.network.element_nodes[elements]
        m = np.arange(len(elements))
        for k in range(2):
            columns[2 * nodes[:, 0] + k, m] -= a[:, k]
            columns[2 * nodes[:, 1] + k, m] += a[:, k]
        return np.concatenate([columns[:n], step.modes @ columns[n:]])

    def _across_kinks(
        self, p: _Point, direction: np.ndarray, tangent: _Tangent, step: _Step
    ) -> tuple[np.ndarray, _Point]:
        """The Newton direction with the elements that cross the slack/taut kink linearized
        on the side its full step puts them, and the evaluated full step of the direction
        returned.

        ``direction`` solved ``K dz = -r`` with ``tangent`` (the exact one, built at ``p``
        or, for a chord step, at an earlier iterate q). An element whose recruitment at the
        full step z + dz, foreseen from its length there (:meth:`_recruited_at`, without the
        fiber law), differs from q's enters the model with its force linearized about its
        kink, on that side (:meth:`_at_kink`), T_e(l) ~ T_k + k_k (l - l_k), instead of
        T_z + k_q (l - l_z): a change of rank one per element (delta_e = k_k - k_q along its
        d l / d z = b_e) and a shift c_e = T_k - T_z - k_k (l_k - l_z) of its force, so
        (K + B diag(delta) B^T) d = -r - B c, solved with the same factorization
        (:class:`~espin.mechanics.kink_correction.KinkColumns`: b_e at the tangent's
        geometry, so K^-1 b_e is solved once per tangent and element, and chord steps reuse
        it). Repeated from the corrected step's foreseen recruitment while the set of
        crossing elements changes (at most :data:`_KINK_ROUNDS` rounds): a semismooth Newton
        step whose active set is taken from its own full step. The corrected direction is
        returned when its full step passes the line search's slope test with a smaller
        residual than ``p``'s (the fiber law evaluated there only); else ``direction``.
        """
        corrected, assumed = direction, np.zeros(0, dtype=np.int64)
        for _ in range(_KINK_ROUNDS):
            try:
                taut = self._recruited_at(p.z + corrected, step, p)
            except InadmissibleState:
                break
            crossing = np.flatnonzero(taut != tangent.recruited)
            if crossing.size == 0 or crossing.size > _KINK_MAX or np.array_equal(crossing, assumed):
                break
            assumed = crossing
            l_k, force_k, k_k = self._at_kink(crossing, taut[crossing], p, step)
            shift = force_k - p.force[crossing] - k_k * (l_k - p.kin.length[crossing])
            new = tangent.kink.missing(crossing)
            if new.size:
                tangent.kink.add(new, self._element_modes(new, tangent.kin, step))
            corrected = tangent.kink.step(direction, crossing, k_k - tangent.axial[crossing], shift)
            if not np.dot(corrected, p.residual) < 0.0:
                corrected = direction
                break
        if corrected is not direction:
            try:
                trial = self._evaluate(p.z + corrected, step, p)
            except InadmissibleState:
                trial = None
            if trial is not None and self._full_step_fits(p, trial, corrected, step):
                return corrected, trial
        return direction, self._evaluate(p.z + direction, step, p)

    @staticmethod
    def _full_step_fits(p: _Point, trial: _Point, direction: np.ndarray, step: _Step) -> bool:
        """Whether the full step ``trial`` of ``direction`` from ``p`` passes the line
        search's slope test with a smaller residual than ``p``'s."""
        s0, s1 = float(np.dot(p.residual, direction)), float(np.dot(trial.residual, direction))
        slope_ok = s1 <= 0.0 or abs(s1) <= SLOPE_RATIO * abs(s0)
        return slope_ok and bool(
            np.linalg.norm(step.weight * trial.residual) < np.linalg.norm(step.weight * p.residual)
        )

    def _at_kink(
        self, elements: np.ndarray, taut: np.ndarray, p: _Point, step: _Step
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Length [um], axial force [uN] and dT/dl [uN/um] of ``elements`` at their slack/taut
        kink, on the side ``taut`` says.

        The kink is at e = lambda / lambda_p = lambda_r, where lambda_p is the step's plastic
        stretch at that stretch: lambda = lambda_r lambda_p(lambda), a fixed point reached in
        a few iterations because an element at its kink barely flows.
        """
        lr = np.maximum(self.tortuosity[elements], 1.0)
        old = step.start.plastic_stretch[elements]
        lam = lr * p.law.plastic_stretch[elements]
        for _ in range(_KINK_FIXED_POINT):
            lam = lr * update(step.law, lam, old, lr, step.dt).plastic_stretch
        lam = lam * np.where(taut, 1.0 + _KINK_SIDE, 1.0 - _KINK_SIDE)
        state = update(step.law, lam, old, lr, step.dt)
        force, stiffness = axial_force_and_stiffness(state, self.area[elements], self.l0[elements])
        return lam * self.l0[elements], force, stiffness

    # -- one step -----------------------------------------------------------------------------
    def iteration_limit(self, n_free: int) -> int:
        """Newton iterations allowed per step: the config's, else 200 (500 with free F)."""
        return self.config.max_iterations or (_MAX_ITERATIONS_MIXED if n_free else _MAX_ITERATIONS)

    def solve(
        self,
        start: StepState,
        time: float,
        F_prescribed: np.ndarray,
        directions: np.ndarray,
        guess_inner: np.ndarray,
        guess_free: np.ndarray,
        lateral: LateralStress | None = None,
    ) -> StepResult:
        """Equilibrium at ``time`` from the converged ``start`` state; ``lateral``: the stress
        target of the one free direction (None: P : G_k = 0 for every free direction).

        Raises
        ------
        StepNotConverged
            When Newton does not converge within the iteration limit, the line search
            cannot lower the potential, the state becomes non-finite or the tangent singular.
        """
        with self._openblas_limit():
            try:
                return self._solve(start, time, F_prescribed, directions, guess_inner, guess_free, self.law, lateral)
            except StepNotConverged as failure:
                return self._solve_by_continuation(
                    failure, start, time, F_prescribed, directions, guess_inner, guess_free, lateral
                )

    def _openblas_limit(self):
        """OpenBLAS on one thread with a backend that does not use it, else no limit.

        numpy's vector products here gain nothing from OpenBLAS's threads, and they spin after
        each call and took a core from the next factorization (PARDISO at plla size: 0.098 s
        per factorization in the run, 0.067 s without; SuperLU needs its threads).
        """
        if getattr(self.linear, "uses_openblas", True):
            return nullcontext()
        return _openblas_pools().limit(limits=1)

    def predicted_error(
        self,
        start: StepState,
        time: float,
        F_prescribed: np.ndarray,
        directions: np.ndarray,
        guess_inner: np.ndarray,
        guess_free: np.ndarray,
        lateral: LateralStress | None = None,
    ) -> float:
        """Local time error of the step the arguments of :meth:`solve` describe, at its guess.

        The fiber law evaluated at the guess (the step's predictor) instead of the
        equilibrium: on plla the predicted error is 0.98-1.02 of the converged step's through
        the yield knee, where steps are rejected, and below it later (docs/performance.md). The
        evaluated guess is kept, and :meth:`solve` of the same step starts from it (one
        evaluation for both). 0 when the guess is inadmissible (:meth:`solve` will say so).
        """
        step = self._context(start, time, F_prescribed, directions, self.law, lateral)
        with self._openblas_limit():
            try:
                p = self._evaluate(np.concatenate([guess_inner.ravel(), guess_free]), step)
            except InadmissibleState:
                return 0.0
        self._guess = (step, p)
        return local_error(
            self.law,
            start.stress,
            start.plastic_stretch,
            p.law.stress,
            p.law.plastic_stretch,
            p.stretch,
            self.tortuosity,
            time - start.time,
            self.area * self.l0,
        )

    def _first_point(self, z: np.ndarray, step: _Step) -> _Point:
        """The evaluated guess ``z`` of ``step``: the one :meth:`predicted_error` kept if it is
        this step's, else evaluated now."""
        kept, self._guess = self._guess, None
        if kept is not None:
            other, p = kept
            same = (
                other.start is step.start
                and other.dt == step.dt
                and other.law is step.law
                and other.lateral is step.lateral
                and np.array_equal(other.F_prescribed, step.F_prescribed)
                and np.array_equal(other.directions, step.directions)
                and np.array_equal(p.z, z)
            )
            if same:
                return p
        return self._evaluate(z, step)

    def _solve_by_continuation(
        self,
        failure: StepNotConverged,
        start: StepState,
        time: float,
        F_prescribed: np.ndarray,
        directions: np.ndarray,
        guess_inner: np.ndarray,
        guess_free: np.ndarray,
        lateral: LateralStress | None,
    ) -> StepResult:
        """The step again, through a continuation in the slack modulus (module docstring).

        Raises
        ------
        StepNotConverged
            When a stage does not converge; counts include the first attempt's.
        """
        history = list(failure.history)
        iterations, factorizations = failure.iterations, failure.factorizations
        inner, free = guess_inner, guess_free
        for factor in _SLACK_CONTINUATION:
            slack = min(factor * self.law.slack_modulus, 0.5 * self.law.taut_modulus)
            law = replace(self.law, slack_modulus=slack) if factor != 1.0 else self.law
            try:
                result = self._solve(start, time, F_prescribed, directions, inner, free, law, lateral)
            except StepNotConverged as stage:
                raise StepNotConverged(
                    f"{failure.reason}; then the continuation in the slack modulus failed at "
                    f"E_b = {slack:g} MPa: {stage.reason}",
                    stage.kind,
                    history=history + stage.history,
                    iterations=iterations + stage.iterations,
                    factorizations=factorizations + stage.factorizations,
                ) from None
            iterations += result.iterations
            factorizations += result.factorizations
            history += result.residual_history
            inner, free = result.state.inner, result.state.free
        return StepResult(
            result.state,
            result.law,
            result.force,
            result.kinematics,
            iterations,
            factorizations,
            result.residual,
            history,
        )

    def _solve(
        self,
        start: StepState,
        time: float,
        F_prescribed: np.ndarray,
        directions: np.ndarray,
        guess_inner: np.ndarray,
        guess_free: np.ndarray,
        law: FiberLaw,
        lateral: LateralStress | None,
    ) -> StepResult:
        """Newton's method from the guess, with ``law`` (the true one, or a continuation stage's)."""
        n_free = len(directions)
        limit = self.iteration_limit(n_free)
        step = self._context(start, time, F_prescribed, directions, law, lateral)
        history: list[float] = []
        counted = self.linear.numeric_factorizations
        choice = _TangentChoice()
        tangent = None
        try:
            p = self._first_point(np.concatenate([guess_inner.ravel(), guess_free]), step)
            for iteration in range(limit + 1):
                ok, norm, tolerance = self._converged(p, n_free)
                # An iteration whose residual ratio, repeated once, reaches the tolerance
                # lends its factorization to the next.
                chord = tangent if history and norm * norm <= tolerance * history[-1] else None
                history.append(norm)
                if ok:
                    n = 2 * self.n_inner
                    state = StepState(
                        time, p.z[:n].reshape(-1, 2), p.z[n:].copy(), p.F, p.law.plastic_stretch, p.law.stress
                    )
                    factorizations = self.linear.numeric_factorizations - counted
                    return StepResult(state, p.law, p.force, p.kin, iteration, factorizations, norm, history)
                if iteration == limit:
                    break
                direction, tangent = self._direction(p, step, chord, choice)
                if tangent.clipped:  # buckling: the plain direction (its full step the first trial)
                    full = self._evaluate(p.z + direction, step, p)
                else:
                    direction, full = self._across_kinks(p, direction, tangent, step)
                if self.max_move > 0:
                    bounded = self._trust_region(direction, step)
                    if bounded is not direction:  # shortened: its own full step is the first trial
                        direction, full = bounded, self._evaluate(p.z + bounded, step, p)

                def evaluate(z: np.ndarray, near: _Point, full: _Point = full) -> _Point:
                    return full if np.array_equal(z, full.z) else self._evaluate(z, step, near)

                p = self._relax_nodes(line_search(p, direction, evaluate, step.weight), step, n_free)
        except StepNotConverged as failure:
            factorizations = self.linear.numeric_factorizations - counted
            raise type(failure)(failure.reason, failure.kind, history=history, factorizations=factorizations) from None
        factorizations = self.linear.numeric_factorizations - counted
        raise StepNotConverged(f"no convergence in {limit} iterations", history=history, factorizations=factorizations)

    def _relax_nodes(self, p: _Point, step: _Step, n_free: int) -> _Point:
        """``p`` after local Newton steps on the inner nodes whose force residual is over the
        tolerance (module docstring): the rounds' point with the lowest largest force
        residual, or ``p`` itself when none is lower, when there are no nodes or too many,
        or with fiber joints.

        The rounds need not lower the residual one after the other: a short, stiff element
        whose other end is held by slack ones turns about it in a soft mode, and its length
        depends on that turn to second order, so a local Newton step can overshoot before
        the next ones converge."""
        if self.joints is not None:
            return p
        n = 2 * self.n_inner
        most = min(_RELAX_MAX_NODES, _RELAX_MAX_SHARE * self.n_inner)
        ok, norm, tolerance = self._converged(p, n_free)
        best, best_norm = p, norm
        for _ in range(_RELAX_ROUNDS):
            forces = p.residual[:n].reshape(-1, 2)
            nodes = np.flatnonzero(np.any(np.abs(forces) > tolerance, axis=1))
            if ok or nodes.size == 0 or nodes.size > most:
                break
            nodes = self._with_neighbours(nodes)
            touched, ends = self._node_elements(nodes)
            try:
                factor = np.linalg.cholesky(self._node_block(p, nodes.size, touched, ends))
            except np.linalg.LinAlgError:  # not positive definite there: leave it to Newton
                break
            move = cho_solve((factor, True), -forces[nodes].ravel())
            z = p.z.copy()
            z[:n].reshape(-1, 2)[nodes] += move.reshape(-1, 2)
            try:
                p = self._evaluate(z, step, p, moved=touched)
            except InadmissibleState:
                break
            ok, norm, tolerance = self._converged(p, n_free)
            if norm < best_norm:
                best, best_norm = p, norm
        return best

    def _with_neighbours(self, nodes: np.ndarray) -> np.ndarray:
        """``nodes`` and the inner nodes up to :data:`_RELAX_RINGS` elements away, ring by
        ring while they stay at most :data:`_RELAX_MAX_BLOCK` (sorted indices)."""
        for _ in range(_RELAX_RINGS):
            ring = self.network.element_nodes[self._elements_of(nodes)].ravel()
            wider = _each_once(np.concatenate([nodes, ring[ring < self.n_inner]]), self.n_inner)
            if wider.size > _RELAX_MAX_BLOCK:
                break
            nodes = wider
        return nodes

    def _elements_of(self, nodes: np.ndarray) -> np.ndarray:
        """The elements with an end among ``nodes`` (sorted indices, each once)."""
        start, stop = self._node_start[nodes], self._node_start[nodes + 1]
        counts = stop - start
        offsets = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
        return _each_once(self._node_elements_list[np.repeat(start, counts) + offsets], self.network.n_elements)

    def _node_elements(self, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The elements with an end among the m ``nodes`` (indices), and their two ends as
        node numbers 0..m-1 (the position in ``nodes``), or -1 for other nodes."""
        local = np.full(self.asm.n_dof // 2, -1)
        local[nodes] = np.arange(nodes.size)
        touched = self._elements_of(nodes)
        return touched, local[self.network.element_nodes[touched]]

    def _node_block(self, p: _Point, m: int, touched: np.ndarray, ends: np.ndarray) -> np.ndarray:
        """(2 m, 2 m) block of the exact tangent at ``p`` on the DOF of m inner nodes
        [uN/um]: the 2 x 2 blocks k a a^T + (T / l)(I - a a^T) of their elements.

        ``touched``, ``ends``: the nodes' elements and their ends, from :meth:`_node_elements`."""
        axial, transverse = self._stiffness(p.force, p.stiffness, p.kin, clipped=False)
        a = p.kin.unit[touched]
        outer = a[:, :, None] * a[:, None, :]
        blocks = axial[touched, None, None] * outer + transverse[touched, None, None] * (np.eye(2) - outer)
        block = np.zeros((m, m, 2, 2))
        for i, j, sign in ((0, 0, 1.0), (1, 1, 1.0), (0, 1, -1.0), (1, 0, -1.0)):
            both = (ends[:, i] >= 0) & (ends[:, j] >= 0)
            np.add.at(block, (ends[both, i], ends[both, j]), sign * blocks[both])
        return block.transpose(0, 2, 1, 3).reshape(2 * m, 2 * m)

    def _trust_region(self, direction: np.ndarray, step: _Step) -> np.ndarray:
        """``direction`` shortened so that no inner node moves more than ``max_move`` [um]
        beyond the affine motion of its free components of F (module docstring)."""
        n = 2 * self.n_inner
        affine = self.asm.reference[: self.n_inner] @ np.tensordot(direction[n:], step.directions, axes=1).T
        move = float(np.max(np.abs(direction[:n].reshape(-1, 2) - affine), initial=0.0))
        return direction * (self.max_move / move) if move > self.max_move else direction

    def time_error(self, start: StepState, result: StepResult) -> float:
        """Relative local time error of the step from ``start`` to ``result``
        (:func:`espin.mechanics.time_steps.local_error`, elements weighted by their volume)."""
        return local_error(
            self.law,
            start.stress,
            start.plastic_stretch,
            result.law.stress,
            result.law.plastic_stretch,
            result.kinematics.length / self.l0,
            self.tortuosity,
            result.state.time - start.time,
            self.area * self.l0,
        )

    def macroscopic_tangent(self, result: StepResult) -> np.ndarray:
        """Algorithmic macroscopic tangent A_iJkL = dP_iJ / dF_kL [MPa] at a converged step.

        By condensation of the exact tangent on the border DOF (docs/model.md section 5):
        S = K_BB - K_BI K_II^-1 K_IB and A_iJkL = (1 / V0) sum_b,b' X_bJ S[(b,i),(b',k)] X_b'L,
        with four solves on one factorization of K_II. The derivative is taken at fixed
        plastic state of the step start and fixed time step (consistent with the step).

        Returns
        -------
        (2, 2, 2, 2) float64
            Indexed [i, J, k, L].
        """
        kin = result.kinematics
        _, stiffness = self.element_forces(result.law, kin.length / self.l0)
        axial, transverse = self._stiffness(result.force, stiffness, kin, clipped=False)
        x = self.asm.positions(result.state.inner, result.state.F)
        K_II, K_IB, K_BB = self.asm.tangents(
            ("II", "IB", "BB"), axial, transverse, kin, self._joint_blocks(x, clipped=False)
        )
        # Border motion for a unit F_kL: x_b = e_k X_bL, flattened like the border DOF.
        X = self.border_reference
        modes = np.zeros((4, 2 * len(X)))
        for k in range(2):
            for L in range(2):
                modes[2 * k + L, k::2] = X[:, L]
        coupling = K_IB @ modes.T
        fluctuation = self.linear.factorize(K_II).solve(coupling) if self.n_inner else coupling[:0]
        condensed = modes @ (K_BB @ modes.T) - coupling.T @ fluctuation
        return condensed.reshape(2, 2, 2, 2) / self.network.reference_volume
