"""The ``espin fit`` command: calibrate eta and fiber-law parameters to measured curves.

``register(app)`` adds the command to espin's typer app. Heavy imports happen inside the
command, so ``espin --help`` stays fast.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Optional

import typer

if TYPE_CHECKING:  # pragma: no cover
    from espin.analysis.calibration import FitResult

from espin.cli.common import (
    DecimalOpt,
    DelimiterOpt,
    OverwriteOpt,
    PercentStrainOpt,
    PlanOnlyOpt,
    PlanOpt,
    SkipRowsOpt,
    StrainColumnOpt,
    StressColumnOpt,
    curve_warnings,
    fail,
    off_terminal_lines,
    parse_set,
    print_plan,
    read_options,
)

__all__ = ["register"]


def _number(text: str, what: str) -> float:
    from espin.core.errors import ConfigError

    try:
        return float(text)
    except ValueError:
        raise ConfigError(f"{what}: {text!r} is not a number") from None


def _parse_seeds(text: str) -> list[int]:
    """``1,2,3`` -> [1, 2, 3]; a seed that is not an integer is an error (never truncated)."""
    from espin.core.errors import ConfigError

    seeds = []
    for item in text.split(","):
        try:
            seeds.append(int(item.strip()))
        except ValueError:
            raise ConfigError(f"--seeds: {item.strip()!r} is not an integer") from None
    return seeds


def _parse_grid(text: str) -> Any:
    """``measured`` or a number of evenly spaced strains (>= 2)."""
    from espin.core.errors import ConfigError

    if text.strip() == "measured":
        return "measured"
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 2:
        raise ConfigError(f"--average-grid: 'measured' or a number of points >= 2 (got {text!r})")
    return n


def _parse_bounds(items: list[str] | None) -> dict[str, tuple[float, float]]:
    """``key=low:high`` items -> {key: (low, high)}."""
    from espin.core.errors import ConfigError

    out = {}
    for item in items or []:
        key, sep, text = item.partition("=")
        low, colon, high = text.partition(":")
        if not (sep and colon):
            raise ConfigError(f"--bounds {item!r}: expected key=low:high, e.g. b_p=1:20")
        out[key.strip()] = (_number(low, f"--bounds {key}"), _number(high, f"--bounds {key}"))
    return out


def _parse_fixed(items: list[str] | None) -> dict[str, float]:
    """``key=value`` items -> {key: value}."""
    from espin.core.errors import ConfigError

    out = {}
    for item in items or []:
        key, sep, text = item.partition("=")
        if not sep:
            raise ConfigError(f"--fix {item!r}: expected key=value, e.g. E_t=3000")
        out[key.strip()] = _number(text, f"--fix {key}")
    return out


def _parse_rates(items: list[str] | None) -> dict[float, list[Path]]:
    """``RATE=FILE,FILE`` items -> {rate [1/s]: [files]}."""
    from espin.core.errors import ConfigError

    out: dict[float, list[Path]] = {}
    for item in items or []:
        rate, sep, files = item.partition("=")
        paths = [Path(f) for f in files.split(",") if f.strip()]
        if not (sep and paths):
            raise ConfigError(f"--curves-at-rate {item!r}: expected RATE=FILE[,FILE...], e.g. 5e-2=a.csv,b.csv")
        out[_number(rate, "--curves-at-rate rate")] = paths
    return out


def _inputs_digest(config: Any, curves: Any, strain_rate: float | None, options: list[Any]) -> str:
    """What a fit starts from: the base config (and its files), every curve file, the strain
    rates and the options (a folder is reused only for the same fit)."""
    from espin.core.config import config_digest
    from espin.core.output_folder import inputs_digest

    by_rate = curves if isinstance(curves, dict) else {strain_rate: curves}
    rates = sorted(by_rate.items(), key=lambda item: str(item[0]))
    files = [path for _, paths in rates for path in paths]
    return inputs_digest(files, config_digest(config), [(rate, len(paths)) for rate, paths in rates], options)


def _curves(curves: list[Path], rate: float | None, other_rates: dict[float, list[Path]]) -> tuple[Any, float | None]:
    """The ``curve`` and ``strain_rate_per_s`` arguments of :func:`espin.analysis.calibration.fit`."""
    from espin.core.errors import ConfigError

    if not other_rates:
        return curves, rate
    if rate is None:
        raise ConfigError("--rate: give the strain rate of the CURVES when --curves-at-rate is used")
    if rate in other_rates:
        raise ConfigError(f"--curves-at-rate {rate:g}: the CURVES are already at that rate (--rate)")
    return {rate: curves, **other_rates}, None


def _sd_text(result: FitResult, key: str, sd: float | None) -> str:
    """An sd as the table shows it: ± sd, or ×/÷ factor for a log-scale parameter."""
    import math

    from espin.analysis.calibration import FIT_PARAMETERS

    if sd is None:
        return "-"
    if not math.isfinite(sd):
        return "n/a"
    if FIT_PARAMETERS[key].log_scale:
        return f"×/÷ {math.exp(sd / result.values[key]):.3g}"
    return f"± {sd:.2g}"


def _table(result: FitResult) -> Any:
    from rich.table import Table

    from espin.analysis.calibration import ETA_KEY, FIT_PARAMETERS

    table = Table(title=f"fit: R^2 = {result.r_squared:.5f}, RMSE = {result.rmse_MPa:.3g} MPa", caption_justify="left")
    table.add_column("parameter", no_wrap=True)
    for name in ("value", "sd", "1-sd interval", "Gauss-Newton sd", "sd over RVEs", "bounds", "note"):
        table.add_column(name)
    for key in result.parameters:
        spread = result.realization_sd[key] if result.realization_sd else None
        low, high = result.bounds[key]
        lo, hi = result.interval(key)
        note = f"at {result.at_bound[key]} bound" if result.at_bound[key] else ""
        if key == ETA_KEY and result.eta_profile_sd is not None:
            note = ", ".join(filter(None, [note, f"profile sd {result.eta_profile_sd:.2g}"]))
        table.add_row(
            f"{FIT_PARAMETERS[key].symbol} ({key})",
            f"{result.values[key]:.5g}",
            _sd_text(result, key, result.uncertainties[key]),
            f"{lo:.4g} .. {hi:.4g}",
            _sd_text(result, key, result.gauss_newton_sd[key]),
            _sd_text(result, key, spread),
            f"{low:.3g} .. {high:.3g}",
            note,
        )
    lines = [
        "sd = sqrt(Gauss-Newton sd^2 + (sd over RVEs)^2 / R); ×/÷: log-scale parameter, "
        "1-sd interval value / f .. value * f"
    ]
    gn = result.gauss_newton_sd.get(ETA_KEY)
    if result.eta_resolution is not None and gn is not None and gn < result.eta_resolution:
        lines.append(
            f"eta: its Gauss-Newton sd ({gn:.2g}) is below the network's step, one fiber per "
            f"layer = {result.eta_resolution:.2g} of volume fraction: eta is not resolved finer "
            "than that"
        )
    table.caption = "\n".join(lines)
    return table


def _live_warnings(console: Any) -> Any:
    """A logging handler that shows the fit's warnings as they happen (failed simulations,
    failed etas), except the result's own, which follow the table."""
    import logging

    class Live(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            if record.name != "espin.analysis.calibration.result":
                console.print(f"warning: {record.getMessage()}", style="yellow", highlight=False, soft_wrap=True)

    return Live(logging.WARNING)


def _fit_plan(problem: Any, workers: int | None, calibration: Any) -> tuple[str, float]:
    """The fit's plan as text, and its least time [s] (the eta grid's evaluations and Jacobians).

    A fit's number of evaluations is known only as it goes: each evaluation simulates every
    realization and curve (one parallel batch), each Jacobian one evaluation per fiber
    parameter (one batch); the eta grid needs at least one evaluation and one Jacobian per
    grid point, then the bracket search adds etas, and each eta's least squares takes up to
    ``MAX_NFEV`` evaluations, each with its Jacobian.
    """
    from espin.analysis.calibration import MAX_NFEV
    from espin.analysis.calibration.simulation import _loading_config
    from espin.mechanics.cost import format_duration, pool_seconds, predict_test

    tests = [
        predict_test(_loading_config(problem.base, steps, curve.strain_rate_per_s), calibration)
        for curve, steps in zip(problem.curves, problem.steps)
    ]
    per_evaluation = [t.seconds for t in tests for _ in problem.seeds]
    k = len(problem.fiber_keys)
    etas = problem.eta_points if problem.fits_eta else 1
    evaluation_s = pool_seconds(per_evaluation, workers)
    jacobian_s = pool_seconds(per_evaluation * k, workers) if k else 0.0
    least = etas * (evaluation_s + jacobian_s)
    most_per_eta = MAX_NFEV * (evaluation_s + jacobian_s) if k else evaluation_s
    where = "one worker of the scheduler" if workers is None else f"{workers} worker{'s' * (workers != 1)}"
    dof = max(t.dof for t in tests)
    steps = "/".join(str(t.steps) for t in tests)
    text = (
        f"plan: fit, each evaluation {len(per_evaluation)} tensile test{'s' * (len(per_evaluation) != 1)} x "
        f"{dof:,.0f} DOF ({steps} load steps) -> about {format_duration(evaluation_s)} on {where}; "
        "the number of evaluations is not known up front: "
    )
    if problem.fits_eta:
        text += (
            f"the {etas}-point eta grid needs at least {etas * (1 + k)} evaluations (1"
            + (f" + {k} Jacobian columns" if k else "")
            + f" per eta) -> at least {format_duration(least)}, "
            "then the eta bracket search adds etas; "
        )
    if k:
        text += (
            f"the least squares at one eta may take up to {MAX_NFEV} evaluations + their Jacobians "
            f"-> at most about {format_duration(most_per_eta)} per eta"
        )
    else:
        text += f"one evaluation per eta, about {format_duration(evaluation_s)} each"
    text += f" (speed calibration {calibration.seconds:.1f} s)"
    return text, least


def _print_fit_plan(
    curve: Any,
    inputs: dict[str, Any],
    workers: int | None,
    scheduler: str | None,
    console: Any,
    plan: bool | None,
    only: bool,
) -> None:
    """Print the fit's plan (:func:`_fit_plan`) before it starts; its inputs are checked here as
    the fit checks them (an error is left for the fit to report)."""
    import warnings

    from espin.analysis.calibration.problem import _problem
    from espin.core.parallel import default_workers
    from espin.mechanics.cost import REFERENCE_CALIBRATION

    problem: list[Any] = []
    n_workers = None if scheduler is not None else (workers or default_workers())

    def checked() -> Any:
        if not problem:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # the fit shows the curves' warnings itself
                problem.append(_problem(curve, **inputs))
        return problem[0]

    print_plan(
        lambda calibration: _fit_plan(checked(), n_workers, calibration)[0],
        console,
        plan,
        lambda: _fit_plan(checked(), n_workers, REFERENCE_CALIBRATION)[1],
        only=only,
    )


def register(app: typer.Typer) -> None:
    """Add the ``fit`` command to ``app``."""

    @app.command("fit")
    def fit_command(
        curves: Annotated[
            list[Path],
            typer.Argument(help="CSV files of the measured curve (specimens: they are averaged)."),
        ],
        params: Annotated[
            str,
            typer.Option(
                help="Parameters to fit, comma-separated: eta (volume_fraction), E_t "
                "(taut_modulus_MPa), E_b, a_p (needs two rates), b_p, c_p; keys or "
                "short names also work."
            ),
        ] = "eta,b_p,c_p",
        bounds: Annotated[
            Optional[list[str]],
            typer.Option("--bounds", help="Bounds of a fitted parameter: key=low:high. Repeatable."),
        ] = None,
        fix: Annotated[
            Optional[list[str]],
            typer.Option("--fix", help="Hold a parameter at a value: key=value. Repeatable."),
        ] = None,
        realizations: Annotated[
            Optional[int], typer.Option(help="RVE realizations per evaluation (default 3).")
        ] = None,
        seeds: Annotated[
            Optional[str],
            typer.Option(help="Seeds of the realizations, comma-separated. Default: base seed, +1, ..."),
        ] = None,
        rate: Annotated[
            Optional[float],
            typer.Option("--rate", help="Strain rate of the CURVES, 1/s. Default: the base config's."),
        ] = None,
        curves_at_rate: Annotated[
            Optional[list[str]],
            typer.Option(
                "--curves-at-rate",
                help="Curves at another strain rate: RATE=FILE[,FILE...] (1/s). Repeatable; "
                "two rates or more let a_p be fitted.",
            ),
        ] = None,
        step_strain: Annotated[
            float,
            typer.Option(
                help="Largest load step (strain) up to twice the curve's knee; beyond, up to "
                "0.01. Segments end at the measured strains."
            ),
        ] = 1e-3,
        average_grid: Annotated[
            str,
            typer.Option(
                help="Where several CURVES are averaged: 'measured' (their common strains, else "
                "the union within the common range) or a number of evenly spaced strains."
            ),
        ] = "measured",
        large_strain: Annotated[
            bool,
            typer.Option(
                "--large-strain", help="Accept strains above 1 (100 %); otherwise refused as probably percent."
            ),
        ] = False,
        eta_points: Annotated[int, typer.Option(help="Points of the eta grid.")] = 5,
        eta_tolerance: Annotated[float, typer.Option(help="Tolerance of the eta bracket search.")] = 0.002,
        workers: Annotated[
            Optional[int], typer.Option(help="Worker processes (default: all cores; 1 = serial).")
        ] = None,
        scheduler: Annotated[
            Optional[str],
            typer.Option(
                help="Dask scheduler: 'local', tcp://host:port or tls://host:port (with --tls-ca-file, "
                "--tls-cert, --tls-key). It and its workers run the tasks they are sent "
                "(pickles): use only one you trust; tcp:// is unencrypted."
            ),
        ] = None,
        tls_ca_file: Annotated[
            Optional[Path], typer.Option("--tls-ca-file", help="CA certificate (PEM) of a tls:// scheduler.")
        ] = None,
        tls_cert: Annotated[
            Optional[Path], typer.Option("--tls-cert", help="This client's certificate (PEM) for tls://.")
        ] = None,
        overwrite: OverwriteOpt = False,
        tls_key: Annotated[
            Optional[Path], typer.Option("--tls-key", help="Its key (PEM), unless --tls-cert holds it.")
        ] = None,
        base: Annotated[str, typer.Option(help="Preset or TOML config holding every value not fitted.")] = "plla",
        set_: Annotated[
            Optional[list[str]],
            typer.Option("--set", help="Override a key of the base config: section.key=VALUE. Repeatable."),
        ] = None,
        out: Annotated[
            Path, typer.Option("--out", "-o", help="Folder for fitted.toml, fit.csv, fit.json, fit.png.")
        ] = Path("fit"),
        strain_column: StrainColumnOpt = None,
        stress_column: StressColumnOpt = None,
        percent_strain: PercentStrainOpt = False,
        delimiter: DelimiterOpt = None,
        decimal: DecimalOpt = None,
        skip_rows: SkipRowsOpt = 0,
        quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress or table.")] = False,
        plan: PlanOpt = None,
        plan_only: PlanOnlyOpt = False,
    ) -> None:
        """Calibrate eta and fiber-law parameters to a measured stress-strain curve (paper 4.2).

        eta by a grid and bracket search, the fiber parameters by least squares for each eta,
        over RVE realizations with common seeds. Prints the fitted values with their
        uncertainty and writes fitted.toml (runs with espin simulate), fit.csv, fit.json, fit.png.
        """
        import logging

        from rich.console import Console

        from espin.analysis.calibration import fit
        from espin.analysis.calibration.result import FIT_OUTPUTS
        from espin.core.cluster import tls_security
        from espin.core.errors import EspinError
        from espin.core.output_folder import OutputFolder
        from espin.geometry.rve import resolve_config

        console = Console(stderr=True, quiet=quiet, width=140)
        live = _live_warnings(console)
        logging.getLogger("espin.analysis.calibration").addHandler(live)
        csv_options = read_options(strain_column, stress_column, percent_strain, delimiter, skip_rows, decimal)
        try:
            security = tls_security(tls_ca_file, tls_cert, tls_key)
            overrides = parse_set(set_)
            config = resolve_config(base, **overrides)
            curve, strain_rate = _curves(curves, rate, _parse_rates(curves_at_rate))
            seed_list = None if seeds is None else _parse_seeds(seeds)
            grid = _parse_grid(average_grid)
            options = [
                params,
                bounds,
                fix,
                realizations,
                seed_list,
                step_strain,
                grid,
                large_strain,
                eta_points,
                eta_tolerance,
                csv_options,
            ]
            digest = _inputs_digest(config, curve, strain_rate, options)
            plan_inputs = dict(
                base=config,
                parameters=[p for p in params.split(",") if p.strip()],
                bounds=_parse_bounds(bounds),
                fixed=_parse_fixed(fix),
                realizations=realizations,
                seeds=seed_list,
                strain_rate_per_s=strain_rate,
                step_strain=step_strain,
                average_grid=grid,
                large_strain=large_strain,
                eta_points=eta_points,
                eta_tolerance=eta_tolerance,
                read_options=csv_options,
            )
            _print_fit_plan(curve, plan_inputs, workers, scheduler, console, plan, plan_only)
            with (
                OutputFolder.claim(out, "fit", digest, FIT_OUTPUTS, overwrite=overwrite, resume="same-inputs"),
                curve_warnings(),
                console.status("fitting") as status,
                off_terminal_lines(console, "fitting: the first evaluation") as say,
            ):

                def on_evaluation(record: dict) -> None:
                    line = f"evaluation {record['evaluation']} ({record['stage']}): SSE {record['sse_MPa2']:.4g} MPa^2"
                    status.update(line)
                    say(line)  # off a terminal: one plain line each, repeated while the next runs

                result = fit(
                    curve,
                    **plan_inputs,
                    workers=workers,
                    scheduler=scheduler,
                    security=security,
                    on_evaluation=on_evaluation,
                )
                written = result.write_files(out)
        except EspinError as err:
            fail(err)
        finally:
            logging.getLogger("espin.analysis.calibration").removeHandler(live)
        console.print(_table(result))
        for curve, steps in zip(result.curves, result.load_steps):
            console.print(
                f"curve {curve.source} ({curve.strain_rate_per_s:g} 1/s): {curve.strain.size} points from "
                f"{curve.points_from}; {steps['load_steps']} load steps, at most {steps['step_strain']:g} "
                f"to strain {steps['fine_steps_to_strain']:.3g}, largest {steps['largest_step_strain']:.3g} "
                "overall",
                highlight=False,
                soft_wrap=True,
            )
        for warning in result.warnings:
            console.print(f"warning: {warning}", style="yellow", highlight=False, soft_wrap=True)
        console.print(
            f"{result.simulations} simulations ({result.failed_simulations} failed) in "
            f"{result.elapsed_s:.1f} s, {result.pool}; seeds {', '.join(map(str, result.seeds))}",
            highlight=False,
        )
        console.print(f"wrote {out}/: " + ", ".join(p.name for p in written.values()), highlight=False)
        console.print(f"next: espin simulate {out}/fitted.toml -o {out}/check", highlight=False, soft_wrap=True)
