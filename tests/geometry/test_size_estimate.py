"""The size and memory estimate made from a config before any work, and the refusals it allows."""

from __future__ import annotations

import pytest

from espin.core.errors import ConfigError
from espin.geometry.rve import generate, resolve_config
from espin.geometry.size_estimate import check_size, estimate_size

GiB = 2**30


@pytest.mark.parametrize("overrides", [
    dict(rve__size_ratio=60, rve__layers=3),
    dict(rve__size_ratio=80, rve__layers=4, rve__volume_fraction=0.35),
    dict(rve__size_ratio=80, rve__layers=3, rve__max_deviation_deg=30, rve__segment_ratio=2),
    dict(rve__size_ratio=80, rve__layers=3, rve__diameter_sd_um=0.2),
])
def test_counts_are_estimated_within_a_quarter(overrides):
    """Fibers, segments, cross-links and DOF of isotropic mats against what generate makes."""
    config = resolve_config("plla", **overrides)
    size, rve = estimate_size(config), generate(config)
    measured = {"fibers": rve.mat.n_fibers, "segments": rve.mat.n_segments, "crosslinks": rve.crosslinks.n,
                "dof": rve.network.n_dof}
    for name, value in measured.items():
        assert getattr(size, name) == pytest.approx(value, rel=0.25), name


def test_the_sparsest_supported_mat_is_accepted_and_forms_a_network():
    """Volume fraction 0.05, L/D 60, diameter CV 0.7 (the corner of the supported ranges),
    one layer: accepted, and an average fiber has more than one cross-link."""
    config = resolve_config("plla", rve__size_ratio=60, rve__layers=1, rve__volume_fraction=0.05,
                            rve__diameter_sd_um=0.7 * 0.45)
    size = check_size(config)
    assert 3 <= size.fibers_per_layer < 3.5 and size.crosslinks_per_fiber > 1.2
    rve = generate(config)
    assert 2 * rve.crosslinks.n / rve.mat.n_fibers > 1 and rve.network.n_dof > 0


def test_aligned_mats_have_fewer_crosslinks_than_estimated():
    """The estimate is for isotropic fibers, which cross the most: an upper bound."""
    config = resolve_config("plla", rve__size_ratio=80, rve__layers=3,
                            rve__orientation={"von_mises": {"mean_deg": 0, "kappa": 5}})
    assert generate(config).crosslinks.n < 0.8 * estimate_size(config).crosslinks


def test_a_mat_estimated_above_24_gib_is_refused_with_the_estimate():
    config = resolve_config("plla", rve__size_ratio=3000)
    size = estimate_size(config)
    assert size.memory_bytes > 24 * GiB
    with pytest.raises(ConfigError, match=r"GiB.*--allow-large") as err:
        check_size(config, available=24 * GiB)
    assert "rve.size_ratio = 3000" in str(err.value)
    assert check_size(config, available=24 * GiB, allow_large=True) == size


@pytest.mark.parametrize("overrides, message", [
    (dict(rve__volume_fraction=1e-9), "fibers"),
    (dict(rve__size_ratio=5, rve__segment_ratio=1), "fibers"),
    (dict(rve__diameter_sd_um=0.45, rve__size_ratio=8, rve__segment_ratio=1), "fibers"),
    (dict(rve__volume_fraction=0.02, rve__size_ratio=40), "fibers"),
    (dict(rve__segment_ratio=1e-6), "memory"),
])
def test_mats_that_cannot_be_made_are_refused_before_any_work(overrides, message):
    with pytest.raises(ConfigError, match=message):
        generate("plla", **overrides)
