"""The design loop: Bayesian optimization of a microstructure against target properties.

1. **Initial design**: a scrambled Sobol' sample of the feasible unit cube (2 d + 2 points, at
   least 6), and replicates of its first point on other seeds, which measure the realization
   scatter of every property.
   The best design is replicated on the same seeds at the end.
2. **Surrogates** (:mod:`espin.design.surrogate`) of every targeted (property, direction),
   fitted to the evaluations on the search seed (common random numbers: every candidate is
   the same realization seed, so the differences between candidates are not seed noise).
3. **Proposals**: the expected improvement of the targets' objective (mean squared
   normalized error, :mod:`espin.design.targets`), estimated by Monte Carlo through the
   surrogates (fixed normal draws), maximized over a Sobol' set of feasible candidates and
   perturbations of the best points; a batch of ``batch`` proposals by the kriging believer
   (each proposal joins the data at its predicted value before the next is chosen), evaluated
   together on the task pool. Proposals depend only on the evaluations sorted by id, so a
   run gives the same designs with any number of workers, and a rerun in the same folder
   repeats no tensile test (finished tests are read back from ``runs/tasks``).
4. Until the best design, on its search seed, is within half of every tolerance
   (:data:`STOP_FRACTION`) with room left for one sd of the scatter between seeds (measured by
   the replicates), or the budget of tensile tests is spent. The best is the evaluated design
   with the least objective predicted by the surrogates (noise-aware, not the luckiest
   evaluation); it is then **verified** on fresh seeds the search never used, against its 95 %
   prediction interval.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from espin.core.config import Config
from espin.core.errors import ConfigError, SolverError
from espin.core.parallel import TaskPlace
from espin.design.surrogate import PropertySurrogate, fit_surrogate
from espin.design.targets import STRESS_AT, CurveTarget, DesignTargets, Target, parse_targets
from espin.design.variables import Constraint, DesignSpace, DesignVariable
from espin.geometry.rve import resolve_config
from espin.studies.ensemble import TensileTask, plan_tasks, run_ensemble

Output = tuple[str, float]
"""(property or ``stress_at_<strain>``, loading direction [deg])."""

__all__ = ["Evaluation", "DesignRun", "DesignProblem", "prepare_design", "run_design", "MC_DRAWS", "CANDIDATES", "Z_95"]

log = logging.getLogger(__name__)

MC_DRAWS = 256
"""Monte Carlo draws of the surrogates per candidate (expected improvement, prediction intervals)."""
CANDIDATES = 1024
"""Sobol' candidates per proposal (plus 128 perturbations of each of the three best points)."""
Z_95 = 1.959963984540054
"""Two-sided 95 % normal quantile."""
STOP_FRACTION = 0.5
"""The search stops early only when the best design, on its search seed, is within this fraction
of every tolerance (and within it with one sd of the seed scatter added): the fresh seeds' mean
differs from one seed's mat by the realization scatter, so stopping at the tolerance's edge
often missed it (benchmarks/bench_design.py)."""
MIN_SEPARATION = 0.02
"""Least distance in the unit cube between a proposal and any evaluated or proposed design (a
closer one repeats a mat that differs by a fiber or none)."""
VERIFY_SEED_OFFSET = 100_000
"""Verification seeds start this far above the search seed (never used by the search)."""


@dataclass
class Evaluation:
    """One design evaluated on one seed in every direction the targets need.

    Attributes
    ----------
    id : int
        Order of proposal (0, 1, ...).
    stage : str
        ``initial``, ``replicate``, ``search`` or ``verify``.
    unit : (d,) float64
        Point in the unit cube.
    values : dict
        Variable key -> value.
    seed : int
        ``rve.seed`` of the realization.
    outputs : dict
        (property, direction) -> value; NaN where the curve has none (no yield) or a test failed.
    seconds : float [s]
        Wall time of its tensile tests (summed over directions).
    error : str
        Why a test failed, else empty.
    curves : dict
        direction -> (strain, stress [MPa]) of its tests.
    """

    id: int
    stage: str
    unit: np.ndarray
    values: dict[str, float]
    seed: int
    outputs: dict[tuple[str, float], float] = field(default_factory=dict)
    seconds: float = 0.0
    error: str = ""
    curves: dict[float, tuple[list[float], list[float]]] = field(default_factory=dict)

    def output_array(self, outputs: Sequence[tuple[str, float]]) -> np.ndarray:
        """The outputs in the given order (NaN where missing)."""
        return np.array([self.outputs.get(o, math.nan) for o in outputs], dtype=float)


