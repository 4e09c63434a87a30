"""The ``espin properties`` command: mechanical properties of measured or simulated curves.

``register(app)`` adds the command to espin's typer app. Heavy imports happen inside the
command, so ``espin --help`` stays fast.
"""

from __future__ import annotations

from contextlib import AbstractContextManager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Optional

import typer

from espin.cli.common import (
    DecimalOpt,
    DelimiterOpt,
    OverwriteOpt,
    PercentStrainOpt,
    SkipRowsOpt,
    StrainColumnOpt,
    StressColumnOpt,
    curve_warnings,
    fail,
    read_options,
)

if TYPE_CHECKING:  # pragma: no cover
    from espin.analysis.experiments import AveragedCurve, Curve
    from espin.analysis.properties import CurveProperties

__all__ = ["register"]

PROPERTIES_OUTPUTS = ("properties.csv", "average_curve.csv", "properties.png")
"""The files the command writes into its ``--out`` folder."""


def _strain_range(text: str | None, percent: bool) -> tuple[float | None, float | None] | None:
    """``--strain-range LO:HI`` as fractions (either end may be empty; percent when ``percent``).

    Raises
    ------
    ConfigError
        If the text is not ``LO:HI`` with finite numbers and LO < HI.
    """
    import math

    from espin.core.errors import ConfigError

    if text is None:
        return None
    rule = ("--strain-range: LO:HI strains with LO < HI, either end may be left empty (e.g. 0.02: "
            "or, with --percent-strain, 2:)")
    parts = text.split(":")
    if len(parts) != 2:
        raise ConfigError(f"{rule}; got {text!r}")
    bounds: list[float | None] = []
    for part in parts:
        if not part.strip():
            bounds.append(None)
            continue
        try:
            value = float(part)
        except ValueError:
            raise ConfigError(f"{rule}; got {text!r}") from None
        if not math.isfinite(value):
            raise ConfigError(f"{rule}; got {text!r}")
        bounds.append(value / 100.0 if percent else value)
    lo, hi = bounds
    if lo is not None and hi is not None and not lo < hi:
        raise ConfigError(f"{rule}; got {text!r}")
    return lo, hi


def _row(name: str, props: CurveProperties) -> list[str]:
    yield_strain = f"{100 * props.yield_strain:.3g}" if props.has_yield else "-"
    return [
        name,
        f"{props.modulus_MPa:.4g}",
        f"{props.yield_stress_MPa:.4g}" if props.has_yield else "-",
        yield_strain,
        f"{props.post_yield_modulus_MPa:.4g}" if props.has_yield else "-",
        f"{props.r_squared:.4f}",
        props.note,
    ]


def _summary_row(summary: dict[str, dict[str, float]], n_curves: int) -> list[str]:
    def cell(name: str, scale: float = 1.0) -> str:
        s = summary[name]
        if s["n"] == 0:
            return "-"
        sd = f" ± {scale * s['sd']:.2g}" if s["n"] > 1 else ""
        return f"{scale * s['mean']:.4g}{sd}"

    with_yield = summary["yield_stress_MPa"]["n"]
    note = "" if with_yield == n_curves else f"yield in {with_yield} of {n_curves}"
    return [f"mean ± sd (N = {n_curves})", cell("modulus_MPa"), cell("yield_stress_MPa"),
            cell("yield_strain", 100.0), cell("post_yield_modulus_MPa"), cell("r_squared"), note]


_HEADER = ["curve", "E [MPa]", "yield stress [MPa]", "yield strain [%]", "post-yield modulus [MPa]",
           "R^2", "note"]


def _write_table(records: list[dict], path: Path) -> Path:
    """The properties as CSV, full precision, one row per curve (and summary rows)."""
    import pandas as pd

    from espin.core.atomic import atomic_write_bytes

    text = pd.DataFrame(records).to_csv(index=False, float_format="%.10g")
    return atomic_write_bytes(path, text.encode("utf-8"))


def _summary_records(summary: dict[str, dict[str, float]], n_curves: int) -> list[dict]:
    """Rows ``mean`` and ``sd`` over the specimens for properties.csv."""
    with_yield = summary["yield_stress_MPa"]["n"]
    note = f"yield quantities over the {with_yield} of {n_curves} specimens with a yield"
    return [{"curve": stat} | {name: s[stat] for name, s in summary.items()} | {"note": note}
            for stat in ("mean", "sd")]


@dataclass
class _Analysis:
    """What the command computed: curves, their properties, the average and the table."""

    names: list[str]
    curves: list[Curve]
    fitted: list[CurveProperties]
    average: AveragedCurve | None
    average_props: CurveProperties | None
    rows: list[list[str]]
    records: list[dict]


