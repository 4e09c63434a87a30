"""How long tensile tests will take on this machine: a speed calibration, a cost model, a plan.

Before a long command (``espin fit``, ``espin study sweep`` / ``rve-size``) the command line
prints its plan, e.g. ``plan: 30 tensile tests x 64,082 DOF on 2 workers -> about 37 min (speed
calibration 0.4 s)``.

**Calibration** (:func:`calibrate`, at most ``CALIBRATION_BUDGET_S`` = 2 s, cached per
process). A fixed small tensile test is run: the ``plla`` mat at L/D 80 with 4 layers (seed 1,
2,304 DOF) pulled to 3 % in 12 steps, the steps around yield where Newton works hardest, on
one BLAS thread as a study's worker runs, with SuperLU (PARDISO's library takes 1-2 s to load
into a process, more than the calibration may take; the main process of a study or fit does
not need it). Its seconds per Newton iteration after the first solve, divided by those of the
development machine, quiet (``REFERENCE_SECONDS_PER_ITERATION``), is this machine's
*slowness* now, other jobs on it included (it takes 0.4 s there). The test stops after the
step past which the next might exceed the budget, and is timed on the iterations done. The
modules it imports (generation, solver), which every command that plans needs anyway, are not
counted in its time.

**Cost of one tensile test** (:func:`predict_test`), in *calibration iterations* (the time of
one Newton iteration of the calibration test, measured), so that the model's constants do not
depend on the machine:

    t = t_cal (n_it u(DOF) + n_rec r DOF) + slowness t_gen segments

- DOF and segments from :func:`espin.geometry.size_estimate.estimate_size` (no mat is made),
  the DOF scaled by :func:`crossing_factor` for aligned fibers (which cross less);
- n_rec, the recorded steps of the loading program (:func:`espin.mechanics.loading.load_program`);
- n_sub, the time steps: the program's steps with ``solver.time_rtol = "off"`` or an elastic
  law, else at least ``SUBSTEPS_PER_STRAIN`` per unit of strain travelled (the adaptive control
  takes about 80 time steps for the ``plla`` program of 30 steps to 30 %);
- n_it = ``ITERATIONS_PER_SUBSTEP`` n_sub + W min(1, strain / ``YIELD_STRAIN_SPAN``): every
  time step costs about one iteration, and the yield region (about 1-9 % strain) a number
  that grows slowly with the mat, W = ``YIELD_ITERATIONS`` (DOF / 10^4)^``YIELD_EXPONENT``
  (half of it for an elastic law), times ``TEST_ITERATIONS`` for an equibiaxial test, and
  more for tortuous fibers (``TURN_EXPONENT``);
- u(DOF) = ``ITERATION_BASE`` + ``ITERATION_SCALE`` (DOF / 10^4)^``ITERATION_EXPONENT`` per
  Newton iteration (fiber law, assembly, factorization, line search; PARDISO, one BLAS
  thread; with SuperLU ``SUPERLU_BASE`` + ``SUPERLU_SCALE`` (DOF / 10^4)^``SUPERLU_EXPONENT``), r =
  ``RECORD_PER_DOF`` per DOF of a recorded step (stresses, fractions), and t_gen =
  ``GENERATE_S_PER_SEGMENT`` per segment for the mat's generation.

The constants were fitted to ``benchmarks/bench_cost_model.py`` (``plla`` at L/D 60-200 with
3-15 layers, a wavy, an aligned and an equibiaxial mat, a fit-like program of 300 uniform
steps); its table in docs/performance.md ("Planning long runs") shows predictions within
0.90-1.22 of the measured time on a quiet machine, three cases not used in the fit included.
The iteration constants and the cost of an iteration were fitted again after the Newton and
kernel changes of [speed] (issue 37; the iterations from exact counts, the cost from a run
on a loaded machine, rows whose calibrations before and after the test differed by more than
20 % left out): 0.77-1.22 of the measured time there. They were fitted a third time after the
node relaxation of [speed] (a local Newton on the few nodes left over the tolerance): 6-20 %
fewer iterations than at the second fit, each dearer in calibration iterations (the
relaxation's residual evaluations). The old constants predicted 0.99-1.32 times the
iterations run, the new 0.86-1.14 (the held-out rows 0.92-1.11), and 0.84-1.29 of the
measured time where the load held still (the same method). They were fitted a fourth time
after the non-monotone node relaxation (up to 10 rounds, neighbours two elements away, up to
200 nodes): the tests ran 0.74-0.90 of the previous fit's iterations, and the calibration test
35 iterations instead of 54 for about the same work, so a calibration iteration is 1.55 times
as dear (``REFERENCE_SECONDS_PER_ITERATION`` 0.0054 -> 0.0084 s) and a test's iterations cost
fewer of them. The old constants predicted 1.12-1.44 times the iterations run and 1.5-3.3
times the measured time; the new 0.91-1.13 times the iterations (the fit's ten rows 0.91-1.11)
and 0.69-1.33 of the measured time where the load held still. The cost of a PARDISO iteration was
fitted a fifth time after PARDISO's Cholesky went to single precision from 5,000 unknowns (its
factorization 0.59 of the time at 60,426 unknowns): the old constants predicted 0.72-1.77 of the
measured time (1.77 for the plla mat), the new 0.75-1.38 in the next run (1.09); the growth with the
DOF is now milder (exponent 1.13 instead of 1.55). SuperLU, unchanged, keeps the fourth fit's
cost (its growing part 3 times PARDISO's then).
Newton's iteration count is the model's weakest part: a mat that stalls near yield (a free
lateral stress, shear, unloading) can take longer than predicted.

**Plan** (:class:`Plan`): n tests on w workers take about sum(t) / (w e) with the parallel
efficiency e = ``PARALLEL_EFFICIENCY`` (two workers on two cores ran ten ``plla`` tests 1.69
times faster than one, docs/performance.md), and never less than the longest test, plus
``START_S`` to start the workers.

Units: seconds, DOF counts.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

from espin.core.config import Config
from espin.geometry.size_estimate import estimate_size
from espin.mechanics.loading import load_program

__all__ = [
    "Calibration",
    "TensileCost",
    "Plan",
    "calibrate",
    "predict_test",
    "plan",
    "pool_seconds",
    "crossing_factor",
    "format_duration",
    "CALIBRATION_BUDGET_S",
    "REFERENCE_CALIBRATION",
]

log = logging.getLogger(__name__)

CALIBRATION_BUDGET_S = 2.0
"""Most wall time the speed calibration may take [s]."""
CALIBRATION_MAT = {
    "rve.size_ratio": 80.0,
    "rve.layers": 4,
    "rve.seed": 1,
    "loading.max_strain": 0.03,
    "loading.steps": 12,
}
"""The calibration's tensile test: overrides of the ``plla`` preset."""
REFERENCE_SECONDS_PER_ITERATION = 0.0084
"""Seconds per Newton iteration of the calibration test on the development machine, quiet [s]
(0.0054 before the non-monotone node relaxation: the test's 54 iterations became 35 for about
the same work, 1.55 times as dear each, docs/performance.md)."""

