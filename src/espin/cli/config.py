"""``espin config``: the resolved configuration of a preset or file, every key filled in."""

from __future__ import annotations

import sys

import typer

from espin.cli.common import SetOpt, SourceArg, fail, parse_set

__all__ = ["register"]


def show_config(source: SourceArg = None, set_: SetOpt = None) -> None:
    """Print the resolved configuration (TOML) of a preset or file, defaults filled in."""
    from espin.core.config import config_to_toml
    from espin.core.errors import EspinError
    from espin.geometry.rve import resolve_config

    try:
        overrides = parse_set(set_)
        config = resolve_config(source, **overrides)
    except EspinError as err:
        fail(err)
    sys.stdout.write(config_to_toml(config))


def register(app: typer.Typer) -> None:
    """Add the ``config`` command to a typer app."""
    app.command("config")(show_config)
