"""Task identity and resume under damage: referenced files in the key, malformed task files,
records a task function should not have returned, temporaries of interrupted writes."""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time

import pytest

from espin.core.config import config_to_toml
from espin.core.errors import ConfigError, InputError
from espin.core.parallel import TaskPlace
from espin.geometry.rve import resolve_config
from espin.studies.ensemble import PROPERTIES, plan_tasks, run_ensemble
from espin.studies.sweeps import sweep

TINY = {"rve__size_ratio": 30.0, "rve__layers": 2, "loading__max_strain": 0.08, "loading__steps": 8}
LATERAL = "loading.lateral.transverse_csv"
SECRET = "do-not-print-me"


def lateral_base(path):
    """The tiny base config pulling with the measured transverse strain in ``path``."""
    return resolve_config("plla", loading__lateral={"transverse_csv": str(path)}, **TINY)


def write_lateral(path, slope: float = 0.3) -> None:
    path.write_text(f"axial_strain,transverse_strain\n0,0\n0.1,{-slope * 0.1:g}\n")


def record_task(task):
    """A stand-in tensile task: a complete record, tagged with the run that made it."""
    return {"key": task.key, "parameters": task.parameters, "seed": task.seed,
            **dict.fromkeys(PROPERTIES, 1.0), "has_yield": True, "r_squared": 1.0, "note": "",
            "run": os.environ.get("ESPIN_TEST_RUN", "first"), "strain": [0.0, 0.1], "stress_MPa": [0.0, 1.0]}


def empty_record_task(task):
    """A task function that returns nothing usable."""
    return {}


def test_key_hashes_the_bytes_of_referenced_files(tmp_path):
    csv = tmp_path / "lateral.csv"
    write_lateral(csv)
    key = plan_tasks(lateral_base(csv), [{}], [1])[0].key
    assert plan_tasks(lateral_base(csv), [{}], [1])[0].key == key  # stable
    write_lateral(csv, slope=0.4)  # same path, same config text, other contents
    assert plan_tasks(lateral_base(csv), [{}], [1])[0].key != key
    # a config without files keeps the key of its TOML alone: older results folders still resume
    plain = plan_tasks(resolve_config("plla", **TINY), [{}], [1])[0]
    assert plain.key == hashlib.sha256(config_to_toml(plain.config).encode()).hexdigest()[:16]


def test_key_hashes_a_loading_path_file(tmp_path):
    path_csv = tmp_path / "path.csv"
    path_csv.write_text("time_s,F11,F12,F21,F22\n0,1,0,0,1\n1,1.01,0,0,1\n")
    base = resolve_config("plla", loading__test="path", loading__path_csv=str(path_csv), **TINY)
    key = plan_tasks(base, [{}], [1])[0].key
    path_csv.write_text("time_s,F11,F12,F21,F22\n0,1,0,0,1\n1,1.02,0,0,1\n")
    assert plan_tasks(base, [{}], [1])[0].key != key


def test_an_edited_referenced_file_runs_its_tasks_again(tmp_path, monkeypatch):
    csv, folder = tmp_path / "lateral.csv", tmp_path / "study"
    write_lateral(csv)
    first = run_ensemble(plan_tasks(lateral_base(csv), [{}], [1, 2]), folder, place=TaskPlace(1), task_function=record_task)
    assert len(first.records) == 2
    write_lateral(csv, slope=0.5)
    monkeypatch.setenv("ESPIN_TEST_RUN", "second")
    again = run_ensemble(plan_tasks(lateral_base(csv), [{}], [1, 2]), folder, place=TaskPlace(1), task_function=record_task)
    assert again.skipped == 0 and again.unplanned == 2
    assert [r["run"] for r in again.records] == ["second", "second"]


@pytest.mark.parametrize("kind, error_type", [("missing", ConfigError), ("directory", InputError)])
def test_an_unusable_referenced_file_is_an_error_before_any_work(tmp_path, kind, error_type):
    """A missing file is a bad config value, a folder where a table should be bad input."""
    csv = tmp_path / "lateral.csv"
    if kind == "directory":
        csv.mkdir()
    base = lateral_base(csv)
    with pytest.raises(error_type, match=LATERAL) as error:
        plan_tasks(base, [{}], [1])
    assert str(csv) in str(error.value)
    folder = tmp_path / "study"
    with pytest.raises(error_type, match=LATERAL):
        sweep(base, realizations=1, folder=folder, workers=1)
    assert not folder.exists()  # nothing written: no plan, no config


GOOD = {**dict.fromkeys(PROPERTIES, 1.0), "has_yield": True, "strain": [0.0, 0.1], "stress_MPa": [0.0, 1.0]}