def _analyse(curves: list[Curve],
             strain_range: tuple[float | None, float | None] | None = None) -> _Analysis:
    """Fit each curve (on ``strain_range``, fractions); with several, summarize them and fit
    their average.

    Raises
    ------
    CurveError
        If a curve cannot be fitted; the message starts with the curve's source.
    """
    from espin.analysis.experiments import average_curves
    from espin.analysis.properties import CurveError, curve_properties, summarize_properties

    def fit(source: str, strain, stress) -> CurveProperties:
        try:
            return curve_properties(strain, stress, strain_range=strain_range)
        except CurveError as err:
            raise CurveError(f"{source}: {err}") from None

    short = [Path(c.source).name for c in curves]
    names = short if len(set(short)) == len(short) else [c.source for c in curves]
    fitted = [fit(c.source, c.strain, c.stress_MPa) for c in curves]
    rows = [_row(name, props) for name, props in zip(names, fitted)]
    records = [{"curve": c.source} | p.as_dict() for c, p in zip(curves, fitted)]
    average = average_props = None
    if len(curves) > 1:
        summary = summarize_properties(fitted)
        rows.append(_summary_row(summary, len(curves)))
        records += _summary_records(summary, len(curves))
        average = average_curves(curves)
        average_props = fit("the average curve", average.strain, average.mean_MPa)
        rows.append(_row("average curve", average_props))
        records.append({"curve": "average"} | average_props.as_dict())
    return _Analysis(names, curves, fitted, average, average_props, rows, records)


def _write_outputs(analysis: _Analysis, folder: Path) -> list[Path]:
    """properties.csv, average_curve.csv (several curves) and properties.png in ``folder``."""
    from espin.analysis.properties import plot_bilinear_fits

    written = [_write_table(analysis.records, folder / "properties.csv")]
    plotted = [(name, c.strain, c.stress_MPa, p)
               for name, c, p in zip(analysis.names, analysis.curves, analysis.fitted)]
    band = None
    average = analysis.average
    if average is not None:
        written.append(average.to_csv(folder / "average_curve.csv"))
        plotted.append(("average", average.strain, average.mean_MPa, analysis.average_props))
        band = (average.strain, average.mean_MPa, average.sd_MPa)
    written.append(plot_bilinear_fits(plotted, folder / "properties.png", band=band))
    return written


def _claim(out: Path | None, paths: list[Path], options: list[Any], overwrite: bool) -> AbstractContextManager:
    """The ``--out`` folder claimed for this run (:mod:`espin.core.output_folder`); nothing
    without ``--out``."""
    from contextlib import nullcontext

    from espin.core.output_folder import OutputFolder, inputs_digest

    if out is None:
        return nullcontext()
    return OutputFolder.claim(out, "properties", inputs_digest(paths, options), PROPERTIES_OUTPUTS,
                              overwrite=overwrite)


def register(app: typer.Typer) -> None:
    """Add the ``properties`` command to ``app``."""

    @app.command("properties")
    def properties(
        curves: Annotated[
            list[Path],
            typer.Argument(help="CSV / text files or .xlsx workbooks of stress-strain curves (specimens, "
                                "or espin's curve.csv)."),
        ],
        strain_column: StrainColumnOpt = None,
        stress_column: StressColumnOpt = None,
        percent_strain: PercentStrainOpt = False,
        delimiter: DelimiterOpt = None,
        decimal: DecimalOpt = None,
        skip_rows: SkipRowsOpt = 0,
        strain_range: Annotated[
            Optional[str],
            typer.Option(metavar="LO:HI",
                         help="Fit only the points with LO <= strain <= HI, in the strain "
                              "column's units (percent with --percent-strain); either end may "
                              "be empty, e.g. 0.02: to leave out a toe region. Default: all."),
        ] = None,
        out: Annotated[
            Optional[Path],
            typer.Option("--out", "-o", help="Folder for properties.csv, the averaged curve "
                                             "(average_curve.csv, 2+ curves), properties.png "
                                             "and run.json."),
        ] = None,
        overwrite: OverwriteOpt = False,
    ) -> None:
        """Elastic modulus, yield and post-yield modulus of curves by a bilinear fit (docs/model.md section 7).

        With several curves (specimens) also their mean ± sd and the properties of their
        average curve.
        """
        from rich.console import Console
        from rich.table import Table

        from espin.analysis.experiments import read_curve
        from espin.core.errors import EspinError

        try:
            options = read_options(strain_column, stress_column, percent_strain, delimiter, skip_rows,
                                   decimal)
            fit_range = _strain_range(strain_range, percent_strain)
            with curve_warnings():
                read = [read_curve(path, **options) for path in curves]
                with _claim(out, curves, [options, fit_range], overwrite):  # after the inputs are read
                    analysis = _analyse(read, fit_range)
                    written = [] if out is None else _write_outputs(analysis, out)
        except EspinError as err:
            fail(err)
        table = Table(*_HEADER, title="bilinear fit: E = initial slope, yield = intersection of the lines")
        for row in analysis.rows:
            table.add_row(*row)
        console = Console(width=140)
        console.print(table)
        if out is not None:
            console.print(f"wrote {out}/: " + ", ".join(p.name for p in written), highlight=False)
