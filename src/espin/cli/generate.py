"""``espin generate``: a virtual mat and its network, with statistics, figures and VTK files."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from espin.cli.common import AllowLargeOpt, OverwriteOpt, SetOpt, SourceArg, fail, parse_set

__all__ = ["register"]


def generate(
    source: SourceArg = None,
    out: Annotated[Optional[Path], typer.Option("--out", "-o", help="Output folder. Default: <name>_rve.")] = None,
    seed: Annotated[Optional[int], typer.Option(help="rve.seed: random seed (>= 0).")] = None,
    layers: Annotated[Optional[int], typer.Option(help="rve.layers: number of layers.")] = None,
    size_ratio: Annotated[Optional[float], typer.Option(help="rve.size_ratio: layer side / diameter.")] = None,
    volume_fraction: Annotated[Optional[float], typer.Option(help="rve.volume_fraction: per layer, in (0, 1).")] = None,
    seeding: Annotated[Optional[str], typer.Option(help="rve.seeding: border (paper) or lines.")] = None,
    sampling: Annotated[
        Optional[str], typer.Option(help="rve.sampling: random (paper) or balanced (less scatter across seeds).")
    ] = None,
    set_: SetOpt = None,
    figures: Annotated[bool, typer.Option(help="Write PNG figures.")] = True,
    vtk: Annotated[bool, typer.Option(help="Write VTK files for ParaView.")] = True,
    overwrite: OverwriteOpt = False,
    allow_large: AllowLargeOpt = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress or table.")] = False,
) -> None:
    """Generate a virtual mat (paper 3.1.1) and its network; write file, statistics, figures."""
    from rich.console import Console
    from rich.progress import Progress

    from espin.core.config import config_digest
    from espin.core.errors import EspinError
    from espin.core.output_folder import OutputFolder
    from espin.geometry.rve import generate as generate_rve
    from espin.geometry.rve import resolve_config
    from espin.geometry.rve_folder import RVE_OUTPUTS, write_rve_files
    from espin.geometry.size_estimate import check_size

    console = Console(stderr=True, quiet=quiet)
    options = {
        "rve.seed": seed,
        "rve.layers": layers,
        "rve.size_ratio": size_ratio,
        "rve.volume_fraction": volume_fraction,
        "rve.seeding": seeding,
        "rve.sampling": sampling,
    }
    try:
        overrides = {k: v for k, v in options.items() if v is not None} | parse_set(set_)
        config = resolve_config(source, **overrides)
        name = Path(source).stem if source else "plla"
        folder = out if out is not None else Path(f"{name}_rve")
        check_size(config, allow_large=allow_large)  # before the folder is claimed
        with (
            OutputFolder.claim(folder, "generate", config_digest(config), RVE_OUTPUTS, overwrite=overwrite) as claimed,
            Progress(console=console, transient=True) as bar,
        ):
            task = bar.add_task("depositing layers", total=config.rve.layers)

            def progress(stage: str, done: int, total: int) -> None:
                if stage == "deposition":
                    bar.update(task, completed=done)
                    if done == total:
                        bar.update(task, description="finding cross-links")
                elif stage == "crosslinks":
                    bar.update(task, description="building the network")

            rve = generate_rve(config, progress=progress, allow_large=allow_large)
            bar.update(task, description="writing files")
            result = write_rve_files(rve, folder, figures=figures, vtk=vtk, run_id=claimed.run_id)
    except EspinError as err:
        fail(err)
    console.print(result.statistics.format_table(), highlight=False, soft_wrap=True)
    console.print(
        f"seeding: {config.rve.seeding}   sampling: {config.rve.sampling}   wrote {folder}/: "
        + ", ".join(p.name for p in result.files.values()),
        highlight=False,
    )


def register(app: typer.Typer) -> None:
    """Add the ``generate`` command to a typer app."""
    app.command("generate")(generate)
