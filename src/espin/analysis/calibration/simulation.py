"""The simulations of a fit: the load steps of each measured curve, and the task the workers
run (with their RVE cache)."""

from __future__ import annotations

import functools
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from espin.core.config import Config, apply_overrides, config_from_dict

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
        return {
            "load_steps": self.count,
            "step_strain": self.step_strain,
            "fine_steps_to_strain": self.fine_until,
            "largest_step_strain": self.largest,
            "points_ending_a_segment": self.on_data,
        }


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


def _steps_are_time_steps(config: Config) -> Config:
    """``config`` with ``solver.time_rtol = "off"`` unless it sets it: a fit's load steps (fine
    up to past the knee, docs/calibration.md) are its time steps."""
    if "time_rtol" in config.solver.model_fields_set:
        return config
    return apply_overrides(config, {"solver.time_rtol": "off"})


def _loading_config(config: Config, steps: _Steps, rate: float, overrides: Mapping[str, Any] | None = None) -> Config:
    """``config`` with ``overrides``, loaded by the curve's program instead of the shorthand;
    validated (a ConfigError names the bad key)."""
    data = config.model_dump(mode="json", exclude_none=True, exclude_unset=True)
    for key in _SHORTHAND:
        data.get("loading", {}).pop(key, None)
    return apply_overrides(
        config_from_dict(data, "(fit)"), {**(overrides or {}), "loading.program": steps.program(rate)}
    )


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
    from espin.mechanics.driver import SimulationFailed, SimulationResult
    from espin.mechanics.run import simulate

    overrides: dict[str, Any] = dict(task.fiber) | {"loading.program": task.steps.program(task.strain_rate_per_s)}
    result: SimulationResult | None
    try:
        result, failure = simulate(_rve(task.rve_toml), progress=False, **overrides), None
    except SimulationFailed as exc:
        result, failure = exc.partial, str(exc)
    if result is None:
        return np.full(task.strain.shape, np.nan), failure
    reached = result.strain[-1]  # a segment's end strain can differ from its to_strain by rounding
    stress = np.interp(np.minimum(task.strain, reached), result.strain, result.stress())
    return np.where(task.strain <= reached + 1e-12 * max(abs(reached), 1.0), stress, np.nan), failure
