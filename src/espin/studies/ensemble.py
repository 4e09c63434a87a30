"""Ensembles of tensile tests: many RVE realizations and parameter points, run in parallel.

Each task generates one RVE (a config and a seed), pulls on it and extracts the curve's
properties (:mod:`espin.analysis.properties`). Tasks run through :class:`espin.core.parallel.TaskPool`
(local processes, or a Dask cluster). With a results folder, every finished task is written at
once to ``tasks/<key>.json`` (atomically), so a crash or a killed job loses nothing that was
finished, and a rerun skips those tasks; the key is a hash of the task's whole resolved
config and of the bytes of every file it references (``loading.path_csv``,
``loading.lateral.transverse_csv``), so a changed setting or an edited input file is a new task.
A task file that is not a complete record of its task is run again. A task that fails is
written to ``failed/<key>.json`` with its parameters, seed and traceback, and is tried again on
a rerun. ``results.csv`` (one row per task: parameters, seed, properties) is rewritten after
every task. A rerun first removes the temporary files of atomic writes that an interrupted run
left behind; two runs in one folder at the same time are not supported.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import re
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from espin.core.atomic import atomic_write, atomic_write_bytes
from espin.core.config import Config, config_digest, dotted_overrides
from espin.core.errors import ConfigError
from espin.core.parallel import TaskOutcome, TaskPlace
from espin.geometry.size_estimate import check_size

__all__ = ["TensileTask", "plan_tasks", "run_tensile", "run_ensemble", "Ensemble", "PROPERTIES"]

log = logging.getLogger(__name__)

PROPERTIES = ("modulus_MPa", "yield_stress_MPa", "post_yield_modulus_MPa", "yield_strain")
"""Curve properties tabulated for every task (see :func:`espin.analysis.properties.curve_properties`)."""


@dataclass(frozen=True)
class TensileTask:
    """One tensile test of one RVE realization.

    Attributes
    ----------
    key : str
        Hash of the resolved config (seed included) and of the files it references: the
        task's identity on disk.
    parameters : dict
        The dotted config keys this task sets (its point of a sweep), without the seed.
    seed : int
        ``rve.seed`` of the realization.
    config : Config
        The resolved configuration of the run.
    """

    key: str
    parameters: dict[str, Any]
    seed: int
    config: Config
    allow_large: bool = False


MAX_TASKS = 100_000
"""Most tasks one study plans (each is a whole tensile test)."""


def plan_tasks(
    base: Config, points: Sequence[Mapping[str, Any]], seeds: Sequence[int], *, allow_large: bool = False
) -> list[TensileTask]:
    """Every (point, seed) task, each config validated before any work starts.

    Parameters
    ----------
    base
        The configuration every task starts from.
    points
        Dotted-key overrides, one mapping per parameter point (``[{}]`` for a plain ensemble).
    seeds
        RVE seeds: the realizations of each point (the same seeds at every point: common
        random numbers).
    allow_large
        Plan (and run) mats whose tensile test is estimated to need more memory than is
        available on this machine.

    Raises
    ------
    ConfigError
        Naming the point whose values are invalid or whose mat is too sparse or too large for
        the memory available (:func:`espin.geometry.size_estimate.check_size`), the config key
        and path of a referenced file that is missing or unreadable, or a study of more than
        :data:`MAX_TASKS` tasks.
    """
    from espin.core.config import apply_overrides

    if not seeds:
        raise ConfigError("realizations: at least one seed is needed")
    if len(set(seeds)) != len(seeds):
        raise ConfigError(f"seeds: must be distinct (got {list(seeds)})")
    if len(points) * len(seeds) > MAX_TASKS:
        raise ConfigError(
            f"grid and realizations: {len(points):,} points x {len(seeds):,} seeds = "
            f"{len(points) * len(seeds):,} tasks, more than {MAX_TASKS:,}; split the study"
        )
    tasks: list[TensileTask] = []
    digests: dict[Path, str] = {}
    for point in points:
        if "rve.seed" in point:
            raise ConfigError("rve.seed: set the realizations' seeds with seeds / --realizations, not in the grid")
        for seed in seeds:
            try:
                config = apply_overrides(base, {**point, "rve.seed": int(seed)})
                if seed == seeds[0]:  # the mat's size does not depend on its seed
                    check_size(config, allow_large=allow_large)
            except ConfigError as err:
                raise ConfigError(f"parameter point {dict(point)}: {err}") from None
            key = config_digest(config, digests)[:16]
            tasks.append(TensileTask(key, dict(point), int(seed), config, allow_large))
    keys = [t.key for t in tasks]
    if len(set(keys)) != len(keys):
        raise ConfigError("grid: two parameter points give the same configuration (repeated values?)")
    return tasks


def run_tensile(task: TensileTask) -> dict[str, Any]:
    """Generate the task's RVE, pull on it and return its record (runs in a worker).

    Returns
    -------
    dict
        ``key``, ``parameters``, ``seed``, the properties of :data:`PROPERTIES` (None where
        the curve has none), ``has_yield``, ``r_squared`` and ``note`` of the bilinear fit,
        ``n_dof``, ``n_fibers``, ``n_crosslinks``, ``iterations``, ``seconds``
        and the curve (``strain``, ``stress_MPa``: the configured stress measure along the
        loading axis).
    """
    from espin.analysis.properties import CurveError, curve_properties
    from espin.geometry.rve import generate
    from espin.mechanics.run import simulate

    start = time.perf_counter()
    rve = generate(task.config, allow_large=task.allow_large)
    result = simulate(rve, progress=False)  # the ensemble shows its own progress
    strain, stress = np.asarray(result.strain), np.asarray(result.stress())
    try:
        props = curve_properties(strain, stress)
        values = {name: _json_float(getattr(props, name)) for name in PROPERTIES}
        has_yield, r_squared, note = bool(props.has_yield), _json_float(props.r_squared), props.note
    except CurveError as err:  # e.g. a loading program that unloads: the curve is kept
        values, has_yield, r_squared, note = dict.fromkeys(PROPERTIES), False, None, f"no properties: {err}"
    return {
        "key": task.key,
        "parameters": task.parameters,
        "seed": task.seed,
        **values,
        "has_yield": has_yield,
        "r_squared": r_squared,
        "note": note,
        "n_dof": int(rve.network.n_dof),
        "n_fibers": int(rve.mat.n_fibers),
        "n_crosslinks": int(rve.crosslinks.n),
        "iterations": int(np.sum(result.iterations)),
        "seconds": time.perf_counter() - start,
        "strain": strain.tolist(),
        "stress_MPa": stress.tolist(),
    }


@dataclass
class Ensemble:
    """Records of finished tasks and the failures of an ensemble run.

    Attributes
    ----------
    records : list of dict
        One per finished task (see :func:`run_tensile`), in planned order.
    failures : list of dict
        ``key``, ``parameters``, ``seed``, ``error`` and ``traceback`` of each failed task.
    parameter_names : list of str
        The dotted keys that vary between points.
    skipped : int
        Tasks found finished in the results folder and not run again.
    unplanned : int
        Finished tasks in the folder that belong to other settings (kept on disk, not used).
    folder : Path or None
        Where the results were written.
    """

    records: list[dict[str, Any]]
    failures: list[dict[str, Any]] = field(default_factory=list)
    parameter_names: list[str] = field(default_factory=list)
    skipped: int = 0
    unplanned: int = 0
    folder: Path | None = None

    def table(self) -> pd.DataFrame:
        """One row per finished task: parameters, seed, properties, size and cost."""
        rows = []
        for record in self.records:
            row = {name: record["parameters"].get(name) for name in self.parameter_names}
            row.update({k: v for k, v in record.items() if k not in ("parameters", "strain", "stress_MPa")})
            rows.append(row)
        columns = [
            *self.parameter_names,
            "seed",
            *PROPERTIES,
            "has_yield",
            "r_squared",
            "note",
            "n_dof",
            "n_fibers",
            "n_crosslinks",
            "iterations",
            "seconds",
            "key",
        ]
        return pd.DataFrame(rows, columns=columns)

    def summary(self) -> pd.DataFrame:
        """Per parameter point: number of realizations, mean, sd and RSD of each property.

        The sd is the sample standard deviation (ddof = 1); RSD = sd / |mean|. A curve without
        a clear yield has NaN yield properties, which are left out of their statistics
        (``n_yield`` counts the curves that have them).
        """
        table = self.table()
        groups = table.groupby(self.parameter_names, sort=True) if self.parameter_names else [((), table)]
        rows = []
        for point, group in groups:
            point = point if isinstance(point, tuple) else (point,)
            row: dict[str, Any] = dict(zip(self.parameter_names, point))
            row["n"] = len(group)
            row["n_yield"] = int(group["has_yield"].sum())
            for name in PROPERTIES:
                values = group[name].to_numpy(dtype=float)
                values = values[np.isfinite(values)]
                mean = float(values.mean()) if values.size else np.nan
                sd = float(values.std(ddof=1)) if values.size > 1 else np.nan
                row[f"{name}_mean"] = mean
                row[f"{name}_sd"] = sd
                row[f"{name}_rsd"] = sd / abs(mean) if values.size > 1 and mean != 0 else np.nan
            rows.append(row)
        return pd.DataFrame(rows)

    def curves(self, **point: Any) -> tuple[np.ndarray, np.ndarray]:
        """Strain and the stacked stress curves of the tasks at one parameter point.

        Keyword names are the parameter names with dots replaced by ``__`` (or the dotted names
        through ``**{...}``). Curves are interpolated onto the strain of the first one (they
        share it when the loading is the same).
        """
        wanted = dotted_overrides(point)
        chosen = [r for r in self.records if all(r["parameters"].get(k) == v for k, v in wanted.items())]
        if not chosen:
            raise KeyError(f"no finished task at {wanted}")
        strain = np.asarray(chosen[0]["strain"])
        stress = np.array([np.interp(strain, r["strain"], r["stress_MPa"]) for r in chosen])
        return strain, stress


def run_ensemble(
    tasks: Sequence[TensileTask],
    folder: str | Path | None = None,
    *,
    place: TaskPlace | None = None,
    task_function: Callable[[TensileTask], dict[str, Any]] = run_tensile,
    on_outcome: Callable[[TaskOutcome, TensileTask], None] | None = None,
) -> Ensemble:
    """Run tensile tasks in parallel, streaming each result to ``folder`` as it finishes.

    Parameters
    ----------
    tasks
        From :func:`plan_tasks`.
    folder
        Results folder; tasks already finished there are skipped (resume), and stale
        temporary files of interrupted writes are removed first. None keeps everything in
        memory. One run at a time per folder.
    place
        Where the tasks run (:class:`espin.core.parallel.TaskPlace`; default: local processes
        on every core).
    task_function
        What a task does (default :func:`run_tensile`); a module-level function. A record it
        returns without the fields of :func:`run_tensile`'s that a rerun needs (``key``, the
        properties, ``has_yield``, ``strain``, ``stress_MPa``) counts as a failed task.
    on_outcome
        Called in this process after each task finishes or fails (e.g. a progress bar).
        Default: in a Jupyter notebook, a bar of the tasks done with the time left; elsewhere
        nothing.

    Returns
    -------
    Ensemble

    """
    place = place or TaskPlace()
    folder = Path(folder) if folder is not None else None
    names = sorted({name for task in tasks for name in task.parameters})
    if folder is not None:
        _remove_stale_temporaries(folder)
    done: dict[str, dict[str, Any]] = _finished_records(folder, tasks) if folder is not None else {}
    todo = [task for task in tasks if task.key not in done]
    failures: dict[str, dict[str, Any]] = {}
    if todo:
        log.info("%d tasks to run, %d already finished", len(todo), len(done))
        if on_outcome is None:
            on_outcome = _notebook_bar(len(todo))
        with place.pool() as pool:
            for outcome in pool.map(task_function, todo):
                task = todo[outcome.index]
                outcome = _checked(outcome, task)
                if outcome.ok:
                    done[task.key] = outcome.value
                    if folder is not None:
                        _write_json(folder / "tasks" / f"{task.key}.json", outcome.value)
                        (folder / "failed" / f"{task.key}.json").unlink(missing_ok=True)
                else:
                    failures[task.key] = _failure(task, outcome)
                    log.info("task %s (%s, seed %d) failed: %s", task.key, task.parameters, task.seed, outcome.error)
                    if folder is not None:
                        _write_json(folder / "failed" / f"{task.key}.json", failures[task.key])
                ensemble = _collect(tasks, done, failures, names, len(tasks) - len(todo), folder)
                if folder is not None:
                    _write_table(ensemble, folder)
                if on_outcome is not None:
                    on_outcome(outcome, task)
    ensemble = _collect(tasks, done, failures, names, len(tasks) - len(todo), folder)
    if folder is not None:
        _write_table(ensemble, folder)
    return ensemble


def _notebook_bar(total: int) -> Callable[[TaskOutcome, TensileTask], None] | None:
    """In a notebook, a progress bar of ``total`` tasks as the ``on_outcome`` of
    :func:`run_ensemble`; None elsewhere."""
    from espin.core.progress import NotebookProgress, in_notebook

    if not in_notebook():
        return None
    bar = NotebookProgress(total, "test")
    finished = 0

    def show(outcome: TaskOutcome, task: TensileTask) -> None:
        nonlocal finished
        finished += 1
        bar.update(finished, "" if outcome.ok else f"last failed (seed {task.seed})")

    return show


def _collect(
    tasks: Sequence[TensileTask],
    done: dict[str, dict[str, Any]],
    failures: dict[str, dict[str, Any]],
    names: list[str],
    skipped: int,
    folder: Path | None,
) -> Ensemble:
    unplanned = 0
    if folder is not None and (folder / "tasks").is_dir():
        planned = {t.key for t in tasks}
        unplanned = sum(path.stem not in planned for path in (folder / "tasks").glob("*.json"))
    return Ensemble(
        [done[t.key] for t in tasks if t.key in done],
        [failures[t.key] for t in tasks if t.key in failures],
        names,
        skipped,
        unplanned,
        folder,
    )


def _finished_records(folder: Path, tasks: Sequence[TensileTask]) -> dict[str, dict[str, Any]]:
    """Records of planned tasks already written to ``folder/tasks``.

    A file that cannot be read, is not JSON or is not a complete record of its task is not
    used (a warning names it and the problem, never its contents): the task runs again.
    """
    done: dict[str, dict[str, Any]] = {}
    for task in tasks:
        path = folder / "tasks" / f"{task.key}.json"
        if path.is_file():
            problem: str | None
            try:
                record = json.loads(path.read_bytes())
            except OSError as err:
                problem = f"cannot be read ({err.strerror})"
            except json.JSONDecodeError as err:
                problem = f"is not JSON (line {err.lineno}, column {err.colno})"
            except UnicodeDecodeError:
                problem = "is not JSON (not UTF-8 text)"
            else:
                problem = _record_problem(record, task.key)
            if problem is not None:
                log.warning("%s %s; the task runs again", path, problem)
                continue
            # The key fixes the whole config; the names of what varies come from this plan.
            done[task.key] = {**record, "parameters": task.parameters, "seed": task.seed}
    return done


RECORD_FIELDS = ("key", *PROPERTIES, "has_yield", "strain", "stress_MPa")
"""Fields a task record must have to count as finished (see :func:`run_tensile`)."""


def _record_problem(record: Any, key: str) -> str | None:
    """What makes ``record`` unusable as the finished record of task ``key``, or None.

    The message describes the problem without quoting the record's values.
    """
    if not isinstance(record, dict):
        return "is not a JSON object"
    missing = [name for name in RECORD_FIELDS if name not in record]
    if missing:
        return f"lacks {', '.join(missing)}"
    if record["key"] != key:
        return "holds the record of another task (its key is not the file's name)"
    wrong = [name for name in PROPERTIES if record[name] is not None and not _is_finite_number(record[name])]
    if not isinstance(record["has_yield"], bool):
        wrong.append("has_yield")
    wrong += [name for name in ("strain", "stress_MPa") if not _is_curve(record[name])]
    if wrong:
        return f"has an invalid value in {', '.join(wrong)}"
    if len(record["strain"]) != len(record["stress_MPa"]):
        return "has strain and stress_MPa of different lengths"
    return None


def _is_finite_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _is_curve(values: Any) -> bool:
    """A non-empty list of numbers."""
    return (
        isinstance(values, list)
        and bool(values)
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)
    )


def _checked(outcome: TaskOutcome, task: TensileTask) -> TaskOutcome:
    """``outcome``, made a failure if its record would not count as finished on a rerun."""
    problem = _record_problem(outcome.value, task.key) if outcome.ok else None
    if problem is None:
        return outcome
    return dataclasses.replace(outcome, value=None, error=f"the task function's record {problem}")


_TEMPORARY = re.compile(r"^\..+\.[a-z0-9_]{8}\.tmp$")
"""Name of an atomic write's temporary file (:mod:`espin.core.atomic`: ``.<name>.<random>.tmp``)."""

