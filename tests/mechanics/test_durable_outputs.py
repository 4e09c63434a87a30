"""Durable outputs: a killed run keeps its converged steps and is marked partial; a folder of
another run is refused unless overwrite, which leaves nothing stale; studies resume only
their own folder."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest
from typer.testing import CliRunner

import espin
from espin.cli import app
from espin.core.errors import ConfigError
from espin.core.output_folder import MANIFEST, OutputFolder, read_manifest

TINY = dict(rve__size_ratio=30, rve__layers=2, loading__max_strain=0.05)
TINY_CLI = ["--set", "rve.size_ratio=30", "--set", "rve.layers=2", "--max-strain", "0.05", "-q"]


def _rows(folder):
    return (folder / "curve.csv").read_text().splitlines()


def _rows_so_far(folder):
    """The curve's lines, none if it is not there (or removed while being read)."""
    try:
        return _rows(folder)
    except FileNotFoundError:
        return []


def _interrupt_at(index: int):
    """An on_step callback that stops the run (as Ctrl-C would) when step ``index`` arrives."""

    def interrupt(record):
        if record.index == index:
            raise KeyboardInterrupt

    return interrupt


def _run_and_kill(folder, steps: int, after_rows: int, overwrite: bool = False) -> None:
    """Start a simulate in another process, SIGKILL it once its curve.csv has ``after_rows`` steps."""
    earlier = read_manifest(folder) if folder.exists() else None
    earlier_rows = _rows_so_far(folder)
    code = (f"import espin; espin.simulate('plla', {str(folder)!r}, overwrite={overwrite}, "
            f"loading__steps={steps}, solver__time_rtol='off', output__figures=False, "
            + ", ".join(f"{k}={v!r}" for k, v in TINY.items()) + ")")
    process = subprocess.Popen([sys.executable, "-c", code])
    deadline = time.monotonic() + 120
    try:
        while time.monotonic() < deadline:
            started = (folder / MANIFEST).exists() and read_manifest(folder) != earlier
            rows = _rows_so_far(folder) if started else []
            # the new run's curve: the earlier run's stays until the new one has cleared it
            if len(rows) > after_rows and rows[1:after_rows + 1] != earlier_rows[1:after_rows + 1]:
                break
            assert process.poll() is None, "the run ended before it could be killed"
            time.sleep(0.02)
        else:
            pytest.fail("the run wrote no curve within 120 s")
    finally:
        process.send_signal(signal.SIGKILL)
        process.wait()


@pytest.mark.slow
def test_a_killed_run_keeps_its_converged_steps_and_is_marked_partial(tmp_path):
    folder = tmp_path / "killed"
    _run_and_kill(folder, steps=400, after_rows=3)
    manifest = read_manifest(folder)
    assert manifest.status == "running" and manifest.partial
    rows = _rows(folder)
    whole = [row for row in rows if row.count(",") == rows[0].count(",")]
    assert 4 <= len(whole) < 402 and len(rows) - len(whole) <= 1  # at most the last line cut mid-write

    with pytest.raises(KeyboardInterrupt):
        espin.simulate("plla", tmp_path / "same", on_step=_interrupt_at(len(whole) - 1), loading__steps=400, solver__time_rtol="off",
                       output__figures=False, **TINY)
    assert whole == _rows(tmp_path / "same")  # every converged step kept, as written


@pytest.mark.slow
def test_a_run_killed_over_an_earlier_one_leaves_no_mixed_folder(tmp_path):
    folder = tmp_path / "run"
    espin.simulate("plla", folder, loading__steps=5, output__figures=False, **TINY)
    earlier = read_manifest(folder).run_id
    _run_and_kill(folder, steps=400, after_rows=3, overwrite=True)
    manifest = read_manifest(folder)
    assert manifest.run_id != earlier and manifest.status == "running"
    assert not (folder / "results.h5").exists()  # the earlier run's, removed before the first step
    steps = sorted(p.name for p in folder.glob("vtk/step_*.vtu"))
    rows = len(_rows(folder)) - 1  # the steps in the curve (one may be cut mid-write)
    assert steps == [f"step_{k:04d}.vtu" for k in range(len(steps))]
    assert rows - 1 <= len(steps) <= rows  # the new run's steps only: the earlier 6 are gone


@pytest.mark.slow
def test_another_runs_folder_is_refused_and_left_as_it_was(tmp_path):
    folder = tmp_path / "run"
    result = CliRunner().invoke(app, ["simulate", "plla", "-o", str(folder), "--steps", "5", *TINY_CLI])
    assert result.exit_code == 0, result.output
    before = {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()}
    again = CliRunner().invoke(app, ["simulate", "plla", "-o", str(folder), "--steps", "3", *TINY_CLI])
    assert again.exit_code == 2 and "--overwrite" in again.output and "Traceback" not in again.output
    assert {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()} == before


def test_overwrite_leaves_no_stale_steps(tmp_path):
    folder = tmp_path / "run"
    espin.simulate("plla", folder, loading__steps=5, output__figures=False, **TINY)
    assert len(list(folder.glob("vtk/step_*.vtu"))) == 6
    (folder / "notes.txt").write_text("mine")
    espin.simulate("plla", folder, overwrite=True, loading__steps=2, output__figures=False, **TINY)
    assert sorted(p.name for p in folder.glob("vtk/step_*.vtu")) == [f"step_{k:04d}.vtu" for k in range(3)]
    assert len(_rows(folder)) == 4 and read_manifest(folder).status == "complete"
    assert (folder / "notes.txt").read_text() == "mine"  # not espin's: left alone


