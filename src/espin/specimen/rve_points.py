"""FE^2: an espin RVE at every quadrature point of the specimen.

Every point holds its own RVE state (inner node positions and plastic stretches): one shared
RVE geometry by default, or one network per point. At a trial F the point's RVE is solved with
the whole F prescribed (its border nodes follow x = F X) over the time step from the committed
state to the macro time (the fiber law is rate-dependent: the RVE time step is the macro time
step, one RVE step per macro step); it returns the nominal stress P and the algorithmic
macroscopic tangent dP/dF (:meth:`espin.mechanics.equilibrium.EquilibriumSolver.macroscopic_tangent`).
Each solve starts from the point's last solution moved to first order in the change of F (its
sensitivity dz/dF, which the macroscopic tangent computes anyway; points solved one by one: the
new affine part), the first trial of a time step also along the last step's motion in time
(:meth:`RVEPoints._guess`). Trials
become the state only on :meth:`RVEPoints.commit` (the macro step converged) and are dropped on
:meth:`RVEPoints.rollback` (it was cut).

The RVEs' Newton tolerance is ``solver.rtol`` of their config, at most 1e-3 of the macro
tolerance (:func:`rve_tolerance`). The solves of a trial run in parallel through the task pool
(:class:`espin.core.parallel.TaskPool`: local processes or Dask), in chunks; each worker keeps
its solvers between calls. Points that share one network (without fiber bending) are solved
together, a chunk at a time (:mod:`espin.specimen.batched_points`); per-point realizations
one by one.

Stresses: the RVE's P [MPa] is the mat's homogenized nominal stress over the reference volume
L^2 N_l D, the specimen's P (the macro thickness is the mat's).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any, NoReturn

import numpy as np

from espin.core.config import Config
from espin.core.errors import StepNotConverged
from espin.core.parallel import TaskOutcome, TaskPool
from espin.geometry.network import Network
from espin.mechanics.driver import StepRecord, step_record
from espin.mechanics.equilibrium import EquilibriumSolver, StepState
from espin.mechanics.linear_solvers import make_linear_solver
from espin.specimen.batched_points import BatchedRVE, batchable

__all__ = ["RVEPoints", "rve_tolerance", "PointStates"]

_NO_FREE = np.zeros((0, 2, 2))


def rve_tolerance(config: Config, macro_rtol: float) -> Config:
    """The RVE config with ``solver.rtol`` and ``solver.atol`` at most 1e-3 of the macro tolerance."""
    limit = 1e-3 * macro_rtol
    solver = config.solver.model_copy(
        update={"rtol": min(config.solver.rtol, limit), "atol": min(config.solver.atol, limit)}
    )
    return config.model_copy(update={"solver": solver})


@dataclass(frozen=True, eq=False)
class PointStates:
    """RVE states of a set of points (arrays over points first).

    Attributes
    ----------
    time : float [s]
    F : (n, 2, 2) float64
    inner : list of (n_inner, 2) float64 [um]
        Inner node positions of each point's RVE (relative to its centre).
    plastic_stretch : list of (n_elements,) float64
    stress : list of (n_elements,) float64 [MPa]
        Element stresses t (they start the next step's local-error estimate).
    sensitivity : list of (2 n_inner, 4) float32 or None [um]
        d inner / dF_kL at the solution (column 2 k + L; :class:`BatchSolved`), the first-order
        predictor of the next solve; None where it is not known (the start, the points solved
        one by one).

    The lists have one array per point (per-point realizations differ in size).
    """

    time: float
    F: np.ndarray
    inner: list[np.ndarray]
    plastic_stretch: list[np.ndarray]
    stress: list[np.ndarray]
    sensitivity: list[np.ndarray | None]

    def take(self, index: np.ndarray) -> PointStates:
        return PointStates(
            self.time,
            self.F[index],
            [self.inner[i] for i in index],
            [self.plastic_stretch[i] for i in index],
            [self.stress[i] for i in index],
            [self.sensitivity[i] for i in index],
        )


@dataclass(frozen=True, eq=False)
class _Chunk:
    """One task: some points' RVE solves at one trial."""

    key: str
    points: np.ndarray  # the points' indices (the solvers' cache keys with per-point networks)
    networks: Sequence[Network]  # one per point of the chunk (the same object when shared)
    shared: bool  # one network for every point
    config: Config
    start: PointStates
    guess: list[np.ndarray]  # (n_inner, 2) [um] per point
    F: np.ndarray  # (n, 2, 2)
    time: float


_SOLVERS: dict[tuple[str, int], EquilibriumSolver] = {}  # per worker process: solvers kept between calls
_CACHED_SOLVERS = 4096  # per-point realizations: one solver per point


def _solver(key: str, index: int, network: Network, config: Config) -> EquilibriumSolver:
    cached = _SOLVERS.get((key, index))
    if cached is None:
        if len(_SOLVERS) >= _CACHED_SOLVERS:
            del _SOLVERS[next(iter(_SOLVERS))]  # the oldest
        cached = EquilibriumSolver.from_config(network, config, make_linear_solver(config.solver.linear))
        _SOLVERS[(key, index)] = cached
    return cached


_BATCHES: dict[str, BatchedRVE] = {}  # per worker process: the shared network's batched solver
_CACHED_BATCHES = 4  # runs whose batched solvers a worker keeps (each holds a linear solver per point)


def _solve_batch(chunk: _Chunk) -> _Solved:
    """The RVE solves of one chunk of points that share a network, together
    (:mod:`espin.specimen.batched_points`)."""
    batch = _BATCHES.get(chunk.key)
    if batch is None:
        if len(_BATCHES) >= _CACHED_BATCHES:
            _BATCHES.pop(next(iter(_BATCHES))).release()  # the oldest run's
        batch = _BATCHES[chunk.key] = BatchedRVE(chunk.networks[0], chunk.config)
    start = chunk.start
    solved = batch.solve(
        start.time,
        start.F,
        np.array(start.inner),
        np.array(start.plastic_stretch),
        np.array(start.stress),
        chunk.time,
        chunk.F,
        np.array(chunk.guess),
        chunk.points,
    )
    return _Solved(
        P=solved.P,
        A=solved.A,
        inner=list(solved.inner),
        plastic_stretch=list(solved.plastic_stretch),
        stress=list(solved.stress),
        local_error=solved.local_error,
        recruited_fraction=solved.recruited_fraction,
        yielded_fraction=solved.yielded_fraction,
        iterations=solved.iterations,
        sensitivity=list(solved.sensitivity),
    )


def _solve_chunk(chunk: _Chunk) -> _Solved:
    """The RVE solves of one chunk (runs in a worker): together when the points share a network
    without bending, else one by one."""
    if chunk.shared and batchable(chunk.config):
        return _solve_batch(chunk)
    records, results, errors = [], [], []
    threshold = chunk.config.output.yield_threshold
    for i in range(len(chunk.F)):
        network = chunk.networks[i]
        solver = _solver(chunk.key, 0 if chunk.shared else int(chunk.points[i]), network, chunk.config)
        start = StepState(
            chunk.start.time,
            chunk.start.inner[i],
            np.zeros(0),
            chunk.start.F[i],
            chunk.start.plastic_stretch[i],
            chunk.start.stress[i],
        )
        try:
            result = solver.solve(start, chunk.time, chunk.F[i], _NO_FREE, chunk.guess[i], np.zeros(0))
        except StepNotConverged as failure:
            raise type(failure)(
                f"RVE point {int(chunk.points[i])}: {failure.reason}",
                failure.kind,
                iterations=failure.iterations,
                factorizations=failure.factorizations,
            ) from None
        records.append(step_record(0, solver, result, 0.0, (result.iterations, result.factorizations, 1), threshold))
        results.append((result, solver.macroscopic_tangent(result)))
        errors.append(solver.time_error(start, result))
    return _Solved(
        P=np.array([r.P for r in records]),
        A=np.array([A for _, A in results]),
        inner=[r.state.inner for r, _ in results],
        plastic_stretch=[r.state.plastic_stretch for r, _ in results],
        stress=[r.law.stress for r, _ in results],
        local_error=np.array(errors),
        recruited_fraction=np.array([r.recruited_fraction for r in records]),
        yielded_fraction=np.array([r.yielded_fraction for r in records]),
        iterations=np.array([r.iterations for r, _ in results]),
        sensitivity=[None] * len(results),
    )


@dataclass(frozen=True, eq=False)
class _Solved:
    """The RVE solves of some points (arrays over points first; the RVE states one array per point)."""

    P: np.ndarray  # (n, 2, 2) [MPa]
    A: np.ndarray  # (n, 2, 2, 2, 2) [MPa]
    inner: list[np.ndarray]
    plastic_stretch: list[np.ndarray]
    stress: list[np.ndarray]
    local_error: np.ndarray
    recruited_fraction: np.ndarray
    yielded_fraction: np.ndarray
    iterations: np.ndarray
    sensitivity: list[np.ndarray | None]  # (2 n_inner, 4) [um] per point (PointStates)

    @classmethod
    def joined(cls, parts: Sequence[_Solved]) -> _Solved:
        """The chunks' solves, in order."""
        values: dict[str, Any] = {}
        for name in cls.__dataclass_fields__:
            items = [getattr(part, name) for part in parts]
            values[name] = [a for item in items for a in item] if isinstance(items[0], list) else np.concatenate(items)
        return cls(**values)


def _raise_failed_chunk(outcome: TaskOutcome, points: np.ndarray) -> NoReturn:
    """Raise what a chunk of points raised: a step that did not converge as itself (the macro
    step is cut), anything else (a bug) with the points and the worker's traceback added."""
    exception = outcome.exception
    if isinstance(exception, StepNotConverged):
        raise exception
    where = f"in the RVE solves of points {points[0]}-{points[-1]}; the task's traceback:\n{outcome.traceback}"
    if exception is None:  # it could not be carried back from the worker: its text
        raise RuntimeError(f"{outcome.error} ({where})")
    exception.add_note(where)
    raise exception


def _predictor(inner: np.ndarray, reference: np.ndarray, sensitivity: np.ndarray | None, dF: np.ndarray) -> np.ndarray:
    """The warm start of a point's next solve [um]: its last solution ``inner`` (n_inner, 2)
    moved to first order by the change ``dF`` of F (``sensitivity``: dz/dF, PointStates), or
    without it by the affine part X dF^T of the change (``reference``: X)."""
    if sensitivity is None:
        return inner + reference @ dF.T
    return inner + (sensitivity @ dF.ravel()).reshape(inner.shape)


def replay_point(network: Network, config: Config, times: np.ndarray, F: np.ndarray) -> list[StepRecord]:
    """The RVE of one point driven again through its (time, F) history (one RVE step per entry).

    Returns the :class:`StepRecord` of every entry (entry 0 is the start, usually F = I).
    """
    solver = EquilibriumSolver.from_config(network, config, make_linear_solver(config.solver.linear))
    X = solver.asm.reference[: network.n_inner]
    state = StepState(
        float(times[0]), X @ F[0].T, np.zeros(0), F[0], np.ones(network.n_elements), np.zeros(network.n_elements)
    )
    records = []
    for k, (t, F_k) in enumerate(zip(times, F, strict=True)):
        guess = X @ F_k.T + (state.inner - X @ state.F.T)
        result = solver.solve(state, float(t), F_k, _NO_FREE, guess, np.zeros(0))
        state = result.state
        records.append(
            step_record(
                k,
                solver,
                result,
                float(F_k[0, 0] - 1.0),
                (result.iterations, result.factorizations, 1),
                config.output.yield_threshold,
            )
        )
    return records


class RVEPoints:
    """The RVEs at ``n_points`` quadrature points (module docstring); a
    :class:`espin.specimen.materials.PointMaterial`.

    Parameters
    ----------
    networks
        One network (shared by every point) or one per point.
    config
        The RVEs' fiber law, solver and output settings (its tolerance as given: see
        :func:`rve_tolerance`).
    n_points
        Quadrature points.
    pool
        Where the solves run (default: in this process).
    chunks_per_worker
        Tasks per worker and trial (more balance the load, fewer cost less pickling and make
        larger batches); None: 2 (on 2 workers the slower of 2 chunks of the holed strip took 10 %
        longer than the mean, the slowest pair of 4 chunks 3 %), 1 in this process.
    """

    def __init__(
        self,
        networks: Network | Sequence[Network],
        config: Config,
        n_points: int,
        *,
        pool: TaskPool | None = None,
        chunks_per_worker: int | None = None,
    ) -> None:
        self.networks = [networks] * n_points if isinstance(networks, Network) else list(networks)
        if len(self.networks) != n_points:
            raise ValueError(f"{len(self.networks)} networks for {n_points} points")
        self.config = config
        self.n_points = n_points
        self.symmetric_tangent = True  # condensed from the Hessian of each RVE's incremental potential
        self.pool = pool or TaskPool(workers=1)
        self.shared = len({id(net) for net in self.networks}) == 1
        if chunks_per_worker is None:
            chunks_per_worker = 1 if self.pool.serial else 2
        self.chunks = max(1, min(n_points, chunks_per_worker * (1 if self.pool.serial else self.pool.workers)))
        self.key = f"{id(self)}-{np.random.default_rng().integers(1 << 62)}"
        inner = [net.node_position[: net.n_inner] - net.centre for net in self.networks]
        self._reference = inner  # [um]
        self.state = PointStates(
            0.0,
            np.tile(np.eye(2), (n_points, 1, 1)),
            inner,
            [np.ones(net.n_elements) for net in self.networks],
            [np.zeros(net.n_elements) for net in self.networks],
            [None] * n_points,
        )
        self._error = 0.0
        self._trial: PointStates | None = None
        self._previous: PointStates | None = None  # the committed state before ``state``
        self._trial_fields: dict[str, np.ndarray] = {}
        self.fields_committed: dict[str, np.ndarray] = {
            name: np.zeros(n_points) for name in ("yielded_fraction", "recruited_fraction")
        }
        self.solves = 0
        self.rve_iterations = 0
        self.history_time: list[float] = []  # every committed time step (the replays' program)
        self.history_F: list[np.ndarray] = []

    def evaluate(self, F: np.ndarray, time: float) -> tuple[np.ndarray, np.ndarray]:
        guess = self._guess(F, time)
        parts = np.array_split(np.arange(self.n_points), self.chunks)
        tasks = [
            _Chunk(
                self.key,
                part,
                [self.networks[i] for i in part],
                self.shared,
                self.config,
                replace(self.state.take(part), sensitivity=[None] * len(part)),  # not needed there
                [guess[i] for i in part],
                F[part],
                time,
            )
            for part in parts
        ]
        results: dict[int, _Solved] = {}
        for outcome in self.pool.map(_solve_chunk, tasks):
            if not outcome.ok:
                _raise_failed_chunk(outcome, parts[outcome.index])
            results[outcome.index] = outcome.value
        solved = _Solved.joined([results[k] for k in range(len(tasks))])
        self.solves += self.n_points
        self.rve_iterations += int(solved.iterations.sum())
        self._trial = PointStates(
            time, F.copy(), solved.inner, solved.plastic_stretch, solved.stress, solved.sensitivity
        )
        self._error = float(solved.local_error.max())
        self._trial_fields = {
            "yielded_fraction": solved.yielded_fraction,
            "recruited_fraction": solved.recruited_fraction,
            "rve_iterations": solved.iterations.astype(float),
        }
        return solved.P, solved.A

    def _guess(self, F: np.ndarray, time: float) -> list[np.ndarray]:
        """Every point's warm start [um] at ``F`` and ``time`` (module docstring): a new trial of
        the step from the last trial, moved to first order in F; the first trial of a time step
        from the committed state, also moved along the last step's motion in time (the plastic
        flow goes on: z_n + r (z_n - z_n-1) + dz/dF (F - F_n - r (F_n - F_n-1)), r the ratio of
        the time steps)."""
        last = self._trial if self._trial is not None and self._trial.time == time else self.state
        before = self._previous
        if last is self._trial or before is None or not before.time < last.time:
            return [
                _predictor(w, X, S, F_p - F_last)
                for w, X, S, F_p, F_last in zip(last.inner, self._reference, last.sensitivity, F, last.F)
            ]
        r = (time - last.time) / (last.time - before.time)
        return [
            _predictor(w + r * (w - w_before), X, S, F_p - F_last - r * (F_last - F_before))
            for w, w_before, X, S, F_p, F_last, F_before in zip(
                last.inner, before.inner, self._reference, last.sensitivity, F, last.F, before.F
            )
        ]

    def time_error(self) -> float:
        """Largest relative local error of the plastic update over the points at the last trial
        (:func:`espin.mechanics.time_steps.local_error`)."""
        return self._error

    def commit(self) -> None:
        if self._trial is None:
            return
        self._previous = self.state
        self.state = self._trial
        self.fields_committed = dict(self._trial_fields)
        self.history_time.append(self.state.time)
        self.history_F.append(self.state.F.copy())
        self._trial = None

    def rollback(self) -> None:
        self._trial = None

    def fields(self) -> dict[str, np.ndarray]:
        return dict(self.fields_committed)
