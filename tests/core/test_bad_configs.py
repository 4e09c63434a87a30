"""Bad configurations: each is refused with a ConfigError naming the key, before any work.

The matrix holds every case of the hardening issue that validated before and broke or misled
later (inf values, huge seeds, empty programs, absurd moduli, booleans read as counts, binary
files) and more of each kind; sizes the machine cannot hold and mats that cannot form a
network are in tests/geometry/test_size_estimate.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from espin.cli import app
from espin.core.config import config_from_dict, load_config
from espin.core.errors import ConfigError

INF, NAN = math.inf, math.nan

# (dotted key, value, text the message must hold)
BAD_VALUES = [
    # inf passed validation for these
    ("rve.size_ratio", INF, "rve.size_ratio"),
    ("rve.size_um", INF, "rve.size_um"),
    ("rve.diameter_sd_um", INF, "rve.diameter_sd_um"),
    ("output.window_ratio", INF, "output.window_ratio"),
    ("fiber.taut_modulus_MPa", INF, "fiber.taut_modulus_MPa"),
    ("fiber.slack_modulus_MPa", INF, "fiber.slack_modulus_MPa"),
    ("fiber.flow_rate_per_s", INF, "fiber.flow_rate_per_s"),
    ("fiber.flow_resistance_MPa", INF, "fiber.flow_resistance_MPa"),
    ("fiber.hardening_exponent", INF, "fiber.hardening_exponent"),
    ("loading.strain_rate_per_s", INF, "loading.strain_rate_per_s"),
    ("loading.program", [{"to_strain": 0.1, "rate_per_s": INF}], "loading.program.0.rate_per_s"),
    ("loading.program", [{"to_strain": 0.1}, {"hold_s": INF}], "loading.program.1.hold_s"),
    ("rve.orientation", {"histogram": {"edges_deg": [0, NAN, 180], "weights": [1, 1]}},
     "rve.orientation.histogram.edges_deg.1"),
    ("rve.orientation", {"histogram": {"edges_deg": [0, 90, 180], "weights": [1, INF]}},
     "rve.orientation.histogram.weights.1"),
    # integers above 2^64 passed as a seed (h5py failed at save, after the work)
    ("rve.seed", 2**64 + 1, "rve.seed"),
    ("rve.seed", 2**63, "rve.seed"),
    # a volume fraction of 360 followed
    ("rve.diameter_sd_um", 100.0, "rve.diameter_sd_um"),
    # a one-point curve followed
    ("loading.program", [], "loading.program"),
    # 1.2e281 MPa followed
    ("fiber.taut_modulus_MPa", 1e300, "fiber.taut_modulus_MPa"),
    # read as 1 layer
    ("rve.layers", True, "rve.layers"),
    # more of the same kinds
    ("rve.layers", 2.0, "rve.layers"),
    ("rve.diameter_um", "0.45", "rve.diameter_um"),
    ("output.figures", 1, "output.figures"),
    ("loading.steps", True, "loading.steps"),
    ("loading.max_strain", NAN, "loading.max_strain"),
    ("loading.direction_deg", -INF, "loading.direction_deg"),
    ("solver.max_iterations", 1.5, "solver.max_iterations"),
    ("rve.diameter_sd_um", 0.46, "rve.diameter_sd_um"),
    ("fiber.flow_rate_per_s", 1e4, "fiber.flow_rate_per_s"),
    ("fiber.hardening_exponent", 1e3, "fiber.hardening_exponent"),
    ("loading.program", [{"hold_s": 1e10}], "loading.program.0.hold_s"),
    ("rve.diameter_um", 1e4, "rve.diameter_um"),
    ("solver.time_rtol", NAN, "solver.time_rtol"),
    ("rve.orientation", {"von_mises": {"mean_deg": 0, "kappa": NAN}}, "rve.orientation.von_mises.kappa"),
]


@pytest.mark.parametrize("key, value, named", BAD_VALUES, ids=[f"{k}={v!r}"[:60] for k, v, _ in BAD_VALUES])
def test_bad_value_is_refused_naming_the_key(key, value, named):
    with pytest.raises(ConfigError) as err:
        load_config("plla", {key: value})
    assert named in str(err.value)


@pytest.mark.parametrize("content, expected", [
    (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xff\xfe", "not UTF-8"),
    (b"[rve\nlayers = 3", "not valid TOML"),
    (b"# " + b"x" * (2**20 + 10), "bytes"),
])
def test_unreadable_config_file_is_refused(tmp_path, content, expected):
    path = tmp_path / "mat.toml"
    path.write_bytes(content)
    with pytest.raises(ConfigError, match=expected) as err:
        load_config(path)
    assert str(path) in str(err.value)


@pytest.mark.parametrize("source", ["/dev/zero", "."])
def test_special_file_as_config_is_refused(source):
    with pytest.raises(ConfigError, match="not a regular file"):
        load_config(source)


def test_numpy_numbers_are_taken_as_the_numbers_they_hold():
    """A sweep's grid or an optimizer hands out numpy scalars: accepted like Python's."""
    config = load_config("plla", {"rve.layers": np.int64(4), "rve.volume_fraction": np.float64(0.2)})
    assert config.rve.layers == 4 and type(config.rve.layers) is int
    assert config.rve.volume_fraction == 0.2


@pytest.mark.parametrize("args", [
    ["--set", "rve.size_ratio=inf"],
    ["--set", "rve.layers=true"],
    ["--set", "loading.program=[]"],
    ["--set", "rve.seed=18446744073709551617"],
    ["--set", "rve.volume_fraction=1e-9"],
])
def test_command_line_refuses_before_any_work(tmp_path, args):
    result = CliRunner().invoke(app, ["simulate", "plla", "-o", str(tmp_path / "out"), *args])
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output and "error:" in result.output
    assert not (tmp_path / "out").exists()


# --------------------------------------------------------------------------------------------
# Property-based: any table of values either validates or raises ConfigError, nothing else
# --------------------------------------------------------------------------------------------
_ANY = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=8),
                 st.lists(st.floats(), max_size=3))
_KEYS = st.sampled_from([
    "rve.diameter_um", "rve.diameter_sd_um", "rve.volume_fraction", "rve.size_ratio", "rve.layers",
    "rve.segment_ratio", "rve.max_deviation_deg", "rve.seed", "rve.orientation", "rve.seeding",
    "fiber.taut_modulus_MPa", "fiber.slack_modulus_MPa", "fiber.flow_rate_per_s",
    "fiber.hardening_exponent", "loading.test", "loading.lateral", "loading.program",
    "loading.max_strain", "loading.steps", "solver.rtol", "solver.time_rtol", "output.window_ratio",
    "targets.diameter_um", "targets.tortuosity", "targets.contour_length_um",
    "targets.diameter_mean_um", "targets.tortuosity_halfnorm_scale", "targets.straightness",
])


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.dictionaries(_KEYS, _ANY, max_size=4))
def test_any_values_validate_or_raise_config_error(values):
    data: dict = {}
    for dotted, value in values.items():
        section, key = dotted.split(".")
        data.setdefault(section, {})[key] = value
    try:
        config = config_from_dict(data)
    except ConfigError:
        return
    values = [v for section in config.model_dump().values() if section is not None
              for v in section.values()]
    numbers = [x for v in values for x in (v if isinstance(v, list) else [v]) if isinstance(x, float)]
    assert all(math.isfinite(v) for v in numbers)


def test_a_deeply_nested_config_is_refused(tmp_path):
    path = tmp_path / "deep.toml"
    path.write_text("[rve]\norientation = " + "[" * 3000 + "]" * 3000 + "\n")
    with pytest.raises(ConfigError, match="too deeply"):
        load_config(path)


def test_a_file_name_too_long_is_a_clear_error(tmp_path):
    with pytest.raises(ConfigError, match="config file"):
        load_config(tmp_path / ("x" * 300 + ".toml"))


def test_an_override_replaces_the_keys_it_is_an_alternative_to(tmp_path):
    """A resolved file (espin config > file) holds size_ratio and the loading shorthand:
    --set rve.size_um or --set loading.program replace them instead of clashing."""
    from espin.core.config import write_config

    path = write_config(load_config("plla"), tmp_path / "resolved.toml")
    config = load_config(path, {"rve.size_um": 30.0, "loading.program": [{"to_strain": 0.03, "steps": 2}]})
    assert config.rve.side_um == 30.0 and config.loading.segments[0].to_strain == 0.03
    back = load_config(write_config(config, tmp_path / "back.toml"), {"loading.max_strain": 0.1})
    assert back.loading.program is None and back.loading.max_strain == 0.1
    with pytest.raises(ConfigError, match="not both"):
        load_config(path, {"rve.size_um": 30.0, "rve.size_ratio": 50.0})


def test_tables_are_found_beside_the_config_file(tmp_path, monkeypatch):
    folder = tmp_path / "mat"
    folder.mkdir()
    (folder / "lateral.csv").write_text("axial_strain,transverse_strain\n0,0\n0.3,-0.1\n")
    (folder / "mat.toml").write_text('[loading]\nlateral = {transverse_csv = "lateral.csv"}\n')
    monkeypatch.chdir(tmp_path)
    config = load_config("mat/mat.toml")
    assert config.loading.lateral.transverse_csv.resolve() == folder / "lateral.csv"


@pytest.mark.parametrize("test", ["equibiaxial", "pure_shear", "simple_shear"])
def test_a_lateral_condition_outside_a_uniaxial_test_is_refused(test):
    with pytest.raises(ConfigError, match="loading.lateral applies to uniaxial tests only"):
        load_config("plla", {"loading.test": test, "loading.lateral": "free"})


def test_an_override_on_a_resolved_file_acts_as_on_the_preset(tmp_path):
    """Values a resolved file holds only because they were derived (seeding from the
    orientation, diameter_min_um = 0.1 D) are derived again when what they came from changes."""
    from espin.core.config import write_config

    path = write_config(load_config("plla"), tmp_path / "resolved.toml")
    for overrides in ({"rve.orientation": {"von_mises": {"mean_deg": 0.0, "kappa": 2.0}}},
                      {"rve.diameter_um": 0.04}, {"rve.orientation.von_mises.kappa": 3.0}):
        assert load_config(path, overrides) == load_config("plla", overrides)
    kept = load_config(path, {"rve.diameter_um": 0.9, "rve.diameter_min_um": 0.05})
    assert kept.rve.diameter_min_um == 0.05