def test_a_complete_run_lists_the_files_it_wrote(tmp_path):
    # A converged run writes no solver.log: its run.json does not promise one (nor a file twice).
    folder = tmp_path / "run"
    espin.simulate("plla", folder, loading__steps=2, output__figures=False, **TINY)
    outputs = read_manifest(folder).outputs
    assert "solver.log" not in outputs and not (folder / "solver.log").exists()
    assert len(outputs) == len(set(outputs)) and {"curve.csv", "results.h5", "vtk/step_*.vtu"} <= set(outputs)
    assert all(list(folder.glob(pattern)) for pattern in outputs)


def test_an_interrupted_run_is_marked_failed(tmp_path):
    with pytest.raises(KeyboardInterrupt):
        espin.simulate("plla", tmp_path / "run", on_step=_interrupt_at(2), loading__steps=5, output__figures=False, **TINY)
    assert read_manifest(tmp_path / "run").status == "failed"
    assert len(_rows(tmp_path / "run")) == 3  # header and steps 0, 1 (step 2's callback raised first)


def test_a_run_refused_before_any_work_leaves_no_folder(tmp_path):
    with pytest.raises(ConfigError, match="no cross-link"):
        espin.simulate("plla", tmp_path / "run", rve__size_ratio=30, rve__layers=1, rve__max_deviation_deg=0,
                       rve__orientation={"histogram": {"edges_deg": [0, 1e-6, 180], "weights": [1, 0]}})
    assert not (tmp_path / "run").exists()


def test_resumable_commands_reuse_only_their_own_folder(tmp_path):
    folder = tmp_path / "fit"
    with OutputFolder.claim(folder, "fit", "abc", ["fit.csv"], resume="same-inputs") as claimed:
        (folder / "fit.csv").write_text("x")
    again = OutputFolder.claim(folder, "fit", "abc", ["fit.csv"], resume="same-inputs")
    assert again.run_id == claimed.run_id and (folder / "fit.csv").exists()
    again.finish()
    with pytest.raises(ConfigError, match="another fit run"):
        OutputFolder.claim(folder, "fit", "other", ["fit.csv"], resume="same-inputs")
    with pytest.raises(ConfigError, match="another fit run"):
        OutputFolder.claim(folder, "sweep", "abc", ["fit.csv"], resume="same-command")
    # a study resumes a folder of the same study whatever its base, and one written before
    # manifests existed; its task files are keyed by their whole config
    study = tmp_path / "study"
    OutputFolder.claim(study, "sweep", "abc", ["results.csv"]).finish()
    (study / "results.csv").write_text("x")
    OutputFolder.claim(study, "sweep", "grown", ["results.csv"], resume="same-command").finish()
    os.remove(study / MANIFEST)
    adopted = OutputFolder.claim(study, "sweep", "new", ["results.csv"], resume="same-command")
    assert (study / "results.csv").exists() and json.loads((study / MANIFEST).read_text())["config_hash"] == "new"
    adopted.finish()
    with pytest.raises(ConfigError, match="another sweep run"):
        OutputFolder.claim(study, "rve-size", "new", ["results.csv"], resume="same-command")


def test_an_unreadable_run_json_is_replaced_only_with_overwrite(tmp_path):
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / MANIFEST).write_text("{not json")
    with pytest.raises(ConfigError, match="not an espin run manifest"):
        OutputFolder.claim(folder, "simulate", "x", ["curve.csv"])
    OutputFolder.claim(folder, "simulate", "x", ["curve.csv"], overwrite=True).finish()
    assert read_manifest(folder).status == "complete"


def test_overwrite_never_removes_a_file_outside_the_folder(tmp_path):
    """A run.json is data: outputs naming ../ or absolute paths make it unreadable, and only
    files inside the folder are ever removed."""
    victim = tmp_path / "victim.txt"
    victim.write_text("mine")
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / "link.csv").symlink_to(victim)
    for outputs in (["../victim.txt"], ["/tmp/*"], 5):
        (folder / MANIFEST).write_text(json.dumps({"run_id": "a", "command": "simulate", "config_hash": "x",
                                                   "espin_version": "0", "status": "complete",
                                                   "started_utc": "", "outputs": outputs}))
        with pytest.raises(ConfigError, match="not an espin run manifest"):
            read_manifest(folder)
        OutputFolder.claim(folder, "simulate", "x", ["*.csv"], overwrite=True).finish()
    assert victim.read_text() == "mine"


def test_the_curve_of_a_killed_run_is_read_with_a_warning(tmp_path):
    from espin.analysis.experiments import CurveWarning, read_curve

    with pytest.raises(KeyboardInterrupt):
        espin.simulate("plla", tmp_path / "run", on_step=_interrupt_at(3), loading__steps=5, output__figures=False, **TINY)
    with pytest.warns(CurveWarning, match="partial result.*failed"):
        curve = read_curve(tmp_path / "run" / "curve.csv")
    assert len(curve.strain) == 3
