"""``espin measure``: fiber diameter, orientation and tortuosity from an SEM image.

``register(app)`` adds the command to espin's typer app. Heavy imports happen inside the
command, so ``espin --help`` stays fast.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from espin.cli.common import OverwriteOpt, fail

__all__ = ["register"]


def measure(
    image: Annotated[Path, typer.Argument(help="SEM image: TIFF (palette, 16-bit), PNG or JPEG.")],
    um_per_px: Annotated[
        Optional[float], typer.Option(help="Pixel size, um per pixel (or give the scale bar; with "
                                           "neither: the pixel size in the TIFF's FEI, Zeiss or "
                                           "ImageJ metadata, never its dpi).")
    ] = None,
    scale_bar_um: Annotated[
        Optional[float],
        typer.Option(help="Length of the scale bar (or span of its ticks), um; needs "
                          "--scale-bar-rows."),
    ] = None,
    scale_bar_rows: Annotated[
        Optional[str],
        typer.Option(help="START:STOP, the image rows holding the whole scale bar; the data bar "
                          "from START down is left out unless --crop-rows says otherwise."),
    ] = None,
    crop_rows: Annotated[
        Optional[str], typer.Option(help="START:STOP, the image rows to analyse (e.g. 0:880).")
    ] = None,
    crop_bottom_px: Annotated[
        Optional[int], typer.Option(help="Leave out this many rows at the bottom (a data bar).")
    ] = None,
    detect_data_bar: Annotated[
        bool, typer.Option(help="Without --crop-rows, --crop-bottom-px or --scale-bar-rows, find "
                                "the microscope's data bar (a separate band, or text overlaid "
                                "on the image, at the bottom or top) and leave it out.")
    ] = True,
    width_px: Annotated[
        Optional[float], typer.Option(help="Typical fiber width in pixels (>= 3); default: "
                                           "estimated.")
    ] = None,
    max_bend_deg: Annotated[
        float, typer.Option(help="Largest bend at which a fiber is traced through a crossing, "
                                 "deg, in (0, 90].")
    ] = 35.0,
    min_length_diameters: Annotated[
        float, typer.Option(help="Drop traced fibers shorter end to end than this many "
                                 "diameters, in [1, 100].")
    ] = 3.0,
    out: Annotated[
        Optional[Path], typer.Option("--out", "-o", help="Output folder. Default: <image>_measure.")
    ] = None,
    figures: Annotated[bool, typer.Option(help="Write histograms.png and overlay.png.")] = True,
    overwrite: OverwriteOpt = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No table.")] = False,
) -> None:
    """Measure fiber diameters, orientation and tortuosity on an SEM image.

    Writes fibers.csv (one row per traced fiber, with the image edges its ends lie on),
    measurement.toml (scale, field of view, counts, fitted distributions, U-turn fraction and
    straightness of the fibers traced edge to edge), histograms.png and overlay.png, and
    run.json. The scale: --um-per-px, else the scale bar, else the pixel size the microscope
    wrote into the TIFF (FEI, Zeiss tags; an ImageJ description with a length unit). With no
    rows given, the data bar is found and left out (--no-detect-data-bar: not).
    """
    from rich.console import Console
    from rich.table import Table

    from espin.core.errors import EspinError
    from espin.core.output_folder import OutputFolder
    from espin.imaging.measurement import MEASURE_OUTPUTS, measurement_digest
    from espin.imaging.measurement import measure as measure_image

    console = Console(stderr=True, quiet=quiet)
    folder = out if out is not None else Path(f"{image.stem}_measure")
    options = {
        "um_per_px": um_per_px, "scale_bar_um": scale_bar_um, "scale_bar_rows": scale_bar_rows,
        "crop_rows": crop_rows, "crop_bottom_px": crop_bottom_px, "width_px": width_px,
        "max_bend_deg": max_bend_deg, "min_length_diameters": min_length_diameters,
        "detect_data_bar": detect_data_bar,
    }
    try:
        digest = measurement_digest(image, **options)  # checks the options and the file first
        with OutputFolder.claim(folder, "measure", digest, MEASURE_OUTPUTS, overwrite=overwrite), \
                console.status(f"measuring {image.name}"):
            result = measure_image(image, **options)
            files = result.write_files(folder, figures=figures)
    except EspinError as err:
        fail(err)
    table = Table(title=f"{image.name}", show_header=False)
    for name, value in result.table_rows():
        table.add_row(name, value)
    console.print(table)
    console.print(f"wrote {folder}/: " + ", ".join(p.name for p in files.values()),
                  highlight=False)


def register(app: typer.Typer) -> None:
    """Add the ``measure`` command to a typer app."""
    app.command("measure")(measure)
