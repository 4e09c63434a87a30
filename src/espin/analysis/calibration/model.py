"""Model evaluations: the model at parameter points, averaged over the realizations, with the
objective's history."""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from espin.analysis.calibration.parameters import ETA_KEY
from espin.analysis.calibration.problem import _Problem
from espin.analysis.calibration.simulation import _simulate_task, _Task
from espin.core.config import apply_overrides, config_to_toml
from espin.core.errors import SolverError
from espin.core.parallel import TaskPool

log = logging.getLogger(__package__)

PENALTY_FACTOR = 10.0
"""A measured point the model did not reach (failed simulation) costs this times max |stress|."""


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
            values = [o.value for o in outcomes[i * per_point : (i + 1) * per_point]]
            evaluations.append(self._record(eta, fiber, values, stage))
        return evaluations

    def _record(self, eta: float, fiber: dict[str, float], values: list, stage: str) -> _Evaluation:
        n_curves = len(self.problem.curves)
        rows = [
            np.concatenate([v[0] for v in values[r * n_curves : (r + 1) * n_curves]])
            for r in range(len(self.problem.seeds))
        ]
        failures = tuple(v[1] for v in values if v[1] is not None)
        self.failed_simulations += len(failures)
        evaluation = _Evaluation(eta, dict(fiber), np.array(rows), failures)
        record = {
            "evaluation": len(self.history) + 1,
            "stage": stage,
            ETA_KEY: eta,
            **fiber,
            "sse_MPa2": _sse(self.residual(evaluation)),
            "failed_simulations": len(failures),
        }
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
