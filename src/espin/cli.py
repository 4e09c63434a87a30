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

    from espin.errors import ConfigError

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

    from espin.errors import EspinError
    from espin.outputs import write_rve_folder
    from espin.rve import generate as generate_rve
    from espin.rve import resolve_config

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


@app.command("config")
def show_config(source: SourceArg = None, set_: SetOpt = None) -> None:
    """Print the resolved configuration (TOML) of a preset or file, defaults filled in."""
    from espin.config import config_to_toml
    from espin.errors import EspinError
    from espin.rve import resolve_config

    try:
        overrides = _parse_set(set_)
        config = resolve_config(source, **{k.replace(".", "__"): v for k, v in overrides.items()})
    except EspinError as err:
        _fail(str(err))
    sys.stdout.write(config_to_toml(config))


if __name__ == "__main__":  # pragma: no cover
    app()