ITERATION_BASE = 0.20
"""Cost of one Newton iteration of a small mat [calibration iterations] (node relaxation
included)."""
ITERATION_SCALE = 1.30
"""Cost of one Newton iteration at 10^4 DOF beyond the base [calibration iterations] (node
relaxation included)."""
ITERATION_EXPONENT = 1.13
"""Growth of an iteration's cost with the DOF (factorization fill; single precision from
5,000 DOF)."""
RECORD_PER_DOF = 1.6e-4
"""Cost of one recorded step per DOF (stresses, fractions, the step's record) [calibration
iterations]."""
GENERATE_S_PER_SEGMENT = 6e-6
"""Generation and cross-linking per fiber segment at the reference speed [s]
(docs/performance.md: 4-7 us)."""
ITERATIONS_PER_SUBSTEP = 1.05
"""Newton iterations of a time step away from yield (with the non-monotone node relaxation)."""
YIELD_ITERATIONS = 68.0
"""Extra Newton iterations of the yield region at 10^4 DOF (with the non-monotone node
relaxation)."""
YIELD_EXPONENT = 0.34
"""Growth of the yield region's iterations with the DOF."""
YIELD_STRAIN_SPAN = 0.09
"""Strain by which the yield region is passed [-]."""
SUPERLU_BASE = 0.37
"""Cost of one Newton iteration of a small mat with SuperLU [calibration iterations] (the fourth
fit's PARDISO base; SuperLU was not refitted since)."""
SUPERLU_SCALE = 3.39
"""Cost of one SuperLU iteration at 10^4 DOF beyond the base [calibration iterations]: 3 times
PARDISO's growing part at the fourth fit (docs/performance.md: the plla test in 117 s against
36 s)."""
SUPERLU_EXPONENT = 1.55
"""Growth of a SuperLU iteration's cost with the DOF (factorization fill, double precision)."""
TURN_REFERENCE_DEG = {"paper": 5.0, "smooth": 8.0}
"""Fiber turns of the mats behind ``YIELD_ITERATIONS``: the paper walk's ``max_deviation_deg``
(plla: 5), the smooth walk's ``waviness_deg`` [deg]."""
TURN_EXPONENT = 0.6
"""Tortuous fibers make Newton work harder: the yield region's iterations grow as (turn /
reference turn)^0.6 (paper walk at 20 deg: 313-547 against 127-151 at 5 deg, L/D 100 with 5
layers, von Mises kappa 0.5-10), the time steps by a quarter of that growth."""
TEST_ITERATIONS = {"equibiaxial": 0.78}
"""Newton iterations of a test against the uniaxial test's on the same mat (equibiaxial: 190
against 242 on the plla mat at L/D 100 with 5 layers); tests not listed count as uniaxial."""
SUBSTEPS_PER_STRAIN = 270.0
"""Time steps per unit strain travelled with the adaptive time steps (plla: about 80 to 30 %)."""
START_S = 3.0
"""Starting the workers: Python, espin and the solver's library imported in each [s]."""
PARALLEL_EFFICIENCY = 0.85
"""Speed-up per worker of a pool (docs/performance.md: 1.69 on two workers)."""


