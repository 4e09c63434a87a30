"""A folder claim is exclusive: while one process holds it (its run is going) another is refused,
exit 2 with the reason, whatever --overwrite says; a killed run's claim is released; the same
process may claim a folder again; a study of another base or other swept keys is refused."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

from espin.core.errors import ConfigError
from espin.core.output_folder import OutputFolder, read_manifest
from espin.studies.sweeps import sweep

TINY = {"rve__size_ratio": 30, "rve__layers": 2, "loading__max_strain": 0.02, "loading__steps": 2}

_HOLD = textwrap.dedent("""
    import sys, time
    from espin.core.output_folder import OutputFolder
    folder = OutputFolder.claim(sys.argv[1], "sweep", "d" * 64, ("results.csv",), resume="same-command")
    print("claimed", flush=True)
    time.sleep(60)
""")


def _holder(folder):
    """A process that claims ``folder`` and holds it (until killed)."""
    proc = subprocess.Popen([sys.executable, "-c", _HOLD, str(folder)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "claimed"
    return proc


@pytest.mark.parametrize("options", [{}, {"overwrite": True}, {"resume": "same-command"}])
def test_a_folder_claimed_by_a_running_process_is_refused(tmp_path, options):
    holder = _holder(tmp_path / "out")
    try:
        with pytest.raises(ConfigError, match=r"out is being written by another sweep run \(started"):
            OutputFolder.claim(tmp_path / "out", "sweep", "d" * 64, ("results.csv",), **options)
        assert read_manifest(tmp_path / "out").status == "running"
    finally:
        holder.kill()
        holder.wait()
    # the killed run's claim is gone with its process: the same study resumes, keeping the manifest's id
    before = read_manifest(tmp_path / "out").run_id
    with OutputFolder.claim(tmp_path / "out", "sweep", "d" * 64, ("results.csv",), resume="same-command") as again:
        assert again.run_id == before
    assert read_manifest(tmp_path / "out").status == "complete"


def test_the_same_process_may_claim_a_folder_again_while_it_holds_it(tmp_path):
    with OutputFolder.claim(tmp_path / "out", "fit", "e" * 64, ("fit.csv",), resume="same-inputs"):
        with OutputFolder.claim(tmp_path / "out", "fit", "e" * 64, ("fit.csv",), resume="same-inputs"):
            pass
        holder = subprocess.run([sys.executable, "-c", _HOLD, str(tmp_path / "out")], capture_output=True,
                                text=True, timeout=60)
        assert holder.returncode != 0 and "being written by another fit run" in holder.stderr
    holder = _holder(tmp_path / "out2")  # released: another process may claim (a new folder)
    holder.kill()
    holder.wait()


def test_a_refused_claim_of_a_new_folder_leaves_it_to_its_owner(tmp_path):
    holder = _holder(tmp_path / "new")
    try:
        with pytest.raises(ConfigError, match="being written"):
            OutputFolder.claim(tmp_path / "new", "sweep", "d" * 64, ("results.csv",))
        assert (tmp_path / "new" / "run.json").is_file()
    finally:
        holder.kill()
        holder.wait()


@pytest.mark.slow
def test_a_study_that_drops_tasks_of_the_folder_is_refused(tmp_path):
    sweep("plla", grid={"fiber.slack_modulus_MPa": [3.0]}, folder=tmp_path / "s", **TINY)
    sweep("plla", grid={"fiber.slack_modulus_MPa": [3.0, 4.0]}, folder=tmp_path / "s", **TINY)  # grown
    with pytest.raises(ConfigError, match="holds another study: 2 of its 2 tasks are not in this one"):
        sweep("plla", grid={"fiber.taut_modulus_MPa": [2000.0]}, folder=tmp_path / "s", **TINY)
    with pytest.raises(ConfigError, match="holds another study"):
        sweep("plla", grid={"fiber.slack_modulus_MPa": [3.0]}, folder=tmp_path / "s",
              **{**TINY, "loading__max_strain": 0.03})
