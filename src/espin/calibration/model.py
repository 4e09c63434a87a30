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

from espin.calibration.parameters import ETA_KEY
from espin.config import Config, apply_overrides, config_from_dict, config_to_toml
from espin.errors import SolverError
from espin.parallel import TaskPool

if TYPE_CHECKING:
    from espin.calibration.problem import _Problem

log = logging.getLogger(__package__)

PENALTY_FACTOR = 10.0
"""A measured point the model did not reach (failed simulation) costs this times max |stress|."""


def _default_steps(base: Config, max_strain: float) -> int:
    """Load steps at the base config's step size (plla: 1 per percent), at least 5."""
    step = base.loading.max_strain / base.loading.steps
    return max(5, math.ceil(max_strain / step - 1e-9))


@dataclass(frozen=True, eq=False)
class _Task:
    """One simulation: an RVE (its config as TOML), fiber values, one curve's loading."""

    rve_toml: str
    fiber: tuple[tuple[str, float], ...]
    strain_rate_per_s: float
    max_strain: float
    steps: int
    strain: np.ndarray  # where the model is read


@functools.lru_cache(maxsize=16)
def _rve(rve_toml: str) -> Any:
    """The RVE of a config, generated once per worker process."""
    from espin.rve import generate

    return generate(config_from_dict(tomllib.loads(rve_toml), "(fit)"))


def _simulate_task(task: _Task) -> tuple[np.ndarray, str | None]:
    """Model stress at the task's strains [MPa] (NaN where a failed run did not reach), and
    the failure message of a run that did not converge (else None)."""
    from espin.driver import SimulationFailed
    from espin.run import simulate

    overrides = {k.replace(".", "__"): v for k, v in task.fiber} | {
        "loading__max_strain": task.max_strain,
        "loading__strain_rate_per_s": task.strain_rate_per_s,
        "loading__steps": task.steps,
    }
    try:
        result, failure = simulate(_rve(task.rve_toml), **overrides), None
    except SimulationFailed as exc:
        result, failure = exc.partial, str(exc)
    if result is None:
        return np.full(task.strain.shape, np.nan), failure
    return np.interp(task.strain, result.strain, result.stress(), right=np.nan), failure


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
            _Task(self._rve_toml(eta, seed), tuple(fiber.items()), c.strain_rate_per_s, c.max_strain,
                  n, c.strain)
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
