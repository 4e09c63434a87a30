"""The [targets] section: measured statistics a mat is graded against."""

from __future__ import annotations

import pytest

from espin.core.config import (
    MAX_SAMPLE_VALUES,
    Config,
    TargetsConfig,
    apply_overrides,
    config_digest,
    config_from_dict,
    config_to_toml,
    load_config,
    write_config,
)
from espin.core.errors import ConfigError

SAMPLES = {
    "source": "PLGA-1500_1.tif, espin measure",
    "diameter_um": [2.1, 2.35, 1.9, 2.8, 2],  # an integer among the floats, as TOML allows
    "orientation_deg": [0.0, 12.5, 179.5, 90.0],
    "tortuosity": [1.0, 1.04, 1.31],
    "contour_length_um": [5.5, 12.0, 30.25],
    "window_um": 120.0,
    "min_chord_um": 4.0,
    "u_turn_fraction": 0.05,
    "straightness": 0.93,
}


def test_a_config_without_targets_has_none():
    assert Config().targets is None
    assert "targets" not in config_to_toml(Config())


def test_samples_round_trip_through_toml(tmp_path):
    config = config_from_dict({"targets": SAMPLES})
    assert config.targets.diameter_um == [2.1, 2.35, 1.9, 2.8, 2.0]
    back = load_config(write_config(config, tmp_path / "run.toml"))
    assert back == config and back.targets.contour_length_um == [5.5, 12.0, 30.25]
    assert config_to_toml(back) == config_to_toml(config)
    # The digest covers the targets.
    other = config_from_dict({"targets": SAMPLES | {"tortuosity": [1.0, 1.04, 1.32]}})
    assert config_digest(other) != config_digest(config)


def test_a_distribution_defaults_to_normal():
    t = TargetsConfig(diameter_mean_um=0.463, diameter_sd_um=0.131)
    assert t.diameter_distribution == "normal"
    assert TargetsConfig().diameter_distribution is None


@pytest.mark.parametrize(
    "targets, fragments",
    [
        ({"diameter_um": [0.4, -0.1]}, ["targets.diameter_um", "> 0", "-0.1"]),
        ({"diameter_um": [0.4, float("nan")]}, ["targets.diameter_um", "finite"]),
        ({"diameter_um": [0.4, "0.5"]}, ["targets.diameter_um", "numbers", "'0.5'"]),
        ({"diameter_um": []}, ["targets.diameter_um", "1 to 100,000 values"]),
        ({"tortuosity": [1.2, 0.99]}, ["targets.tortuosity", ">= 1", "0.99"]),
        ({"orientation_deg": [180.0]}, ["targets.orientation_deg", "[0, 180)"]),
        ({"contour_length_um": [1.0, 0.0], "tortuosity": [1.0, 1.1]},
         ["targets.contour_length_um", "> 0"]),
        ({"tortuosity": [1.0, 1.1], "contour_length_um": [3.0]},
         ["targets.contour_length_um", "one contour length per targets.tortuosity", "1 lengths"]),
        ({"contour_length_um": [3.0]}, ["targets.contour_length_um needs targets.tortuosity"]),
        ({"tortuosity": [1.0, 1.1], "tortuosity_halfnorm_scale": 0.14},
         ["targets.tortuosity", "targets.tortuosity_halfnorm_scale", "not both"]),
        ({"diameter_um": [0.4], "diameter_mean_um": 0.4, "diameter_sd_um": 0.1},
         ["targets.diameter_um", "targets.diameter_mean_um", "not both"]),
        ({"diameter_mean_um": 0.4}, ["targets.diameter_mean_um", "targets.diameter_sd_um"]),
        ({"diameter_distribution": "weibull"}, ["targets.diameter_distribution", "lognormal"]),
        ({"tortuosity_halfnorm_scale": 0.0}, ["targets.tortuosity_halfnorm_scale", "greater than 0"]),
        ({"u_turn_fraction": 1.5}, ["targets.u_turn_fraction", "less than or equal to 1"]),
        ({"straightness": 0.0}, ["targets.straightness", "greater than 0"]),
        ({"window_um": -1.0}, ["targets.window_um", "greater than 0"]),
        ({"min_chord_um": -1.0}, ["targets.min_chord_um", "greater than or equal to 0"]),
        ({"source": "x" * 501}, ["targets.source", "at most 500 characters"]),
        ({"diameter": [0.4]}, ["targets.diameter: unknown key"]),
    ],
)
def test_bad_targets_are_refused_naming_the_key(targets, fragments):
    with pytest.raises(ConfigError) as err:
        config_from_dict({"targets": targets})
    for fragment in fragments:
        assert fragment in str(err.value)


def test_a_long_bad_sample_is_one_short_error():
    values = [-1.0] * (MAX_SAMPLE_VALUES + 1)
    with pytest.raises(ConfigError) as err:
        config_from_dict({"targets": {"diameter_um": values}})
    assert "100,001" in str(err.value) and len(str(err.value)) < 300
    values = [0.5] * 999 + [-1.0]
    with pytest.raises(ConfigError) as err:
        config_from_dict({"targets": {"diameter_um": values}})
    message = str(err.value)
    assert "value 999 is -1.0" in message and "a list of 1,000 values" in message
    assert len(message) < 300


def test_overrides_set_targets_and_replace_the_alternative():
    plla = load_config("plla")
    assert apply_overrides(plla, {"targets.window_um": 30.0}).targets.window_um == 30.0
    # A sample replaces the distribution of the same quantity, and back.
    sample = apply_overrides(plla, {"targets.diameter_um": [0.4, 0.5]})
    assert sample.targets.diameter_um == [0.4, 0.5] and sample.targets.diameter_mean_um is None
    assert sample.targets.tortuosity_halfnorm_scale == 0.14  # the other quantity is kept
    back = apply_overrides(sample, {"targets.diameter_mean_um": 0.5, "targets.diameter_sd_um": 0.1})
    assert back.targets.diameter_um is None and back.targets.diameter_distribution == "normal"
    pieces = load_config("plla", {"targets.tortuosity": [1.0, 1.2], "targets.contour_length_um": [2.0, 3.0]})
    assert pieces.targets.tortuosity_halfnorm_scale is None
    assert apply_overrides(Config(), {"targets.straightness": 0.9}).targets.straightness == 0.9
