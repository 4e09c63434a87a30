"""The RVE solves of many FE^2 points that share one network, together (issue [speed], part C).

:class:`BatchedRVE` runs the Newton method of :class:`espin.mechanics.equilibrium.EquilibriumSolver`
(whole F prescribed, no bending) on all points at once: the points are the leading axis of every
array, and each Newton round makes one call of a compiled kernel (:mod:`espin.specimen.batched_kernels`)
per task for all the points that need it: the evaluation (kinematics, the fiber law's return
mapping, element forces, residual), the tangents K_II filled into the one sparsity pattern and
factorized by Cholesky with one symbolic analysis for all points, the triangular solves. Each
point keeps its own Newton state:

* the exact tangent when its Cholesky factorization succeeds (K_II positive definite), else the
  clipped one for the next few iterations (by Cholesky too; a clipped tangent that is singular
  by the linear solver of ``solver.linear``, whose LDL^T perturbs the zero pivots); a chord step
  with the point's last factorization after an iteration that cut the residual 10-fold;
* the line search of :mod:`espin.mechanics.line_search`, run for all points in lockstep (each point
  its own bracket; one evaluation of all the points that need a trial per round);
* convergence by the same test per point; converged points drop out of the batch.

A point whose Newton fails here (an inadmissible iterate, a return mapping that does not
converge, no descent) is solved again by the per-point solver (which adds the continuation in
the slack modulus) and raises as today, naming the point, when that fails too.

The results are today's per-point solve (:meth:`EquilibriumSolver.solve`) within the RVE
tolerance: the same iterates up to the rounding of the sums over a point's DOF and of the
factorization.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from espin.core.config import Config
from espin.core.errors import StepFailureKind, StepNotConverged
from espin.geometry.network import Network
from espin.mechanics.assembly import SparsePattern
from espin.mechanics.equilibrium import EquilibriumSolver, StepState
from espin.mechanics.fiber_law import (
    STRETCH_FLOOR,
    axial_force_and_stiffness,
    yielded,
)
from espin.mechanics.line_search import MAX_TRIALS, SHORTEST, accepts, next_step, shortened, simpson_decrease
from espin.mechanics.linear_solvers import Factorization, LinearSolver, make_linear_solver
from espin.mechanics.time_steps import local_errors
from espin.specimen import batched_kernels

__all__ = ["BatchedRVE", "BatchSolved", "batchable"]

_NO_FREE = np.zeros((0, 2, 2))
_CLIPPED_AFTER_INDEFINITE = 3  # as the per-point solver
_CHORD_RATIO = 0.1
_MAX_ITERATIONS = 200
_NO_NEAR = np.zeros((0, 0))
_NONE, _CHOLESKY, _SINGULAR = 0, 1, 2  # the factorization a point holds


def batchable(config: Config) -> bool:
    """Whether the RVEs of ``config`` can be solved in a batch: the paper's network (fiber
    bending, fused crossings, the compression limit and the trust region are not batched:
    those points take the per-point solver)."""
    fiber, solver = config.fiber, config.solver
    return (
        fiber.bending_modulus_MPa == 0.0
        and fiber.fused_crossing_fraction == 0.0
        and fiber.compression_limit == 0.0
        and solver.max_move_ratio == 0.0
    )


@dataclass(frozen=True, eq=False)
class BatchSolved:
    """The converged RVE solves of a batch (arrays over points first).

    Attributes
    ----------
    P : (n, 2, 2) float64 [MPa]
        Nominal stress.
    A : (n, 2, 2, 2, 2) float64 [MPa]
        Algorithmic macroscopic tangent dP/dF.
    inner : (n, n_inner, 2) float64 [um]
    plastic_stretch, stress : (n, n_elements) float64 [-, MPa]
    local_error, recruited_fraction, yielded_fraction : (n,) float64
    iterations, factorizations : (n,) int64
        Newton iterations and factorizations of each point's solve.
    sensitivity : (n, 2 n_inner, 4) float32 [um]
        dz / dF_kL of the inner DOF z at the solution (column 2 k + L), at fixed plastic state
        of the step start and fixed time step: the first-order predictor of the next solve.
    """

    P: np.ndarray
    A: np.ndarray
    inner: np.ndarray
    plastic_stretch: np.ndarray
    stress: np.ndarray
    local_error: np.ndarray
    recruited_fraction: np.ndarray
    yielded_fraction: np.ndarray
    iterations: np.ndarray
    factorizations: np.ndarray
    sensitivity: np.ndarray


@dataclass(eq=False)
class _Iterates:
    """Everything evaluated at the iterates of some points (points first)."""

    z: np.ndarray  # (k, n) inner DOF
    length: np.ndarray  # (k, e)
    unit: np.ndarray  # (k, e, 2)
    stress: np.ndarray  # (k, e)
    plastic: np.ndarray  # (k, e)
    recruited: np.ndarray  # (k, e) bool
    force: np.ndarray  # (k, e)
    stiffness: np.ndarray  # (k, e)
    residual: np.ndarray  # (k, n)

    @classmethod
    def empty(cls, k: int, e: int, n: int) -> _Iterates:
        """k points of e elements and n DOF, not filled."""
        return cls(
            z=np.empty((k, n)),
            length=np.empty((k, e)),
            unit=np.empty((k, e, 2)),
            stress=np.empty((k, e)),
            plastic=np.empty((k, e)),
            recruited=np.empty((k, e), dtype=bool),
            force=np.empty((k, e)),
            stiffness=np.empty((k, e)),
            residual=np.empty((k, n)),
        )

    def take(self, rows: np.ndarray) -> _Iterates:
        return _Iterates(**{name: getattr(self, name)[rows] for name in self.__dataclass_fields__})

    def put(self, rows: np.ndarray, other: _Iterates, other_rows: np.ndarray) -> None:
        """Rows ``rows`` from rows ``other_rows`` of ``other``."""
        for name in self.__dataclass_fields__:
            getattr(self, name)[rows] = getattr(other, name)[other_rows]


def _sorted(matrix: sp.spmatrix) -> sp.csr_matrix:
    """``matrix`` as CSR with sorted column indices (its products sum in column order)."""
    out = sp.csr_matrix(matrix)
    out.sort_indices()
    return out


class BatchedRVE:
    """Load steps of one network at many points at once (module docstring).

    Parameters
    ----------
    network
        The RVE shared by the points.
    config
        Its fiber law (without bending: :func:`batchable`) and solver settings.
    """

    def __init__(self, network: Network, config: Config) -> None:
        if not batchable(config):
            raise ValueError("fiber.bending_modulus_MPa > 0: the batched RVE solves have no bending")
        self.config = config
        self.solver = EquilibriumSolver.from_config(network, config, make_linear_solver(config.solver.linear))
        solver = self.solver
        asm = solver.asm
        self.network = network
        self.law = solver.law
        self.n_inner = network.n_inner
        self.n = 2 * network.n_inner
        self.n_dof = asm.n_dof
        self.nodes = network.element_nodes
        self.l0, self.area, self.tortuosity = solver.l0, solver.area, solver.tortuosity
        self.X_border = solver.border_reference
        self.X_inner = asm.reference[: network.n_inner]
        self.reference_unit = network.element_vector / network.element_length[:, None]
        nodes = network.element_nodes
        self.dof = np.stack([2 * nodes[:, 0], 2 * nodes[:, 0] + 1, 2 * nodes[:, 1], 2 * nodes[:, 1] + 1], 1).ravel()
        # The tangent blocks as sums of the elements' 2 x 2 stiffness k (components k11, k12, k22
        # of each element, in element order): data = S @ components, one sparse product. S is
        # the pattern's sum of the 4 x 4 element matrices [[k, -k], [-k, k]] (entry r, c holds
        # +-k[r % 2, c % 2]); a slot sums one entry per element, in element order, as the pattern does.
        self.patterns = {part: asm.pattern(part) for part in ("II", "IB", "BB")}
        r, c = np.divmod(np.arange(16), 4)
        component = np.array([[0, 1], [1, 2]])[r % 2, c % 2]
        sign = np.where(r // 2 == c // 2, 1.0, -1.0)
        n_el = network.n_elements
        expand = sp.csr_matrix(
            (np.tile(sign, n_el), (np.arange(16 * n_el), (3 * np.arange(n_el)[:, None] + component).ravel())),
            shape=(16 * n_el, 3 * n_el),
        )
        self.sum_into = {part: _sorted(_summation(self.patterns[part], n_el) @ expand) for part in ("IB", "BB")}
        # Border motion of a unit F_kL (row 2k + L), flattened like the border DOF; the
        # macroscopic tangent's K_IB modes^T (n x 4) and modes K_BB modes^T (4 x 4) as sums of
        # the element components too.
        modes = np.zeros((4, 2 * len(self.X_border)))
        for k in range(2):
            for L in range(2):
                modes[2 * k + L, k::2] = self.X_border[:, L]
        IB, BB = self.patterns["IB"].matrix, self.patterns["BB"].matrix
        ib_row = np.repeat(np.arange(IB.shape[0]), np.diff(IB.indptr))
        to_coupling = sp.csr_matrix(
            (
                modes[:, IB.indices].T.ravel(),
                ((4 * ib_row[:, None] + np.arange(4)).ravel(), np.repeat(np.arange(IB.nnz), 4)),
            ),
            shape=(4 * IB.shape[0], IB.nnz),
        )
        bb_row = np.repeat(np.arange(BB.shape[0]), np.diff(BB.indptr))
        to_corner = (modes[:, bb_row][:, None, :] * modes[:, BB.indices][None, :, :]).reshape(16, BB.nnz)
        self.sum_into["coupling"] = _sorted(to_coupling @ self.sum_into["IB"])
        self.sum_into["corner"] = _sorted(sp.csr_matrix(to_corner) @ self.sum_into["BB"])
        self.volume = network.element_area * network.element_contour_length
        self.element_vector = network.element_vector
        self._linear: list[LinearSolver] = []
        self._K = _sorted(self.patterns["II"].matrix)
        self.slot = self.patterns["II"].slot
        self.cholesky = batched_kernels.CholeskyPattern.of(self._K)
        self._factor_memory = (np.empty((0, self._K.nnz)), np.empty((0, self.cholesky.nnz)))

    # -- evaluation -------------------------------------------------------------------------
    def _evaluate(
        self, z: np.ndarray, F: np.ndarray, plastic_start: np.ndarray, dt: float, near: np.ndarray | None
    ) -> tuple[_Iterates, np.ndarray]:
        """The iterates ``z`` (k, n) at ``F`` (k, 2, 2) from the plastic stretches at the step's
        start; ``near``: plastic stretches that start the return mapping. Returns them and which
        points are admissible (z finite, the return mapping converged; the others' rows: NaN)."""
        k, e = len(z), len(self.l0)
        out = _Iterates.empty(k, e, self.n)
        out.z[:] = z
        ok = batched_kernels.evaluate(
            out.z,
            np.ascontiguousarray(F),
            np.ascontiguousarray(plastic_start),
            _NO_NEAR if near is None else np.ascontiguousarray(near),
            self.X_border,
            self.nodes,
            self.reference_unit,
            self.l0,
            self.area,
            self.tortuosity,
            float(self.law.flow_scale(dt)),
            self.law.kernel_constants(),
            out.length,
            out.unit,
            out.stress,
            out.plastic,
            out.recruited,
            out.force,
            out.stiffness,
            out.residual,
        )
        if not ok.all():
            bad = ~ok
            for name in ("length", "unit", "stress", "plastic", "force", "stiffness", "residual"):
                getattr(out, name)[bad] = np.nan
            out.recruited[bad] = False
        return out, ok

    def _converged(self, residual: np.ndarray, force: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per point: converged (the per-point solver's test on the residual g_I and the element
        forces) and max |g_I|."""
        norm = np.max(np.abs(residual), axis=1) if self.n else np.zeros(len(residual))
        tolerance = self.config.solver.rtol * np.max(np.abs(force), axis=1) + self.solver.force_tolerance_abs
        return norm <= tolerance, norm

    # -- tangents ---------------------------------------------------------------------------
    def _element_values(self, p: _Iterates, clipped: bool) -> np.ndarray:
        """(k, 3 e) components k11, k12, k22 of each element's stiffness
        k = dT/dl a (x) a + T / l (I - a (x) a) (the per-point solver's, and its clipping)."""
        floor = STRETCH_FLOOR * self.l0
        transverse = np.where(p.length > floor, p.force / np.maximum(p.length, floor), 0.0)
        axial = p.stiffness
        if clipped:
            axial, transverse = np.maximum(axial, 0.0), np.maximum(transverse, 0.0)
        a0, a1 = p.unit[..., 0], p.unit[..., 1]
        aa00, aa01, aa11 = a0 * a0, a0 * a1, a1 * a1
        components = np.stack(
            [
                axial * aa00 + transverse * (1.0 - aa00),
                axial * aa01 + transverse * (0.0 - aa01),
                axial * aa11 + transverse * (1.0 - aa11),
            ],
            axis=-1,
        )
        return components.reshape(len(a0), -1)

    def _matrix(self, data: np.ndarray) -> sp.csr_matrix:
        """K_II with the values ``data``: one matrix object whose values are replaced (the
        linear solver copies them)."""
        self._K.data = data
        return self._K

    def release(self) -> None:
        """Free the linear solvers' factorizations and analyses and the factors' memory."""
        for linear in self._linear:
            linear.release()
        self._linear.clear()
        self._factor_memory = (np.empty((0, self._K.nnz)), np.empty((0, self.cholesky.nnz)))

    def _linear_solvers(self, k: int) -> list[LinearSolver]:
        """One linear solver per point of the batch (each keeps its point's factorization)."""
        while len(self._linear) < k:
            self._linear.append(make_linear_solver(self.config.solver.linear))
        return self._linear[:k]

    # -- one step of all points -------------------------------------------------------------
    def solve(
        self,
        start_time: float,
        start_F: np.ndarray,
        start_inner: np.ndarray,
        start_plastic: np.ndarray,
        start_stress: np.ndarray,
        time: float,
        F: np.ndarray,
        guess: np.ndarray,
        names: np.ndarray,
    ) -> BatchSolved:
        """Equilibrium of every point at ``time`` and ``F`` (k, 2, 2) from its converged start
        (``start_*``, points first) and the guess (k, n_inner, 2) [um] of its inner nodes.

        Raises
        ------
        StepNotConverged
            ``"RVE point N: ..."`` (N from ``names``) when a point does not converge, here and
            by the per-point solver with its continuation.
        """
        k = len(F)
        dt = time - start_time
        if np.any(np.linalg.det(F) <= 0.0):
            bad = int(names[int(np.argmax(np.linalg.det(F) <= 0.0))])
            raise StepNotConverged(f"RVE point {bad}: det F <= 0", StepFailureKind.INADMISSIBLE)
        p, ok = self._evaluate(guess.reshape(k, -1).copy(), F, start_plastic, dt, None)
        failed = ~ok
        iterations = np.zeros(k, dtype=np.int64)
        factorizations = np.zeros(k, dtype=np.int64)
        last_norm = np.full(k, np.inf)
        factors = _Factors(self, k)
        clipped_left = np.zeros(k, dtype=np.int64)
        done = np.zeros(k, dtype=bool)
        limit = self.config.solver.max_iterations or _MAX_ITERATIONS
        for iteration in range(limit + 1):
            active = np.flatnonzero(~done & ~failed)
            if not len(active):
                break
            converged, norm = self._converged(p.residual[active], p.force[active])
            done[active[converged]] = True
            iterations[active[converged]] = iteration
            going = active[~converged]
            chord_ok = norm[~converged] <= _CHORD_RATIO * last_norm[going]
            last_norm[active] = norm
            if iteration == limit:
                failed[going] = True
                break
            if not len(going):
                continue
            current = p.take(going)
            direction = np.empty((len(going), self.n))
            # A chord step with the point's last factorization where the residual fell 10-fold.
            chord = np.flatnonzero(chord_ok & factors.held(going))
            descends = np.zeros(len(going), dtype=bool)
            if len(chord):
                direction[chord] = factors.solve(going[chord], -current.residual[chord])
                descends[chord] = np.einsum("kn,kn->k", direction[chord], current.residual[chord]) < 0.0
            need = ~descends
            exact = np.flatnonzero(need & (clipped_left[going] == 0))
            if len(exact):
                factorizations[going[exact]] += 1
                pd = factors.factorize(current, exact, going[exact], clipped=False)
                tried = exact[pd]
                direction[tried] = factors.solve(going[tried], -current.residual[tried])
                descends[tried] = np.einsum("kn,kn->k", direction[tried], current.residual[tried]) < 0.0
                clipped_left[going[exact[~descends[exact]]]] = _CLIPPED_AFTER_INDEFINITE
            clipped = np.flatnonzero(~descends & (clipped_left[going] > 0))
            if len(clipped):
                clipped_left[going[clipped]] -= 1
                factorizations[going[clipped]] += 1
                pd = factors.factorize(current, clipped, going[clipped], clipped=True)
                direction[clipped[pd]] = factors.solve(going[clipped[pd]], -current.residual[clipped[pd]])
                for j in clipped[~pd]:  # singular: PARDISO's LDL^T with perturbed pivots
                    d = factors.factorize_singular(current, j, going[j])
                    if d is None:
                        failed[going[j]] = True
                    else:
                        direction[j] = d
            moving = np.flatnonzero(~failed[going])
            rows = going[moving]
            point = current if len(moving) == len(going) else current.take(moving)
            ok = self._line_search(point, direction[moving], F[rows], start_plastic[rows], dt, p, rows)
            failed[rows[~ok]] = True
        retried = {
            i: self._solve_one(
                StepState(start_time, start_inner[i], np.zeros(0), start_F[i], start_plastic[i], start_stress[i]),
                time,
                F[i],
                guess[i],
                int(names[i]),
            )
            for i in map(int, np.flatnonzero(failed))
        }
        return self._results(p, retried, start_stress, start_plastic, iterations, factorizations, F, dt, factors)

    def _solve_one(self, start: StepState, time: float, F: np.ndarray, guess: np.ndarray, name: int):
        """A point the batch did not converge, by the per-point solver (with its continuation)."""
        try:
            return self.solver.solve(start, time, F, _NO_FREE, guess, np.zeros(0))
        except StepNotConverged as failure:
            raise type(failure)(
                f"RVE point {name}: {failure.reason}",
                failure.kind,
                iterations=failure.iterations,
                factorizations=failure.factorizations,
            ) from None

    # -- the line search of all points ------------------------------------------------------
    def _line_search(
        self,
        point: _Iterates,
        direction: np.ndarray,
        F: np.ndarray,
        plastic_start: np.ndarray,
        dt: float,
        out: _Iterates,
        out_rows: np.ndarray,
    ) -> np.ndarray:
        """:func:`espin.mechanics.line_search.line_search` of every point in lockstep: the
        accepted trials into rows ``out_rows`` of ``out``; returns which points found one (the
        others could not lower the potential)."""
        k = len(direction)
        s0 = np.einsum("kn,kn->k", point.residual, direction)
        lo, s_lo = np.zeros(k), s0.copy()
        hi = np.full(k, np.nan)  # NaN: no upper end yet
        s_hi = np.full(k, np.nan)  # NaN: the upper end's slope is unknown
        alpha = np.ones(k)
        best = _Iterates.empty(k, len(self.l0), self.n)  # the trial at ``lo`` where has_best
        has_best = np.zeros(k, dtype=bool)
        searching = np.ones(k, dtype=bool)
        accepted = np.zeros(k, dtype=bool)
        base_norm = np.linalg.norm(point.residual, axis=1)
        for _ in range(MAX_TRIALS):
            rows = np.flatnonzero(searching)
            if not len(rows):
                break
            a = alpha[rows]
            trial, ok = self._evaluate(
                point.z[rows] + a[:, None] * direction[rows], F[rows], plastic_start[rows], dt, point.plastic[rows]
            )
            at = np.arange(len(rows))  # rows of ``trial``
            if not ok.all():
                bad = rows[~ok]  # overshot into inadmissible states: shorten
                hi[bad], s_hi[bad] = alpha[bad], np.nan
                alpha[bad] = shortened(alpha[bad], lo[bad])
                rows, at = rows[ok], at[ok]
            a = alpha[rows]
            s = np.einsum("kn,kn->k", trial.residual[at], direction[rows])
            candidate = accepts(s, a, s0[rows])
            decreases = np.zeros(len(rows), dtype=bool)
            if candidate.any():
                c = np.flatnonzero(candidate)
                decreases[c], broken = self._decreases(
                    point, rows[c], trial.residual[at[c]], direction, a[c], s0, s[c], F, plastic_start, dt, base_norm
                )
                if broken.any():
                    # An inadmissible midpoint ends the point's search: it fails here (as it
                    # does in the per-point line search, which raises) and is solved again one by one.
                    stop = rows[c[broken]]
                    searching[stop], has_best[stop] = False, False
                    keep = np.flatnonzero(~np.isin(rows, stop))
                    rows, at, a, s = rows[keep], at[keep], a[keep], s[keep]
                    candidate, decreases = candidate[keep], decreases[keep]
            win = np.flatnonzero(decreases)
            out.put(out_rows[rows[win]], trial, at[win])
            accepted[rows[win]] = True
            searching[rows[win]] = False
            rejected = candidate & ~decreases
            up = ~candidate & (s > 0.0)
            down = ~candidate & ~(s > 0.0)
            hi[rows[rejected]], s_hi[rows[rejected]] = a[rejected], np.nan
            hi[rows[up]], s_hi[rows[up]] = a[up], s[up]
            lo[rows[down]], s_lo[rows[down]] = a[down], s[down]
            if down.any():
                best.put(rows[down], trial, at[down])
                has_best[rows[down]] = True
            move = rows[~decreases]
            alpha[move] = next_step(alpha[move], lo[move], hi[move], s_lo[move], s_hi[move])
            searching[move[hi[move] - lo[move] < SHORTEST]] = False
        rest = np.flatnonzero(~accepted & has_best)
        if len(rest):
            fallback, _ = self._decreases(
                point, rest, best.residual[rest], direction, lo[rest], s0, s_lo[rest], F, plastic_start, dt, base_norm
            )
            out.put(out_rows[rest[fallback]], best, rest[fallback])
            accepted[rest[fallback]] = True
        return accepted

    def _decreases(
        self,
        point: _Iterates,
        rows: np.ndarray,
        trial_residual: np.ndarray,
        direction: np.ndarray,
        alpha: np.ndarray,
        s0: np.ndarray,
        s_trial: np.ndarray,
        F: np.ndarray,
        plastic_start: np.ndarray,
        dt: float,
        base_norm: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per trial (its residual ``trial_residual``): the potential fell from ``point`` (the
        line search's ``_decreases``), and whether the midpoint it needed was inadmissible (then
        it did not fall)."""
        out = np.linalg.norm(trial_residual, axis=1) <= base_norm[rows]
        broken = np.zeros(len(rows), dtype=bool)
        check = np.flatnonzero(~out)
        if len(check):
            r = rows[check]
            middle, ok = self._evaluate(
                point.z[r] + 0.5 * alpha[check, None] * direction[r], F[r], plastic_start[r], dt, point.plastic[r]
            )
            s_middle = np.einsum("kn,kn->k", np.where(ok[:, None], middle.residual, 0.0), direction[r])
            out[check] = ok & (simpson_decrease(alpha[check], s0[r], s_middle, s_trial[check]) < 0.0)
            broken[check] = ~ok
        return out, broken

    # -- results ----------------------------------------------------------------------------
    def _results(
        self,
        p: _Iterates,
        retried: dict,
        start_stress: np.ndarray,
        start_plastic: np.ndarray,
        iterations: np.ndarray,
        factorizations: np.ndarray,
        F: np.ndarray,
        dt: float,
        factors: _Factors,
    ) -> BatchSolved:
        """Stresses, macroscopic tangents, local errors and fractions of the converged points
        (``factors``: the Newton iterations', whose memory the tangents at the solutions take)."""
        k = len(F)
        for i, result in retried.items():
            law = result.law
            p.z[i] = result.state.inner.ravel()
            p.length[i], p.unit[i] = result.kinematics.length, result.kinematics.unit
            p.stress[i], p.plastic[i], p.recruited[i] = law.stress, law.plastic_stretch, law.recruited
            p.force[i], p.stiffness[i] = axial_force_and_stiffness(law, self.area, self.l0)
            iterations[i], factorizations[i] = result.iterations, result.factorizations
        values = self._element_values(p, clipped=False)
        # A = (modes K_BB modes^T - coupling^T K_II^-1 coupling) / V0, coupling = K_IB modes^T.
        coupling = (self.sum_into["coupling"] @ values.T).T.reshape(k, self.n, 4)
        corner = (self.sum_into["corner"] @ values.T).T.reshape(k, 4, 4)
        factors.kind[:], points = _NONE, np.arange(k)
        factors.singular.clear()
        for i in map(int, np.flatnonzero(~factors.factorize(p, points, points, clipped=False))):
            factors.kind[i], factors.singular[i] = (
                _SINGULAR,
                self._linear_solvers(k)[i].factorize(self._matrix(factors.K[i])),
            )
        fluctuation = factors.solve(points, coupling)
        A = (corner - np.einsum("kna,knb->kab", coupling, fluctuation)).reshape(k, 2, 2, 2, 2)
        # P of every point (homogenization.nominal_stress) and its local time error.
        P = np.einsum("ke,kei,eJ->kiJ", p.force, p.unit, self.element_vector)
        errors = local_errors(
            self.law,
            start_stress,
            start_plastic,
            p.stress,
            p.plastic,
            p.length / self.l0,
            self.tortuosity,
            dt,
            self.area * self.l0,
        )
        volume = self.volume
        threshold = self.config.output.yield_threshold
        return BatchSolved(
            P=P / self.network.reference_volume,
            A=A / self.network.reference_volume,
            inner=p.z.reshape(k, self.n_inner, 2).copy(),
            plastic_stretch=p.plastic.copy(),
            stress=p.stress.copy(),
            local_error=errors,
            recruited_fraction=(p.recruited @ volume) / volume.sum(),
            yielded_fraction=(yielded(p.plastic, threshold) @ volume) / volume.sum(),
            iterations=iterations,
            factorizations=factorizations,
            sensitivity=(-fluctuation).astype(np.float32),  # a predictor: single precision is enough
        )


class _Factors:
    """The tangent factorizations of the points of one batch solve (kept for the chord steps):
    the compiled Cholesky factorization (:mod:`espin.specimen.batched_kernels`) of all the
    points that need one in one call, and for a tangent that is not positive definite the
    linear solver of ``solver.linear`` (PARDISO's LDL^T), one per point."""

    def __init__(self, batch: BatchedRVE, k: int) -> None:
        self.batch = batch
        if len(batch._factor_memory[0]) < k:  # kept between solves: no fresh pages per call
            batch._factor_memory = (np.empty((k, batch._K.nnz)), np.empty((k, batch.cholesky.nnz)))
        self.K, self.L = (memory[:k] for memory in batch._factor_memory)
        self.kind = np.zeros(k, dtype=np.int8)  # _NONE, _CHOLESKY or _SINGULAR
        self.singular: dict[int, Factorization] = {}

    def held(self, points: np.ndarray) -> np.ndarray:
        """Which of ``points`` hold a factorization."""
        return self.kind[points] != _NONE

    def factorize(self, p: _Iterates, rows: np.ndarray, points: np.ndarray, clipped: bool) -> np.ndarray:
        """The (``clipped``) tangents of rows ``rows`` of ``p``, the batch's ``points``, by
        Cholesky; returns which were positive definite (those points now hold the factor)."""
        batch = self.batch
        pd = batched_kernels.factorize(
            rows,
            points,
            p.length,
            p.unit,
            p.force,
            p.stiffness,
            batch.l0,
            clipped,
            batch.slot,
            batch._K.nnz,
            batch.cholesky.arrays(),
            self.K,
            self.L,
        )
        self.kind[points] = np.where(pd, _CHOLESKY, _NONE)
        return pd

    def factorize_singular(self, p: _Iterates, row: int, point: int) -> np.ndarray | None:
        """The direction -K^-1 r of row ``row`` of ``p`` (the batch's ``point``) whose clipped
        tangent (in ``K`` from :meth:`factorize`) is not positive definite, by the linear
        solver; None when it fails."""
        batch = self.batch
        try:
            fact = batch._linear_solvers(point + 1)[point].factorize(batch._matrix(self.K[point]))
        except StepNotConverged:
            self.kind[point] = _NONE
            return None
        self.kind[point], self.singular[point] = _SINGULAR, fact
        return fact.solve(-p.residual[row])

    def solve(self, points: np.ndarray, B: np.ndarray) -> np.ndarray:
        """K^-1 B[j] of every point ``points[j]`` with its held factorization (B: (m, n) or
        (m, n, c))."""
        single = B.ndim == 2
        B3 = B[..., None] if single else B
        out = np.empty_like(B3)
        own = self.kind[points] == _CHOLESKY
        if own.any():
            c = self.batch.cholesky
            out[own] = batched_kernels.solve(
                points[own], self.K, self.L, np.ascontiguousarray(B3[own]), c.perm, c.l_ptr, c.l_row, c.k_ptr, c.k_col
            )
        for j in np.flatnonzero(~own):
            out[j] = self.singular[int(points[j])].solve(B3[j])
        return out[..., 0] if single else out


def _summation(pattern: SparsePattern, n_elements: int) -> sp.csr_matrix:
    """(nnz, 16 n_elements) 0/1 matrix: which element-matrix entries each pattern slot sums."""
    entry = np.flatnonzero(pattern.slot[: 16 * n_elements] >= 0)
    ones = np.ones(len(entry))
    return sp.csr_matrix((ones, (pattern.slot[entry], entry)), shape=(pattern.matrix.nnz, 16 * n_elements))
