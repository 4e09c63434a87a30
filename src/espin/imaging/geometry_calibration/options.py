"""Config plumbing of the calibration: options check, base config, window and written config."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, cast

import numpy as np

from espin.core.config import Config
from espin.core.errors import ConfigError
from espin.geometry.targets import GeometryTargets, MeasurementError
from espin.imaging.geometry_calibration.fits import truncated_normal_parameters


def _resolve_base(base: Config | str | Path | None) -> Config:
    from espin.geometry.rve import resolve_config

    return resolve_config(base)


def _base_rve_data(base: Config) -> dict[str, Any]:
    """The base config's rve keys as given (derived values re-resolve when others change)."""
    return base.rve.model_dump(mode="json", exclude_none=True, exclude_unset=True)


MIN_PORTIONS = 1000
"""Default least number of traced fiber portions the virtual mats of one evaluation give."""


def check_options(
    fit: str,
    segment_ratio: float | None,
    max_deviation_deg: float | None,
    seeds: int,
    min_portions: int,
    window_um: float | None,
    walk: str = "auto",
) -> None:
    """Refuse, before any work, search options out of range or in contradiction.

    Raises
    ------
    ConfigError
        Naming the option and its allowed values.
    """
    if fit not in ("deviation", "segment", "both"):
        raise ConfigError(f"fit must be deviation, segment or both, got {fit!r}")
    if walk not in ("auto", "paper", "smooth"):
        raise ConfigError(f"walk must be auto, paper or smooth, got {walk!r}")
    if walk == "smooth" and (max_deviation_deg is not None or fit != "deviation"):
        raise ConfigError(
            "fit and max_deviation_deg set the paper walk: do not give them with "
            "walk = smooth (its waviness and correlation length are both searched)"
        )
    if fit in ("deviation", "both") and max_deviation_deg is not None:
        raise ConfigError("max_deviation_deg is searched with fit = deviation or both: do not fix it")
    if fit in ("segment", "both") and segment_ratio is not None:
        raise ConfigError("segment_ratio is searched with fit = segment or both: do not fix it")
    if segment_ratio is not None and not (math.isfinite(segment_ratio) and segment_ratio > 0):
        raise ConfigError(f"segment_ratio must be > 0, got {segment_ratio!r}")
    if max_deviation_deg is not None and not 0.0 <= max_deviation_deg < 90.0:
        raise ConfigError(f"max_deviation_deg must be in [0, 90), got {max_deviation_deg!r}")
    if not 1 <= seeds <= 1000:
        raise ConfigError(f"seeds must be in [1, 1000], got {seeds!r}")
    if not 50 <= min_portions <= 10**6:
        raise ConfigError(f"min_portions must be in [50, 1000000], got {min_portions!r}")
    if window_um is not None and not (math.isfinite(window_um) and window_um > 0):
        raise ConfigError(f"window_um must be > 0, got {window_um!r}")


def _window(targets: GeometryTargets, window_um: float | None, config: Config) -> tuple[float, str]:
    if targets.window_um is not None and window_um is not None:
        raise ConfigError(
            "the observation window comes from field_of_view_um of the measurement; do not give window_um as well"
        )
    if targets.window_um is not None:
        w, h = cast(tuple[float, float], targets.field_of_view_um)  # the window comes from it
        return targets.window_um, f"square of equal mean chord to the {w:g} x {h:g} um field of view"
    if window_um is not None:
        return float(window_um), "window_um"
    return config.output.window_ratio * config.rve.diameter_um, f"default {config.output.window_ratio:g} D"


def _diameter_keys(targets: GeometryTargets, base: Config) -> tuple[dict[str, Any], str | None]:
    """``diameter_um``, ``diameter_sd_um`` and ``diameter_distribution`` with the target
    moments, and a note on the family chosen.

    A measured sample (sd > 0) gets the family of larger likelihood: the normal truncated at
    ``diameter_min_um`` whose truncation has the sample's mean and sd, or the lognormal of
    that mean and sd (both have two parameters, so this is the smaller AIC). Typed-in
    targets keep the base config's family. Values computed here (a sample's moments, a
    truncation correction) are rounded to four significant digits; typed-in values that need
    no correction are written as typed.
    """
    sample = targets.diameter_um
    if sample is not None:
        mean, sd = float(np.mean(sample)), float(np.std(sample, ddof=1))
    else:
        mean, sd = cast(float, targets.diameter_mean_um), targets.diameter_sd_um or 0.0  # no sample: a mean
    explicit_min = base.rve.diameter_min_um if "diameter_min_um" in base.rve.model_fields_set else None
    family: str = base.rve.diameter_distribution
    note = None
    if sample is not None and sd > 0.0:
        log_likelihood = _diameter_log_likelihoods(sample, mean, sd, explicit_min)
        if max(log_likelihood.values()) > -math.inf:  # else the normal's error below
            family = max(log_likelihood, key=log_likelihood.__getitem__)
        note = (
            "diameter family: "
            + ", ".join(f"{name} log-likelihood {value:.1f}" for name, value in log_likelihood.items())
            + f" -> {family}"
        )
    mu, sigma = (mean, sd) if family == "lognormal" else truncated_normal_parameters(mean, sd, explicit_min)
    keys: dict[str, Any] = {"diameter_distribution": family}
    if sample is None and (mu, sigma) == (mean, sd):
        return keys | {"diameter_um": float(mu), "diameter_sd_um": float(sigma)}, note
    return keys | {"diameter_um": float(f"{mu:.4g}"), "diameter_sd_um": float(f"{sigma:.4g}")}, note


