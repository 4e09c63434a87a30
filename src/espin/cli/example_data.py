"""The ``espin example-data`` command: sample files to try the other commands on."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from espin.cli.common import OverwriteOpt, fail

__all__ = ["register"]

FILES = ("mat.tif", "spec1.csv", "spec2.csv", "spec3.csv", "calibrated_mat.toml")
"""What the command writes."""


def example_data(
    out: Annotated[Path, typer.Option("--out", "-o", help="Folder to write the files into.")] = Path("."),
    overwrite: OverwriteOpt = False,
) -> None:
    """Write sample data: mat.tif (a synthetic SEM image with a data bar, its pixel size in the
    TIFF's ImageJ tags), spec1.csv .. spec3.csv (synthetic specimen curves) and
    calibrated_mat.toml (the mat espin calibrate-geometry fits to mat.tif).

    Try: espin measure mat.tif -o measured; espin properties spec1.csv spec2.csv spec3.csv;
    espin simulate calibrated_mat.toml. All are made by espin (espin.datasets), not measured.
    """
    from espin.core.errors import ConfigError
    from espin.datasets import calibrated_config, sem_image, specimen_curves

    existing = [name for name in FILES if (out / name).exists()]
    if existing and not overwrite:
        fail(ConfigError(f"{out}: {', '.join(existing)} already there; give --overwrite to replace "
                         "them, or --out another folder"))
    out.mkdir(parents=True, exist_ok=True)
    written = [sem_image(out / "mat.tif"), *specimen_curves(out), calibrated_config(out / "calibrated_mat.toml")]
    typer.echo(f"wrote {', '.join(str(p) for p in written)}")


def register(app: typer.Typer) -> None:
    """Add the ``example-data`` command to ``app``."""
    app.command("example-data")(example_data)
