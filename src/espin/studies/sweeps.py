"""Studies built on ensembles: RVE size (paper Appendix A) and parameter sweeps (paper 4.3).

Both plan every task first (all configs validated before any work), run them through
:func:`espin.studies.ensemble.run_ensemble` (parallel, streamed to disk, resumable) and write a tidy
table, a per-point summary (mean, sd, RSD of each property) and figures.
"""

from __future__ import annotations

import contextlib
import itertools
import json
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import pandas as pd

from espin.core.atomic import atomic_write, atomic_write_bytes
from espin.core.config import Config, config_digest, dotted_overrides, write_config
from espin.core.errors import ConfigError
from espin.core.output_folder import OutputFolder
from espin.core.parallel import TaskOutcome, TaskPlace
from espin.geometry.rve import resolve_config
from espin.studies.ensemble import Ensemble, TensileTask, plan_tasks, run_ensemble

__all__ = ["StudyResult", "rve_size_study", "sweep", "realization_seeds"]

OnOutcome = Callable[[TaskOutcome, TensileTask], None]


@dataclass
class StudyResult:
    """An ensemble, its per-point summary and the files written.

    Attributes
    ----------
    ensemble : Ensemble
        Every finished task (records with curves) and every failure.
    summary : pandas.DataFrame
        Per parameter point: n, and mean / sd / RSD of each property.
    files : dict of str to Path
        What was written, by role.
    """

    ensemble: Ensemble
    summary: pd.DataFrame
    files: dict[str, Path] = field(default_factory=dict)

    @property
    def table(self) -> pd.DataFrame:
        """One row per finished task (see :meth:`Ensemble.table`)."""
        return self.ensemble.table()


def realization_seeds(base: Config, realizations: int, seed_start: int | None = None) -> list[int]:
    """``realizations`` consecutive RVE seeds from ``seed_start`` (default the base config's seed)."""
    if realizations < 1:
        raise ConfigError(f"realizations: must be >= 1 (got {realizations})")
    start = base.rve.seed if seed_start is None else seed_start
    if start < 0:
        raise ConfigError(f"seed_start: must be >= 0 (got {start})")
    return list(range(start, start + realizations))


def rve_size_study(
    base: Config | str | Path | None = None,
    *,
    size_ratios: Sequence[float] = (50, 100, 150, 200),
    layer_counts: Sequence[int] = (5, 10, 15, 20),
    layers_for_sizes: int = 5,
    size_for_layers: float = 200,
    realizations: int = 10,
    seed_start: int | None = None,
    folder: str | Path | None = None,
    workers: int | None = None,
    scheduler: Any = None,
    blas_threads: int | None = 1,
    security: Any = None,
    on_outcome: OnOutcome | None = None,
    overwrite: bool = False,
    allow_large: bool = False,
    **overrides: Any,
) -> StudyResult:
    """Mean, sd and RSD of modulus, yield stress and post-yield modulus versus RVE size.

    Two series, as in the paper's Appendix A: L_tilde = ``size_ratios`` at ``layers_for_sizes``
    layers, and N_l = ``layer_counts`` at L_tilde = ``size_for_layers``; ``realizations`` RVEs
    (seeds) each, the same seeds at every size.

    Parameters
    ----------
    base
        Config, preset or TOML file (default ``plla``); ``**overrides`` as ``section__key``.
    folder
        Results folder: ``results.csv``, ``summary.csv``, ``study.toml`` (the base config) and
        ``plan.json`` (sizes and seeds; both written before any work), ``tasks/``, and the figures
        ``rve_size_<property>.png`` (Figs. A.15-A.17) and ``rve_size_curves.png`` (Fig. A.18, at the largest RVE).
    workers, scheduler, blas_threads, security
        Where the tasks run (:class:`espin.core.parallel.TaskPool`); a Dask scheduler must be
        trusted (it runs the pickled tasks), ``security`` holds the TLS files of a ``tls://``
        one (:func:`espin.core.cluster.tls_security`).
    overwrite
        Replace another run's results in ``folder`` instead of refusing; a folder of the
        same kind of study is resumed without it (finished tasks, keyed by their whole
        config, are reused).
    allow_large
        Run mats whose tensile test is estimated to need more memory than is available here.

    Returns
    -------
    StudyResult
    """
    flat = dotted_overrides(overrides)
    fixed = sorted(k for k in flat if k in ("rve.size_ratio", "rve.size_um", "rve.layers"))
    if fixed:
        raise ConfigError(
            f"{', '.join(fixed)}: set by the study's sizes (size_ratios, layer_counts, "
            "layers_for_sizes, size_for_layers), not as an override"
        )
    place = TaskPlace(workers, scheduler, blas_threads, security)
    base = resolve_config(base, **flat)
    if not size_ratios and not layer_counts:
        raise ConfigError("size_ratios, layer_counts: give at least one RVE size")
    points = [{"rve.size_ratio": float(s), "rve.layers": int(layers_for_sizes)} for s in size_ratios]
    points += [{"rve.size_ratio": float(size_for_layers), "rve.layers": int(n)} for n in layer_counts]
    points = list({tuple(p.items()): p for p in points}.values())  # the shared point once
    seeds = realization_seeds(base, realizations, seed_start)
    tasks = plan_tasks(base, points, seeds, allow_large=allow_large)
    plan = {
        "study": "rve-size",
        "size_ratios": list(size_ratios),
        "layer_counts": list(layer_counts),
        "layers_for_sizes": layers_for_sizes,
        "size_for_layers": size_for_layers,
        "seeds": seeds,
    }
    with _claimed(folder, "rve-size", base, overwrite, tasks) as claimed:
        result = _run(tasks, base, plan, folder, place, on_outcome, claimed)
        ensemble = result.ensemble
        if folder is not None and ensemble.records:
            from espin.studies.figures import plot_curve_band, plot_rve_size

            folder = Path(folder)
            for name, path in plot_rve_size(
                result.summary, folder, layers_for_sizes=int(layers_for_sizes), size_for_layers=float(size_for_layers)
            ).items():
                result.files[name] = path
            largest = max(
                ensemble.records, key=lambda r: (r["parameters"]["rve.size_ratio"], r["parameters"]["rve.layers"])
            )
            strain, stress = ensemble.curves(**largest["parameters"])
            label = (
                rf"$\tilde L$ = {largest['parameters']['rve.size_ratio']:g}, "
                rf"$N_l$ = {largest['parameters']['rve.layers']}"
            )
            result.files["curves"] = plot_curve_band(strain, stress, folder / "rve_size_curves.png", label=label)
    return result


