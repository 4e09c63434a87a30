"""Fixtures shared by the imaging tests."""

from __future__ import annotations

import pytest
import typer


@pytest.fixture
def measure_app() -> typer.Typer:
    """A typer app with the ``measure`` command (and a second one, which keeps ``measure`` a
    subcommand), for CliRunner."""
    from espin.cli.measure import register

    app = typer.Typer()
    register(app)
    app.command("noop")(lambda: None)
    return app
