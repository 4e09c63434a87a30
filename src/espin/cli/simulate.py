"""``espin simulate``: pull on a virtual mat along a loading program and write the results."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from espin.cli.common import AllowLargeOpt, OverwriteOpt, SetOpt, fail, parse_set

__all__ = ["register"]


def simulate(
    source: Annotated[
        Optional[str],
        typer.Argument(
            help="Preset (plla), TOML config, a saved RVE file (.h5), or a network file made "
            "elsewhere (plain HDF5 or the authors' mesh text, docs/mechanics.md). Default: plla."
        ),
    ] = None,
    config_file: Annotated[
        Optional[str],
        typer.Option(
            "--config",
            "-c",
            help="With a network file: the preset or TOML config whose fiber, "
            "loading, solver and output apply. Default: plla.",
        ),
    ] = None,
    out: Annotated[Optional[Path], typer.Option("--out", "-o", help="Results folder. Default: <name>_test.")] = None,
    test: Annotated[
        Optional[str],
        typer.Option(help="loading.test: uniaxial, equibiaxial, pure_shear, simple_shear, path."),
    ] = None,
    lateral: Annotated[
        Optional[str], typer.Option(help="loading.lateral for uniaxial: fixed or free (other forms: --set).")
    ] = None,
    direction_deg: Annotated[
        Optional[float], typer.Option(help="loading.direction_deg: loading axis, degrees from +x.")
    ] = None,
    max_strain: Annotated[Optional[float], typer.Option(help="loading.max_strain.")] = None,
    strain_rate_per_s: Annotated[Optional[float], typer.Option(help="loading.strain_rate_per_s, 1/s.")] = None,
    steps: Annotated[Optional[int], typer.Option(help="loading.steps.")] = None,
    linear: Annotated[Optional[str], typer.Option(help="solver.linear: auto, superlu or pardiso.")] = None,
    set_: SetOpt = None,
    overwrite: OverwriteOpt = False,
    allow_large: AllowLargeOpt = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress or table.")] = False,
) -> None:
    """Pull on a virtual mat: generate or load the RVE, run the loading program, write results.

    Writes the curve (CSV), results (HDF5), a VTK series for ParaView and figures.
    """
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    from espin.analysis.properties import curve_marks
    from espin.core.errors import EspinError
    from espin.geometry.network import Network
    from espin.mechanics.driver import MEASURES
    from espin.mechanics.loading import load_program
    from espin.mechanics.run import resolve_source
    from espin.mechanics.run import simulate as run_simulation

    console = Console(stderr=True, quiet=quiet)
    options = {
        "loading.test": test,
        "loading.lateral": lateral,
        "loading.direction_deg": direction_deg,
        "loading.max_strain": max_strain,
        "loading.strain_rate_per_s": strain_rate_per_s,
        "loading.steps": steps,
        "solver.linear": linear,
    }
    try:
        overrides = {k: v for k, v in options.items() if v is not None} | parse_set(set_)
        name = Path(source).stem if source else "plla"
        folder = out if out is not None else Path(f"{name}_test")
        # Validate everything (config, tables of the loading program) before any work.
        config, rve = resolve_source(source, overrides, config_file)
        target = config if rve is None else rve
        program = load_program(config.loading)
        columns = (
            TextColumn("{task.description}"),
            BarColumn(),
            TextColumn("{task.fields[info]}"),
            TimeElapsedColumn(),
            TextColumn("ETA"),
            TimeRemainingColumn(),
        )
        # Off a terminal no live bar (rich would print its last frame, cut at 80 columns): the
        # plain line per step below.
        with Progress(*columns, console=console, disable=not console.is_terminal) as bar:
            task = bar.add_task("generating", total=program.n_steps, info="")

            def on_step(record) -> None:
                stress = getattr(record, MEASURES[config.output.stress_measure])
                R = program.rotation
                local = R.T @ stress @ R
                value = local[0, 1] if program.test == "simple_shear" else local[0, 0]
                info = f"strain {record.strain:.4f}  stress {value:.4g} MPa  iterations {record.iterations}"
                bar.update(
                    task, completed=record.index, description=f"step {record.index}/{program.n_steps}", info=info
                )
                if not console.is_terminal:  # no live bar off a terminal: one plain line per step
                    console.print(f"step {record.index}/{program.n_steps}: {info}", highlight=False)

            result = run_simulation(
                target,
                folder,
                config=config if isinstance(rve, Network) else None,
                on_step=on_step,
                overwrite=overwrite,
                allow_large=allow_large,
                curve_marks=curve_marks,
            )
    except EspinError as err:
        fail(err)
    stress = result.stress()
    console.print(
        f"{config.loading.test} test, {program.n_steps} steps: stress {stress[-1]:.4g} MPa at strain "
        f"{result.strain[-1]:.4g} ({config.output.stress_measure}); Newton iterations "
        f"{int(result.iterations.sum())}, factorizations {int(result.factorizations.sum())}",
        highlight=False,
        soft_wrap=True,  # one line in a log too (rich wraps at 80 columns there)
    )
    console.print(f"wrote {folder}/", highlight=False)


def register(app: typer.Typer) -> None:
    """Add the ``simulate`` command to a typer app."""
    app.command("simulate")(simulate)