@dataclass
class DesignRun:
    """Everything the loop produced; :mod:`espin.design.result` turns it into a report."""

    targets: DesignTargets
    space: DesignSpace
    evaluations: list[Evaluation]
    surrogates: dict[tuple[str, float], PropertySurrogate]
    best: Evaluation
    realization_sd: dict[tuple[str, float], tuple[float, int]]
    verification: list[Evaluation]
    tests: int
    budget: int
    checks: int
    """Tests of the final replicates and the verification (not in the budget)."""
    seconds: float
    met: bool
    folder: Path | None
    realizations: int = 1
    """Seeds each searched design ran on (the surrogates model their mean)."""


def _sobol(d: int, n: int, seed: int) -> np.ndarray:
    from scipy.stats import qmc

    m = max(int(math.ceil(math.log2(max(n, 2)))), 1)
    return qmc.Sobol(d, scramble=True, seed=seed).random_base2(m)[:n]


def _snap(space: DesignSpace, unit: np.ndarray) -> np.ndarray:
    """Unit points of the values actually used (integers rounded)."""
    unit = np.clip(np.atleast_2d(unit), 0.0, 1.0).copy()
    for j, v in enumerate(space.variables):
        if v.integer:
            unit[:, j] = v.unit(v.value(unit[:, j]))
    return unit


def _tasks(space: DesignSpace, directions: Sequence[float], evaluation: Evaluation) -> list[TensileTask]:
    overrides = space.overrides(evaluation.values)
    return [
        task
        for direction in directions
        for task in plan_tasks(space.base, [overrides | {"loading.direction_deg": float(direction)}], [evaluation.seed])
    ]


Evaluator = Callable[[DesignSpace, DesignTargets, Sequence[Evaluation], Path | None, TaskPlace], None]
"""Fills the outputs of evaluations: (space, targets, evaluations, folder, where tasks run) -> None."""


def _evaluate(
    space: DesignSpace, targets: DesignTargets, evaluations: Sequence[Evaluation], folder: Path | None, place: TaskPlace
) -> None:
    """Run the tensile tests of ``evaluations`` (every direction) together and fill their outputs."""
    directions = targets.directions
    planned = [
        (evaluation, direction, task)
        for evaluation in evaluations
        for direction, task in zip(directions, _tasks(space, directions, evaluation))
    ]
    unique = list({task.key: task for _, _, task in planned}.values())
    # no bar per batch: the design shows its own progress (espin.design.design)
    ensemble = run_ensemble(
        unique, None if folder is None else folder / "runs", place=place, on_outcome=lambda outcome, task: None
    )
    records = {r["key"]: r for r in ensemble.records}
    failures = {f["key"]: f for f in ensemble.failures}
    for evaluation, direction, task in planned:
        record = records.get(task.key)
        if record is None:
            evaluation.error = str(failures.get(task.key, {}).get("error", "the tensile test failed"))
            for name, d in targets.outputs:
                if d == direction:
                    evaluation.outputs[(name, d)] = math.nan
            continue
        evaluation.seconds += float(record.get("seconds") or 0.0)
        evaluation.curves[direction] = (record["strain"], record["stress_MPa"])
        for name, d in targets.outputs:
            if d == direction:
                evaluation.outputs[(name, d)] = _output(record, name)


def _output(record: Mapping[str, Any], name: str) -> float:
    """An output of a tensile test's record: a property, or the stress at a strain (a curve target's)."""
    if name.startswith(STRESS_AT):
        strain, stress = np.asarray(record["strain"]), np.asarray(record["stress_MPa"])
        at = float(name.removeprefix(STRESS_AT))
        return float(np.interp(at, strain, stress)) if at <= strain.max() * (1 + 1e-9) else math.nan
    value = record.get(name)
    return math.nan if value is None else float(value)


