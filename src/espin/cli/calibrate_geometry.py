"""The ``espin calibrate-geometry`` command: deposition parameters from measured mat statistics.

``register(app)`` adds the command to espin's typer app. Heavy imports happen
inside the command, so ``espin --help`` stays fast.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Optional, cast

import typer

from espin.cli.common import fail, off_terminal_lines

if TYPE_CHECKING:  # pragma: no cover
    from espin.core.config import Config
    from espin.imaging.geometry_calibration import Fit, Walk  # checked by check_options

__all__ = ["register"]


def _inputs_digest(base: Config, measured: Path | None, options: list[Any]) -> str:
    """What a calibration starts from: the base config (and its files), the measured files (a
    measure folder's fibers.csv and measurement.toml, or the table) and the typed-in targets
    and options."""
    from espin.core.config import config_digest
    from espin.core.output_folder import inputs_digest

    if measured is None:
        files = []
    elif measured.is_dir():
        files = [measured / "fibers.csv", measured / "measurement.toml"]
    else:
        files = [measured]
    return inputs_digest(files, config_digest(base), options)


def calibrate_geometry_command(
    measured: Annotated[
        Optional[Path],
        typer.Argument(
            help="Folder written by espin measure (fibers.csv + measurement.toml) "
            "or a fibers.csv. Optional: targets may be typed in instead."
        ),
    ] = None,
    diameter_um: Annotated[Optional[float], typer.Option(help="Typed-in target: mean fiber diameter, um.")] = None,
    diameter_sd_um: Annotated[Optional[float], typer.Option(help="Typed-in target: sd of the diameter, um.")] = None,
    tortuosity_scale: Annotated[
        Optional[float],
        typer.Option(
            help="Typed-in target: half-normal tortuosity halfnorm(loc=1, scale); the paper's PLLA mats: 0.14."
        ),
    ] = None,
    orientation: Annotated[Optional[str], typer.Option(help="Typed-in target: uniform.")] = None,
    orientation_mean_deg: Annotated[
        Optional[float], typer.Option(help="Typed-in target: von Mises mean axis, degrees in [0, 180).")
    ] = None,
    orientation_kappa: Annotated[
        Optional[float], typer.Option(help="Typed-in target: von Mises concentration in [0, 700].")
    ] = None,
    window_um: Annotated[
        Optional[float],
        typer.Option(
            help="Observation window side, um, when the measurement has no "
            "field_of_view_um. Default: 50 fiber diameters."
        ),
    ] = None,
    base: Annotated[str, typer.Option(help="Preset (plla) or TOML config whose other keys are kept.")] = "plla",
    fit: Annotated[
        str,
        typer.Option(
            help="Paper walk parameter matched to the tortuosity: deviation "
            "(rve.max_deviation_deg), segment (rve.segment_ratio) or both."
        ),
    ] = "deviation",
    walk: Annotated[
        str,
        typer.Option(
            help="Deposition walk: auto (fit the paper and the smooth walk, keep the "
            "better; the paper walk when the measurement has no fibers crossing "
            "the image edge to edge), paper or smooth."
        ),
    ] = "auto",
    segment_ratio: Annotated[
        Optional[float], typer.Option(help="Fixed rve.segment_ratio when it is not fitted.")
    ] = None,
    max_deviation_deg: Annotated[
        Optional[float], typer.Option(help="Fixed rve.max_deviation_deg when it is not fitted.")
    ] = None,
    correct_orientation: Annotated[
        bool,
        typer.Option(
            help="Raise the deposition kappa of an aligned target so the visible "
            "orientation matches (the deposition walk widens it)."
        ),
    ] = True,
    rendered_check: Annotated[
        bool,
        typer.Option(
            help="With the measured image at hand: render the fitted mat like it, "
            "measure the renderings like the image, correct the tortuosity target "
            "for the tracer's bias and check the calibrated mat the same way "
            "(about a minute more)."
        ),
    ] = True,
    seeds: Annotated[int, typer.Option(help="Mats per evaluation (fixed seeds).")] = 8,
    out: Annotated[
        Path,
        typer.Option(
            "--out",
            "-o",
            help="Where to write. A path ending in .toml is the "
            "calibrated config, with the report beside it as "
            "<name>.calibration.json; any other path is a "
            "folder (created if needed) that gets config.toml, "
            "calibration.json, calibration.txt and run.json. "
            "Existing files are refused without --overwrite.",
        ),
    ] = Path("calibrated.toml"),
    overwrite: Annotated[
        bool,
        typer.Option(
            "--overwrite",
            help="Replace the files of another run: an existing -o .toml and "
            "its .calibration.json, or another run's results in the -o folder (removed "
            "first); without it they are refused.",
        ),
    ] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress or table.")] = False,
) -> None:
    """Find deposition parameters whose mat, measured in the same window, matches measured
    fiber diameter, orientation and tortuosity distributions; write a config for espin
    generate / simulate. The mechanics change with the geometry: run espin fit next."""
    from rich.console import Console

    from espin.core.errors import ConfigError, EspinError
    from espin.geometry.rve import resolve_config
    from espin.geometry.targets import GeometryTargets, MeasurementError
    from espin.imaging.geometry_calibration import (
        MECHANICS_NOTE,
        MIN_PORTIONS,
        calibrate_geometry,
        check_options,
        measured_image,
    )
    from espin.imaging.geometry_calibration.result import claim_output

    console = Console(stderr=True, quiet=quiet)
    try:
        if orientation not in (None, "uniform"):
            raise ConfigError(
                f"--orientation must be uniform (or give --orientation-mean-deg and "
                f"--orientation-kappa), got {orientation!r}"
            )
        typed: dict[str, Any] = {
            "diameter_mean_um": diameter_um,
            "diameter_sd_um": diameter_sd_um,
            "tortuosity_scale": tortuosity_scale,
            "orientation_uniform": orientation == "uniform",
            "orientation_mean_deg": orientation_mean_deg,
            "orientation_kappa": orientation_kappa,
        }
        measured_targets = GeometryTargets.from_path(measured) if measured is not None else None
        try:  # a typed-in value out of range is a usage error, a bad measured file an input error
            targets = measured_targets.with_typed(**typed) if measured_targets else GeometryTargets(**typed)
        except MeasurementError as err:
            raise ConfigError(str(err)) from None
        base_config = resolve_config(base)
        check_options(fit, segment_ratio, max_deviation_deg, seeds, MIN_PORTIONS, window_um, walk)  # before the claim
        options = [
            typed,
            fit,
            walk,
            segment_ratio,
            max_deviation_deg,
            window_um,
            correct_orientation,
            rendered_check,
            seeds,
        ]
        digest = _inputs_digest(base_config, measured, options)
        with (
            claim_output(out, digest, overwrite=overwrite),
            console.status("calibrating the deposition") as status,
            off_terminal_lines(console, "calibrating the deposition") as say,
        ):

            def progress(message: str) -> None:
                status.update(f"calibrating: {message}")
                say(f"calibrating: {message}")

            result = calibrate_geometry(
                targets,
                base_config,
                fit=cast("Fit", fit),
                walk=cast("Walk", walk),
                segment_ratio=segment_ratio,
                max_deviation_deg=max_deviation_deg,
                window_um=window_um,
                correct_orientation=correct_orientation,
                seeds=seeds,
                progress=progress,
                image=measured_image(measured) if measured is not None else None,
                rendered_check=rendered_check,
            )
            status.update("writing the config and comparison.png")
            say("writing the config and comparison.png")
            files = result.write_files(out)
    except EspinError as err:
        fail(err)
    console.print(result.format_table(), highlight=False, soft_wrap=True)
    console.print("wrote " + ", ".join(str(f) for f in files.values()), highlight=False)
    # The note (last line of the table) and the next steps are printed even with --quiet.
    if quiet:
        typer.echo(f"note: {MECHANICS_NOTE}", err=True)
    typer.echo(
        "next:\n"
        f"  espin generate {files['config']}\n"
        "  espin fit            (fit the fiber parameters again for this geometry)\n"
        f"  espin simulate {files['config']}",
        err=True,
    )


def register(app: typer.Typer) -> None:
    """Add the ``calibrate-geometry`` command to ``app``."""
    app.command("calibrate-geometry")(calibrate_geometry_command)
