"""Model evaluations: the simulation task run by the workers (with their RVE cache), and the
model at parameter points, averaged over the realizations, with the objective's history."""

from __future__ import annotations

import functools
import logging
import math
import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from espin.analysis.calibration.parameters import ETA_KEY
from espin.core.config import Config, apply_overrides, config_from_dict, config_to_toml
from espin.core.errors import SolverError
from espin.core.parallel import TaskPool

if TYPE_CHECKING:
    from espin.analysis.calibration.problem import _Problem

log = logging.getLogger(__package__)

PENALTY_FACTOR = 10.0
"""A measured point the model did not reach (failed simulation) costs this times max |stress|."""

STEP_STRAIN = 1e-3
"""Default largest load step [strain] from 0 to ``KNEE_FACTOR`` times the knee of the measured
curve. Backward Euler on the flow rule is first order in the step: on an L = 50 D, 4-layer RVE
(b_p 4, c_p 0.8) the stress at the knee differs from a run with 0.05 % steps by 0.013 MPa with
0.1 % steps, 0.05 with 0.25 %, 0.10 with 0.5 % (docs/calibration.md)."""
KNEE_FACTOR = 2.0
"""Fine steps run to this multiple of the measured curve's knee (its bilinear yield strain)."""
COARSE_STEP_STRAIN = 1e-2
"""Largest load step [strain] beyond the fine zone, where the curve is nearly straight."""

_SHORTHAND = ("max_strain", "strain_rate_per_s", "steps")


@dataclass(frozen=True, eq=False)
class _Steps:
    """The load steps of one curve's simulations: a loading program whose segments end at
    measured strains, each cut into equal steps no longer than the local limit (``step_strain``
    up to ``fine_until``, ``max(step_strain, COARSE_STEP_STRAIN)`` beyond)."""

    segments: tuple[tuple[float, int], ...]  # (to_strain, steps)
    step_strain: float
    fine_until: float
    on_data: int  # measured strains that end a segment (any others are read between steps)

    @property
    def count(self) -> int:
        """Number of load steps."""
        return sum(n for _, n in self.segments)

    @property
    def largest(self) -> float:
        """Largest step [strain]."""
        ends = [0.0] + [e for e, _ in self.segments]
        return max((b - a) / n for a, b, (_, n) in zip(ends, ends[1:], self.segments))

    def program(self, rate: float) -> list[dict[str, float | int]]:
        """The ``loading.program`` segments at strain rate ``rate`` [1/s]."""
        return [{"to_strain": e, "rate_per_s": rate, "steps": n} for e, n in self.segments]

    def describe(self) -> dict[str, float | int]:
        """What fit.json reports of the steps."""
        return {"load_steps": self.count, "step_strain": self.step_strain,
                "fine_steps_to_strain": self.fine_until, "largest_step_strain": self.largest,
                "points_ending_a_segment": self.on_data}


def _load_steps(strain: np.ndarray, step_strain: float, fine_until: float) -> _Steps:
    """Segments ending at the measured strains, cut into steps of at most the local limit.

    A measured strain closer than a quarter of the local limit to the previous segment end
    ends no segment (it is read by linear interpolation between steps that short): data denser
    than that cost no extra steps.
    """
    segments: list[tuple[float, int]] = []
    start, on_data, last = 0.0, 0, float(strain[-1])
    for e in (float(x) for x in strain):
        limit = step_strain if start < fine_until else max(step_strain, COARSE_STEP_STRAIN)
        if e - start < 0.25 * limit and e < last:
            continue
        segments.append((e, max(1, math.ceil((e - start) / limit - 1e-9))))
        start, on_data = e, on_data + 1
    return _Steps(tuple(segments), step_strain, min(fine_until, last), on_data)


def _knee(strain: np.ndarray, stress: np.ndarray) -> float | None:
    """Strain at the knee of a measured curve (its bilinear yield), None without a clear yield."""
    from espin.analysis.properties import CurveError, curve_properties

    try:
        props = curve_properties(np.r_[0.0, strain], np.r_[0.0, stress])
    except CurveError:
        return None
    knee = props.yield_strain + props.strain_offset
    return float(knee) if props.has_yield and math.isfinite(knee) and knee > 0 else None


def _curve_steps(strain: np.ndarray, stress: np.ndarray | None, step_strain: float) -> _Steps:
    """Load steps of a curve: at most ``step_strain`` up to ``KNEE_FACTOR`` x its knee (the whole
    curve when it shows no clear knee, or when no stress is given), coarser beyond."""
    knee = None if stress is None else _knee(strain, stress)
    fine_until = float(strain[-1]) if knee is None else KNEE_FACTOR * knee
    return _load_steps(strain, step_strain, fine_until)


def _loading_config(config: Config, steps: _Steps, rate: float,
                    overrides: Mapping[str, Any] | None = None) -> Config:
    """``config`` with ``overrides``, loaded by the curve's program instead of the shorthand;
    validated (a ConfigError names the bad key)."""
    data = config.model_dump(mode="json", exclude_none=True, exclude_unset=True)
    for key in _SHORTHAND:
        data.get("loading", {}).pop(key, None)
    return apply_overrides(config_from_dict(data, "(fit)"),
                           {**(overrides or {}), "loading.program": steps.program(rate)})


@dataclass(frozen=True, eq=False)
class _Task:
    """One simulation: an RVE (its config as TOML), fiber values, one curve's loading."""

    rve_toml: str
    fiber: tuple[tuple[str, float], ...]
    strain_rate_per_s: float
    steps: _Steps
    strain: np.ndarray  # where the model is read