def sweep(
    base: Config | str | Path | None = None,
    grid: Mapping[str, Sequence[Any]] | None = None,
    *,
    realizations: int = 1,
    seed_start: int | None = None,
    folder: str | Path | None = None,
    table_format: Literal["csv", "parquet"] = "csv",
    workers: int | None = None,
    scheduler: Any = None,
    blas_threads: int | None = 1,
    security: Any = None,
    on_outcome: OnOutcome | None = None,
    overwrite: bool = False,
    allow_large: bool = False,
    **overrides: Any,
) -> StudyResult:
    """Properties over a full grid of parameters (every combination), ``realizations`` RVEs each.

    Parameters
    ----------
    base
        Config, preset or TOML file (default ``plla``); ``**overrides`` as ``section__key``.
    grid
        Dotted config keys to their values, e.g. ``{"rve.volume_fraction": [0.15, 0.19],
        "rve.max_deviation_deg": [5, 15], "rve.orientation.von_mises.kappa": [0, 2, 8]}``.
        None or empty: an ensemble of ``realizations`` RVEs of the base config.
    folder
        Results folder: the tidy table ``results.csv`` (one row per realization, rewritten as
        tasks finish) and, with ``table_format="parquet"``, ``sweep.parquet``; ``summary.csv``,
        ``study.toml`` (the base config) and ``plan.json`` (grid and seeds, written before any
        work), ``tasks/`` and ``sweep_<property>.png`` (property versus each parameter).
    table_format
        ``"csv"`` or ``"parquet"`` (needs pyarrow: ``pip install "espin[parquet]"``).
    workers, scheduler, blas_threads, security
        Where the tasks run (:class:`espin.core.parallel.TaskPool`); a Dask scheduler must be
        trusted (it runs the pickled tasks), ``security`` holds the TLS files of a ``tls://``
        one (:func:`espin.core.cluster.tls_security`).
    overwrite
        Replace another run's results in ``folder`` instead of refusing; a folder of the
        same kind of study is resumed without it (finished tasks, keyed by their whole
        config, are reused).
    allow_large
        Run mats whose tensile test is estimated to need more memory than is available here.

    Returns
    -------
    StudyResult
    """
    place = TaskPlace(workers, scheduler, blas_threads, security)
    base = resolve_config(base, **overrides)
    if table_format not in ("csv", "parquet"):
        raise ConfigError(f"table_format: 'csv' or 'parquet' (got {table_format!r})")
    if table_format == "parquet":
        try:
            import pyarrow  # noqa: F401
        except ImportError:
            raise ConfigError('table_format: parquet needs pyarrow (pip install "espin[parquet]")') from None
    grid = {key: _grid_values(key, values) for key, values in (grid or {}).items()}
    keys = list(grid)
    points = [dict(zip(keys, combo)) for combo in itertools.product(*grid.values())] if keys else [{}]
    seeds = realization_seeds(base, realizations, seed_start)
    tasks = plan_tasks(base, points, seeds, allow_large=allow_large)
    with _claimed(folder, "sweep", base, overwrite, tasks) as claimed:
        result = _run(tasks, base, {"study": "sweep", "grid": grid, "seeds": seeds}, folder, place, on_outcome, claimed)
        if folder is not None and result.ensemble.records:
            from espin.studies.figures import plot_sweep

            folder = Path(folder)
            if table_format == "parquet":
                table = result.table
                result.files["table"] = atomic_write(
                    folder / "sweep.parquet", lambda tmp: table.to_parquet(tmp, index=False)
                )
            if keys:
                result.files.update(plot_sweep(result.summary, keys, folder))
    return result


