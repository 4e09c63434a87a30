"""The ``espin`` command line: one module per command group, wired into one typer app here.

Heavy imports happen inside the commands, so ``espin --help`` is fast. Shared options and
helpers are in :mod:`espin.cli.common`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from espin.cli import (
    calibrate_geometry,
    config,
    design,
    example_data,
    fit,
    generate,
    measure,
    properties,
    simulate,
    specimen,
    study,
)

__all__ = ["app"]

app = typer.Typer(
    name="espin",
    help="Virtual electrospun fiber mats and their mechanics, from microstructure to curves.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    # Plain (click) help: rich's option tables cut long option names short at 80 columns.
    rich_markup_mode=None,
)


def _print_version(value: bool) -> None:
    if value:
        from espin.core.version import __version__

        typer.echo(f"espin {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[
        bool, typer.Option("--version", callback=_print_version, is_eager=True, help="Print espin's version and exit.")
    ] = False,
    verbose: Annotated[
        bool, typer.Option("--verbose", "-v", help="Print what espin does (its log, INFO level) on stderr.")
    ] = False,
    log_file: Annotated[
        Optional[Path], typer.Option(help="Append espin's full log (DEBUG level, with times) to this file.")
    ] = None,
) -> None:
    """Virtual electrospun fiber mats and their mechanics, from microstructure to curves."""
    _configure_logging(verbose, log_file)


def _configure_logging(verbose: bool, log_file: Path | None) -> None:
    """The ``espin`` logger's handlers for ``--verbose`` (stderr, INFO) and ``--log-file``
    (appended, DEBUG); without either, espin logs nothing."""
    import logging

    logger = logging.getLogger("espin")
    for old in [h for h in logger.handlers if getattr(h, "espin_cli", False)]:  # an earlier call's
        logger.removeHandler(old)
        old.close()
    handlers: list[logging.Handler] = []
    if verbose:
        handler: logging.Handler = logging.StreamHandler()
        handler.setLevel(logging.INFO)
        handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
        handlers.append(handler)
    if log_file is not None:
        try:
            file_handler = logging.FileHandler(log_file, mode="a", encoding="utf-8")
        except OSError as err:
            raise typer.BadParameter(
                f"cannot open {log_file} for appending: {err.strerror or err}", param_hint="--log-file"
            ) from None
        file_handler.setLevel(logging.DEBUG)
        file_handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
        handlers.append(file_handler)
    for handler in handlers:
        handler.espin_cli = True  # type: ignore[attr-defined]  # our mark, to find our handlers again
        logger.addHandler(handler)
    if handlers:
        logger.setLevel(logging.DEBUG if log_file is not None else logging.INFO)


for _group in (
    generate,
    simulate,
    config,
    measure,
    properties,
    fit,
    study,
    design,
    specimen,
    calibrate_geometry,
    example_data,
):
    _group.register(app)

if __name__ == "__main__":  # pragma: no cover
    app()
