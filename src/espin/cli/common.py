"""What the command groups share: the config source and ``--set`` options, how a command fails,
and the options of every command that reads curve CSV files (``properties``, ``fit``).

No command imports another command or the app: each imports from here.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Annotated, Any, NoReturn, Optional

import typer

__all__ = [
    "SourceArg",
    "SetOpt",
    "OverwriteOpt",
    "AllowLargeOpt",
    "PlanOpt",
    "PlanOnlyOpt",
    "parse_set",
    "fail",
    "StrainColumnOpt",
    "StressColumnOpt",
    "PercentStrainOpt",
    "DelimiterOpt",
    "DecimalOpt",
    "SkipRowsOpt",
    "read_options",
    "curve_warnings",
    "print_plan",
    "LONG_WORK_S",
    "off_terminal_lines",
    "HEARTBEAT_S",
]

SourceArg = Annotated[
    Optional[str],
    typer.Argument(help="Preset name (plla) or TOML config file. Default: plla."),
]
SetOpt = Annotated[
    Optional[list[str]],
    typer.Option(
        "--set",
        help="Override any config key: --set section.key=VALUE (VALUE in TOML syntax, "
        "e.g. --set 'rve.orientation={von_mises={mean_deg=0, kappa=2}}'). Repeatable.",
    ),
]


OverwriteOpt = Annotated[
    bool,
    typer.Option(
        "--overwrite",
        help="Replace the results of another run in the output folder "
        "(its files are removed first); without it such a folder is refused.",
    ),
]
AllowLargeOpt = Annotated[
    bool,
    typer.Option(
        "--allow-large",
        help="Go on when the RVE is estimated to need more memory than "
        "is available (the estimate is printed in the refusal).",
    ),
]

PlanOpt = Annotated[
    Optional[bool],
    typer.Option(
        "--plan/--no-plan",
        envvar="ESPIN_PLAN",
        help="Print the plan before the work: tensile tests x DOF -> estimated time on the "
        "workers, from a speed calibration of this machine (at most 2 s). Default: only "
        "when the work looks long (a minute or more at reference speed). Environment: "
        "ESPIN_PLAN=1 / 0.",
    ),
]
PlanOnlyOpt = Annotated[
    bool,
    typer.Option(
        "--plan-only",
        help="Print the plan (tensile tests x DOF -> estimated time on this machine) on stdout "
        "and stop: nothing is run and no folder is written.",
    ),
]
LONG_WORK_S = 60.0
"""Work expected to take at least this long at the reference speed [s] gets its plan printed by
default (the speed calibration then costs at most 2 s more)."""


def print_plan(
    make_text: Callable[[Any], str],
    console: Any,
    plan: bool | None,
    reference_seconds: Callable[[], float],
    only: bool = False,
) -> None:
    """Print a long command's plan (one plain line on ``console``) before its work starts.

    Parameters
    ----------
    make_text
        ``make_text(calibration)`` -> the plan's text
        (:class:`espin.mechanics.cost.Calibration`).
    console
        A rich console (quiet: nothing is printed and nothing is calibrated).
    plan
        ``--plan/--no-plan``: True always, False never, None when ``reference_seconds()`` is
        at least :data:`LONG_WORK_S`.
    reference_seconds
        The work's expected time at the reference speed [s] (no calibration needed).
    only
        ``--plan-only``: print the plan on stdout whatever ``plan`` and quiet say, then end the
        command (exit status 0); a plan that cannot be made is then an error.

    A plan that cannot be made (a config error the command itself will report, a calibration
    that failed) is left out: the command goes on.
    """
    import logging

    from espin.mechanics.cost import calibrate

    if only:
        typer.echo(make_text(calibrate()))
        raise typer.Exit(0)
    if plan is False or getattr(console, "quiet", False):
        return
    try:
        if plan is None and reference_seconds() < LONG_WORK_S:
            return
        text = make_text(calibrate())
    except Exception as exc:  # noqa: BLE001 - the plan is an extra: the command itself goes on
        logging.getLogger("espin.cli").debug("no plan: %s", exc)
        return
    console.print(text, highlight=False, soft_wrap=True)


HEARTBEAT_S = 20.0
"""Off a terminal, a long phase's last line is printed again after this long without a line [s]:
no phase of a command is silent for 30 s in a log file or a batch job's output."""