def _designs(targets: DesignTargets, evaluations: Sequence[Evaluation]) -> list[Evaluation]:
    """The searched designs in id order, each with its outputs averaged over its search seeds
    (geometric mean of positive values; ``realizations`` seeds per design), as an evaluation
    carrying the id, stage and seed of its first."""
    groups: dict[bytes, list[Evaluation]] = {}
    for e in sorted(evaluations, key=lambda e: e.id):
        if e.stage in ("initial", "search"):
            groups.setdefault(np.round(e.unit, 12).tobytes(), []).append(e)
    out = []
    for group in groups.values():
        first = group[0]
        if len(group) == 1:
            out.append(first)
            continue
        means = {}
        for output in targets.outputs:
            values = np.array([e.outputs.get(output, math.nan) for e in group], dtype=float)
            values = values[np.isfinite(values)]
            if len(values) == 0:
                means[output] = math.nan
            elif np.all(values > 0):
                means[output] = float(np.exp(np.mean(np.log(values))))
            else:
                means[output] = float(np.mean(values))
        out.append(
            Evaluation(
                first.id,
                first.stage,
                first.unit,
                dict(first.values),
                first.seed,
                means,
                sum(e.seconds for e in group),
                "; ".join(e.error for e in group if e.error),
                dict(first.curves),
            )
        )
    return out


def _fit(targets: DesignTargets, evaluations: Sequence[Evaluation], seed: int) -> dict[Output, PropertySurrogate]:
    """Surrogates of every output from the searched designs (their seed means), in id order."""
    usable = _designs(targets, evaluations)
    surrogates = {}
    for output in targets.outputs:
        rows = [(e.unit, e.outputs.get(output, math.nan)) for e in usable]
        rows = [(u, y) for u, y in rows if math.isfinite(y)]
        if len(rows) < 3:
            failed = [e.error for e in evaluations if e.error]
            why = (
                f"{len(failed)} tensile tests failed, the first: {failed[0]}"
                if failed
                else "the curves show no such property (no yield?)"
            )
            raise SolverError(
                f"design: only {len(rows)} designs give {output[0]} at {output[1]:g} deg: {why}; "
                "narrow the bounds, or see the tests' errors in the folder's runs/failed/"
            )
        surrogates[output] = fit_surrogate(np.array([u for u, _ in rows]), np.array([y for _, y in rows]), seed=seed)
    return surrogates


def _draws(n_outputs: int, seed: int) -> np.ndarray:
    """Fixed standard normal draws (MC_DRAWS, n_outputs)."""
    return np.random.default_rng([seed, 7]).standard_normal((MC_DRAWS, n_outputs))


def _objective_samples(
    targets: DesignTargets, surrogates: Mapping[tuple[str, float], PropertySurrogate], unit: np.ndarray, z: np.ndarray
) -> np.ndarray:
    """Objective draws (n, MC_DRAWS) at the rows of ``unit`` through the surrogates' latent sd."""
    props = {}
    for j, output in enumerate(targets.outputs):
        mean, sd = surrogates[output].predict(unit)
        props[output] = surrogates[output].to_property(mean[:, None] + sd[:, None] * z[None, :, j])
    return targets.objective(props)


def predicted_objective(
    targets: DesignTargets, surrogates: Mapping[tuple[str, float], PropertySurrogate], unit: np.ndarray
) -> np.ndarray:
    """The objective of the surrogates' median properties at the rows of ``unit``."""
    return targets.objective({o: surrogates[o].median(unit) for o in targets.outputs})


def _candidates(space: DesignSpace, best: np.ndarray, seed: int) -> np.ndarray:
    rng = np.random.default_rng([seed, 11])
    local = [np.clip(b + rng.normal(0.0, 0.05, (128, space.dimension)), 0.0, 1.0) for b in best]
    unit = _snap(space, np.vstack([_sobol(space.dimension, CANDIDATES, seed), *local]))
    return unit[space.feasible(unit)]


def _believed(surrogates: dict[Output, PropertySurrogate], x: np.ndarray) -> dict[Output, PropertySurrogate]:
    """The surrogates with ``x`` added at its predicted mean, hyperparameters kept (kriging believer)."""
    from sklearn.gaussian_process import GaussianProcessRegressor

    out = {}
    for output, s in surrogates.items():
        model = s.model
        X = np.vstack([model.X_train_, x[None, :]])
        y_train = model.y_train_ * model._y_train_std + model._y_train_mean
        y = np.append(y_train, model.predict(x[None, :]))
        refit = GaussianProcessRegressor(model.kernel_, optimizer=None, normalize_y=True).fit(X, y)
        out[output] = PropertySurrogate(refit, s.log, s.noise_sd)
    return out


