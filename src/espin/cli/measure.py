"""``espin measure``: fiber diameter, orientation, tortuosity, porosity and pores from SEM
images, one or a batch.

``register(app)`` adds the command to espin's typer app. Heavy imports happen inside the
command, so ``espin --help`` stays fast.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Optional

import typer

from espin.cli.common import OverwriteOpt, fail

if TYPE_CHECKING:
    from rich.console import Console

    from espin.imaging.batch import BatchMeasurement

__all__ = ["register"]


def measure(
    images: Annotated[
        list[Path],
        typer.Argument(
            help="SEM image: TIFF (palette, 16-bit), PNG or JPEG; or a folder of them (.tif, .tiff, "
            ".png, .jpg, .jpeg), or several: a batch.",
            metavar="IMAGE_OR_FOLDER",
            show_default=False,
        ),
    ],
    um_per_px: Annotated[
        Optional[float],
        typer.Option(
            help="Pixel size, um per pixel (or give the scale bar; with "
            "neither: the pixel size in the TIFF's FEI, Zeiss or "
            "ImageJ metadata, never its dpi)."
        ),
    ] = None,
    scale_bar_um: Annotated[
        Optional[float],
        typer.Option(help="Length of the scale bar (or span of its ticks), um; needs --scale-bar-rows."),
    ] = None,
    scale_bar_rows: Annotated[
        Optional[str],
        typer.Option(
            help="START:STOP, the image rows holding the whole scale bar; the data bar "
            "from START down is left out unless --crop-rows says otherwise."
        ),
    ] = None,
    crop_rows: Annotated[
        Optional[str], typer.Option(help="START:STOP, the image rows to analyse (e.g. 0:880).")
    ] = None,
    crop_bottom_px: Annotated[
        Optional[int], typer.Option(help="Leave out this many rows at the bottom (a data bar).")
    ] = None,
    detect_data_bar: Annotated[
        bool,
        typer.Option(
            help="Without --crop-rows, --crop-bottom-px or --scale-bar-rows, find "
            "the microscope's data bar (a separate band, or text overlaid "
            "on the image, at the bottom or top) and leave it out."
        ),
    ] = True,
    invert: Annotated[
        Optional[bool],
        typer.Option(
            "--invert/--no-invert",
            help="--invert: the fibers are dark on a bright "
            "background, invert the image first; --no-invert: measure it as it is, "
            "unchecked. Default: check that the fibers are bright and refuse dark ones.",
        ),
    ] = None,
    width_px: Annotated[
        Optional[float], typer.Option(help="Typical fiber width in pixels (>= 3); default: estimated.")
    ] = None,
    max_bend_deg: Annotated[
        float, typer.Option(help="Largest bend at which a fiber is traced through a crossing, deg, in (0, 90].")
    ] = 35.0,
    min_length_diameters: Annotated[
        float, typer.Option(help="Drop traced fibers shorter end to end than this many diameters, in [1, 100].")
    ] = 3.0,
    out: Annotated[
        Optional[Path],
        typer.Option(
            "--out",
            "-o",
            help="Output folder. Default: <image stem>_measure; "
            "for a folder <folder name>_measure, for several files "
            "<their folder's name>_measure.",
        ),
    ] = None,
    figures: Annotated[bool, typer.Option(help="Write histograms.png, overlay.png and orientation_map.png.")] = True,
    overwrite: OverwriteOpt = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress, no table.")] = False,
) -> None:
    """Measure fiber diameters, orientation, tortuosity, porosity and pores on SEM images.

    One image: writes fibers.csv (one row per traced fiber, with the image edges its ends lie
    on), measurement.toml (scale, field of view, counts, fitted distributions, U-turn fraction
    and straightness of the fibers traced edge to edge), histograms.png, overlay.png,
    orientation_map.png, and run.json. The scale: --um-per-px, else the scale bar, else the
    pixel size the microscope wrote into the TIFF (FEI, Zeiss tags; an ImageJ description with
    a length unit). With no rows given, the data bar is found and left out
    (--no-detect-data-bar: not).

    A folder or several images: the same options for each; each image's files in
    <out>/<image stem>/, images.csv (one row per image) and pooled.toml (pooled statistics
    with bootstrap confidence intervals over images). An image that cannot be measured is
    reported and skipped.
    """
    from rich.console import Console

    from espin.core.errors import EspinError
    from espin.imaging.batch import image_files

    console = Console(stderr=True, quiet=quiet)
    options = {
        "um_per_px": um_per_px,
        "scale_bar_um": scale_bar_um,
        "scale_bar_rows": scale_bar_rows,
        "crop_rows": crop_rows,
        "crop_bottom_px": crop_bottom_px,
        "width_px": width_px,
        "max_bend_deg": max_bend_deg,
        "min_length_diameters": min_length_diameters,
        "detect_data_bar": detect_data_bar,
        "invert": invert,
    }
    try:
        files = image_files(images)
    except EspinError as err:
        fail(err)
    if len(files) == 1 and not images[0].is_dir():
        _measure_one(files[0], out, options, figures, overwrite, console)
    else:
        _measure_batch(files, out or _batch_folder(files), options, figures, overwrite, console)


def _measure_one(
    image: Path, out: Path | None, options: dict[str, Any], figures: bool, overwrite: bool, console: Console
) -> None:
    """One image: its files in ``out`` (default ``<image stem>_measure``) and its table."""
    from rich.table import Table

    from espin.core.errors import EspinError
    from espin.core.output_folder import OutputFolder
    from espin.imaging.measurement import MEASURE_OUTPUTS, measurement_digest
    from espin.imaging.measurement import measure as measure_image

    folder = out if out is not None else Path(f"{image.stem}_measure")
    try:
        digest = measurement_digest(image, **options)  # checks the options and the file first
        with (
            OutputFolder.claim(folder, "measure", digest, MEASURE_OUTPUTS, overwrite=overwrite),
            console.status(f"measuring {image.name}"),
        ):
            result = measure_image(image, **options)
            files = result.write_files(folder, figures=figures)
    except EspinError as err:
        fail(err)
    table = Table(title=f"{image.name}", show_header=False)
    for name, value in result.table_rows():
        table.add_row(name, value)
    console.print(table)
    console.print(f"wrote {folder}/: " + ", ".join(p.name for p in files.values()), highlight=False)


def _batch_folder(files: list[Path]) -> Path:
    """Default output folder of a batch: ``<folder name>_measure`` for the folder holding the
    images, ``measure_batch`` when they come from several folders."""
    parents = {p.resolve().parent for p in files}
    return Path(f"{parents.pop().name}_measure" if len(parents) == 1 else "measure_batch")


def _measure_batch(
    files: list[Path], folder: Path, options: dict[str, Any], figures: bool, overwrite: bool, console: Console
) -> None:
    """Several images: a progress line per image, the per-image table and the pooled values."""
    import time

    from espin.core.errors import EspinError, SEMError
    from espin.imaging.batch import measure_batch

    started = [time.perf_counter()]

    def progress(i: int, n: int, row: dict[str, Any]) -> None:
        seconds = time.perf_counter() - started[0]
        started[0] = time.perf_counter()
        name = Path(row["file"]).name
        if row["status"] == "ok":
            console.print(
                f"[{i}/{n}] {name}: {row['n_fibers']} fibers, diameter "
                f"{row['diameter_mean_um']:.3g} µm, porosity {row['porosity']:.2f} "
                f"({seconds:.1f} s)",
                highlight=False,
            )
        else:
            console.print(f"[{i}/{n}] {name}: [red]not measured[/red]: {row['error']}", highlight=False)

    try:
        batch = measure_batch(files, folder, overwrite=overwrite, figures=figures, progress=progress, **options)
    except EspinError as err:
        fail(err)
    for table in _batch_tables(batch):
        console.print(table)
    console.print(f"wrote {folder}/: images.csv, pooled.toml and a folder per image", highlight=False)
    if batch.n_failed == len(batch.images):
        fail(SEMError(f"none of the {len(batch.images)} images could be measured (images.csv gives each error)"))


def _batch_tables(batch: BatchMeasurement) -> list[Any]:
    """The per-image summary table, and the pooled values with their 95 % intervals and the
    spread across images."""
    from rich import box
    from rich.table import Table

    images = Table(title=f"{len(batch.images)} images, {batch.n_failed} not measured", box=box.SIMPLE_HEAD)
    names = [Path(f).name for f in batch.images["file"]]
    images.add_column("image", overflow="fold", min_width=min(30, max(map(len, names))))
    for column in ("fibers", "D\n[µm]", "dir\n[°]", "coh.", "tort.", "poros.", "pore\n[µm]", "junct.\n/µm²"):
        images.add_column(column, justify="right", overflow="fold")
    for name, (_, r) in zip(names, batch.images.iterrows()):
        if r["status"] != "ok":
            images.add_row(f"{name} [red](not measured)[/red]")
            continue
        images.add_row(
            name,
            str(r["n_fibers"]),
            f"{r['diameter_mean_um']:.3g}",
            f"{r['dominant_direction_deg']:.0f}",
            f"{r['coherency']:.2f}",
            f"{r['tortuosity_mean']:.3f}",
            f"{r['porosity']:.2f}",
            f"{r['pore_diameter_median_um']:.3g}",
            f"{r['intersection_density_per_um2']:.3g}",
        )
    p = batch.pooled
    if not p.get("n_measured"):
        return [images]
    pooled = Table(
        title=f"pooled over {p['n_measured']} images (95 % CI: bootstrap of whole "
        f"images, B = {p['bootstrap']['resamples']})",
        box=box.SIMPLE_HEAD,
    )
    for column in ("quantity", "pooled", "95 % CI", "sd across images"):
        pooled.add_column(column, justify="left" if column == "quantity" else "right")
    for label, section, key, spread, fmt in (
        ("diameter mean [µm]", "diameter", "mean_um", "image_sd_of_mean_um", ".3g"),
        ("diameter median [µm]", "diameter", "median_um", None, ".3g"),
        ("fiber axis mean [°]", "orientation", "axial_mean_deg", None, ".1f"),
        ("coherency", "orientation", "coherency_mean", "image_sd_of_coherency", ".3f"),
        ("tortuosity mean", "tortuosity", "mean", "image_sd_of_mean", ".4f"),
        ("porosity", "porosity", "porosity", "image_sd", ".3f"),
        ("pore size median [µm]", "pores", "pore_diameter_median_um", "image_sd_of_median_um", ".3g"),
        ("intersections [1/µm²]", "intersections", "density_per_um2", "image_sd_of_density_per_um2", ".3g"),
    ):
        values = p[section]
        lo, hi = values[f"ci95_{key}"]
        pooled.add_row(
            label,
            f"{values[key]:{fmt}}",
            f"{lo:{fmt}} - {hi:{fmt}}",
            "" if spread is None else f"{values[spread]:{fmt}}",
        )
    return [images, pooled]


def register(app: typer.Typer) -> None:
    """Add the ``measure`` command to a typer app."""
    app.command("measure")(measure)