def _diameter_log_likelihoods(sample: np.ndarray, mean: float, sd: float, lower: float | None) -> dict[str, float]:
    """Log-likelihood of a diameter sample [um] under the two families the deposition draws,
    each truncated below at ``lower`` (default 0.1 of its mean) and of the sample's moments."""
    from scipy import stats

    from espin.geometry.deposition import lognormal_diameters

    out = {"normal": -math.inf, "lognormal": -math.inf}  # -inf: no such law a config accepts
    try:
        mu, sigma = truncated_normal_parameters(mean, sd, lower)
    except MeasurementError:
        mu, sigma = math.nan, math.nan
    if sigma <= mu:  # rve.diameter_sd_um <= rve.diameter_um
        low = 0.1 * mu if lower is None else lower
        normal = stats.truncnorm((low - mu) / sigma, np.inf, loc=mu, scale=sigma)
        out["normal"] = float(np.sum(normal.logpdf(sample)))
    if sd <= mean:
        low = 0.1 * mean if lower is None else lower
        lognormal = lognormal_diameters(mean, sd)
        out["lognormal"] = float(np.sum(lognormal.logpdf(sample)) - len(sample) * np.log(lognormal.sf(low)))
    return out


def _fitted(targets: GeometryTargets, fit: str, walk: str | None) -> list[str]:
    """The keys a calibration searched; ``walk`` is the walk it chose (None: none fitted)."""
    keys = []
    if targets.has_diameter:
        keys += ["rve.diameter_um", "rve.diameter_sd_um", "rve.diameter_distribution"]
    if walk == "smooth":
        keys += ["rve.walk", "rve.waviness_deg", "rve.waviness_length_ratio"]
    elif walk == "paper":
        keys += {
            "deviation": ["rve.max_deviation_deg"],
            "segment": ["rve.segment_ratio"],
            "both": ["rve.segment_ratio", "rve.max_deviation_deg"],
        }[fit]
    if targets.has_orientation:
        keys.append("rve.orientation")
    return keys


DERIVED_RVE_KEYS = ("size_ratio", "segment_ratio", "diameter_min_um", "seeding")
"""rve keys that espin derives when unset (docs/model.md section 1 defaults, :class:`espin.core.config.RVEConfig`)."""


def _written_data(config: Config) -> dict[str, Any]:
    """The calibrated config as TOML data, derived rve values left unset unless given.

    ``diameter_min_um`` (0.1 D), ``seeding`` (border if uniform, else lines) and the default
    sizes follow the calibrated values when unset; pinning them would make later edits of the
    file (another diameter, an orientation) keep stale values.
    """
    from espin.core.config import config_to_dict

    data = config_to_dict(config)
    given = config.rve.model_fields_set
    for key in DERIVED_RVE_KEYS:
        if key not in given:
            data["rve"].pop(key, None)
    return data


def _with_section(
    base: Config, rve: dict[str, Any], output: dict[str, Any], targets: dict[str, Any] | None = None
) -> dict[str, Any]:
    """The base config's given keys with the rve and output keys replaced, and its
    ``[targets]`` replaced by ``targets`` (left out when None: the base's targets describe
    the base's geometry, not the calibrated one)."""
    data = base.model_dump(mode="json", exclude_none=True, exclude_unset=True)
    data["rve"] = rve
    data["output"] = data.get("output", {}) | output
    data.pop("targets", None)
    if targets:
        data["targets"] = targets
    return data


def _targets_section(
    targets: GeometryTargets, window_um: float, min_chord_um: float, tortuosity_shift: float | None = None
) -> dict[str, Any]:
    """The ``[targets]`` a calibrated config carries: what it was calibrated to, so that
    ``espin generate`` grades its mats against them (docs/configuration.md). With
    ``tortuosity_shift`` the tortuosity sample is the tracer-corrected one (``espin
    generate`` measures true pieces, not traced ones), and the source says so.

    Measured samples are written as samples (6 significant digits, as fibers.csv), the piece
    contour lengths only when they pair one to one with the tortuosity sample; typed-in
    diameter and tortuosity laws as laws (a typed-in orientation law is the config's own
    ``rve.orientation``, which generate grades against anyway); the observation window and
    shortest chord; and the long-range shape (U-turn fraction, straightness) when measured.
    """

    def sample(values: np.ndarray) -> list[float]:
        return [float(f"{v:.6g}") for v in np.asarray(values, dtype=float)]

    source = targets.source[:300]
    if tortuosity_shift is not None:
        source += f"; tortuosity corrected for the SEM tracer (quantile map, median shift {tortuosity_shift:+.4f})"
    out: dict[str, Any] = {
        "source": source[:500],
        "window_um": float(f"{window_um:.6g}"),
        "min_chord_um": float(f"{min_chord_um:.6g}"),
    }
    if targets.diameter_um is not None:
        out["diameter_um"] = sample(targets.diameter_um)
    elif targets.diameter_mean_um is not None:
        out |= {"diameter_mean_um": targets.diameter_mean_um, "diameter_sd_um": targets.diameter_sd_um or 0.0}
    if targets.orientation_deg is not None:
        out["orientation_deg"] = [v % 180.0 for v in sample(targets.orientation_deg)]  # 179.9999996 -> 0
    if targets.tortuosity is not None:
        out["tortuosity"] = sample(targets.tortuosity)
        lengths = targets.contour_length_um
        if lengths is not None and len(lengths) == len(targets.tortuosity):
            out["contour_length_um"] = sample(lengths)
    elif targets.tortuosity_scale is not None:
        out["tortuosity_halfnorm_scale"] = targets.tortuosity_scale
    for key in ("u_turn_fraction", "straightness"):
        if getattr(targets, key) is not None:
            out[key] = float(f"{getattr(targets, key):.6g}")
    return out
