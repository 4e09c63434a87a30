"""The line search on known potentials: full Newton steps kept, overshoots shortened to a lower
potential, inadmissible trials stepped back from, an uphill direction refused."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from espin.core.errors import InadmissibleState, StepNotConverged
from espin.mechanics.line_search import line_search


@dataclass(frozen=True)
class _At:
    z: np.ndarray
    residual: np.ndarray


class _Potential:
    """phi(z) = sum sqrt(1 + z^2) (convex; Newton overshoots far from 0), counted evaluations;
    z beyond ``wall`` is inadmissible."""

    def __init__(self, wall: float = np.inf) -> None:
        self.wall, self.calls = wall, 0

    def phi(self, z: np.ndarray) -> float:
        return float(np.sum(np.sqrt(1.0 + z**2)))

    def __call__(self, z: np.ndarray, near: _At | None = None) -> _At:
        self.calls += 1
        if np.any(np.abs(z) > self.wall):
            raise InadmissibleState("beyond the wall")
        return _At(z, z / np.sqrt(1.0 + z**2))

    def newton(self, at: _At) -> np.ndarray:
        return -at.residual * (1.0 + at.z**2) ** 1.5  # -g / phi''


def test_a_newton_step_near_the_minimum_is_kept_whole():
    potential = _Potential()
    start = potential(np.array([0.3, -0.2]))
    trial = line_search(start, potential.newton(start), potential, np.ones(2))
    np.testing.assert_allclose(trial.z, start.z + potential.newton(start))
    assert potential.calls == 2  # the start and the full step


def test_an_overshooting_step_is_shortened_to_a_lower_potential():
    potential = _Potential()
    start = potential(np.array([2.0]))  # Newton's full step lands at -8: the potential rises
    direction = potential.newton(start)
    assert potential.phi(start.z + direction) > potential.phi(start.z)
    trial = line_search(start, direction, potential, np.ones(1))
    assert potential.phi(trial.z) < potential.phi(start.z)
    assert abs(trial.residual @ direction) <= 0.5 * abs(start.residual @ direction)


def test_inadmissible_trials_are_stepped_back_from():
    potential = _Potential(wall=3.0)
    start = potential(np.array([2.0]))
    trial = line_search(start, potential.newton(start), potential, np.ones(1))
    assert abs(trial.z[0]) <= 3.0 and potential.phi(trial.z) < potential.phi(start.z)


def test_an_uphill_direction_is_refused():
    potential = _Potential()
    start = potential(np.array([1.0]))
    with pytest.raises(StepNotConverged) as refused:
        line_search(start, np.array([1.0]), potential, np.ones(1))
    assert refused.value.kind == "uphill"