@dataclass(frozen=True)
class Calibration:
    """This machine's speed now, from a fixed small tensile test.

    Attributes
    ----------
    seconds_per_iteration : float
        Wall time of one Newton iteration of the calibration test [s] (other jobs included).
    cpu_seconds_per_iteration : float
        Its CPU time (all threads of the process) [s].
    seconds : float
        Wall time of the calibration [s].
    iterations : int
        Newton iterations timed.
    """

    seconds_per_iteration: float
    cpu_seconds_per_iteration: float
    seconds: float
    iterations: int

    @property
    def slowness(self) -> float:
        """Wall time per iteration here over the development machine's, quiet (> 1: slower)."""
        return self.seconds_per_iteration / REFERENCE_SECONDS_PER_ITERATION


REFERENCE_CALIBRATION = Calibration(REFERENCE_SECONDS_PER_ITERATION, REFERENCE_SECONDS_PER_ITERATION, 0.0, 0)
"""The development machine's speed: predictions without calibrating (e.g. to decide whether
work is long enough to be worth a calibration)."""

_CACHE: dict[str, Calibration] = {}


class _Budget(Exception):
    """Raised from the step callback when the calibration's budget is spent."""


def calibrate(*, budget_s: float = CALIBRATION_BUDGET_S, refresh: bool = False) -> Calibration:
    """Time a fixed small tensile test and compare it with the development machine (module docs).

    The result is cached for the process; ``refresh`` measures again.

    Parameters
    ----------
    budget_s
        Most wall time to spend [s]; the test stops after a step when the next (taken as 1.5
        times the last) might overrun it.
    refresh
        Ignore the cached calibration.

    Returns
    -------
    Calibration
    """
    if not refresh and "speed" in _CACHE:
        return _CACHE["speed"]
    from threadpoolctl import threadpool_limits

    from espin.geometry.rve import generate, resolve_config
    from espin.mechanics.driver import run_program
    from espin.mechanics.linear_solvers import SuperLUSolver

    start = time.perf_counter()  # the modules above are the commands' own: not counted
    rve = generate(resolve_config("plla", **CALIBRATION_MAT))
    counted: list[tuple[float, float, int]] = []  # (time, CPU time, iterations so far) after each step

    def on_step(record) -> None:
        now = time.perf_counter()
        last = now - counted[-1][0] if counted else 0.0
        counted.append((now, time.process_time(), record.iterations + (counted[-1][2] if counted else 0)))
        if record.index > 0 and now - start + 1.5 * last > budget_s:
            raise _Budget  # the next step might not fit in the budget

    with SuperLUSolver() as linear, threadpool_limits(limits=1):
        try:
            run_program(rve.network, rve.config, linear, on_step=on_step)
        except _Budget:
            pass
    # step 0 (the first solve) warms up: time the steps after it
    (t0, c0, n0), (t1, c1, n1) = counted[0], counted[-1]
    n = max(n1 - n0, 1)
    result = Calibration((t1 - t0) / n, (c1 - c0) / n, time.perf_counter() - start, n1 - n0)
    log.debug(
        "speed calibration: %.4f s per iteration (CPU %.4f s), slowness %.2f, %.2f s",
        result.seconds_per_iteration,
        result.cpu_seconds_per_iteration,
        result.slowness,
        result.seconds,
    )
    _CACHE["speed"] = result
    return result


