"""Loading programs (SPEC 6): steps, times at the prescribed rate, F of every test."""

from __future__ import annotations

import numpy as np
import pytest

from espin.core.config import load_config
from espin.core.errors import ConfigError, InputError
from espin.mechanics.loading import load_program


def _program(**loading):
    return load_program(load_config(None, {f"loading.{k}": v for k, v in loading.items()}).loading)


def test_shorthand_program_rate_and_steps():
    p = _program(max_strain=0.3, strain_rate_per_s=5e-3, steps=30)
    assert p.n_steps == 30
    assert np.allclose(np.diff(p.strain), 0.01) and np.allclose(np.diff(p.time), 2.0)
    assert np.allclose(p.prescribed_F(60.0), np.diag([1.3, 1.0]))
    assert p.free_directions.shape == (0, 2, 2)


def test_load_unload_hold_reload():
    p = _program(program=[{"to_strain": 0.04, "rate_per_s": 1e-3, "steps": 4},
                          {"hold_s": 100.0, "steps": 5},
                          {"to_strain": 0.01, "rate_per_s": 2e-3},
                          {"to_strain": 0.05, "rate_per_s": 1e-3}])
    assert p.n_steps == 4 + 5 + 3 + 4  # default: one step per percent of strain
    assert p.time[4] == pytest.approx(40.0) and p.time[9] == pytest.approx(140.0)
    assert p.time[12] == pytest.approx(155.0) and p.time[-1] == pytest.approx(195.0)
    assert np.allclose(p.strain[4:10], 0.04) and p.strain[12] == pytest.approx(0.01)
    assert list(p.segment) == [0] * 4 + [1] * 5 + [2] * 3 + [3] * 4


@pytest.mark.parametrize("direction", [0.0, 30.0, 90.0, 135.0])
def test_uniaxial_in_any_direction(direction):
    p = _program(direction_deg=direction, max_strain=0.1, steps=2)
    F = p.prescribed_F(p.time[-1])
    a = np.array([np.cos(np.radians(direction)), np.sin(np.radians(direction))])
    n = np.array([-a[1], a[0]])
    assert a @ F @ a == pytest.approx(1.1) and n @ F @ n == pytest.approx(1.0)
    assert n @ F @ a == pytest.approx(0.0, abs=1e-15)  # no rigid rotation


def test_lateral_conditions(tmp_path):
    p = _program(lateral={"poisson_ratio": 0.4}, max_strain=0.1, steps=1)
    assert np.allclose(p.prescribed_F(p.time[-1]), np.diag([1.1, 0.96]))
    csv = tmp_path / "transverse.csv"
    csv.write_text("axial_strain,transverse_strain\n0,0\n0.05,-0.02\n0.2,-0.1\n")
    p = _program(lateral={"transverse_csv": str(csv)}, max_strain=0.1, steps=1)
    # Interpolated on the axial strain: -0.02 + (0.05 / 0.15) * (-0.08).
    assert p.prescribed_F(p.time[-1])[1, 1] == pytest.approx(1 - 0.02 - 0.08 / 3)
    p = _program(lateral="free", direction_deg=90.0)
    assert p.free_directions.shape == (2, 2, 2)
    # In the loading frame the free components are F'12 and F'22.
    R = p.rotation
    local = [R.T @ G @ R for G in p.free_directions]
    assert np.allclose(local[0], [[0, 1], [0, 0]]) and np.allclose(local[1], [[0, 0], [0, 1]])


def test_other_tests():
    F = _program(test="equibiaxial", max_strain=0.1, steps=1).prescribed_F(20.0)
    assert np.allclose(F, np.diag([1.1, 1.1]))
    F = _program(test="pure_shear", max_strain=0.25, steps=1).prescribed_F(50.0)
    assert np.allclose(F, np.diag([1.25, 0.8])) and np.linalg.det(F) == pytest.approx(1.0)
    F = _program(test="simple_shear", max_strain=0.2, steps=1).prescribed_F(40.0)
    assert np.allclose(F, [[1.0, 0.2], [0.0, 1.0]])


def test_path_table(tmp_path):
    csv = tmp_path / "path.csv"
    csv.write_text("time_s,F11,F12,F21,F22\n0,1,0,0,1\n10,1.1,0.05,0,0.98\n30,1.2,0,0,1\n")
    p = _program(test="path", path_csv=str(csv))
    assert p.n_steps == 2 and np.allclose(p.time, [0, 10, 30])
    assert np.allclose(p.prescribed_F(10.0), [[1.1, 0.05], [0.0, 0.98]])
    assert np.allclose(p.prescribed_F(20.0), [[1.15, 0.025], [0.0, 0.99]])


@pytest.mark.parametrize(
    "content, message",
    [
        ("time_s,F11,F12,F21,F22\n0,1,0,0,1\n1,x,0,0,1\n", r"line 3, column 2 \(F11\): not a number"),
        ("time_s,F11,F12,F21,F22\n0,1,0,0,1\n", "1 data row\\(s\\); a table needs at least 2"),
        ("time_s,F11\n0,1\n1,2\n", "lacks column"),
        ("time_s,F11,F12,F21,F22\n0,1,0,0,1\n0,1,0,0,1\n", "line 3, column 1 .*increase strictly"),
        ("time_s,F11,F12,F21,F22\n0,1,0,0,1\n1,1,0,0,nan\n", r"line 3, column 5 \(F22\): NaN"),
        ("time_s,F11,F12,F21,F22\n0,1,0,0,1\n1,-1,0,0,1\n", "line 3: det F = -1; every F must have det F > 0"),
    ],
)
def test_bad_tables_name_the_key_and_line(tmp_path, content, message):
    csv = tmp_path / "path.csv"
    csv.write_text(content)
    with pytest.raises(InputError, match=message) as err:
        _program(test="path", path_csv=str(csv))
    assert "loading.path_csv" in str(err.value)


def test_segment_going_nowhere_is_an_error():
    with pytest.raises(ConfigError, match=r"loading.program\[1\]"):
        _program(program=[{"to_strain": 0.1}, {"to_strain": 0.1}])
