"""The run configuration: validation messages, presets, overrides, round trip."""

from __future__ import annotations

import numpy as np
import pytest

from espin.core.config import (
    Config,
    HoldSegment,
    LoadSegment,
    PoissonLateral,
    VonMises,
    apply_overrides,
    config_to_toml,
    load_config,
    write_config,
)
from espin.core.errors import ConfigError
from espin.geometry.rve import generate


def test_plla_preset_is_tables_2_and_3():
    c = load_config("plla")
    assert (c.rve.diameter_um, c.rve.volume_fraction, c.rve.size_ratio) == (0.45, 0.19, 200)
    assert (c.rve.segment_ratio, c.rve.max_deviation_deg, c.rve.layers) == (5, 5, 15)
    assert c.rve.orientation == "uniform" and c.rve.seeding == "border"
    f = c.fiber
    assert (f.taut_modulus_MPa, f.slack_modulus_MPa, f.flow_rate_per_s) == (3000, 3, 1e-8)
    assert (f.flow_resistance_MPa, f.hardening_exponent) == (5, 0.5)
    assert c.rve.side_um == pytest.approx(90.0) and c.rve.segment_length_um == pytest.approx(2.25)
    # The built-in defaults are the plla values, without the paper's measured targets.
    assert load_config(None) == c.model_copy(update={"targets": None})
    t = c.targets
    assert (t.diameter_mean_um, t.diameter_sd_um, t.diameter_distribution) == (0.463, 0.131, "normal")
    assert t.tortuosity_halfnorm_scale == 0.14 and "Fig. 10" in t.source


@pytest.mark.parametrize(
    "overrides, fragments",
    [
        ({"rve.diameter_um": -1}, ["rve.diameter_um", "greater than or equal to 0.001"]),
        ({"rve.volume_fraction": 1.5}, ["rve.volume_fraction", "less than 1"]),
        ({"rve.max_deviation_deg": 90}, ["rve.max_deviation_deg", "less than 90"]),
        ({"rve.layers": 0}, ["rve.layers", "greater than or equal to 1"]),
        ({"rve.diamter_um": 1}, ["rve.diamter_um", "unknown key"]),
        ({"fiber.slack_modulus_MPa": 4000}, ["taut_modulus_MPa", "slack_modulus_MPa"]),
        ({"rve.size_ratio": 4}, ["size_ratio", "segment_ratio"]),
        ({"rve.size_ratio": 100, "rve.size_um": 40}, ["size_ratio", "size_um", "not both"]),
        ({"rve.Layers": 3}, ["rve.Layers: unknown key"]),
        ({"loading.program": [{"hold_s": -1}]}, ["loading.program.0.hold_s", "greater than 0"]),
        ({"loading.program": [{"to_strain": 0.1}], "loading.steps": 5}, ["replaces the shorthand", "loading.steps"]),
        ({"rve.orientation": "isotropic"}, ["rve.orientation", "uniform"]),
        ({"rve.orientation": {"vonmises": {}}}, ["rve.orientation", "von_mises"]),
        ({"rve.orientation": {"von_mises": {"mean_deg": 180}}}, ["mean_deg", "less than 180"]),
        ({"loading.lateral": {"poisson": 0.3}}, ["loading.lateral", "poisson_ratio"]),
        ({"loading.test": "tension"}, ["loading.test", "uniaxial"]),
        ({"loading.test": "path"}, ["loading.path_csv"]),
        ({"solver.linear": "umfpack"}, ["solver.linear", "superlu"]),
    ],
)
def test_errors_name_the_key_and_range(overrides, fragments):
    with pytest.raises(ConfigError) as err:
        load_config("plla", overrides)
    for fragment in fragments:
        assert fragment in str(err.value)


def test_unknown_section_and_bad_file(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[rvee]\nlayers = 3\n")
    with pytest.raises(ConfigError, match="rvee: unknown key"):
        load_config(bad)
    broken = tmp_path / "broken.toml"
    broken.write_text("[rve\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(broken)
    with pytest.raises(ConfigError, match="neither a preset"):
        load_config("pla")
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "missing.toml")


def test_defaults_resolved():
    c = load_config(None, {"rve.orientation": {"von_mises": {"mean_deg": 30, "kappa": 2}}})
    assert isinstance(c.rve.orientation, VonMises)
    assert c.rve.seeding == "lines"  # aligned mats default to the stationary seeding
    assert load_config(None, {"rve.seeding": "border", "rve.orientation": {"von_mises": {}}}).rve.seeding == "border"
    assert c.rve.diameter_min_um == pytest.approx(0.045)
    c = load_config(None, {"rve.size_um": 30.0, "rve.segment_um": 1.0})
    assert c.rve.side_um == 30.0 and c.rve.segment_length_um == 1.0 and c.rve.size_ratio is None


def test_loading_program_forms():
    c = load_config(None, {"loading.program": [
        {"to_strain": 0.05, "rate_per_s": 1e-3}, {"hold_s": 60}, {"to_strain": 0.0}]})
    kinds = [type(s) for s in c.loading.segments]
    assert kinds == [LoadSegment, HoldSegment, LoadSegment]
    assert load_config(None).loading.segments == [LoadSegment(to_strain=0.3, rate_per_s=5e-3, steps=30)]
    lateral = load_config(None, {"loading.lateral": {"poisson_ratio": 0.4}}).loading.lateral
    assert lateral == PoissonLateral(poisson_ratio=0.4)


def test_overrides_resolve_derived_values_anew(tmp_path):
    plla = load_config("plla")
    thin = apply_overrides(plla, {"rve.diameter_um": 0.04})
    assert thin.rve.diameter_min_um == pytest.approx(0.004)
    aligned = apply_overrides(plla, {"rve.orientation": {"von_mises": {"kappa": 2.0}}})
    assert aligned.rve.seeding == "lines"
    assert apply_overrides(plla, {"rve.size_um": 50.0}).rve.side_um == 50.0
    program = apply_overrides(plla, {"loading.program": [{"to_strain": 0.1}, {"hold_s": 5}]})
    assert len(program.loading.segments) == 2
    # A resolved config with a program reads back (the shorthand is not written beside it).
    assert load_config(write_config(program, tmp_path / "program.toml")) == program


def test_round_trip_gives_the_same_run(tmp_path):
    c = load_config("plla", {"rve.size_ratio": 30, "rve.layers": 2, "rve.seed": 7,
                             "rve.orientation": {"histogram": {"edges_deg": [0, 90, 180], "weights": [2, 1]}}})
    path = write_config(c, tmp_path / "run.toml")
    back = load_config(path)
    assert back == c and config_to_toml(back) == config_to_toml(c)
    a, b = generate(c), generate(back)
    assert np.array_equal(a.mat.vertices, b.mat.vertices)
    assert np.array_equal(a.network.element_nodes, b.network.element_nodes)


def test_config_is_immutable():
    c = Config()
    with pytest.raises(Exception):
        c.rve.layers = 3


def test_override_reaches_inside_a_table():
    from espin.core.config import apply_overrides, load_config

    config = apply_overrides(load_config("plla"), {"rve.orientation.von_mises.kappa": 3.0})
    assert config.rve.orientation.von_mises.kappa == 3.0
    assert config.rve.orientation.von_mises.mean_deg == 0.0
    again = apply_overrides(config, {"rve.orientation.von_mises.mean_deg": 30.0})
    assert (again.rve.orientation.von_mises.kappa, again.rve.orientation.von_mises.mean_deg) == (3.0, 30.0)