@dataclass(frozen=True)
class TensileCost:
    """Predicted cost of one tensile test.

    Attributes
    ----------
    dof : float
        Degrees of freedom (estimated from the config).
    steps : int
        Recorded steps of the loading program.
    substeps : float
        Time steps expected.
    iterations : float
        Newton iterations expected.
    seconds : float
        Wall time on this machine at its calibrated speed [s].
    """

    dof: float
    steps: int
    substeps: float
    iterations: float
    seconds: float


def _pardiso(linear: str) -> bool:
    """Whether ``solver.linear`` will be PARDISO (``auto``: when pypardiso is installed; its
    library is not loaded to find out)."""
    import importlib.util

    return linear == "pardiso" or (linear == "auto" and importlib.util.find_spec("pypardiso") is not None)


def crossing_factor(config: Config) -> float:
    """Cross-links of the config's fibers relative to isotropic fibers of the same length:
    E|sin(theta_1 - theta_2)| / (2 / pi) over pairs of segment directions (1 for ``uniform``).

    :func:`espin.geometry.size_estimate.estimate_size` counts the crossings of isotropic fibers,
    an upper bound for aligned mats; the DOF follow the cross-links. The segments' directions
    are the orientation distribution (``rve.orientation``) smeared by the walk: a normal of sd
    ``waviness_deg`` for the smooth walk; for the paper walk, turns uniform within
    +-``max_deviation_deg`` add up along a fiber of n = L / l_s segments, sd
    max_deviation_deg sqrt(n / 6) on average over the fiber.
    """
    import numpy as np

    from espin.geometry.orientation import UniformOrientation, orientation_distribution

    rve = config.rve
    distribution = orientation_distribution(rve.orientation)
    if isinstance(distribution, UniformOrientation):
        return 1.0
    theta = (np.arange(360) + 0.5) * np.pi / 360
    p = np.clip(distribution.pdf(theta), 0.0, None)
    if not np.isfinite(p).all() or p.sum() <= 0:
        return 1.0
    if rve.walk == "smooth":
        sd = math.radians(rve.waviness_deg or 0.0)
    else:
        sd = math.radians(rve.max_deviation_deg or 0.0) * math.sqrt(rve.side_um / rve.segment_length_um / 6.0)
    if sd > 0:
        lag = (theta - theta[0] + np.pi / 2) % np.pi - np.pi / 2  # circular lags, period pi
        kernel = sum(np.exp(-0.5 * ((lag + k * np.pi) / sd) ** 2) for k in range(-3, 4))
        p = np.real(np.fft.ifft(np.fft.fft(p) * np.fft.fft(kernel)))
    p = np.clip(p, 0.0, None)
    p = p / p.sum()
    mean_sin = float(p @ np.abs(np.sin(theta[:, None] - theta[None, :])) @ p)
    return min(1.0, mean_sin / (2.0 / np.pi))


def _strain_path(program) -> float:
    """Strain travelled by a program (sum of |changes| of its load parameter)."""
    strain = program.strain
    return float(sum(abs(b - a) for a, b in zip(strain[:-1], strain[1:])))


def predict_test(config: Config, calibration: Calibration | None = None) -> TensileCost:
    """The wall time of one tensile test of ``config`` (generation included; module docs).

    Parameters
    ----------
    config
        A validated run configuration (its loading program is read; tables are read too).
    calibration
        This machine's speed; default :func:`calibrate` (cached).

    Returns
    -------
    TensileCost
    """
    calibration = calibration or calibrate()
    size = estimate_size(config)
    dof = size.dof * crossing_factor(config)
    program = load_program(config.loading)
    steps = program.n_steps
    path = _strain_path(program)
    adaptive = config.solver.time_rtol != "off" and config.fiber.flow_rate_per_s > 0
    rve = config.rve
    turn = rve.max_deviation_deg if rve.walk == "paper" else rve.waviness_deg
    tortuous = max(1.0, (turn or 0.0) / TURN_REFERENCE_DEG[rve.walk]) ** TURN_EXPONENT
    substeps = (
        max(float(steps), SUBSTEPS_PER_STRAIN * path * (1.0 + 0.25 * (tortuous - 1.0))) if adaptive else float(steps)
    )
    plastic = tortuous * (1.0 if config.fiber.flow_rate_per_s > 0 else 0.5)
    yield_part = plastic * YIELD_ITERATIONS * (dof / 1e4) ** YIELD_EXPONENT * min(1.0, path / YIELD_STRAIN_SPAN)
    iterations = (ITERATIONS_PER_SUBSTEP * substeps + yield_part) * TEST_ITERATIONS.get(program.test, 1.0)
    x = dof / 1e4
    if _pardiso(config.solver.linear):
        per_iteration = ITERATION_BASE + ITERATION_SCALE * x**ITERATION_EXPONENT
    else:
        per_iteration = SUPERLU_BASE + SUPERLU_SCALE * x**SUPERLU_EXPONENT
    units = iterations * per_iteration + steps * RECORD_PER_DOF * dof
    seconds = calibration.seconds_per_iteration * units + calibration.slowness * GENERATE_S_PER_SEGMENT * size.segments
    return TensileCost(dof, steps, substeps, iterations, seconds)