def _propose(
    space: DesignSpace,
    targets: DesignTargets,
    evaluations: Sequence[Evaluation],
    surrogates: dict[tuple[str, float], PropertySurrogate],
    batch: int,
    seed: int,
) -> list[np.ndarray]:
    """``batch`` proposals by expected improvement with the kriging believer."""
    evaluated = np.array([e.unit for e in _designs(targets, evaluations)])
    z = _draws(len(targets.outputs), seed)
    proposals: list[np.ndarray] = []
    current = surrogates
    for k in range(batch):
        # the believed proposals count as data: no improvement is expected right beside them
        known = np.vstack([evaluated, *proposals]) if proposals else evaluated
        incumbent = predicted_objective(targets, current, known)
        order = np.argsort(incumbent[: len(evaluated)], kind="stable")[:3]
        candidates = _candidates(space, evaluated[order], seed * 1000 + k)
        taken = np.vstack([evaluated, *proposals]) if proposals else evaluated
        distance = np.min(np.linalg.norm(candidates[:, None, :] - taken[None, :, :], axis=-1), axis=1)
        candidates = candidates[distance > MIN_SEPARATION]
        if len(candidates) == 0:
            break
        samples = _objective_samples(targets, current, candidates, z)
        improvement = np.maximum(incumbent.min() - samples, 0.0).mean(axis=1)
        pick = int(np.argmax(improvement)) if improvement.max() > 0.0 else int(np.argmin(samples.mean(axis=1)))
        proposals.append(candidates[pick])
        if k + 1 < batch:
            current = _believed(current, candidates[pick])
    return proposals


def _initial(space: DesignSpace, n: int, seed: int) -> np.ndarray:
    draw = _snap(space, _sobol(space.dimension, 4096, seed))
    feasible = draw[space.feasible(draw)]
    if len(feasible) == 0:
        raise ConfigError(
            "constraints: no point inside the variables' bounds meets them ("
            + ", ".join(map(str, space.constraints))
            + "); widen the bounds or relax a constraint"
        )
    unique = np.unique(feasible, axis=0, return_index=True)[1]
    return feasible[np.sort(unique)][:n]


def _realization_sd(targets: DesignTargets, evaluations: Sequence[Evaluation]) -> dict[Output, tuple[float, int]]:
    """Pooled sd of each output over the replicate groups (a design on several seeds: the first
    initial design and the best), in the surrogates' scale (log: relative), with its degrees of
    freedom."""
    groups: dict[bytes, dict[int, Evaluation]] = {}
    for e in evaluations:  # one realization per (design, seed)
        if e.stage in ("initial", "search", "replicate"):
            groups.setdefault(np.round(e.unit, 12).tobytes(), {}).setdefault(e.seed, e)
    out = {}
    for output in targets.outputs:
        squares, dof = 0.0, 0
        for group in groups.values():
            values = np.array([e.outputs.get(output, math.nan) for e in group.values()], dtype=float)
            values = values[np.isfinite(values)]
            if len(values) < 2:
                continue
            scaled = np.log(values) if np.all(values > 0) else values
            squares += float(np.sum((scaled - scaled.mean()) ** 2))
            dof += len(values) - 1
        out[output] = (math.sqrt(squares / dof) if dof else math.nan, dof)
    return out


@dataclass(frozen=True)
class DesignProblem:
    """A design's checked inputs: its targets, its space (base config, variables, constraints)
    and its initial designs (unit-cube points)."""

    targets: DesignTargets
    space: DesignSpace
    first: np.ndarray
    realizations: int = 1