@pytest.mark.parametrize("text, problem", [
    pytest.param("{}", "lacks key", id="empty-object"),
    pytest.param("[]", "not a JSON object", id="list"),
    pytest.param(f"{SECRET} {{", "not JSON", id="not-json"),
    pytest.param(b"\xff\xfe{", "not JSON", id="not-text"),
    pytest.param("KEY", "another task", id="record-of-another-task"),
    pytest.param(json.dumps({**GOOD, "key": "KEY", "modulus_MPa": SECRET}), "invalid value in modulus_MPa",
                 id="text-modulus"),
    pytest.param(json.dumps({**GOOD, "key": "KEY", "modulus_MPa": float("nan")}), "invalid value in modulus_MPa",
                 id="nan-modulus"),
    pytest.param(json.dumps({**GOOD, "key": "KEY", "has_yield": "yes"}), "invalid value in has_yield",
                 id="text-has-yield"),
    pytest.param(json.dumps({**GOOD, "key": "KEY", "strain": "0,0.1"}), "invalid value in strain", id="text-strain"),
    pytest.param(json.dumps({**GOOD, "key": "KEY", "strain": [0.0]}), "different lengths", id="short-strain"),
    pytest.param(json.dumps({k: v for k, v in {**GOOD, "key": "KEY"}.items() if k != "yield_stress_MPa"}),
                 "lacks yield_stress_MPa", id="no-yield-stress"),
])
def test_a_malformed_task_file_runs_again_with_a_warning(tmp_path, monkeypatch, caplog, text, problem):
    tasks = plan_tasks(resolve_config("plla", **TINY), [{}], [1, 2])
    run_ensemble(tasks, tmp_path, place=TaskPlace(1), task_function=record_task)
    damaged = tmp_path / "tasks" / f"{tasks[0].key}.json"
    if text == "KEY":
        damaged.write_bytes((tmp_path / "tasks" / f"{tasks[1].key}.json").read_bytes())
    elif isinstance(text, bytes):
        damaged.write_bytes(text)
    else:
        damaged.write_text(text.replace('"KEY"', json.dumps(tasks[0].key)))
    monkeypatch.setenv("ESPIN_TEST_RUN", "again")
    with caplog.at_level(logging.WARNING, logger="espin.studies.ensemble"):
        again = run_ensemble(tasks, tmp_path, place=TaskPlace(1), task_function=record_task)
    assert again.skipped == 1 and [r["run"] for r in again.records] == ["again", "first"]
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and damaged.name in warnings[0] and problem in warnings[0], warnings
    assert SECRET not in warnings[0]
    assert json.loads(damaged.read_text())["run"] == "again"  # replaced by the new record


def test_a_record_that_would_not_resume_is_a_failure(tmp_path):
    tasks = plan_tasks(resolve_config("plla", **TINY), [{}], [1])
    result = run_ensemble(tasks, tmp_path, place=TaskPlace(1), task_function=empty_record_task)
    assert not result.records and len(result.failures) == 1
    assert "record lacks key" in result.failures[0]["error"]
    assert not list((tmp_path / "tasks").glob("*.json")) and (tmp_path / "failed" / f"{tasks[0].key}.json").is_file()


def test_stale_temporaries_of_interrupted_writes_are_removed(tmp_path):
    tasks = plan_tasks(resolve_config("plla", **TINY), [{}], [1])
    (tmp_path / "tasks").mkdir()
    (tmp_path / "failed").mkdir()
    stale = [tmp_path / ".results.csv.k2j_9x0a.tmp", tmp_path / "tasks" / f".{tasks[0].key}.json.abcdefgh.tmp",
             tmp_path / "failed" / ".0123456789abcdef.json.z_z_z_z_.tmp"]
    fresh = tmp_path / "tasks" / ".other.json.qwertyui.tmp"  # perhaps being written right now
    foreign = [tmp_path / "notes.tmp", tmp_path / ".notes.tmp", tmp_path / ".results.csv.SHORT.tmp",
               tmp_path / "tasks" / "mine.json.abcdefgh.tmp"]
    an_hour_ago = time.time() - 3600
    for path in [*stale, fresh, *foreign]:
        path.write_bytes(b"")
        if path is not fresh:
            os.utime(path, (an_hour_ago, an_hour_ago))
    run_ensemble(tasks, tmp_path, place=TaskPlace(1), task_function=record_task)
    assert not any(path.exists() for path in stale)
    assert fresh.exists() and all(path.exists() for path in foreign)


@pytest.mark.parametrize("options, message", [
    ({"workers": 0}, "workers"),
    ({"blas_threads": 0}, "blas_threads"),
    ({"grid": {"rve.size_ratio": [30.0, 1e5]}}, "memory"),
    ({"grid": {"rve.volume_fraction": [0.19, 0.001]}}, "fibers"),
    ({"grid": {"rve.layers": list(range(1, 101))}, "realizations": 1001}, "tasks"),
])
def test_a_study_refused_before_any_work_leaves_no_folder(tmp_path, options, message):
    """Pool options, mats too large or too sparse at any point, and too many tasks are
    refused before the folder is claimed."""
    options = {"grid": None, "realizations": 1, **options}
    with pytest.raises(ConfigError, match=message):
        sweep("plla", folder=tmp_path / "study", **options, **TINY)
    assert not (tmp_path / "study").exists()


def test_a_grid_of_too_many_values_is_refused():
    from espin.cli.study import parse_grid

    with pytest.raises(ConfigError, match="count must be in"):
        parse_grid(["rve.volume_fraction=0.1:0.3:1000000000"])


def test_a_grid_range_of_whole_numbers_stays_integer():
    from espin.cli.study import parse_grid

    grid = parse_grid(["rve.layers=2:8:4", "rve.volume_fraction=0.1:0.3:3"])
    assert grid["rve.layers"] == [2, 4, 6, 8] and all(type(v) is int for v in grid["rve.layers"])
    assert grid["rve.volume_fraction"] == pytest.approx([0.1, 0.2, 0.3])


def test_overwrite_clears_a_folder_of_the_same_study(tmp_path):
    from espin.core.output_folder import OutputFolder

    folder = tmp_path / "study"
    OutputFolder.claim(folder, "sweep", "a", ["results.csv", "sweep_*.png"], resume="same-command").finish()
    (folder / "sweep_old.png").write_bytes(b"png")
    OutputFolder.claim(folder, "sweep", "a", ["results.csv", "sweep_*.png"], resume="same-command",
                       overwrite=True).finish()
    assert not (folder / "sweep_old.png").exists()