@functools.lru_cache(maxsize=16)
def _rve(rve_toml: str) -> Any:
    """The RVE of a config, generated once per worker process."""
    from espin.geometry.rve import generate

    data = tomllib.loads(rve_toml)
    for key in _SHORTHAND:  # the loading is a program, given with each task
        data.get("loading", {}).pop(key, None)
    return generate(config_from_dict(data, "(fit)"))


def _simulate_task(task: _Task) -> tuple[np.ndarray, str | None]:
    """Model stress at the task's strains [MPa] (NaN where a failed run did not reach), and
    the failure message of a run that did not converge (else None)."""
    from espin.mechanics.driver import SimulationFailed
    from espin.mechanics.run import simulate

    overrides = {k.replace(".", "__"): v for k, v in task.fiber} | {
        "loading__program": task.steps.program(task.strain_rate_per_s),
    }
    try:
        result, failure = simulate(_rve(task.rve_toml), **overrides), None
    except SimulationFailed as exc:
        result, failure = exc.partial, str(exc)
    if result is None:
        return np.full(task.strain.shape, np.nan), failure
    reached = result.strain[-1]  # a segment's end strain can differ from its to_strain by rounding
    stress = np.interp(np.minimum(task.strain, reached), result.strain, result.stress())
    return np.where(task.strain <= reached + 1e-12 * max(abs(reached), 1.0), stress, np.nan), failure


@dataclass(frozen=True, eq=False)
class _Evaluation:
    """The model at one parameter point.

    per_realization : (R, m) model stress at every measured point [MPa] (NaN: not reached)
    """

    eta: float
    fiber: dict[str, float]
    per_realization: np.ndarray
    failures: tuple[str, ...]

    @property
    def mean(self) -> np.ndarray:
        return self.per_realization.mean(axis=0)


@dataclass(eq=False)
class _Model:
    """Evaluates parameter points through one pool, and keeps the objective history."""

    problem: _Problem
    pool: TaskPool
    on_evaluation: Callable[[dict[str, Any]], None] | None = None
    simulate: Callable[[_Task], tuple[np.ndarray, str | None]] = _simulate_task
    """The task function the workers run (module-level: workers pickle it by name)."""
    history: list[dict[str, Any]] = field(default_factory=list)
    simulations: int = 0
    failed_simulations: int = 0
    rve_configs: dict[tuple[float, int], str] = field(default_factory=dict)

    def _rve_toml(self, eta: float, seed: int) -> str:
        """The RVE's config as TOML (the task's identity in the workers' RVE cache)."""
        if (eta, seed) not in self.rve_configs:
            config = apply_overrides(self.problem.base, {ETA_KEY: eta, "rve.seed": seed})
            self.rve_configs[eta, seed] = config_to_toml(config)
        return self.rve_configs[eta, seed]

    def evaluate(self, points: Sequence[tuple[float, dict[str, float]]], stage: str) -> list[_Evaluation]:
        """Simulate every realization and curve of each (eta, fiber values) point."""
        problem = self.problem
        tasks = [
            _Task(self._rve_toml(eta, seed), tuple(fiber.items()), c.strain_rate_per_s, n, c.strain)
            for eta, fiber in points
            for seed in problem.seeds
            for c, n in zip(problem.curves, problem.steps)
        ]
        outcomes = sorted(self.pool.map(self.simulate, tasks), key=lambda o: o.index)
        self.simulations += len(tasks)
        for outcome in outcomes:
            if not outcome.ok:
                eta, fiber = points[outcome.index // (len(problem.seeds) * len(problem.curves))]
                raise SolverError(f"fit evaluation at {_describe(eta, fiber)} raised {outcome.error}")
        per_point = len(problem.seeds) * len(problem.curves)
        evaluations = []
        for i, (eta, fiber) in enumerate(points):
            values = [o.value for o in outcomes[i * per_point:(i + 1) * per_point]]
            evaluations.append(self._record(eta, fiber, values, stage))
        return evaluations

    def _record(self, eta: float, fiber: dict[str, float], values: list, stage: str) -> _Evaluation:
        n_curves = len(self.problem.curves)
        rows = [np.concatenate([v[0] for v in values[r * n_curves:(r + 1) * n_curves]])
                for r in range(len(self.problem.seeds))]
        failures = tuple(v[1] for v in values if v[1] is not None)
        self.failed_simulations += len(failures)
        evaluation = _Evaluation(eta, dict(fiber), np.array(rows), failures)
        record = {"evaluation": len(self.history) + 1, "stage": stage, ETA_KEY: eta, **fiber,
                  "sse_MPa2": _sse(self.residual(evaluation)), "failed_simulations": len(failures)}
        self.history.append(record)
        if failures:
            log.warning("%d simulation(s) failed at %s: %s", len(failures), _describe(eta, fiber), failures[0])
        if self.on_evaluation is not None:
            self.on_evaluation(record)
        return evaluation

    def residual(self, evaluation: _Evaluation) -> np.ndarray:
        """Model minus data [MPa]; a point no realization reached costs a large penalty."""
        data = self.problem.data
        r = evaluation.mean - data
        return np.where(np.isfinite(r), r, PENALTY_FACTOR * np.max(np.abs(data)))


def _sse(residual: np.ndarray) -> float:
    return float(residual @ residual)


def _describe(eta: float, fiber: Mapping[str, float]) -> str:
    return ", ".join(f"{k} = {v:.6g}" for k, v in {ETA_KEY: eta, **fiber}.items())
