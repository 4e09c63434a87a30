"""The ``espin properties`` command: mechanical properties of measured or simulated curves.

``register(app)`` adds the command to espin's typer app. Heavy imports happen inside the
command, so ``espin --help`` stays fast.
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Optional, cast

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
    rule = (
        "--strain-range: LO:HI strains with LO < HI, either end may be left empty (e.g. 0.02: "
        "or, with --percent-strain, 2:)"
    )
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
    return [
        f"mean ± sd (N = {n_curves})",
        cell("modulus_MPa"),
        cell("yield_stress_MPa"),
        cell("yield_strain", 100.0),
        cell("post_yield_modulus_MPa"),
        cell("r_squared"),
        note,
    ]


def _standard_options(
    chord_range: str | None, percent: bool, offset_percent: float, break_drop_percent: float
) -> dict[str, Any]:
    """Keywords of :func:`~espin.analysis.standard_properties.standard_properties` from the
    command's options; a stated chord range must hold points of every curve."""
    import math

    from espin.analysis.standard_properties import ISO_CHORD_RANGE
    from espin.core.errors import ConfigError

    if not (math.isfinite(offset_percent) and offset_percent > 0.0):
        raise ConfigError(f"--offset-percent: a strain > 0 %, e.g. 0.2 (got {offset_percent})")
    if not 0.0 < break_drop_percent < 100.0:
        raise ConfigError(f"--break-drop-percent: in (0, 100) (got {break_drop_percent})")
    chord = ISO_CHORD_RANGE
    if chord_range is not None:
        lo, hi = cast(tuple[float | None, float | None], _strain_range(chord_range, percent))  # text given
        if lo is None or hi is None or lo < 0.0:
            raise ConfigError(f"--chord-range: LO:HI, both given, 0 <= LO < HI (got {chord_range!r})")
        chord = (lo, hi)
    return {
        "chord_range": chord,
        "offset": offset_percent / 100.0,
        "break_drop": break_drop_percent / 100.0,
        "require_chord": chord_range is not None,
    }


def _percent(strains: tuple[float, float]) -> str:
    return f"{100 * strains[0]:g} % to {100 * strains[1]:g} %"


def _standard_row(name: str, p) -> list[str]:
    def cell(value: float, scale: float = 1.0) -> str:
        return "-" if value != value else f"{scale * value:.4g}"

    return [
        name,
        cell(p.chord_modulus_MPa),
        cell(p.offset_yield_stress_MPa),
        cell(p.offset_yield_strain, 100.0),
        cell(p.tensile_strength_MPa),
        cell(p.strain_at_strength, 100.0),
        cell(p.strain_at_break, 100.0),
        p.note,
    ]


_STANDARD_HEADER = [
    "curve",
    "chord modulus [MPa]",
    "offset yield [MPa]",
    "at strain [%]",
    "tensile strength [MPa]",
    "at strain [%]",
    "strain at break [%]",
    "note",
]

_HEADER = ["curve", "E [MPa]", "yield stress [MPa]", "yield strain [%]", "post-yield modulus [MPa]", "R^2", "note"]


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
    return [
        {"curve": stat} | {name: s[stat] for name, s in summary.items()} | {"note": note} for stat in ("mean", "sd")
    ]


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
    standard_options: dict[str, Any]
    standard_rows: list[list[str]]


