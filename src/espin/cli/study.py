"""``espin study ...``: RVE-size, DOF and parameter-sweep studies from the command line."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Optional

import typer

from espin.cli.common import (
    AllowLargeOpt,
    OverwriteOpt,
    PlanOnlyOpt,
    PlanOpt,
    fail,
    off_terminal_lines,
    parse_set,
    print_plan,
)
from espin.core.errors import EXIT_SOLVER

__all__ = ["register", "parse_grid"]

study_app = typer.Typer(
    help="Ensembles of virtual tests: RVE size (Appendix A), DOF (Fig. 14), parameter sweeps.",
    no_args_is_help=True,
    rich_markup_mode=None,
)

BaseArg = Annotated[Optional[str], typer.Argument(help="Preset (plla) or TOML config. Default: plla.")]
RealizationsOpt = Annotated[int, typer.Option(help="RVE realizations (seeds) per point.")]
SeedStartOpt = Annotated[
    Optional[int], typer.Option(help="First seed of the realizations. Default: the config's rve.seed.")
]
WorkersOpt = Annotated[Optional[int], typer.Option(help="Local worker processes. Default: all cores; 1 = serial.")]
SchedulerOpt = Annotated[
    Optional[str],
    typer.Option(
        help="Dask scheduler: 'local' (a Dask LocalCluster), tcp://host:port or tls://host:port "
        "(with --tls-ca-file, --tls-cert, --tls-key). The scheduler and its workers run the "
        "tasks they are sent (pickles): use only one you trust; tcp:// is unencrypted. "
        "Default: local processes without Dask."
    ),
]
TlsCaOpt = Annotated[Optional[Path], typer.Option("--tls-ca-file", help="CA certificate (PEM) of a tls:// scheduler.")]
TlsCertOpt = Annotated[Optional[Path], typer.Option("--tls-cert", help="This client's certificate (PEM) for tls://.")]
TlsKeyOpt = Annotated[Optional[Path], typer.Option("--tls-key", help="Its key (PEM), unless --tls-cert holds it.")]
BlasThreadsOpt = Annotated[int, typer.Option(help="BLAS / MKL threads per worker.")]
SetOpt = Annotated[
    Optional[list[str]],
    typer.Option("--set", help="Override a config key of the base: --set section.key=VALUE. Repeatable."),
]
QuietOpt = Annotated[bool, typer.Option("--quiet", "-q", help="No progress or table.")]


def parse_grid(items: list[str] | None) -> dict[str, list[Any]]:
    """``key=v1,v2,...`` or ``key=start:stop:count`` (evenly spaced, ends included) to a grid.

    Values are read as TOML (numbers, true/false, quoted strings); a bare word is a string.
    """
    import tomllib

    import numpy as np

    from espin.core.errors import ConfigError

    grid: dict[str, list[Any]] = {}
    for item in items or []:
        key, sep, text = item.partition("=")
        key, text = key.strip(), text.strip()
        if not sep or not key or not text:
            raise ConfigError(f"--grid {item!r}: expected section.key=v1,v2,... or section.key=start:stop:count")
        if key in grid:
            raise ConfigError(f"--grid {key}: given twice")
        parts = text.split(":")
        if len(parts) == 3:
            try:
                start, stop, count = float(parts[0]), float(parts[1]), int(parts[2])
            except ValueError:
                raise ConfigError(f"--grid {item!r}: start:stop:count needs two numbers and an integer") from None
            if not 1 <= count <= 10_000:
                raise ConfigError(f"--grid {key}: count must be in [1, 10000] (got {count})")
            spaced = np.linspace(start, stop, count)
            integral = all(float(v).is_integer() for v in spaced) and "." not in parts[0] + parts[1]
            grid[key] = [int(v) if integral else float(v) for v in spaced]  # rve.layers=2:8:4 stays integer
            continue
        values = []
        for word in text.split(","):
            try:
                values.append(tomllib.loads(f"v = {word.strip()}")["v"])
            except tomllib.TOMLDecodeError:
                values.append(word.strip())
        grid[key] = values
    return grid


def _print_study_plan(
    base: str | None,
    set_: list[str] | None,
    points: list[dict[str, Any]],
    realizations: int,
    seed_start: int | None,
    out: Path,
    workers: int | None,
    scheduler: str | None,
    plan: bool | None,
    quiet: bool,
    plan_only: bool,
) -> None:
    """Print the plan of a study's tensile tests (``points`` x ``realizations``, less those
    already finished in ``out``) before it runs."""
    from rich.console import Console

    from espin.core.parallel import default_workers
    from espin.geometry.rve import resolve_config
    from espin.mechanics.cost import REFERENCE_CALIBRATION
    from espin.mechanics.cost import plan as make_plan
    from espin.studies.ensemble import plan_tasks
    from espin.studies.sweeps import realization_seeds

    todo: list[Any] = []
    finished: list[int] = []

    def tests() -> list[Any]:
        if not todo and not finished:
            config = resolve_config(base, **parse_set(set_))
            seeds = realization_seeds(config, realizations, seed_start)
            tasks = plan_tasks(config, points, seeds, allow_large=True)
            per_point: dict[int, Any] = {}  # one config object per point: the cost does not depend on the seed
            for i, task in enumerate(tasks):
                if (out / "tasks" / f"{task.key}.json").is_file():
                    finished.append(i)
                else:
                    todo.append(per_point.setdefault(i // len(seeds), task.config))
        return todo

    def text(calibration: Any) -> str:
        line = make_plan(tests(), n_workers, calibration).text() if tests() else "plan: nothing to run"
        if finished:
            line += (
                f"; {len(finished)} tensile test{'s' * (len(finished) != 1)} already finished in {out}/ not run again"
            )
        return line

    n_workers = None if scheduler is not None else (workers or default_workers())
    print_plan(
        text,
        Console(stderr=True, quiet=quiet),
        plan,
        lambda: make_plan(tests(), n_workers, REFERENCE_CALIBRATION).seconds,
        only=plan_only,
    )


def _run_with_progress(run, n_tasks: int, quiet: bool):
    """Call ``run(on_outcome)`` under a progress bar (on stderr)."""
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    console = Console(stderr=True, quiet=quiet)
    failed = 0
    with (
        Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            TextColumn("ETA"),
            TimeRemainingColumn(),
            console=console,
            transient=True,
        ) as bar,
        off_terminal_lines(console, f"tensile tests: 0/{n_tasks} done") as say,
    ):
        task_id = bar.add_task("tensile tests", total=n_tasks)

        def on_outcome(outcome, task) -> None:
            nonlocal failed
            failed += not outcome.ok
            bar.update(
                task_id, advance=1, description=f"tensile tests ({failed} failed)" if failed else "tensile tests"
            )
            # off a terminal (no live bar): one plain line per task, repeated while the next runs
            say(f"tensile tests: {int(bar.tasks[0].completed)}/{n_tasks} done ({failed} failed)")

        return run(on_outcome)


def _run_study(prepare, out: Path, columns: list[str], quiet: bool) -> None:
    """``prepare()`` -> (run, number of tasks), inside the CLI's error handling; run under a
    progress bar, then report."""
    from espin.core.errors import EspinError

    try:
        run, n_tasks = prepare()
        result = _run_with_progress(run, n_tasks, quiet)
    except EspinError as err:
        fail(err)
    _report(result, out, columns, quiet)


def _report(result, folder: Path, columns: list[str], quiet: bool) -> None:
    """Summary table on stdout; notes, failures and the files written on stderr."""
    from rich.console import Console

    console = Console(stderr=True, quiet=quiet)
    ensemble = result.ensemble
    if ensemble.skipped:
        console.print(
            f"{ensemble.skipped} task(s) were already finished in {folder}/ and were not run again", highlight=False
        )
    if ensemble.unplanned:
        console.print(
            f"{ensemble.unplanned} finished task(s) in {folder}/tasks/ belong to other settings (kept, not used)",
            highlight=False,
        )
    if ensemble.records:
        table = result.summary[
            [
                c
                for c in result.summary.columns
                if c in columns
                or c.startswith("rve.")
                or c.startswith(("fiber.", "loading.", "solver."))
                or c in ("n", "n_yield")
            ]
        ]
        if not quiet:
            typer.echo(table.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
        console.print(f"wrote {folder}/: " + ", ".join(p.name for p in result.files.values()), highlight=False)
    else:
        console.print("no task finished", highlight=False)
    if ensemble.failures:
        failures = Console(stderr=True)  # printed under --quiet too: the exit code alone says too little
        for failure in ensemble.failures:
            first_line = (failure["error"] or "").splitlines()[0][:200]
            failures.print(
                f"[red]failed[/red] {failure['parameters']} seed {failure['seed']}: {first_line}", highlight=False
            )
        failures.print(
            f"{len(ensemble.failures)} task(s) failed (tracebacks in {folder}/failed/; run.json says "
            "partial or failed); rerun the same command to retry them: finished tasks are skipped",
            highlight=False,
        )
        raise typer.Exit(code=EXIT_SOLVER)


_MEANS = [f"{p}_mean" for p in ("modulus_MPa", "yield_stress_MPa", "post_yield_modulus_MPa")]
_SDS = [f"{p}_sd" for p in ("modulus_MPa", "yield_stress_MPa", "post_yield_modulus_MPa")]
_RSDS = [f"{p}_rsd" for p in ("modulus_MPa", "yield_stress_MPa", "post_yield_modulus_MPa")]


@study_app.command("rve-size")
def rve_size(
    base: BaseArg = None,
    size_ratios: Annotated[
        str, typer.Option(help="L/D values at --layers-for-sizes layers, comma-separated.")
    ] = "50,100,150,200",
    layer_counts: Annotated[str, typer.Option(help="N_l values at --size-for-layers, comma-separated.")] = "5,10,15,20",
    layers_for_sizes: Annotated[int, typer.Option(help="N_l of the L/D series.")] = 5,
    size_for_layers: Annotated[float, typer.Option(help="L/D of the N_l series.")] = 200,
    realizations: RealizationsOpt = 10,
    seed_start: SeedStartOpt = None,
    out: Annotated[Path, typer.Option("--out", "-o", help="Results folder.")] = Path("rve_size_study"),
    workers: WorkersOpt = None,
    scheduler: SchedulerOpt = None,
    tls_ca_file: TlsCaOpt = None,
    tls_cert: TlsCertOpt = None,
    tls_key: TlsKeyOpt = None,
    blas_threads: BlasThreadsOpt = 1,
    set_: SetOpt = None,
    overwrite: OverwriteOpt = False,
    allow_large: AllowLargeOpt = False,
    quiet: QuietOpt = False,
    plan: PlanOpt = None,
    plan_only: PlanOnlyOpt = False,
) -> None:
    """Mean, sd and RSD of modulus, yield stress, post-yield modulus versus L/D and N_l (Appendix A).

    Reruns skip finished realizations (resume after a crash or a killed job); a folder of
    another run is refused unless --overwrite.
    """
    from espin.core.cluster import tls_security
    from espin.studies.sweeps import rve_size_study

    def prepare():
        security = tls_security(tls_ca_file, tls_cert, tls_key)
        sizes = _numbers("--size-ratios", size_ratios, float)
        layers = _numbers("--layer-counts", layer_counts, int)
        points = list(dict.fromkeys([*((s, layers_for_sizes) for s in sizes), *((size_for_layers, n) for n in layers)]))
        n_points = len(points)
        _print_study_plan(
            base,
            set_,
            [{"rve.size_ratio": float(s), "rve.layers": int(n)} for s, n in points],
            realizations,
            seed_start,
            out,
            workers,
            scheduler,
            plan,
            quiet,
            plan_only,
        )
        return (
            lambda on_outcome: rve_size_study(
                base,
                size_ratios=sizes,
                layer_counts=layers,
                layers_for_sizes=layers_for_sizes,
                size_for_layers=size_for_layers,
                realizations=realizations,
                seed_start=seed_start,
                folder=out,
                workers=workers,
                scheduler=scheduler,
                blas_threads=blas_threads,
                security=security,
                on_outcome=on_outcome,
                overwrite=overwrite,
                allow_large=allow_large,
                **parse_set(set_),
            )
        ), n_points * realizations

    _run_study(prepare, out, _MEANS + _RSDS, quiet)


@study_app.command("sweep")
def sweep(
    base: BaseArg = None,
    grid: Annotated[
        Optional[list[str]],
        typer.Option(
            "--grid",
            help="A swept key: section.key=v1,v2,... or section.key=start:stop:count; "
            "e.g. --grid rve.orientation.von_mises.kappa=0,2,8. Repeatable (full grid). "
            "None: an ensemble of the base config.",
        ),
    ] = None,
    realizations: RealizationsOpt = 1,
    seed_start: SeedStartOpt = None,
    out: Annotated[Path, typer.Option("--out", "-o", help="Results folder.")] = Path("sweep"),
    table_format: Annotated[str, typer.Option("--format", help="Table format: csv or parquet.")] = "csv",
    workers: WorkersOpt = None,
    scheduler: SchedulerOpt = None,
    tls_ca_file: TlsCaOpt = None,
    tls_cert: TlsCertOpt = None,
    tls_key: TlsKeyOpt = None,
    blas_threads: BlasThreadsOpt = 1,
    set_: SetOpt = None,
    overwrite: OverwriteOpt = False,
    allow_large: AllowLargeOpt = False,
    quiet: QuietOpt = False,
    plan: PlanOpt = None,
    plan_only: PlanOnlyOpt = False,
) -> None:
    """Properties (modulus, yield stress, post-yield modulus) over any parameter grid, in parallel.

    Writes a tidy table (one row per realization), a summary per point and plots. Reruns skip
    finished tasks; a folder of another run is refused unless --overwrite.
    """
    import itertools
    import math

    from espin.core.cluster import tls_security
    from espin.studies.sweeps import sweep as run_sweep

    def prepare():
        security = tls_security(tls_ca_file, tls_cert, tls_key)
        parsed = parse_grid(grid)
        n_points = math.prod(len(values) for values in parsed.values())
        points = [dict(zip(parsed, combo)) for combo in itertools.product(*parsed.values())]
        _print_study_plan(base, set_, points, realizations, seed_start, out, workers, scheduler, plan, quiet, plan_only)
        return (
            lambda on_outcome: run_sweep(
                base,
                parsed,
                realizations=realizations,
                seed_start=seed_start,
                folder=out,
                table_format=table_format,
                workers=workers,
                scheduler=scheduler,
                blas_threads=blas_threads,
                security=security,
                on_outcome=on_outcome,
                overwrite=overwrite,
                allow_large=allow_large,
                **parse_set(set_),
            )
        ), n_points * realizations

    _run_study(prepare, out, _MEANS + _SDS, quiet)


@study_app.command("dof")
def dof(
    base: BaseArg = None,
    size_ratios: Annotated[str, typer.Option(help="L/D values, comma-separated.")] = "50,100,150,200,250,300",
    layers: Annotated[str, typer.Option(help="N_l values, comma-separated.")] = "15",
    realizations: RealizationsOpt = 1,
    seed_start: SeedStartOpt = None,
    elements_per_segment: Annotated[
        int, typer.Option(help="Beam elements per piece of fiber between nodes of the beam model.")
    ] = 1,
    out: Annotated[Path, typer.Option("--out", "-o", help="Results folder.")] = Path("dof_study"),
    set_: SetOpt = None,
    overwrite: OverwriteOpt = False,
    quiet: QuietOpt = False,
) -> None:
    """DOF of espin's model versus RVE size beside a beam finite-element model (paper Fig. 14).

    Writes dof.csv, dof.png and the quadratic fits DOF = c0 + c1 L + c2 L^2 (dof_fit.csv).
    """
    from rich.console import Console

    from espin.core.atomic import atomic_write
    from espin.core.config import config_digest
    from espin.core.errors import EspinError
    from espin.core.output_folder import OutputFolder
    from espin.geometry.rve import resolve_config
    from espin.studies.dof import dof_fit_table, dof_study, plot_dof_study
    from espin.studies.sweeps import realization_seeds

    try:
        sizes = _numbers("--size-ratios", size_ratios, float)
        layer_list = _numbers("--layers", layers, int)
        config = resolve_config(base, **parse_set(set_))
        seeds = realization_seeds(config, realizations, seed_start)
        with OutputFolder.claim(
            out, "dof", config_digest(config), ("dof.csv", "dof.png", "dof_fit.csv"), overwrite=overwrite
        ):
            table = dof_study(sizes, layer_list, base=config, seeds=seeds, elements_per_segment=elements_per_segment)
            fits = dof_fit_table(table)
            files = [
                atomic_write(out / "dof.csv", lambda tmp: table.to_csv(tmp, index=False)),
                plot_dof_study(table, out / "dof.png"),
                atomic_write(out / "dof_fit.csv", lambda tmp: fits.to_csv(tmp, index=False)),
            ]
    except EspinError as err:
        fail(err)
    if not quiet:
        typer.echo(table.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
        typer.echo(fits.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    Console(stderr=True, quiet=quiet).print(f"wrote {out}/: " + ", ".join(p.name for p in files), highlight=False)


def _numbers(option: str, text: str, kind: type) -> list:
    """A comma-separated list of numbers, or an error naming the option."""
    from espin.core.errors import ConfigError

    try:
        values = [kind(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ConfigError(
            f"{option}: comma-separated {'integers' if kind is int else 'numbers'} (got {text!r})"
        ) from None
    if not values:
        raise ConfigError(f"{option}: give at least one value")
    return values


def register(app: typer.Typer) -> None:
    """Add the ``study`` command group to ``app``."""
    app.add_typer(study_app, name="study")
