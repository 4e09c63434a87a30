"""The ``espin`` command line: one module per command group, wired into one typer app here.

Heavy imports happen inside the commands, so ``espin --help`` is fast. Shared options and
helpers are in :mod:`espin.cli.common`.
"""

from __future__ import annotations

import typer

from espin.cli import calibrate_geometry, config, fit, generate, measure, properties, simulate, study

__all__ = ["app"]

app = typer.Typer(
    name="espin",
    help="Virtual electrospun fiber mats and their mechanics, from microstructure to curves.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

for _group in (generate, simulate, config, measure, properties, fit, study, calibrate_geometry):
    _group.register(app)

if __name__ == "__main__":  # pragma: no cover
    app()