@contextmanager
def off_terminal_lines(console: Any, first: str) -> Iterator[Callable[[str], None]]:
    """A long phase's progress off a terminal (a log file, a batch job), where rich draws no
    live bar or spinner: yields ``say(text)``, which prints ``text`` as one plain line with the
    time elapsed since the phase began; the last line is printed again (``still ...``) after
    :data:`HEARTBEAT_S` seconds without one. ``first`` is printed at once.

    On a terminal (its live display shows the progress) and with a quiet console, ``say`` does
    nothing.
    """
    import threading
    import time

    from espin.core.progress import clock

    if console.is_terminal or getattr(console, "quiet", False):
        yield lambda text: None
        return
    start = time.monotonic()
    lock = threading.Lock()
    last_text, last_at = first, start

    def say(text: str, again: bool = False) -> None:
        nonlocal last_text, last_at
        with lock:
            last_text, last_at = text, time.monotonic()
            console.print(
                f"{'still: ' if again else ''}{text}  [{clock(last_at - start)} elapsed]",
                highlight=False,
                soft_wrap=True,
            )

    def beat() -> None:
        while not stop.wait(min(1.0, HEARTBEAT_S / 4)):
            if time.monotonic() - last_at >= HEARTBEAT_S:
                say(last_text, again=True)

    stop = threading.Event()
    say(first)
    thread = threading.Thread(target=beat, name="espin-heartbeat", daemon=True)
    thread.start()
    try:
        yield say
    finally:
        stop.set()
        thread.join()


def parse_set(items: list[str] | None) -> dict[str, Any]:
    """``--set section.key=VALUE`` items as config overrides (VALUE in TOML syntax, else a bare word)."""
    import tomllib

    from espin.core.errors import ConfigError

    out: dict[str, Any] = {}
    for item in items or []:
        key, sep, text = item.partition("=")
        if not sep:
            raise ConfigError(f"--set {item!r}: expected section.key=VALUE")
        try:
            value = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError:
            value = text  # a bare word such as lines or uniform
        except RecursionError:
            raise ConfigError(f"--set {key.strip()[:60]}: the value nests too deeply to be a config value") from None
        out[key.strip()] = value
    return out


def fail(error: Exception | str) -> NoReturn:
    """Print ``error: message`` in red on stderr and exit with the error's code.

    The code follows the error's type (:mod:`espin.core.errors`): 2 for a usage error (and for
    a plain message), 3 for bad input data, 4 for a solver failure.
    """
    typer.secho(f"error: {error}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=getattr(error, "exit_code", 2))


_DELIMITER_NAMES = {"tab": "\t", "\\t": "\t", "space": " ", "whitespace": " "}

# Options of every command that reads curve CSV files (properties, fit).
StrainColumnOpt = Annotated[
    Optional[str],
    typer.Option(
        help="Strain column: 0-based index or header name (any case). "
        "Default: the header's 'strain' column; 0 without a header or with two columns."
    ),
]
StressColumnOpt = Annotated[
    Optional[str],
    typer.Option(
        help="Stress column [MPa]: 0-based index or header name (any case). "
        "Default: the header's 'stress_MPa', 'stress [MPa]', 'stress (MPa)', 'stress' or "
        "'mean_MPa' column; 1 without a header or with two columns."
    ),
]
PercentStrainOpt = Annotated[
    bool,
    typer.Option(help="The strain column is in percent (a curve whose strain exceeds 1 without it is warned about)."),
]
DelimiterOpt = Annotated[
    Optional[str],
    typer.Option(help="Field separator, one character (',', ';', tab, space). Default: detected from the first line."),
]
DecimalOpt = Annotated[
    Optional[str],
    typer.Option(
        help="Decimal mark, '.' or ','. Default: ',' when a file not separated "
        "by commas has commas and no points in its numbers (0,01;1,5)."
    ),
]
SkipRowsOpt = Annotated[int, typer.Option(min=0, help="Lines (rows) to skip at the top of each file.")]


def read_options(
    strain_column: str | None,
    stress_column: str | None,
    percent_strain: bool,
    delimiter: str | None,
    skip_rows: int,
    decimal: str | None = None,
) -> dict:
    """The curve-file options of the command line as keyword arguments of
    :func:`espin.analysis.experiments.read_curve` (which checks their values)."""
    return {
        "strain_column": _column(strain_column),
        "stress_column": _column(stress_column),
        "percent_strain": percent_strain,
        "delimiter": _DELIMITER_NAMES.get(delimiter.lower(), delimiter) if delimiter else None,
        "skip_rows": skip_rows,
        "decimal": decimal,
    }


@contextmanager
def curve_warnings() -> Iterator[None]:
    """Show the curve readers' warnings (units that look wrong) as ``warning: message`` lines on
    stderr, each time one is given; other warnings are shown as usual."""
    import warnings

    from espin.analysis.experiments import CurveWarning

    with warnings.catch_warnings():
        warnings.simplefilter("always", CurveWarning)
        usual = warnings.showwarning

        def show(
            message: Warning | str,
            category: type[Warning],
            filename: str,
            lineno: int,
            file: Any = None,
            line: str | None = None,
        ) -> None:
            if issubclass(category, CurveWarning):
                typer.secho(f"warning: {message}", fg=typer.colors.YELLOW, err=True)
            else:
                usual(message, category, filename, lineno, file, line)

        warnings.showwarning = show
        yield


def _column(text: str | None) -> int | str | None:
    """A column option: a 0-based index when it is a (short) decimal number, else a header name."""
    if text is None:
        return None
    index = text.strip()
    return int(index) if index.isdecimal() and len(index) < 10 else text
