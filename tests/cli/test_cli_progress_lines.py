"""Off a terminal (a log file, a batch job) a long command's phases print plain lines, with the
time elapsed, and repeat the last one while a phase runs on: none is silent for 30 s."""

from __future__ import annotations

import io
import time

from rich.console import Console

import espin.cli.common as common


def _console(terminal: bool, quiet: bool = False) -> tuple[Console, io.StringIO]:
    out = io.StringIO()
    return Console(file=out, force_terminal=terminal, quiet=quiet, width=200), out


def test_lines_off_a_terminal_with_elapsed_time_and_a_heartbeat(monkeypatch):
    monkeypatch.setattr(common, "HEARTBEAT_S", 0.2)
    console, out = _console(terminal=False)
    with common.off_terminal_lines(console, "calibrating the deposition") as say:
        say("evaluation 1 (fit): SSE 0.5 MPa^2")
        time.sleep(1.0)  # a long evaluation: its line is printed again
    lines = out.getvalue().splitlines()
    assert lines[0] == "calibrating the deposition  [0:00 elapsed]"
    assert lines[1] == "evaluation 1 (fit): SSE 0.5 MPa^2  [0:00 elapsed]"
    assert any(line.startswith("still: evaluation 1 (fit)") for line in lines[2:])
    printed = len(out.getvalue())
    time.sleep(0.5)
    assert len(out.getvalue()) == printed  # nothing once the phase has ended


def test_nothing_on_a_terminal_or_when_quiet(monkeypatch):
    monkeypatch.setattr(common, "HEARTBEAT_S", 0.2)
    for terminal, quiet in ((True, False), (False, True)):
        console, out = _console(terminal, quiet)
        with common.off_terminal_lines(console, "fitting") as say:
            say("evaluation 1")
            time.sleep(0.5)
        assert out.getvalue() == ""
