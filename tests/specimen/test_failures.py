"""Only a step that did not converge cuts a macro step: a bug inside an RVE point's solve stops
the run at once, in this process or in a worker, with the points and the worker's traceback."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

import espin
from espin.core.config import apply_overrides
from espin.core.parallel import TaskPool
from espin.specimen.membrane import Membrane
from espin.specimen.rve_points import RVEPoints
from espin.specimen.shapes import strip
from espin.specimen.solver import GripProgram, run_specimen

T = 0.1


class _Counted(RVEPoints):
    """RVE points that count their evaluations."""

    calls = 0

    def evaluate(self, F, time):
        type(self).calls += 1
        return super().evaluate(F, time)


@pytest.mark.slow
@pytest.mark.parametrize("workers", [1, 2])
def test_a_value_error_in_an_rve_point_stops_the_run_with_the_point_and_the_traceback(workers):
    rve = espin.generate("plla", rve__size_ratio=30, rve__layers=2)
    # A network whose arrays disagree: its solver raises a numpy ValueError inside the point's task.
    broken = dataclasses.replace(rve.network, element_diameter=rve.network.element_diameter[:-1])
    specimen = strip(20.0, 5.0, elements_across=1)
    membrane = Membrane(specimen.mesh, T)
    _Counted.calls = 0
    with TaskPool(workers=workers) as pool:
        points = _Counted(broken, rve.config, membrane.n_points, pool=pool)
        with pytest.raises(ValueError, match="could not be broadcast") as raised:
            run_specimen(specimen, points, GripProgram(0.02, 2, 1e-2), thickness_mm=T, membrane=membrane,
                         time_rtol=1e-3)
    notes = "\n".join(getattr(raised.value, "__notes__", []))
    assert re.search(r"in the RVE solves of points \d+-\d+; the task's traceback", notes)
    assert "equilibrium.py" in notes and "ValueError: operands could not be broadcast" in notes
    assert _Counted.calls == 1  # the first evaluation: no cut, no retry


def test_a_point_that_does_not_converge_cuts_the_macro_step():
    """The other side of the contract: an RVE whose Newton fails is a step to cut, and names its point."""
    from espin.core.errors import StepNotConverged

    rve = espin.generate("plla", rve__size_ratio=30, rve__layers=2)
    config = apply_overrides(rve.config, {"solver.max_iterations": 1})  # one iteration: cannot converge
    points = RVEPoints(rve.network, config, 2)
    F = np.tile(np.diag([1.05, 1.0]), (2, 1, 1))
    with pytest.raises(StepNotConverged, match="RVE point 0: "):
        points.evaluate(F, 5.0)
