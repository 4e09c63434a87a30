"""The command line's help and version: every option name in full at 80 columns."""

from __future__ import annotations

import subprocess
import sys

import pytest
import typer.main
from typer.testing import CliRunner

from espin.cli import app
from espin.core.version import __version__


def _commands(command, path: tuple[str, ...] = ()):
    yield path, command
    if hasattr(command, "commands"):  # a group (typer's own click classes, not click's)
        for name, sub in command.commands.items():
            yield from _commands(sub, (*path, name))


COMMANDS = list(_commands(typer.main.get_command(app)))


@pytest.mark.parametrize("path,command", COMMANDS, ids=[" ".join(p) or "espin" for p, _ in COMMANDS])
def test_help_shows_every_option_name_in_full_at_80_columns(path, command):
    result = CliRunner().invoke(app, [*path, "--help"], terminal_width=80, env={"COLUMNS": "80"})
    assert result.exit_code == 0, result.output
    names = [name for p in command.params if p.param_type_name == "option" for name in (*p.opts, *p.secondary_opts)]
    words = {word.strip(",[]") for word in result.output.split()}
    missing = [name for name in [*names, "--help"] if name not in words]
    assert not missing, result.output
    assert max(len(line) for line in result.output.splitlines()) <= 80


def test_version_from_the_command_and_the_module():
    result = CliRunner().invoke(app, ["--version"])
    assert result.exit_code == 0 and result.output.strip() == f"espin {__version__}"
    module = subprocess.run([sys.executable, "-m", "espin", "--version"], capture_output=True, text=True, check=True)
    assert module.stdout.strip() == f"espin {__version__}"


def test_verbose_and_log_file(tmp_path):
    log = tmp_path / "espin.log"
    for _ in range(2):  # a second call replaces the first one's handlers, it does not add to them
        result = CliRunner().invoke(app, ["-v", "--log-file", str(log), "generate", "plla", "--size-ratio", "30",
                                          "--layers", "2", "--no-figures", "--no-vtk", "-q", "-o", str(tmp_path / "g"),
                                          "--overwrite"])
        assert result.exit_code == 0, result.output
    lines = log.read_text().splitlines()
    assert sum("depositing 2 layers" in line for line in lines) == 2
    assert "INFO espin.geometry.rve: depositing 2 layers" in result.output
    bad = CliRunner().invoke(app, ["--log-file", str(tmp_path / "no" / "such.log"), "config"])
    assert bad.exit_code == 2 and "--log-file" in bad.output
