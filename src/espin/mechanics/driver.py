"""Pull on a virtual mat: run a loading program and record the homogenized response.

The program's steps are the recorded points of the curve, hit exactly. Each is reached in one
or more time steps (sub-steps): their size follows the local error of the plastic update
(``solver.time_rtol``, :mod:`espin.mechanics.time_steps`; a step over the tolerance is done
again, smaller), is halved when Newton does not converge (the strain rate stays the
prescribed one: time and strain are cut together) and grows after easy convergence; it is
carried from one recorded step to the next. Each sub-step starts from a predictor that
extrapolates the non-affine part of the node motion (docs/model.md sections 4, 6). With
``solver.kinematics = "affine"`` the same march places every node at F X instead
(:mod:`espin.mechanics.affine`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from espin.core.config import Config
from espin.core.errors import SolverError, StepFailureKind, StepNotConverged
from espin.core.html import html_table
from espin.geometry.network import Network
from espin.mechanics.affine import AffineSteps
from espin.mechanics.equilibrium import EquilibriumSolver, StepResult, StepState
from espin.mechanics.fiber_law import yielded
from espin.mechanics.homogenization import cauchy_stress, kirchhoff_stress, nominal_stress, paper_stress
from espin.mechanics.loading import LateralStress, LoadProgram, load_program
from espin.mechanics.march import MarchFailed, ReportTally, StepPolicy, march

__all__ = [
    "StepRecord",
    "step_record",
    "MEASURES",
    "SimulationResult",
    "SimulationFailed",
    "run_program",
    "result_from_records",
    "FREE_LATERAL_NOTE",
    "curve_columns",
    "curve_summary",
]

log = logging.getLogger(__name__)

FREE_LATERAL_NOTE = (
    "lateral = free or {stress_MPa = s}: in this 2-D network fibers resist compression only with the slack "
    "modulus E_b, so the mat contracts laterally far more than a real one, the response is "
    "governed by E_b, and equilibrium can be non-unique (compressed chains buckle). Compare "
    "the stress P, not the lateral stretch, between runs (fused crossings, "
    "fiber.fused_crossing_fraction, give the mat lateral stiffness: docs/mechanics.md)."
)


@dataclass(frozen=True, eq=False)
class StepRecord:
    """Macroscopic data of one recorded step (also passed to ``on_step`` callbacks).

    Attributes
    ----------
    index : int
        Step number (0 is the undeformed start).
    time : float [s]
    strain : float
        Load parameter of the program.
    F : (2, 2) float64
    P : (2, 2) float64 [MPa]
        Nominal (first Piola-Kirchhoff) stress.
    P_paper : (2, 2) float64 [MPa]
        Stress of the paper's Eq. 17.
    kirchhoff : (2, 2) float64 [MPa]
        Kirchhoff stress per reference volume, P F^T = det F times Cauchy.
    cauchy : (2, 2) float64 [MPa]
        In-plane Cauchy stress at unchanged thickness.
    recruited_fraction, yielded_fraction : float
        Fiber volume (A L0) fraction of recruited / yielded elements.
    iterations, factorizations, substeps : int
        Newton iterations and matrix factorizations spent on the step (failed and rejected
        attempts included), and the time steps it took.
    residual : float [uN]
        Final max |residual force| on inner nodes.
    positions : (n_nodes, 2) float64 [um]
        Node positions (relative to the RVE centre).
    stress : (n_elements,) float64 [MPa]
        Element engineering stress t.
    plastic_stretch : (n_elements,) float64
    recruited : (n_elements,) bool
    """

    index: int
    time: float
    strain: float
    F: np.ndarray
    P: np.ndarray
    P_paper: np.ndarray
    kirchhoff: np.ndarray
    cauchy: np.ndarray
    recruited_fraction: float
    yielded_fraction: float
    iterations: int
    factorizations: int
    substeps: int
    residual: float
    positions: np.ndarray
    stress: np.ndarray
    plastic_stretch: np.ndarray
    recruited: np.ndarray


_CURVE_TENSORS = (
    ("F", "F", ""),
    ("P", "P", "_MPa"),
    ("paper", "P_paper", "_MPa"),
    ("kirchhoff", "kirchhoff", "_MPa"),
    ("cauchy", "cauchy", "_MPa"),
)
"""(column prefix, SimulationResult attribute, unit suffix) of the tensors of ``curve.csv``."""
MEASURES = {"nominal": "P", "paper": "P_paper", "kirchhoff": "kirchhoff"}
"""``output.stress_measure`` -> the attribute of :class:`StepRecord` and :class:`SimulationResult`
that holds it."""
_CURVE_SCALARS = (
    ("recruited_fraction", "recruited_fraction"),
    ("yielded_fraction", "yielded_fraction"),
    ("iterations", "iterations"),
    ("factorizations", "factorizations"),
    ("substeps", "substeps"),
    ("residual_uN", "residual"),
)
"""(column, SimulationResult attribute) of the per-step scalars of ``curve.csv``, after ``stress_MPa``."""


def curve_columns(steps: Mapping[str, np.ndarray], stress: np.ndarray, first_step: int = 0) -> dict[str, np.ndarray]:
    """The columns of ``curve.csv`` (also :meth:`SimulationResult.to_dataframe`), in order.

    Parameters
    ----------
    steps
        (n,) or (n, 2, 2) arrays by :class:`SimulationResult` attribute name (``time``,
        ``strain``, ``F``, ``P``, ``P_paper``, ``kirchhoff``, ``cauchy``, ``recruited_fraction``, ...).
    stress
        (n,) curve stress [MPa] (:meth:`SimulationResult.stress`).
    first_step
        Number of the first row's step.

    Returns
    -------
    dict
        Column name -> (n,) array: ``step``, ``time_s``, ``strain``, the tensor components
        ``F11`` .. ``F22``, ``P11_MPa`` .. , ``paper11_MPa`` .., ``kirchhoff11_MPa`` ..,
        ``cauchy11_MPa`` .. (RVE
        axes), ``stress_MPa``, ``recruited_fraction``, ``yielded_fraction``, ``iterations``,
        ``factorizations``, ``substeps``, ``residual_uN``.
    """
    n = len(steps["time"])
    columns = {"step": first_step + np.arange(n), "time_s": steps["time"], "strain": steps["strain"]}
    for prefix, attr, unit in _CURVE_TENSORS:
        flat = np.asarray(steps[attr]).reshape(n, 4)
        columns |= {f"{prefix}{i}{j}{unit}": flat[:, 2 * (i - 1) + j - 1] for i in (1, 2) for j in (1, 2)}
    columns["stress_MPa"] = stress
    columns |= {name: steps[attr] for name, attr in _CURVE_SCALARS}
    return columns


def curve_summary(test: str, stress_measure: str, strain: np.ndarray, stress: np.ndarray) -> dict[str, str]:
    """Key numbers of a recorded curve as text, for the reprs of the results.

    Parameters
    ----------
    test
        The loading's test (``uniaxial``, ``simple_shear``, ...).
    stress_measure
        ``nominal``, ``paper`` or ``kirchhoff`` (``output.stress_measure``).
    strain
        (n,) load parameter of each step (step 0 undeformed).
    stress
        (n,) curve stress [MPa]: the 11 component (12 for simple shear) of the measure, in the
        loading frame.

    Returns
    -------
    dict
        ``test``; ``steps`` (step 0 not counted); ``max strain`` (the value of largest
        magnitude, signed); ``peak stress`` (likewise) and ``last stress`` with ``MPa``;
        ``stress`` (the component and measure).
    """
    symbol = {"nominal": "P", "paper": "T17", "kirchhoff": "tau"}[stress_measure]
    component = f"{symbol}'12" if test == "simple_shear" else f"{symbol}'11"
    return {
        "test": test,
        "steps": str(len(strain) - 1),
        "max strain": f"{strain[np.argmax(np.abs(strain))]:.4g}",
        "peak stress": f"{stress[np.argmax(np.abs(stress))]:.4g} MPa",
        "last stress": f"{stress[-1]:.4g} MPa",
        "stress": f"{component}, {stress_measure}",
    }


@dataclass(frozen=True, eq=False, repr=False)
class SimulationResult:
    """The recorded curve of a loading program (one row per step, step 0 undeformed).

    Attributes
    ----------
    config : Config
    program : LoadProgram
    time, strain : (n,) float64
    F, P, P_paper, kirchhoff, cauchy : (n, 2, 2) float64 (stresses MPa)
    recruited_fraction, yielded_fraction : (n,) float64
    iterations, factorizations, substeps : (n,) int64
    residual : (n,) float64 [uN]
    final : StepRecord
        The last step, with per-element state and node positions.
    """

    config: Config
    program: LoadProgram
    time: np.ndarray
    strain: np.ndarray
    F: np.ndarray
    P: np.ndarray
    P_paper: np.ndarray
    kirchhoff: np.ndarray
    cauchy: np.ndarray
    recruited_fraction: np.ndarray
    yielded_fraction: np.ndarray
    iterations: np.ndarray
    factorizations: np.ndarray
    substeps: np.ndarray
    residual: np.ndarray
    final: StepRecord

    def loading_frame(self, tensor: np.ndarray) -> np.ndarray:
        """(n, 2, 2) tensors expressed in the loading frame: R^T T R."""
        R = self.program.rotation
        return np.einsum("ji,njk,kl->nil", R, tensor, R)

    def stress(self, measure: str | None = None) -> np.ndarray:
        """(n,) stress of the curve [MPa] in the loading frame: the 11 component (12 for simple
        shear) of the measure.

        ``measure`` is ``"nominal"``, ``"paper"`` or ``"kirchhoff"`` (default:
        ``output.stress_measure``).
        """
        measure = measure or self.config.output.stress_measure
        tensor = self.loading_frame(getattr(self, MEASURES[measure]))
        return tensor[:, 0, 1] if self.program.test == "simple_shear" else tensor[:, 0, 0]

    def to_dataframe(self) -> Any:
        """The curve as a pandas DataFrame, one row per step (step 0 undeformed), with the
        columns of ``curve.csv`` (:func:`curve_columns`; stresses [MPa], time [s], residual
        [uN]); ``stress_MPa`` is :meth:`stress` of ``output.stress_measure``."""
        import pandas as pd

        steps = {
            name: getattr(self, name)
            for name in ("time", "strain", *(a for _, a, _ in _CURVE_TENSORS), *(a for _, a in _CURVE_SCALARS))
        }
        return pd.DataFrame(curve_columns(steps, self.stress()))

    def _summary(self) -> dict[str, str]:
        summary = curve_summary(self.program.test, self.config.output.stress_measure, self.strain, self.stress())
        if len(self.strain) - 1 < self.program.n_steps:
            summary["steps"] += f" of {self.program.n_steps}"
        summary["elements"] = str(len(self.final.stress))
        summary["nodes"] = str(len(self.final.positions))
        return summary

    def __repr__(self) -> str:
        """One line: test, steps, max strain, peak and last curve stress [MPa], elements, nodes."""
        s = self._summary()
        return (
            f"SimulationResult({s['test']}, {s['steps']} steps, max strain {s['max strain']}, "
            f"peak {s['peak stress']}, last {s['last stress']} ({s['stress']}), {s['elements']} elements, "
            f"{s['nodes']} nodes)"
        )

    def _repr_html_(self) -> str:
        """The key numbers as an HTML table (Jupyter)."""
        summary = self._summary()
        summary["direction"] = f"{self.config.loading.direction_deg:g} deg"
        summary["strain rate"] = f"{self.config.loading.strain_rate_per_s:.4g} 1/s"
        summary["Newton iterations"] = str(int(self.iterations.sum()))
        return html_table("SimulationResult", list(summary.items()))


def step_record(
    index: int,
    solver: EquilibriumSolver,
    result: StepResult,
    strain: float,
    counts: tuple[int, int, int] | list[int],
    threshold: float,
) -> StepRecord:
    """The :class:`StepRecord` of a converged step: homogenized stresses and fractions of the
    ``result`` of ``solver``, with (iterations, factorizations, substeps) ``counts`` and the
    yield ``threshold`` on lambda_p - 1."""
    network = solver.network
    volume = network.element_area * network.element_contour_length
    law = result.law
    is_yielded = yielded(law.plastic_stretch, threshold)
    F = result.state.F
    positions = solver.asm.positions(result.state.inner, F)
    return StepRecord(
        index=index,
        time=result.state.time,
        strain=strain,
        F=F,
        P=nominal_stress(network, result.force, result.kinematics, solver.joints, positions),
        P_paper=paper_stress(network, law.stress, result.kinematics),
        kirchhoff=kirchhoff_stress(network, result.force, result.kinematics, solver.joints, positions),
        cauchy=cauchy_stress(network, result.force, result.kinematics, F, solver.joints, positions),
        recruited_fraction=float(volume[law.recruited].sum() / volume.sum()),
        yielded_fraction=float(volume[is_yielded].sum() / volume.sum()),
        iterations=counts[0],
        factorizations=counts[1],
        substeps=counts[2],
        residual=result.residual,
        positions=positions,
        stress=law.stress,
        plastic_stretch=law.plastic_stretch,
        recruited=law.recruited,
    )


def _predict(state: StepState, previous: StepState | None, t_next: float, F_next, directions, asm, n_inner):
    """Guess of inner positions and free values at ``t_next``: the non-affine fluctuation
    w = x - F X and the free values extrapolated linearly in time from the last two states.
    The affine part uses the whole predicted F (prescribed part plus free components), so
    inner and border nodes move together under mixed control."""
    X = asm.reference[:n_inner]
    w = state.inner - X @ state.F.T
    free = state.free
    if previous is not None and state.time > previous.time:
        ratio = (t_next - state.time) / (state.time - previous.time)
        w = w + ratio * (w - (previous.inner - X @ previous.F.T))
        free = free + ratio * (free - previous.free)
    F = F_next + np.tensordot(free, directions, axes=1) if len(free) else F_next
    return X @ F.T + w, free


class _ProgramSteps:
    """A loading program on one network as a :class:`~espin.mechanics.march.StepProblem`: each
    attempt solves the equilibrium at the program's F from the predictor."""

    def __init__(self, solver: EquilibriumSolver, program: LoadProgram, lateral: LateralStress | None) -> None:
        self.solver, self.program, self.lateral = solver, program, lateral
        self.directions = program.free_directions
        self.iteration_limit = solver.iteration_limit(len(self.directions))
        F0 = program.prescribed_F(0.0)
        network = solver.network
        # the undeformed state: the first attempt is at time 0
        self.state = StepState(
            0.0,
            solver.asm.reference[: network.n_inner] @ F0.T,
            np.zeros(len(self.directions)),
            F0,
            network.initial_plastic_stretch,
            np.zeros(network.n_elements),
        )
        self.previous: StepState | None = None  # the state before, for the predictor

    def _guess(self, end: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The prescribed F at ``end`` and the predictor's inner positions and free values."""
        F_next = self.program.prescribed_F(end)
        guess_inner, guess_free = _predict(
            self.state, self.previous, end, F_next, self.directions, self.solver.asm, self.solver.n_inner
        )
        return F_next, guess_inner, guess_free

    def attempt(self, start: float, end: float) -> StepResult:
        F_next, guess_inner, guess_free = self._guess(end)
        return self.solver.solve(self.state, end, F_next, self.directions, guess_inner, guess_free, self.lateral)

    def estimate(self, start: float, end: float) -> float:
        """The step's local time error foreseen at its predictor (the march's ``estimate``;
        :meth:`~espin.mechanics.equilibrium.EquilibriumSolver.predicted_error`)."""
        F_next, guess_inner, guess_free = self._guess(end)
        return self.solver.predicted_error(
            self.state, end, F_next, self.directions, guess_inner, guess_free, self.lateral
        )

    def error(self, trial: StepResult) -> float:
        return self.solver.time_error(self.state, trial)

    def commit(self, trial: StepResult) -> None:
        self.previous, self.state = self.state, trial.state

    def rollback(self) -> None:
        pass

    def new_segment(self) -> None:
        """The next report starts a new segment (e.g. unloading): do not extrapolate across it."""
        self.previous = None


def run_program(
    network: Network,
    config: Config,
    linear_solver,
    program: LoadProgram | None = None,
    on_step: Callable[[StepRecord], None] | None = None,
) -> SimulationResult:
    """Run the configured loading program on a network.

    Parameters
    ----------
    network
        The network (reference state).
    config
        Fiber law, loading, solver and output settings.
    linear_solver
        A linear solver object (see :mod:`espin.mechanics.linear_solvers`).
    program
        Loading program; default built from ``config.loading``.
    on_step
        Called with each :class:`StepRecord` as soon as the step has converged.

    Returns
    -------
    SimulationResult

    Raises
    ------
    SimulationFailed
        When a step cannot converge even after ``solver.max_cuts`` halvings in a row; the
        message names the step, time, strain and the residual history of the last attempt,
        and ``partial`` holds the curve up to the last converged step.
    """
    program = program or load_program(config.loading)
    if program.test == "uniaxial" and len(program.free_directions) and config.fiber.fused_crossing_fraction == 0:
        log.warning(FREE_LATERAL_NOTE)
    solver = EquilibriumSolver.from_config(network, config, linear_solver)
    lateral = (
        None
        if program.lateral_stress_MPa is None
        else LateralStress(program.lateral_stress_MPa, config.output.stress_measure == "kirchhoff")
    )
    steps = (
        AffineSteps(solver, program, lateral)
        if config.solver.kinematics == "affine"
        else _ProgramSteps(solver, program, lateral)
    )
    threshold = config.output.yield_threshold
    records: list[StepRecord] = []

    def record(k: int, result: StepResult, counts: tuple[int, int, int]) -> None:
        records.append(step_record(k, solver, result, program.strain[k], counts, threshold))
        if on_step is not None:
            on_step(records[-1])

    def fail(failure: StepNotConverged, k: int, time: float, cuts: int) -> SimulationFailed:
        return SimulationFailed(
            failure,
            step=k,
            n_steps=program.n_steps,
            time=time,
            strain=program.strain_at(time),
            cuts=cuts,
            mixed=bool(len(program.free_directions)),
            partial=result_from_records(config, program, records) if records else None,
        )

    try:
        first = steps.attempt(0.0, 0.0)
    except StepNotConverged as failure:
        raise fail(failure, 0, 0.0, 0) from None
    steps.commit(first)
    record(0, first, (first.iterations, first.factorizations, 1))

    def reached(tally: ReportTally[StepResult]) -> None:
        assert tally.trial is not None
        record(tally.index, tally.trial, (tally.iterations, tally.factorizations, tally.substeps))
        if tally.index < program.n_steps and program.segment[tally.index] != program.segment[tally.index - 1]:
            steps.new_segment()

    policy = StepPolicy.from_solver(config.solver)
    try:
        estimate = steps.estimate if isinstance(steps, _ProgramSteps) else None
        march(steps, program.time[1:], policy, on_report=reached, estimate=estimate)
    except MarchFailed as stopped:
        raise fail(stopped.failure, stopped.tally.index, stopped.time, stopped.tally.cuts) from None
    return result_from_records(config, program, records)


_WHY = {
    "stalled": "the residual stalled",
    "uphill": "no step along the Newton direction lowered the potential (the tangent points uphill)",
    "inadmissible": "an iterate left the admissible states (non-finite, or the RVE inverted)",
    "singular": "the tangent could not be factorized (a part of the network without stiffness?)",
}
_TRY = {
    "stalled": "more load steps (loading.steps); where slack and compressed fibers dominate "
    "(unloading, shear) the network is nearly a mechanism, and a larger "
    "fiber.slack_modulus_MPa makes it solvable but is another model (docs/mechanics.md)",
    "uphill": "more load steps (loading.steps)",
    "inadmissible": "more load steps (loading.steps)",
    "singular": "a mat that holds together: a larger rve.volume_fraction or more rve.layers",
    "stiff": "a larger solver.time_rtol, or check fiber.flow_rate_per_s and fiber.flow_resistance_MPa "
    "(a large a_p with a small b_p makes the flow too fast to follow)",
}
_TRY_MIXED = (
    'lateral = "fixed" or {poisson_ratio = ...} (a free lateral stress is the hardest '
    "case, docs/mechanics.md), or more load steps (loading.steps)"
)


class SimulationFailed(SolverError):
    """A load step could not converge.

    ``str()`` is one line: which step, at which strain, why and what to try. :meth:`details`
    adds the residual history of the last attempt (``espin simulate`` writes it to
    ``solver.log`` in the output folder, named then in the message as ``log_path``).

    Attributes
    ----------
    step, n_steps : int
        The reported step that failed (0: the initial state) and the program's steps.
    time : float [s]
    strain : float
        Time and load parameter of the last attempt.
    cuts : int
        Halvings of the step tried.
    kind : StepFailureKind
        Why (compares equal to its name: ``"stalled"``, ``"uphill"``, ...).
    reason : str
        The last attempt's failure, in words.
    history : list of float [uN]
        Residual norms of the last attempt (of each of its solves, one after another).
    iterations : int
        Newton iterations of the last attempt.
    partial : SimulationResult or None
        The curve up to the last converged step.
    log_path : Path or None
        Where the details were written, if they were.
    """

    def __init__(
        self,
        failure: StepNotConverged,
        *,
        step: int,
        n_steps: int,
        time: float,
        strain: float,
        cuts: int,
        mixed: bool,
        partial: SimulationResult | None,
    ) -> None:
        self.step, self.n_steps, self.time, self.strain, self.cuts = step, n_steps, time, strain, cuts
        self.kind, self.reason, self.history = failure.kind, failure.reason, list(failure.history)
        self.iterations = failure.iterations
        self.advice = _TRY_MIXED if mixed and failure.kind != StepFailureKind.SINGULAR else _TRY[failure.kind]
        self.partial = partial
        self.log_path: Path | None = None
        super().__init__(self.summary())

    def summary(self) -> str:
        """The one-line message."""
        where = "the initial state" if self.step == 0 else f"step {self.step} of {self.n_steps}"
        cuts = f" after {self.cuts} cuts" if self.cuts else ""
        why = self.reason if self.kind == StepFailureKind.STIFF else _WHY[self.kind]
        if self.kind == StepFailureKind.STALLED and self.history:
            n = self.iterations
            why += (
                f" ({n} iteration{'s' * (n != 1)}; residual {self.history[-1]:.3g} uN at the end, "
                f"{min(self.history):.3g} at best)"
            )
        log_note = ""
        if self.log_path is not None:
            kept = 0 if self.partial is None else len(self.partial.time) - 1
            what = {0: "the initial state is", 1: "the converged step is"}.get(kept, f"the {kept} converged steps are")
            log_note = f"; {what} kept beside the residual history in {self.log_path}"
        return (
            f"{where} (strain {self.strain:.6g}, time {self.time:.6g} s) did not converge{cuts}: "
            f"{why}. Try {self.advice}{log_note}."
        )

    def __str__(self) -> str:
        return self.summary()

    def details(self) -> str:
        """The message, the last attempt's failure and its residual history, as log text."""
        history = "\n".join(f"{k:5d}  {r:.6e}" for k, r in enumerate(self.history))
        return (
            f"{self.summary()}\n\nlast attempt: {self.reason}\n"
            f"converged steps kept: {0 if self.partial is None else len(self.partial.time) - 1}\n\n"
            f"residual [uN] at the start and after each Newton iteration (solves one after another)\n"
            f"    k  residual\n{history}\n"
        )


def result_from_records(config: Config, program: LoadProgram, records: list[StepRecord]) -> SimulationResult:
    """The :class:`SimulationResult` of the recorded steps so far (``final`` is the last one)."""

    def stack(name: str) -> np.ndarray:
        return np.array([getattr(r, name) for r in records])

    return SimulationResult(
        config=config,
        program=program,
        time=stack("time"),
        strain=stack("strain"),
        F=stack("F"),
        P=stack("P"),
        P_paper=stack("P_paper"),
        kirchhoff=stack("kirchhoff"),
        cauchy=stack("cauchy"),
        recruited_fraction=stack("recruited_fraction"),
        yielded_fraction=stack("yielded_fraction"),
        iterations=stack("iterations").astype(np.int64),
        factorizations=stack("factorizations").astype(np.int64),
        substeps=stack("substeps").astype(np.int64),
        residual=stack("residual"),
        final=records[-1],
    )