def _count(name: str, value: Any, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ConfigError(f"{name}: an integer >= {low} (got {value!r})")
    return int(value)


def prepare_design(
    targets: Iterable[str | Target] | Mapping[str, float] | DesignTargets,
    variables: Iterable[str | tuple[str, float, float] | DesignVariable] | Mapping[str, tuple[float, float]],
    *,
    base: Config | str | Path | None = "plla",
    constraints: Iterable[str | Constraint] = (),
    budget: int = 60,
    batch: int = 2,
    initial: int | None = None,
    replicates: int = 3,
    verify: int = 5,
    seed: int = 0,
    realizations: int = 1,
    **overrides: Any,
) -> DesignProblem:
    """Check every input of a design (the parameters of :func:`espin.design.design`) before
    any work or any file: the targets, the base config's loading, the variables' bounds, the
    constraints (some initial designs must meet them), the counts and the budget.

    Raises
    ------
    ConfigError
        Naming the input and what is allowed.
    """
    targets = parse_targets(targets)
    base = resolve_config(base, **overrides)
    if base.loading.test != "uniaxial" or base.loading.program is not None:
        raise ConfigError(
            "design: the targets are properties of a uniaxial tensile test; the base config's "
            f"loading must be loading.test = 'uniaxial' without a program (got {base.loading.test!r})"
        )
    for target in targets.targets:
        if target.name == "yield_strain" and target.value * (1 + target.tolerance) >= base.loading.max_strain:
            raise ConfigError(
                f"target yield_strain {target.value:g}: the tests stop at loading.max_strain = "
                f"{base.loading.max_strain:g}, before such a yield could show; raise loading.max_strain "
                "to a few times the target"
            )
        if isinstance(target, CurveTarget) and max(target.strain) > base.loading.max_strain * (1 + 1e-9):
            raise ConfigError(
                f"curve target {target.source}: it reaches strain {max(target.strain):g} but the tests "
                f"stop at loading.max_strain = {base.loading.max_strain:g}; raise it "
                f"(--set loading.max_strain={max(target.strain):g}) or narrow the curve's strain range"
            )
    space = DesignSpace.build(base, variables, constraints)
    budget, batch = _count("budget", budget, 1), _count("batch", batch, 1)
    replicates, verify, seed = _count("replicates", replicates, 2), _count("verify", verify, 2), _count("seed", seed, 0)
    n_initial = max(2 * space.dimension + 2, 6) if initial is None else _count("initial", initial, 3)
    n_dir = len(targets.directions)
    realizations = _count("realizations", realizations, 1)
    needed = (n_initial * realizations + replicates - 1) * n_dir
    if budget < needed + n_dir * realizations:
        raise ConfigError(
            f"budget: {budget} tensile tests cannot hold the initial design ({n_initial} designs x "
            f"{realizations} realization(s) + {replicates - 1} replicates) x {n_dir} direction(s) = "
            f"{needed} tests and one proposal; give at least {needed + n_dir * realizations}"
        )
    first = _initial(space, n_initial, seed)
    if len(first) < 3:
        what = "bounds and constraints leave" if space.constraints else "bounds leave"
        raise ConfigError(
            f"variables: the {what} only {len(first)} distinct design(s) (integer keys such as layers "
            "are rounded); widen the bounds" + (" or relax a constraint" if space.constraints else "")
        )
    return DesignProblem(targets, space, first, realizations)


def run_design(
    targets: Iterable[str | Target] | Mapping[str, float] | DesignTargets,
    variables: Iterable[str | tuple[str, float, float] | DesignVariable] | Mapping[str, tuple[float, float]],
    *,
    base: Config | str | Path | None = "plla",
    constraints: Iterable[str | Constraint] = (),
    budget: int = 60,
    batch: int = 2,
    initial: int | None = None,
    replicates: int = 3,
    verify: int = 5,
    seed: int = 0,
    realizations: int = 1,
    folder: str | Path | None = None,
    place: TaskPlace | None = None,
    on_batch: Callable[[list[Evaluation], Evaluation], None] | None = None,
    evaluator: Evaluator | None = None,
    **overrides: Any,
) -> DesignRun:
    """Run the design loop (module docstring); :func:`espin.design.design` is the public entry.

    Parameters are those of :func:`espin.design.design`; ``place`` is where the tensile tests
    run (:class:`espin.core.parallel.TaskPlace`). ``evaluator`` replaces
    the tensile tests (it fills the outputs of the evaluations it is given; e.g. a known
    function to check the optimizer).
    """
    start = time.perf_counter()
    problem = prepare_design(
        targets,
        variables,
        base=base,
        constraints=constraints,
        budget=budget,
        batch=batch,
        initial=initial,
        replicates=replicates,
        verify=verify,
        seed=seed,
        realizations=realizations,
        **overrides,
    )
    targets, space, base, first = problem.targets, problem.space, problem.space.base, problem.first
    n_dir = len(targets.directions)
    cost = n_dir * realizations  # tensile tests per proposed design
    place = place or TaskPlace()
    folder = None if folder is None else Path(folder)
    evaluate = evaluator or _evaluate
    search_seed = base.rve.seed
    evaluations: list[Evaluation] = []

    def new(stage: str, unit: np.ndarray, seed_: int) -> Evaluation:
        evaluation = Evaluation(len(evaluations), stage, unit, space.values(unit), seed_)
        evaluations.append(evaluation)
        return evaluation

    seeds = [search_seed + k for k in range(realizations)]  # every design on the same seeds
    spare = search_seed + realizations - 1  # replicate seeds come after the search seeds
    batch_ = [new("initial", u, s) for u in first for s in seeds]
    batch_ += [new("replicate", first[0], spare + k) for k in range(1, replicates)]
    evaluate(space, targets, batch_, folder, place)
    tests = len(batch_) * n_dir
    surrogates = _fit(targets, evaluations, seed)
    best = _best(targets, evaluations, surrogates)
    if on_batch is not None:
        on_batch(batch_, best)
    round_ = 1
    scatter = _realization_sd(targets, evaluations)  # from the first design's replicates
    while not _confident(targets, best, scatter, realizations) and tests + cost <= budget:
        q = min(batch, (budget - tests) // cost)
        proposals = _propose(space, targets, evaluations, surrogates, q, seed + round_)
        if not proposals:
            log.info("design: no new candidate left to propose")
            break
        batch_ = [new("search", u, s) for u in proposals for s in seeds]
        evaluate(space, targets, batch_, folder, place)
        tests += len(batch_) * n_dir
        surrogates = _fit(targets, evaluations, seed)
        best = _best(targets, evaluations, surrogates)
        round_ += 1
        if on_batch is not None:
            on_batch(batch_, best)
    # Replicates at the best design too: the realization scatter varies over the design space
    # (a sparse mat scatters more), and the prediction interval is for this design.
    # seeds the first design's replicates did not use: the best may be that design
    again = [new("replicate", best.unit, spare + replicates - 1 + k) for k in range(1, replicates)]
    evaluate(space, targets, again, folder, place)
    sd = _realization_sd(targets, evaluations)
    verification = [
        Evaluation(len(evaluations) + k, "verify", best.unit, dict(best.values), search_seed + VERIFY_SEED_OFFSET + k)
        for k in range(verify)
    ]
    evaluate(space, targets, verification, folder, place)
    checks = (len(again) + len(verification)) * n_dir
    return DesignRun(
        targets,
        space,
        evaluations,
        surrogates,
        best,
        sd,
        verification,
        tests,
        budget,
        checks,
        time.perf_counter() - start,
        _meets(targets, best),
        folder,
        realizations,
    )


def _best(
    targets: DesignTargets, evaluations: Sequence[Evaluation], surrogates: Mapping[tuple[str, float], PropertySurrogate]
) -> Evaluation:
    """The searched design whose surrogate-predicted objective is least (ties: lowest id), with
    its seed-mean outputs."""
    usable = [e for e in _designs(targets, evaluations) if np.all(np.isfinite(e.output_array(targets.outputs)))]
    if not usable:
        raise SolverError(
            "design: no evaluated design gave every targeted property; the curves show no yield or "
            "the tests fail in this design space: narrow the bounds"
        )
    predicted = predicted_objective(targets, surrogates, np.array([e.unit for e in usable]))
    return usable[int(np.argmin(predicted))]


def _target_scatter(target: Any, scatter: Mapping[Output, tuple[float, int]]) -> float:
    """Relative sd between seeds of a target's quantity (a ratio: of both its moduli; a curve:
    not estimated, 0)."""
    if isinstance(target, CurveTarget):
        return 0.0
    sds = [scatter.get(o, (math.nan, 0))[0] for o in target.outputs]
    return math.sqrt(sum(s * s for s in sds if math.isfinite(s)))


def _confident(
    targets: DesignTargets, best: Evaluation, scatter: Mapping[Output, tuple[float, int]], realizations: int = 1
) -> bool:
    """Whether the search may stop: the best design's own errors within :data:`STOP_FRACTION`
    of every tolerance and, with one sd of the scatter between seeds added, within the
    tolerance (a target that scatters by more than its tolerance never stops the search early)."""
    props = {o: np.array(best.outputs.get(o, math.nan)) for o in targets.outputs}
    for target in targets.targets:
        error = abs(float(target.error(props)))
        spread = _target_scatter(target, scatter) / math.sqrt(realizations)  # of the design's seed mean
        if not (math.isfinite(error) and error <= STOP_FRACTION and error + spread / target.tolerance <= 1.0):
            return False
    return True


def _meets(targets: DesignTargets, evaluation: Evaluation, fraction: float = 1.0) -> bool:
    """Whether an evaluation's own outputs meet every target within ``fraction`` of its tolerance."""
    props = {o: np.array(evaluation.outputs.get(o, math.nan)) for o in targets.outputs}
    errors = targets.errors(props)
    return bool(np.all(np.isfinite(errors)) and np.all(np.abs(errors) <= fraction))
