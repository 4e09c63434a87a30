"""The surrogate's samples file: it names its mat and is refused for another (unless allowed), it is
checked as any input file, a build keeps every finished path in it and resumes from them, and a
failed path says which, where (its strain, not its time) and what to try."""

from __future__ import annotations

import json

import numpy as np
import pytest

import espin
from espin.core.errors import ConfigError, InputError, SolverError
from espin.specimen import surrogate as surrogate_module
from espin.specimen.shapes import strip
from espin.specimen.surrogate import build_surrogate, read_surrogate
from espin.specimen.surrogate_file import read_samples, write_samples

TINY = dict(rve__size_ratio=30, rve__layers=2)
BUILD = dict(reach=1.0, steps=3, speeds=(1.0, 4.0),
             paths=[(1.0, 0.0, 0.0), (1.0, -0.5, 0.0), (0.0, 1.0, 0.0), (1.0, 0.0, 0.5)])


@pytest.fixture(scope="module")
def rve():
    return espin.generate("plla", **TINY)


@pytest.fixture(scope="module")
def built(rve):
    return build_surrogate(rve.network, rve.config, 0.02, **BUILD)


@pytest.fixture()
def samples(built, tmp_path):
    return write_samples(tmp_path / "surrogate_samples.csv", built.identity, built.runs)


def _other_law(rve):
    return rve.config.model_copy(update={"fiber": rve.config.fiber.model_copy(update={"taut_modulus_MPa": 4000.0})})


def test_the_file_names_its_mat_and_reads_back_the_same_samples(rve, built, samples):
    text = samples.read_text()
    assert text.startswith("# espin surrogate samples, schema 2\n# config_digest = ")
    assert f"# law = taut_modulus_MPa={rve.config.fiber.taut_modulus_MPa:g}," in text
    again = read_surrogate(samples, rve.config, 0.02)
    assert np.array_equal(again.E, built.E) and np.array_equal(again.S, built.S)
    assert np.array_equal(again.speed, built.speed)


@pytest.mark.parametrize("change, message", [
    (lambda c: c.model_copy(update={"fiber": c.fiber.model_copy(update={"taut_modulus_MPa": 4000.0})}),
     "fiber law"),
    (lambda c: c.model_copy(update={"rve": c.rve.model_copy(update={"seed": c.rve.seed + 1})}), "another mat"),
    (lambda c: c.model_copy(update={"loading": c.loading.model_copy(update={"strain_rate_per_s": 1e-2})}),
     "strain rate"),
])
def test_samples_of_another_mat_are_refused_unless_allowed(rve, samples, change, message):
    with pytest.raises(ConfigError, match=f"surrogate_from: .*{message}.*--allow-surrogate-mismatch"):
        read_surrogate(samples, change(rve.config), 0.02)
    assert read_surrogate(samples, change(rve.config), 0.02, allow_mismatch=True).E.shape[1] == 3


def test_a_run_pulling_beyond_the_samples_is_refused(rve, samples):
    with pytest.raises(ConfigError, match="built for a grip strain of 0.02, this run pulls to 0.05"):
        read_surrogate(samples, rve.config, 0.05)


def test_another_mat_is_refused_by_specimen_and_an_allowed_one_is_recorded(rve, samples, tmp_path):
    with pytest.raises(ConfigError, match="fiber law"):
        espin.specimen(_other_law(rve), strip(20.0, 5.0, elements_across=1), model="surrogate", max_strain=0.02,
                       steps=1, surrogate_from=samples, out=tmp_path / "refused", **TINY)
    assert not (tmp_path / "refused").exists()
    espin.specimen(_other_law(rve), strip(20.0, 5.0, elements_across=1), model="surrogate", max_strain=0.02,
                   steps=1, surrogate_from=samples, allow_surrogate_mismatch=True, out=tmp_path / "allowed",
                   figures=False, **TINY)
    recorded = json.loads((tmp_path / "allowed" / "specimen.json").read_text())["surrogate_samples"]
    assert recorded["source"] == str(samples) and "fiber law" in recorded["mismatches"][0]


def _edit(path, edit):
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(edit(lines)))


def _scale_stress(lines):
    head = [i for i, line in enumerate(lines) if line.startswith("path,")][0]
    out = lines[:head + 1]
    for line in lines[head + 1:]:
        v = line.rstrip("\n").split(",")
        v[5:8] = [repr(100.0 * float(x)) for x in v[5:8]]
        out.append(",".join(v) + "\n")
    return out


@pytest.mark.parametrize("edit, message", [
    (_scale_stress, "checksum"),
    (lambda lines: lines[:-5], "checksum"),
    (lambda lines: lines[:12] + lines[13:] + lines[12:13], "checksum"),
    (lambda lines: [line for line in lines if not line.startswith("#")], "first line"),
    (lambda lines: [line for line in lines if not line.startswith("# reach")], "no reach line"),
    (lambda lines: [line.replace("strain_rate_per_s = ", "strain_rate_per_s = x") for line in lines],
     "not a number"),
])
def test_an_edited_cut_or_reordered_file_is_refused(rve, samples, edit, message):
    _edit(samples, edit)
    with pytest.raises(InputError, match=f"surrogate_from: {samples}.*{message}"):
        read_surrogate(samples, rve.config, 0.02)


