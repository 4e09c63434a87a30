"""The ``espin`` command line: one module per command group, wired into one typer app here.

Heavy imports happen inside the commands, so ``espin --help`` is fast. Shared options and
helpers are in :mod:`espin.cli.common`.
"""

from __future__ import annotations

from typing import Annotated

import typer

from espin.cli import calibrate_geometry, config, fit, generate, measure, properties, simulate, study

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
    version: Annotated[bool, typer.Option("--version", callback=_print_version, is_eager=True,
                                          help="Print espin's version and exit.")] = False,
) -> None:
    """Virtual electrospun fiber mats and their mechanics, from microstructure to curves."""


for _group in (generate, simulate, config, measure, properties, fit, study, calibrate_geometry):
    _group.register(app)

if __name__ == "__main__":  # pragma: no cover
    app()