def format_duration(seconds: float) -> str:
    """A duration rounded for a plan: ``40 s``, ``about 3 min``, ``2.5 h``, ``1.2 days``."""
    if not math.isfinite(seconds):
        return "unknown"
    if seconds < 90:
        return f"{max(1, round(seconds, -1 if seconds >= 20 else 0)):.0f} s"
    if seconds < 90 * 60:
        return f"{round(seconds / 60):.0f} min"
    if seconds < 36 * 3600:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:.1f} days"


@dataclass(frozen=True)
class Plan:
    """What a command is about to run and how long it should take here.

    Attributes
    ----------
    simulations : int
        Tensile tests.
    dof : float
        DOF of each (the mean when they differ).
    workers : int or None
        Worker processes (None: a Dask scheduler's, not known here; ``seconds`` is then the
        time on one worker).
    seconds : float
        Expected wall time of all of them [s].
    calibration_s : float
        Wall time of the speed calibration [s].
    per_test_s : float
        Expected wall time of one test alone [s] (the mean).
    max_dof : float
        DOF of the largest test.
    """

    simulations: int
    dof: float
    workers: int | None
    seconds: float
    calibration_s: float
    per_test_s: float
    max_dof: float

    def text(self) -> str:
        """One line, e.g. ``plan: 30 tensile tests x 60,146 DOF on 2 workers -> about 20 min
        (speed calibration 1.4 s)``."""
        tests = f"{self.simulations:,} tensile test{'s' * (self.simulations != 1)}"
        dof = (
            f"{self.dof:,.0f} DOF"
            if self.max_dof <= 1.05 * self.dof
            else f"{self.dof:,.0f} DOF on average (up to {self.max_dof:,.0f})"
        )
        if self.workers is None:
            where = (
                f"about {format_duration(self.seconds)} on one worker of the scheduler "
                f"({format_duration(self.per_test_s)} per test)"
            )
        else:
            where = f"{self.workers} worker{'s' * (self.workers != 1)} -> about {format_duration(self.seconds)}"
            where = "on " + where
        return f"plan: {tests} x {dof} {where} (speed calibration {self.calibration_s:.1f} s)"

    def __str__(self) -> str:
        return self.text()


def pool_seconds(seconds: Sequence[float], workers: int | None) -> float:
    """Wall time of tests of ``seconds`` [s] each on ``workers`` processes (module docs; None:
    one worker)."""
    if not seconds:
        return 0.0
    workers = max(1, min(workers or 1, len(seconds)))
    efficiency = 1.0 if workers == 1 else PARALLEL_EFFICIENCY
    return max(sum(seconds) / (workers * efficiency), max(seconds))


def plan(configs: Sequence[Config], workers: int | None, calibration: Calibration | None = None) -> Plan:
    """The plan of one tensile test per config on ``workers`` processes.

    Parameters
    ----------
    configs
        The tests' configs (one per simulation; equal configs may repeat).
    workers
        Worker processes (>= 1); None for a Dask scheduler's workers (not known here).
    calibration
        This machine's speed; default :func:`calibrate` (cached).

    Returns
    -------
    Plan
    """
    calibration = calibration or calibrate()
    cache: dict[int, TensileCost] = {}
    costs = []
    for config in configs:
        key = id(config)
        if key not in cache:
            cache[key] = predict_test(config, calibration)
        costs.append(cache[key])
    seconds = [c.seconds for c in costs]
    n = len(costs)
    mean_dof = sum(c.dof for c in costs) / n if n else 0.0
    workers = None if workers is None else max(1, int(workers))
    start = START_S * calibration.slowness if n else 0.0
    return Plan(
        n,
        mean_dof,
        workers,
        start + pool_seconds(seconds, workers),
        calibration.seconds,
        sum(seconds) / n if n else 0.0,
        max((c.dof for c in costs), default=0.0),
    )