def _analyse(
    curves: list[Curve],
    strain_range: tuple[float | None, float | None] | None = None,
    standard: dict[str, Any] | None = None,
) -> _Analysis:
    """Fit each curve (on ``strain_range``, fractions) and find its standard tensile
    properties (``standard``: the keywords of
    :func:`espin.analysis.standard_properties.standard_properties`); with several, summarize
    them and fit their average.

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

    from espin.analysis.standard_properties import standard_properties

    standard = _standard_options(None, False, 0.2, 50.0) if standard is None else standard

    def measure(source: str, strain, stress):
        try:
            return standard_properties(strain, stress, **standard)
        except CurveError as err:
            raise CurveError(f"{source}: {err}") from None

    short = [Path(c.source).name for c in curves]
    names = short if len(set(short)) == len(short) else [c.source for c in curves]
    fitted = [fit(c.source, c.strain, c.stress_MPa) for c in curves]
    rows = [_row(name, props) for name, props in zip(names, fitted)]
    measured = [measure(c.source, c.strain, c.stress_MPa) for c in curves]
    standard_rows = [_standard_row(name, p) for name, p in zip(names, measured)]
    records = [
        {"curve": c.source} | p.as_dict() | {f"standard_{k}": v for k, v in m.as_dict().items()}
        for c, p, m in zip(curves, fitted, measured)
    ]
    average = average_props = None
    if len(curves) > 1:
        summary = summarize_properties(fitted)
        rows.append(_summary_row(summary, len(curves)))
        records += _summary_records(summary, len(curves))
        average = average_curves(curves)
        average_props = fit("the average curve", average.strain, average.mean_MPa)
        rows.append(_row("average curve", average_props))
        records.append({"curve": "average"} | average_props.as_dict())
    return _Analysis(names, curves, fitted, average, average_props, rows, records, standard, standard_rows)


def _write_outputs(analysis: _Analysis, folder: Path) -> list[Path]:
    """properties.csv, average_curve.csv (several curves) and properties.png in ``folder``."""
    from espin.analysis.properties import plot_bilinear_fits

    written = [_write_table(analysis.records, folder / "properties.csv")]
    plotted = [
        (name, c.strain, c.stress_MPa, p) for name, c, p in zip(analysis.names, analysis.curves, analysis.fitted)
    ]
    band = None
    average = analysis.average
    if average is not None:
        written.append(average.to_csv(folder / "average_curve.csv"))
        plotted.append(("average", average.strain, average.mean_MPa, cast("CurveProperties", analysis.average_props)))
        band = (average.strain, average.mean_MPa, average.sd_MPa)
    written.append(
        plot_bilinear_fits(
            plotted, folder / "properties.png", band=band, band_n=len(analysis.curves) if band is not None else None
        )
    )
    return written


def _claim(out: Path | None, paths: list[Path], options: list[Any], overwrite: bool) -> AbstractContextManager:
    """The ``--out`` folder claimed for this run (:mod:`espin.core.output_folder`); nothing
    without ``--out``."""
    from contextlib import nullcontext

    from espin.core.output_folder import OutputFolder, inputs_digest

    if out is None:
        return nullcontext()
    return OutputFolder.claim(out, "properties", inputs_digest(paths, options), PROPERTIES_OUTPUTS, overwrite=overwrite)


def _print_table(console: Any, header: Sequence[str], rows: Sequence[Sequence[str]], title: str) -> None:
    """A table whose last column (the notes) holds footnote marks [1], [2], ..., the notes
    printed in full below it (the same note once), so that long reasons do not stretch rows."""
    from rich.table import Table
    from rich.text import Text

    notes: list[str] = []
    table = Table(*header, title=title)
    for *cells, note in rows:
        if note and note not in notes:
            notes.append(note)
        table.add_row(*cells, Text(f"[{notes.index(note) + 1}]") if note else "")
    console.print(table)
    for k, note in enumerate(notes, start=1):
        console.print(f"  [{k}] {note}", highlight=False, markup=False)


def register(app: typer.Typer) -> None:
    """Add the ``properties`` command to ``app``."""

    @app.command("properties")
    def properties(
        curves: Annotated[
            list[Path],
            typer.Argument(
                help="CSV / text files or .xlsx workbooks of stress-strain curves (specimens, or espin's curve.csv)."
            ),
        ],
        strain_column: StrainColumnOpt = None,
        stress_column: StressColumnOpt = None,
        percent_strain: PercentStrainOpt = False,
        delimiter: DelimiterOpt = None,
        decimal: DecimalOpt = None,
        skip_rows: SkipRowsOpt = 0,
        strain_range: Annotated[
            Optional[str],
            typer.Option(
                metavar="LO:HI",
                help="Fit only the points with LO <= strain <= HI, in the strain "
                "column's units (percent with --percent-strain); either end may "
                "be empty, e.g. 0.02: to leave out a toe region. Default: all.",
            ),
        ] = None,
        chord_range: Annotated[
            Optional[str],
            typer.Option(
                metavar="LO:HI",
                help="Strain range of the chord modulus, in the strain column's units "
                "(percent with --percent-strain); at least two points of each "
                "curve must lie in it. Default: 0.05 % to 0.25 % (ISO 527-1), "
                "reported as missing where a curve has no points there.",
            ),
        ] = None,
        offset_percent: Annotated[
            float, typer.Option(help="Offset strain of the offset yield (proof stress), percent.")
        ] = 0.2,
        break_drop_percent: Annotated[
            float,
            typer.Option(
                help="Drop of the stress after its maximum, percent of the tensile strength, that marks the break."
            ),
        ] = 50.0,
        out: Annotated[
            Optional[Path],
            typer.Option(
                "--out",
                "-o",
                help="Folder for properties.csv, the averaged curve "
                "(average_curve.csv, 2+ curves), properties.png "
                "and run.json.",
            ),
        ] = None,
        overwrite: OverwriteOpt = False,
    ) -> None:
        """Elastic modulus, yield and post-yield modulus of curves by a bilinear fit (docs/model.md section 7).

        With several curves (specimens) also their mean ± sd and the properties of their
        average curve. Beside the fit, what testing standards report (ISO 527-1, ASTM D882;
        docs/properties.md): chord modulus, offset yield, tensile strength, strain at break.
        """
        from rich.console import Console

        from espin.analysis.experiments import read_curve
        from espin.core.errors import EspinError

        try:
            options = read_options(strain_column, stress_column, percent_strain, delimiter, skip_rows, decimal)
            fit_range = _strain_range(strain_range, percent_strain)
            standard = _standard_options(chord_range, percent_strain, offset_percent, break_drop_percent)
            with curve_warnings():
                read = [read_curve(path, **options) for path in curves]
                with _claim(out, curves, [options, fit_range, standard], overwrite):  # after the inputs are read
                    analysis = _analyse(read, fit_range, standard)
                    written = [] if out is None else _write_outputs(analysis, out)
        except EspinError as err:
            fail(err)
        console = Console(width=140)
        _print_table(
            console, _HEADER, analysis.rows, "bilinear fit: E = initial slope, yield = intersection of the lines"
        )
        _print_table(
            console,
            _STANDARD_HEADER,
            analysis.standard_rows,
            (
                f"testing standards: chord modulus over {_percent(analysis.standard_options['chord_range'])} strain, "
                f"offset yield at {analysis.standard_options['offset'] * 100:g} %, break at a "
                f"{analysis.standard_options['break_drop'] * 100:g} % drop"
            ),
        )
        if out is not None:
            console.print(f"wrote {out}/: " + ", ".join(p.name for p in written), highlight=False)