STALE_TEMPORARY_S = 60.0
"""Age [s] beyond which such a temporary file is an interrupted write's, not one in progress."""


def _remove_stale_temporaries(folder: Path) -> None:
    """Delete atomic writes' temporary files older than :data:`STALE_TEMPORARY_S` in
    ``folder``, ``folder/tasks`` and ``folder/failed`` (left by a run killed mid-write)."""
    now = time.time()
    removed = 0
    for directory in (folder, folder / "tasks", folder / "failed"):
        if not directory.is_dir():
            continue
        for path in directory.iterdir():
            if (
                _TEMPORARY.match(path.name)
                and path.is_file()
                and not path.is_symlink()
                and now - path.stat().st_mtime > STALE_TEMPORARY_S
            ):
                path.unlink(missing_ok=True)
                removed += 1
    if removed:
        log.info("removed %d temporary file(s) left in %s by an interrupted write", removed, folder)


def _failure(task: TensileTask, outcome: TaskOutcome) -> dict[str, Any]:
    return {
        "key": task.key,
        "parameters": task.parameters,
        "seed": task.seed,
        "error": outcome.error,
        "traceback": outcome.traceback,
    }


def _write_json(path: Path, data: dict[str, Any]) -> None:
    atomic_write_bytes(path, json.dumps(data, indent=1, default=_json_default).encode())


def _write_table(ensemble: Ensemble, folder: Path) -> None:
    table = ensemble.table()
    atomic_write(folder / "results.csv", lambda tmp: table.to_csv(tmp, index=False))


def _json_float(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"not JSON serializable: {type(value).__name__}")
