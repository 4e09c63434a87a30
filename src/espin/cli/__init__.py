"""The ``espin`` command line. Heavy imports happen inside the commands, so --help is fast."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Any, Optional

import typer

app = typer.Typer(
    name="espin",
    help="Virtual electrospun fiber mats and their mechanics, from microstructure to curves.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

SourceArg = Annotated[
    Optional[str],
    typer.Argument(help="Preset name (plla) or TOML config file. Default: plla."),
]
SetOpt = Annotated[
    Optional[list[str]],
    typer.Option(
        "--set",
        help="Override any config key: --set section.key=VALUE (VALUE in TOML syntax, "
        "e.g. --set 'rve.orientation={von_mises={mean_deg=0, kappa=2}}'). Repeatable.",
    ),
]


def _parse_set(items: list[str] | None) -> dict[str, Any]:
    import tomllib

    from espin.core.errors import ConfigError

    out: dict[str, Any] = {}
    for item in items or []:
        key, sep, text = item.partition("=")
        if not sep:
            raise ConfigError(f"--set {item!r}: expected section.key=VALUE")
        try:
            value = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError:
            value = text  # a bare word such as lines or uniform
        out[key.strip()] = value
    return out


def _fail(message: str) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


@app.command()
def generate(
    source: SourceArg = None,
    out: Annotated[
        Optional[Path], typer.Option("--out", "-o", help="Output folder. Default: <name>_rve.")
    ] = None,
    seed: Annotated[Optional[int], typer.Option(help="rve.seed: random seed (>= 0).")] = None,
    layers: Annotated[Optional[int], typer.Option(help="rve.layers: number of layers.")] = None,
    size_ratio: Annotated[
        Optional[float], typer.Option(help="rve.size_ratio: layer side / diameter.")
    ] = None,
    volume_fraction: Annotated[
        Optional[float], typer.Option(help="rve.volume_fraction: per layer, in (0, 1).")
    ] = None,
    seeding: Annotated[
        Optional[str], typer.Option(help="rve.seeding: border (paper) or lines.")
    ] = None,
    set_: SetOpt = None,
    figures: Annotated[bool, typer.Option(help="Write PNG figures.")] = True,
    vtk: Annotated[bool, typer.Option(help="Write VTK files for ParaView.")] = True,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress or table.")] = False,
) -> None:
    """Generate a virtual mat (paper 3.1.1) and its network; write file, statistics, figures."""
    from rich.console import Console
    from rich.progress import Progress

    from espin.core.errors import EspinError
    from espin.geometry.rve_folder import write_rve_folder
    from espin.geometry.rve import generate as generate_rve
    from espin.geometry.rve import resolve_config

    console = Console(stderr=True, quiet=quiet)
    options = {
        "rve.seed": seed,
        "rve.layers": layers,
        "rve.size_ratio": size_ratio,
        "rve.volume_fraction": volume_fraction,
        "rve.seeding": seeding,
    }
    try:
        overrides = {k: v for k, v in options.items() if v is not None} | _parse_set(set_)
        config = resolve_config(source, **{k.replace(".", "__"): v for k, v in overrides.items()})
        name = Path(source).stem if source else "plla"
        folder = out if out is not None else Path(f"{name}_rve")
        with Progress(console=console, transient=True) as bar:
            task = bar.add_task("depositing layers", total=config.rve.layers)

            def progress(stage: str, done: int, total: int) -> None:
                if stage == "deposition":
                    bar.update(task, completed=done)
                    if done == total:
                        bar.update(task, description="finding cross-links")
                elif stage == "crosslinks":
                    bar.update(task, description="building the network")

            rve = generate_rve(config, progress=progress)
            bar.update(task, description="writing files")
            result = write_rve_folder(rve, folder, figures=figures, vtk=vtk)
    except EspinError as err:
        _fail(str(err))
    console.print(result.statistics.format_table(), highlight=False)
    console.print(f"seeding: {config.rve.seeding}   wrote {folder}/: " + ", ".join(
        p.name for p in result.files.values()
    ), highlight=False)


@app.command()
def simulate(
    source: Annotated[
        Optional[str],
        typer.Argument(help="Preset (plla), TOML config, or a saved RVE file (.h5). Default: plla."),
    ] = None,
    out: Annotated[
        Optional[Path], typer.Option("--out", "-o", help="Results folder. Default: <name>_test.")
    ] = None,
    test: Annotated[
        Optional[str],
        typer.Option(help="loading.test: uniaxial, equibiaxial, pure_shear, simple_shear, path."),
    ] = None,
    lateral: Annotated[
        Optional[str], typer.Option(help="loading.lateral for uniaxial: fixed or free.")
    ] = None,
    direction_deg: Annotated[
        Optional[float], typer.Option(help="loading.direction_deg: loading axis, degrees from +x.")
    ] = None,
    max_strain: Annotated[Optional[float], typer.Option(help="loading.max_strain.")] = None,
    strain_rate_per_s: Annotated[
        Optional[float], typer.Option(help="loading.strain_rate_per_s, 1/s.")
    ] = None,
    steps: Annotated[Optional[int], typer.Option(help="loading.steps.")] = None,
    linear: Annotated[
        Optional[str], typer.Option(help="solver.linear: auto, superlu or pardiso.")
    ] = None,
    set_: SetOpt = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress or table.")] = False,
) -> None:
    """Pull on a virtual mat: generate or load the RVE, run the loading program, write results.

    Writes the curve (CSV), results (HDF5), a VTK series for ParaView and figures.
    """
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from espin.core.errors import EspinError
    from espin.mechanics.loading import load_program
    from espin.mechanics.run import resolve_rve
    from espin.mechanics.run import simulate as run_simulation
    from espin.geometry.rve import resolve_config

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
        overrides = {k: v for k, v in options.items() if v is not None} | _parse_set(set_)
        name = Path(source).stem if source else "plla"
        folder = out if out is not None else Path(f"{name}_test")
        # Validate everything (config, tables of the loading program) before any work.
        if source and source.endswith((".h5", ".hdf5")):
            target = resolve_rve(source, overrides)[0]
            config = target.config
        else:
            target = config = resolve_config(source, **{k.replace(".", "__"): v for k, v in overrides.items()})
        program = load_program(config.loading)
        columns = (TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[info]}"),
                   TimeElapsedColumn())
        with Progress(*columns, console=console) as bar:
            task = bar.add_task("generating", total=program.n_steps, info="")

            def on_step(record) -> None:
                stress = record.P if config.output.stress_measure == "nominal" else record.P_paper
                R = program.rotation
                local = R.T @ stress @ R
                value = local[0, 1] if program.test == "simple_shear" else local[0, 0]
                bar.update(task, completed=record.index, description=f"step {record.index}/{program.n_steps}",
                           info=f"strain {record.strain:.4f}  stress {value:.4g} MPa  "
                                f"iterations {record.iterations}")

            result = run_simulation(target, folder, on_step=on_step)
    except EspinError as err:
        _fail(str(err))
    stress = result.stress()
    console.print(
        f"{config.loading.test} test, {program.n_steps} steps: stress {stress[-1]:.4g} MPa at strain "
        f"{result.strain[-1]:.4g} ({config.output.stress_measure}); Newton iterations "
        f"{int(result.iterations.sum())}, factorizations {int(result.factorizations.sum())}",
        highlight=False,
    )
    console.print(f"wrote {folder}/", highlight=False)


@app.command("config")
def show_config(source: SourceArg = None, set_: SetOpt = None) -> None:
    """Print the resolved configuration (TOML) of a preset or file, defaults filled in."""
    from espin.core.config import config_to_toml
    from espin.core.errors import EspinError
    from espin.geometry.rve import resolve_config

    try:
        overrides = _parse_set(set_)
        config = resolve_config(source, **{k.replace(".", "__"): v for k, v in overrides.items()})
    except EspinError as err:
        _fail(str(err))
    sys.stdout.write(config_to_toml(config))


def _register_command_groups() -> None:
    """Commands that live in their own modules (studies, calibrations, images)."""
    from espin.cli import calibrate_geometry, fit, measure, properties, study

    measure.register(app)
    properties.register(app)
    fit.register(app)
    study.register(app)
    calibrate_geometry.register(app)


_register_command_groups()

if __name__ == "__main__":  # pragma: no cover
    app()
