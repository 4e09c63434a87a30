"""The ``espin specimen`` command: pull a tensile specimen of the mat (FE^2 or its surrogate)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from espin.cli.common import OverwriteOpt, SetOpt, fail, off_terminal_lines, parse_set

__all__ = ["register"]


def _shape_options(items: list[str] | None) -> dict[str, float]:
    from espin.core.errors import ConfigError

    options: dict[str, float] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        try:
            options[key.strip().replace("-", "_")] = float(value)
        except ValueError:
            sep = ""
        if not sep:
            raise ConfigError(f"--shape-option {item!r}: write NAME=VALUE in mm, e.g. hole_diameter_mm=3")
    return options


def specimen_command(
    source: Annotated[
        Optional[str],
        typer.Argument(
            help="The mat: preset, TOML config or saved RVE (.h5). Default: plla (a generated RVE is L/D 60 with "
            "3 layers unless --set rve.size_ratio / rve.layers say otherwise)."
        ),
    ] = None,
    shape: Annotated[
        str,
        typer.Option(
            help="strip, dogbone (ISO 527-2 type 5A), holed_strip, notched_strip, or a mesh file meshio reads "
            "(x = loading axis; grips = the faces at min and max x)."
        ),
    ] = "holed_strip",
    shape_option: Annotated[
        Optional[list[str]],
        typer.Option(
            "--shape-option",
            help="A dimension of the built-in shape, NAME=VALUE in mm: length_mm, width_mm, "
            "hole_diameter_mm, notch_depth_mm, notch_radius_mm, scale (dogbone). "
            "Repeatable.",
        ),
    ] = None,
    model: Annotated[
        str,
        typer.Option(
            help="fe2 (an RVE at every quadrature point), surrogate (a law interpolated from RVE runs: "
            "seconds), neo_hookean (closed form, needs --modulus and --poisson)."
        ),
    ] = "fe2",
    thickness: Annotated[float, typer.Option(help="Specimen thickness [mm].")] = 0.1,
    max_strain: Annotated[float, typer.Option(help="Final grip strain (grip displacement / grip distance).")] = 0.2,
    steps: Annotated[int, typer.Option(help="Recorded steps.")] = 20,
    grips: Annotated[str, typer.Option(help="clamped (no lateral motion at the grips) or sliding.")] = "clamped",
    lateral: Annotated[
        Optional[str],
        typer.Option(
            help="fixed (the outer sides keep their width; holes stay free) or free (traction-free sides: "
            "the paper's 2-D fiber model has almost no lateral stiffness, small strains only; a mat with "
            "fused crossings, e.g. plla-bonded, holds its width). Default: free with fused crossings, "
            "else fixed."
        ),
    ] = None,
    elements_across: Annotated[int, typer.Option(help="Elements across the narrowest width.")] = 4,
    rve_seeds: Annotated[str, typer.Option(help="shared (one RVE geometry) or per_point.")] = "shared",
    rtol: Annotated[float, typer.Option(help="Macro tolerance (the RVEs solve to 1e-3 of it).")] = 1e-6,
    surrogate_from: Annotated[
        Optional[Path],
        typer.Option(
            help="surrogate: the surrogate_samples.csv of an earlier surrogate run of the same mat (no RVE runs: "
            "seconds). Samples of another mat, law or strain rate, or built for a smaller --max-strain, are "
            "refused."
        ),
    ] = None,
    allow_surrogate_mismatch: Annotated[
        bool,
        typer.Option(
            "--allow-surrogate-mismatch",
            help="Use --surrogate-from samples of another mat or reach anyway (recorded in specimen.json).",
        ),
    ] = False,
    surrogate_reach: Annotated[
        float,
        typer.Option(
            help="surrogate: the RVE paths reach this times --max-strain (stress concentrations strain more)."
        ),
    ] = 3.0,
    modulus: Annotated[Optional[float], typer.Option(help="neo_hookean: modulus [MPa].")] = None,
    poisson: Annotated[Optional[float], typer.Option(help="neo_hookean: Poisson's ratio.")] = None,
    workers: Annotated[int, typer.Option(help="Worker processes for the RVE solves (1 = serial).")] = 1,
    scheduler: Annotated[
        Optional[str],
        typer.Option(help="Dask scheduler: 'local' or tcp://host:port (the RVE solves then run on its workers)."),
    ] = None,
    set_: SetOpt = None,
    out: Annotated[Path, typer.Option("--out", "-o", help="Results folder.")] = Path("specimen"),
    overwrite: OverwriteOpt = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress or report.")] = False,
) -> None:
    """Pull a tensile specimen of the mat between its grips (docs/specimen.md).

    A membrane finite-element model of the specimen (mm, N, MPa) with an espin RVE at every
    quadrature point (FE^2), or a surrogate built from RVE runs. Writes force_displacement.csv,
    fields.pvd + vtk/ (ParaView), force.png, specimen.png, specimen.json and, for FE^2, rve.h5 and
    rve_points.h5 (any point reopens as an RVE result: espin.specimen.reopen_point).
    """
    from rich.console import Console

    from espin.core.errors import EspinError
    from espin.specimen import specimen

    console = Console(stderr=True, quiet=quiet, width=140)

    try:
        with off_terminal_lines(console, "specimen: starting") as say:

            def line(text: str) -> None:
                """A progress line: plain on a terminal; off one with the time elapsed, repeated while
                the next is long in coming (a surrogate path, an FE^2 step)."""
                if console.is_terminal:
                    console.print(text, highlight=False, soft_wrap=True)
                else:
                    say(text)

            def on_step(step) -> None:
                line(
                    f"step {step.index}/{steps}: grip strain {step.grip_strain:.4g}, force {step.force_N:.4g} N "
                    f"({step.iterations} iterations, {step.substeps} time steps)"
                )

            result = specimen(
                source or "plla",
                shape,
                model=model,
                thickness_mm=thickness,
                max_strain=max_strain,
                steps=steps,
                grips=grips,
                lateral=lateral,
                elements_across=elements_across,
                shape_options=_shape_options(shape_option),
                rve_seeds=rve_seeds,
                rtol=rtol,
                modulus_MPa=modulus,
                poisson_ratio=poisson,
                surrogate_from=surrogate_from,
                allow_surrogate_mismatch=allow_surrogate_mismatch,
                surrogate_reach=surrogate_reach,
                out=out,
                overwrite=overwrite,
                workers=workers,
                scheduler=scheduler,
                on_step=on_step,
                report=line,
                **parse_set(set_),
            )
    except EspinError as err:
        fail(err)
    console.print(result.format_summary(), highlight=False, soft_wrap=True)
    console.print(f"wrote {out}/: " + ", ".join(sorted(p.name for p in out.iterdir())), highlight=False, soft_wrap=True)


def register(app: typer.Typer) -> None:
    """Add the ``specimen`` command to a typer app."""
    app.command("specimen")(specimen_command)
