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
    The folder follows the output policy of every command (a run.json; another run's folder or
    these files refused without --overwrite).
    """
    from espin.core.errors import EspinError
    from espin.core.output_folder import OutputFolder, inputs_digest
    from espin.core.version import __version__
    from espin.datasets import calibrated_config, sem_image, specimen_curves

    try:
        with OutputFolder.claim(out, "example-data", inputs_digest([], FILES, __version__), FILES, overwrite=overwrite):
            written = [
                sem_image(out / "mat.tif"),
                *specimen_curves(out),
                calibrated_config(out / "calibrated_mat.toml"),
            ]
    except EspinError as err:
        fail(err)
    typer.echo(f"wrote {', '.join(str(p) for p in written)} (and {out / 'run.json'})")


def register(app: typer.Typer) -> None:
    """Add the ``example-data`` command to ``app``."""
    app.command("example-data")(example_data)