STUDY_OUTPUTS = (
    "study.toml",
    "plan.json",
    "results.csv",
    "summary.csv",
    "sweep.parquet",
    "sweep_*.png",
    "rve_size_*.png",
    "tasks/*.json",
    "failed/*.json",
)
"""The files a study writes (glob patterns relative to its folder)."""


def _claimed(
    folder: str | Path | None, command: str, base: Config, overwrite: bool, tasks: list[TensileTask]
) -> contextlib.AbstractContextManager[OutputFolder | None]:
    """The study's claim on ``folder`` (resumed when it holds the same study, grown or not), or
    nothing.

    Raises
    ------
    ConfigError
        When the folder holds another study: its plan has tasks this one does not (without
        ``overwrite``).
    """
    if folder is None:
        return contextlib.nullcontext()
    plan = Path(folder) / "plan.json"
    if not overwrite and plan.is_file():
        try:
            earlier = set(json.loads(plan.read_text("utf-8")).get("tasks", []))
        except (OSError, UnicodeDecodeError, ValueError, AttributeError):
            earlier = set()  # an unreadable plan is the claim's to judge (the manifest's command)
        dropped = earlier - {task.key for task in tasks}
        if dropped:
            raise ConfigError(
                f"output folder {folder} holds another study: {len(dropped)} of its {len(earlier)} "
                "tasks are not in this one (a study may only grow in a folder of its own); pass "
                "--overwrite (overwrite=True in Python) to replace it, or choose another folder"
            )
    return OutputFolder.claim(
        folder, command, config_digest(base), STUDY_OUTPUTS, overwrite=overwrite, resume="same-command"
    )


def _grid_values(key: str, values: Any) -> list[Any]:
    """The values of one grid key as a list of plain Python scalars (numpy arrays welcome)."""
    if isinstance(values, (str, bytes, Mapping)) or not isinstance(values, Iterable):
        raise ConfigError(f"grid {key}: give a non-empty list of values (got {values!r})")
    values = [v.item() if hasattr(v, "item") else v for v in values]
    if not values:
        raise ConfigError(f"grid {key}: give a non-empty list of values (got none)")
    if len(set(map(repr, values))) != len(values):
        raise ConfigError(f"grid {key}: repeated values in {values}")
    return values


def _run(
    tasks: list[TensileTask],
    base: Config,
    plan: dict[str, Any],
    folder: str | Path | None,
    place: TaskPlace,
    on_outcome: OnOutcome | None,
    claimed: OutputFolder | None,
) -> StudyResult:
    """Write the plan (before any work), run the ensemble where ``place`` says, write the summary;
    the folder's status ``partial`` or ``failed`` when tasks failed."""
    files: dict[str, Path] = {}
    if folder is not None:
        folder = Path(folder)
        files["config"] = write_config(base, folder / "study.toml")
        plan = {**plan, "tasks": [task.key for task in tasks]}
        files["plan"] = atomic_write_bytes(folder / "plan.json", json.dumps(plan, indent=1).encode())
    ensemble = run_ensemble(tasks, folder, place=place, on_outcome=on_outcome)
    if claimed is not None:
        claimed.mark(len(ensemble.failures), len(tasks))
    summary = ensemble.summary()
    if folder is not None:
        files["results"] = folder / "results.csv"
        files["summary"] = atomic_write(folder / "summary.csv", lambda tmp: summary.to_csv(tmp, index=False))
    return StudyResult(ensemble, summary, files)