def test_a_file_that_is_not_a_samples_file_is_refused(rve, tmp_path):
    with pytest.raises(ConfigError, match="no such file"):
        read_surrogate(tmp_path / "missing.csv", rve.config, 0.02)
    with pytest.raises(InputError, match="directory"):
        read_surrogate(tmp_path, rve.config, 0.02)
    (tmp_path / "binary.csv").write_bytes(b"\x00\x01" * 100)
    with pytest.raises(InputError, match="binary.csv"):
        read_surrogate(tmp_path / "binary.csv", rve.config, 0.02)


def test_a_build_keeps_each_finished_path_and_resumes_from_them(rve, built, tmp_path):
    path = tmp_path / "surrogate_samples.csv"
    write_samples(path, built.identity, {k: built.runs[k] for k in (0, 3, 5)})
    lines = []
    again = build_surrogate(rve.network, rve.config, 0.02, samples_path=path, report=lines.append, **BUILD)
    assert "3 finished paths reused" in lines[0]
    assert sum("path" in line and " in " in line for line in lines[1:]) == 5  # only the 5 missing ones ran
    assert np.allclose(again.S, built.S, rtol=1e-9, atol=1e-12)
    assert read_samples(path).complete


def test_a_failed_path_says_where_what_to_try_and_keeps_the_finished_ones(rve, tmp_path, monkeypatch):
    run = surrogate_module._run_path
    calls = []

    def fail_the_third(path):
        calls.append(path)
        if len(calls) == 3:
            return surrogate_module._PathFailure("step 3 of 3 (path strain 0.04, time 8 s) did not converge: "
                                                 "the residual stalled", 0.04)
        return run(path)

    monkeypatch.setattr(surrogate_module, "_run_path", fail_the_third)
    path = tmp_path / "surrogate_samples.csv"
    with pytest.raises(SolverError) as failure:
        build_surrogate(rve.network, rve.config, 0.02, samples_path=path, **{**BUILD, "reach": 3.0})
    message = str(failure.value)
    assert "path 3 of 8" in message and "G = (0, 1, 0)" in message and "path strain 0.04" in message
    assert "--surrogate-reach 1.8" in message and "--model fe2" in message
    assert f"the 2 finished paths are kept in {path}" in message
    assert "np.float64" not in message and "loading.steps" not in message
    assert sorted(read_samples(path).runs) == [0, 1]


def test_the_path_program_strain_is_the_stretch_not_the_time(rve):
    program_strains = []
    real = surrogate_module.path_program

    def spy(time, U, strain=None):
        program_strains.append((time[-1], strain[-1]))
        return real(time, U, strain=strain)

    surrogate_module.path_program = spy
    try:
        build_surrogate(rve.network, rve.config, 0.02, **{**BUILD, "speeds": (1.0,)})
    finally:
        surrogate_module.path_program = real
    rate = rve.config.loading.strain_rate_per_s
    assert all(np.isclose(strain, 0.02) and np.isclose(time, 0.02 / rate) for time, strain in program_strains)


def test_the_command_line_reports_the_build_off_a_terminal_and_resumes(tmp_path, monkeypatch):
    """CliRunner is not a terminal: the plan, a line per path; a rerun into the folder reuses the paths."""
    import functools

    from typer.testing import CliRunner

    from espin.cli import app
    from espin.specimen import surrogate as module

    small = functools.partial(module.build_surrogate, paths=BUILD["paths"], speeds=(1.0,), steps=3)
    monkeypatch.setattr(module, "build_surrogate", small)  # a build of 4 short paths
    argv = ["specimen", "plla", "--model", "surrogate", "--set", "rve.size_ratio=30", "--set", "rve.layers=2",
            "--shape", "strip", "--elements-across", "1", "--max-strain", "0.02", "--steps", "1", "--surrogate-reach",
            "1", "-o", str(tmp_path / "s")]
    first = CliRunner().invoke(app, argv)
    assert first.exit_code == 0, first.output
    assert "specimen: generating the RVE" in first.output
    assert "surrogate: 4 RVE paths (4 directions x 1 speeds, 3 steps each" in first.output
    assert first.output.count("RVE paths done") == 4
    again = CliRunner().invoke(app, argv)
    assert again.exit_code == 0, again.output
    assert "4 finished paths reused" in again.output and "RVE paths done" not in again.output


def test_a_nearly_crushed_point_is_inadmissible_not_a_nan(built):
    """det F > 0 but so small that a difference probe of dS/dE inverts the point: the step must be
    cut (InadmissibleState), not evaluated through the square root of a negative det C."""
    from espin.core.errors import InadmissibleState

    F = np.array([np.eye(2), np.diag([1.0, 1e-4])])
    with np.errstate(invalid="raise"), pytest.raises(InadmissibleState, match="det F near 0 at 1 point"):
        built.stress(F, np.tile(np.eye(2), (2, 1, 1)), 1.0)
    P, _, _ = built.stress(F[:1], np.eye(2)[None], 1.0)
    assert np.all(np.isfinite(P))
