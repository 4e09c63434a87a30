"""The source keeps its habits: ``ruff check src``, ``ruff format --check src`` and ``mypy src/espin``
find nothing.

Both tools are configured in ``pyproject.toml`` ([tool.ruff], [tool.mypy]) and come with the
``test`` extra; where one is not installed its test is skipped and says so. A failure shows the
tool's own report.
"""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]


def _command(tool: str) -> list[str]:
    """How to run ``tool``: as a module of this Python if it has one, else from PATH; or skip."""
    if importlib.util.find_spec(tool) is not None:
        return [sys.executable, "-m", tool]
    found = shutil.which(tool)
    if found is None:
        pytest.skip(f"{tool} is not installed (pip install -e '.[test]' brings it)")
    return [found]


def _run(tool: str, *args: str) -> None:
    done = subprocess.run([*_command(tool), *args], cwd=ROOT, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        pytest.fail(f"{tool} {' '.join(args)} exited with {done.returncode}:\n{done.stdout}{done.stderr}",
                    pytrace=False)


def test_ruff_finds_nothing_in_src():
    _run("ruff", "check", "--no-fix", "src")


def test_src_is_formatted():
    _run("ruff", "format", "--check", "src")


@pytest.mark.slow
def test_mypy_finds_nothing_in_src():
    # About 20 s without mypy's cache (.mypy_cache in the checkout), 1-2 s with it.
    _run("mypy", "--config-file", "pyproject.toml", "src/espin")
