"""The ``espin design`` command: the microstructure that meets target properties."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Optional

import typer

from espin.cli.common import OverwriteOpt, PlanOnlyOpt, PlanOpt, SetOpt, fail, off_terminal_lines, parse_set, print_plan

__all__ = ["register"]


def _plan_text(
    space: Any, targets: Any, budget: int, replicates: int, verify: int, workers: int | None, calibration: Any
) -> str:
    from espin.mechanics.cost import plan

    middle = space.config([0.5] * space.dimension)
    n_tests = budget + (replicates - 1 + verify) * len(targets.directions)
    return (
        plan([middle] * n_tests, workers, calibration).text() + " (the search's budget, then the best design's "
        "replicates and verification)"
    )


def design_command(
    base: Annotated[
        Optional[str],
        typer.Argument(
            help="Preset or TOML config holding everything not searched: the fiber law (e.g. espin fit's "
            "fitted.toml), the RVE size and sampling, the loading. Default: plla."
        ),
    ] = None,
    target: Annotated[
        Optional[list[str]],
        typer.Option(
            "--target",
            "-t",
            help="A target: NAME[@DIR]=VALUE[+-TOL%] (E=150, sigma_y=5+-3%, E@90=70) or a ratio "
            "E@0/E@90=3. NAME: E, sigma_y, H, eps_y or modulus_MPa ... Tolerance default "
            "5 %. Repeatable.",
        ),
    ] = None,
    target_curve: Annotated[
        Optional[list[str]],
        typer.Option(
            "--target-curve",
            help="A whole target curve: CSV FILE[@DIR] (strain, stress [MPa] columns as espin "
            "properties reads them), compared at --curve-points strains. Repeatable (one "
            "per direction).",
        ),
    ] = None,
    curve_range: Annotated[
        Optional[str],
        typer.Option(
            help="Strain range of the curve comparison, LOW:HIGH (fractions). Default: from a --curve-points-th "
            "of the last strain to it."
        ),
    ] = None,
    curve_points: Annotated[int, typer.Option(help="Strains at which a target curve is compared.")] = 12,
    curve_tolerance: Annotated[
        float, typer.Option(help="Largest RMS deviation from a target curve, as a fraction of its largest stress.")
    ] = 0.05,
    var: Annotated[
        Optional[list[str]],
        typer.Option(
            "--var",
            "-v",
            help="A design variable with bounds: NAME=LOW:HIGH (eta=0.1:0.3, kappa=0:8, "
            "waviness_deg=0:20, diameter_cv=0:0.4, layers=3:15; log:LOW:HIGH for a log "
            "scale). Repeatable.",
        ),
    ] = None,
    constraint: Annotated[
        Optional[list[str]],
        typer.Option(
            "--constraint",
            "-c",
            help="QUANTITY>=BOUND or <=BOUND: porosity, volume_fraction, diameter_um, "
            "diameter_sd_um, diameter_cv, layers. Repeatable.",
        ),
    ] = None,
    budget: Annotated[
        int, typer.Option(help="Tensile tests the search may run (one design, one direction, one seed each).")
    ] = 60,
    batch: Annotated[int, typer.Option(help="Designs run together per round.")] = 2,
    initial: Annotated[
        Optional[int], typer.Option(help="Designs of the initial sample (default 2 d + 2, at least 6).")
    ] = None,
    replicates: Annotated[
        int, typer.Option(help="Seeds run at the first and the best design to measure the realization scatter.")
    ] = 3,
    verify: Annotated[int, typer.Option(help="Fresh seeds the best design is verified on.")] = 5,
    realizations: Annotated[
        int,
        typer.Option(
            help="Seeds every searched design runs on (their mean is modelled). Raise it to 2-4 when the report says "
            "the scatter between seeds is comparable to the tolerance."
        ),
    ] = 1,
    seed: Annotated[int, typer.Option(help="Seed of the search (initial sample, candidates).")] = 0,
    workers: Annotated[Optional[int], typer.Option(help="Worker processes (default: all cores; 1 = serial).")] = None,
    scheduler: Annotated[
        Optional[str],
        typer.Option(help="Dask scheduler: 'local', tcp://host:port (the tests then run on its workers)."),
    ] = None,
    set_: SetOpt = None,
    out: Annotated[
        Path, typer.Option("--out", "-o", help="Folder for design.toml, design.json, evaluations.csv and the figures.")
    ] = Path("design"),
    overwrite: OverwriteOpt = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress or report.")] = False,
    plan: PlanOpt = None,
    plan_only: PlanOnlyOpt = False,
) -> None:
    """Find the microstructure whose tensile properties meet target values (paper 4.3).

    Bayesian optimization over the design variables within their bounds and constraints;
    the best design is verified on fresh seeds against its 95 % prediction interval. Writes
    design.toml (runs with espin generate / simulate), design.json, evaluations.csv,
    convergence.png, maps.png, verification.png. A rerun with the same inputs resumes.
    """
    from rich.console import Console

    from espin.core.errors import ConfigError, EspinError
    from espin.core.parallel import default_workers
    from espin.design import design
    from espin.design.targets import parse_targets
    from espin.design.variables import DesignSpace
    from espin.geometry.rve import resolve_config
    from espin.mechanics.cost import REFERENCE_CALIBRATION

    console = Console(stderr=True, quiet=quiet, width=140)
    try:
        if not target_curve and (curve_range is not None or curve_points != 12 or curve_tolerance != 0.05):
            raise ConfigError(
                "--curve-range, --curve-points and --curve-tolerance apply to a --target-curve; "
                "give one, or leave them out"
            )
        targets = parse_targets(
            [*(target or []), *_curves(target_curve or [], curve_range, curve_points, curve_tolerance)]
        )
        config = resolve_config(base, **parse_set(set_))
        space = DesignSpace.build(config, var or [], constraint or [])
        n_workers = None if scheduler is not None else (workers or default_workers())
        replicated = budget + (replicates - 1) * len(targets.directions)
        print_plan(
            lambda calibration: _plan_text(space, targets, budget, replicates, verify, n_workers, calibration),
            console,
            plan,
            lambda: _plan_seconds(space, targets, replicated, verify, REFERENCE_CALIBRATION),
            only=plan_only,
        )

        with off_terminal_lines(console, "designing: the first batch of tensile tests") as say:

            def on_batch(evaluations: list, best: Any) -> None:
                ids = f"{evaluations[0].id}-{evaluations[-1].id}" if len(evaluations) > 1 else str(evaluations[0].id)
                shown = ", ".join(f"{key.removeprefix('rve.')} {value:.4g}" for key, value in best.values.items())
                line = f"designs {ids} ({evaluations[0].stage}) done; best so far #{best.id}: {shown}"
                if console.is_terminal:
                    console.print(line, highlight=False, soft_wrap=True)
                say(line)  # off a terminal: with the time elapsed, repeated while the next batch runs

            result = design(
                targets,
                var or [],
                base=config,
                constraints=constraint or [],
                budget=budget,
                batch=batch,
                initial=initial,
                replicates=replicates,
                verify=verify,
                seed=seed,
                realizations=realizations,
                folder=out,
                workers=workers,
                scheduler=scheduler,
                overwrite=overwrite,
                on_batch=on_batch,
            )
    except EspinError as err:
        fail(err)
    console.print(result.format_table(), highlight=False, soft_wrap=True)
    console.print(f"wrote {out}/: " + ", ".join(p.name for p in result.files.values()), highlight=False)
    console.print(f"next: espin simulate {out}/design.toml -o {out}/check", highlight=False, soft_wrap=True)


def _curves(items: list[str], strain_range: str | None, points: int, tolerance: float) -> list[Any]:
    """Curve targets from ``FILE[@DIR]`` items."""
    from espin.analysis.experiments import read_curve
    from espin.core.errors import ConfigError
    from espin.design.targets import CurveTarget

    bounds = None
    if strain_range is not None:
        low, sep, high = strain_range.partition(":")
        try:
            bounds = (float(low), float(high)) if sep else None
        except ValueError:
            bounds = None
        if bounds is None:
            raise ConfigError(f"--curve-range {strain_range!r}: write LOW:HIGH strains, e.g. 0.005:0.2")
    out = []
    for item in items:
        path, _, direction = item.rpartition("@") if "@" in Path(item).name else (item, "", "0")
        try:
            angle = float(direction)
        except ValueError:
            raise ConfigError(f"--target-curve {item!r}: the direction after @ is an angle in degrees") from None
        curve = read_curve(path)
        out.append(
            CurveTarget.from_curve(
                curve.strain,
                curve.stress_MPa,
                points=points,
                strain_range=bounds,
                tolerance=tolerance,
                direction_deg=angle,
                source=Path(path).name,
            )
        )
    return out


def _plan_seconds(space: Any, targets: Any, budget: int, verify: int, calibration: Any) -> float:
    from espin.mechanics.cost import predict_test

    middle = space.config([0.5] * space.dimension)
    return predict_test(middle, calibration).seconds * (budget + verify * len(targets.directions))


def register(app: typer.Typer) -> None:
    """Add the ``design`` command to ``app``."""
    app.command("design")(design_command)
