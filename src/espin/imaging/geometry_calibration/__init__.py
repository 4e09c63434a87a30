"""Deposition parameters whose mat, measured like an SEM image, matches measured distributions.

:func:`calibrate_geometry` takes measured (or typed-in) distributions of fiber diameter,
orientation and tortuosity (:class:`espin.geometry.targets.GeometryTargets`) and a base
config, and returns a config whose virtual mat, measured the same way, matches them. The other
keys of the base config are kept. "The same way": in the same square observation window, and,
when the measured sample records the contour lengths of its pieces (as ``espin measure``
writes), on virtual pieces of the same lengths (length-matched sampling,
:mod:`espin.imaging.geometry_calibration.virtual`): the SEM tracer cuts fibers at crossings, so its
pieces are much shorter than the window, and tortuosity grows with the observation length.
Without lengths (typed-in targets) whole window portions are measured
(:func:`espin.geometry.statistics.window_tortuosity`). The report says which was used.

Method (docs/geometry_calibration.md)
-------------------------------------
1. **Diameters** are set directly, with the sample's mean and sd: of a lognormal, or of a
   normal truncated below at ``rve.diameter_min_um`` as the deposition draws it (the parent
   normal is solved for so that the *truncated* distribution has the target mean and sd);
   of a measured sample, the family of larger likelihood.
2. **Tortuosity.** The visible tortuosity depends on the walk (segment length l_s and largest
   turn theta_max) through, mainly, its persistence length
   ``l_p = -l_s / ln(sin theta_max / theta_max)`` relative to the window: pairs along a curve
   of constant l_p give nearly the same distribution, so only one combination is identifiable.
   One parameter is searched with the other fixed (default: ``max_deviation_deg`` at the base
   segment length), minimizing the Kolmogorov-Smirnov distance between the visible tortuosity
   of generated mats and the target: a coarse grid, then a bounded scalar refinement. Mats are
   small RVEs (side twice the window) over fixed seeds (common random numbers), so the
   objective is deterministic. With ``fit="both"`` the search is repeated over a grid of
   segment lengths and the whole valley is reported; of the points whose KS lies within the
   sampling spread (1 / sqrt(n)) of the best, the one nearest the base segment length is
   kept, since the window cannot tell them apart.
   **Walk model.** When the targets carry the long-range shape of the fibers (``espin
   measure``: of the traced fibers crossing the image edge to edge, the U-turn fraction and
   the straightness, end-to-end over contour), the score adds their squared standardized
   misfits to (KS / its sampling spread)^2, and the smooth walk (``rve.walk = "smooth"``) is
   fitted too: its waviness and correlation length over a grid, then refined one at a time.
   The walk of smaller score is kept. The paper walk, matched to the waviness of short pieces,
   curls at long range; the smooth one keeps each fiber's course.
3. **Orientation**: uniform, or an axial von Mises fitted to the sample, the model of smaller
   AIC (``espin measure``'s rule, so the mat follows what measure reported). The deposition walk
   widens the visible distribution (a fiber forgets its direction over about l_p / 4), so the
   deposition kappa is raised until the visible order parameter, measured in the RVE of the
   written config, matches the target's; where even kappa = 700 cannot, the closest is kept
   and a warning says so.

With length-matched sampling the report also gives the tortuosity of the calibrated mat's
whole window portions: what tracing fibers by hand across the image would measure, which the
tracer's pieces cannot show.

New deposition parameters change the network and thus the mechanics: the fiber parameters
must be fitted again (``espin fit``) before stresses of the calibrated mat mean anything.

Units: um, degrees at the edge (configs, reports); radians inside.

The package: :mod:`~espin.imaging.geometry_calibration.fits` (persistence, von Mises and truncated
normal fits), :mod:`~espin.imaging.geometry_calibration.virtual` (the virtual SEM),
:mod:`~espin.imaging.geometry_calibration.matching` (targets and KS matches),
:mod:`~espin.imaging.geometry_calibration.search` (walk and kappa searches),
:mod:`~espin.imaging.geometry_calibration.result` (:class:`GeometryCalibration`) and
:mod:`~espin.imaging.geometry_calibration.options` (config plumbing); :func:`calibrate_geometry`
is here.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

import numpy as np

from espin.core.config import WALK_DEFAULTS, Config, config_from_dict
from espin.core.errors import ConfigError
from espin.geometry.targets import GeometryTargets, MeasurementError
from espin.imaging.geometry_calibration.fits import (
    KAPPA_MAX,
    fit_axial_von_mises,
    persistence_ratio,
    truncated_normal_parameters,
)
from espin.imaging.geometry_calibration.matching import (
    FIXED_TOLERANCE,
    DistributionMatch,
    _diameter_target,
    _orientation_spec,
    _tortuosity_target,
    crossing_target,
)
from espin.imaging.geometry_calibration.options import (
    MIN_PORTIONS,
    _base_rve_data,
    _diameter_keys,
    _fitted,
    _resolve_base,
    _targets_section,
    _window,
    _with_section,
    check_options,
)
from espin.imaging.geometry_calibration.result import (
    MECHANICS_NOTE,
    SCHEMA,
    SCHEMA_VERSION,
    GeometryCalibration,
    MeasuredImage,
)
from espin.imaging.geometry_calibration.search import (
    DEVIATION_GRID_STEP_DEG,
    DEVIATION_RANGE_DEG,
    SEGMENT_RATIO_MAX_FRACTION,
    SEGMENT_RATIO_MIN,
    VALLEY_SEGMENT_RATIOS,
    ValleyPoint,
    WalkFit,
    _correct_kappa,
    _fit_walks,
    _Objective,
    _with_walk,
)
from espin.imaging.geometry_calibration.tracer import measure_renderings, tracer_corrected
from espin.imaging.geometry_calibration.virtual import (
    VirtualMeasurement,
    _layers_per_seed,
    _validated_rve,
)

__all__ = [
    "MECHANICS_NOTE",
    "MIN_PORTIONS",
    "check_options",
    "DistributionMatch",
    "ValleyPoint",
    "VirtualMeasurement",
    "GeometryCalibration",
    "MeasuredImage",
    "calibrate_geometry",
    "measured_image",
    "persistence_ratio",
    "fit_axial_von_mises",
    "truncated_normal_parameters",
    # constants (those of the submodules re-exported)
    "SCHEMA",
    "SCHEMA_VERSION",
    "FIXED_TOLERANCE",
    "TORTUOSITY_MEAN_TOLERANCE",
    "HALFNORM_MEDIAN",
    "KAPPA_MAX",
    "DEVIATION_RANGE_DEG",
    "DEVIATION_GRID_STEP_DEG",
    "SEGMENT_RATIO_MIN",
    "SEGMENT_RATIO_MAX_FRACTION",
    "VALLEY_SEGMENT_RATIOS",
    "SEARCH_SIDE_OVER_WINDOW",
    "Fit",
]

log = logging.getLogger(__name__)

TORTUOSITY_MEAN_TOLERANCE = 0.02
"""A warning is printed when the calibrated mat's mean tortuosity is further from the target's
(the KS objective matches the distribution's bulk, not its mean)."""
HALFNORM_MEDIAN = 0.6744897501960817
"""Median of the standard half-normal distribution (its scale is (median - loc) / this)."""
SEARCH_SIDE_OVER_WINDOW = 2.0
"""Side of the search RVE over the window side (the window sits in its central quarter)."""
Fit = Literal["deviation", "segment", "both"]
Walk = Literal["auto", "paper", "smooth"]


def calibrate_geometry(
    targets_or_path: GeometryTargets | str | Path | Any,
    base: Config | str | Path | None = None,
    *,
    fit: Fit = "deviation",
    walk: Walk = "auto",
    segment_ratio: float | None = None,
    max_deviation_deg: float | None = None,
    segment_ratios: tuple[float, ...] = VALLEY_SEGMENT_RATIOS,
    window_um: float | None = None,
    correct_orientation: bool = True,
    seeds: int = 8,
    seed: int = 0,
    min_portions: int = MIN_PORTIONS,
    progress: Callable[[str], None] | None = None,
    image: MeasuredImage | None = None,
    rendered_check: bool = True,
) -> GeometryCalibration:
    """Find deposition parameters whose mat, measured in the same window, matches the targets.

    Parameters
    ----------
    targets_or_path
        :class:`GeometryTargets`, a ``fibers.csv``, a folder written by ``espin measure`` or
        an :class:`espin.imaging.measurement.SEMMeasurement`.
    base
        Config, preset name or TOML whose other keys are kept (default ``plla``).
    fit
        Walk parameter(s) searched to match the tortuosity: ``"deviation"``
        (``rve.max_deviation_deg``, default), ``"segment"`` (``rve.segment_ratio``) or
        ``"both"`` (deviation searched at several segment lengths; the valley is reported,
        and of the equally good points the one nearest the base segment length is kept).
    walk
        ``"auto"`` (default): fit the paper walk and the smooth walk and keep the one of
        smaller score; only the paper walk when the targets carry no long-range shape
        (U-turn fraction and straightness of fibers crossing the image edge to edge), which
        alone tells them apart. ``"paper"`` or ``"smooth"``: that walk.
    segment_ratio
        Fixed segment length over D when it is not searched (default: the base's; the
        smooth walk takes segments of at most a quarter of its correlation length).
    max_deviation_deg : float [deg]
        Fixed largest turn when it is not searched (default: the base's).
    segment_ratios
        Segment lengths over D at which ``fit="both"`` searches the deviation (those longer
        than a third of the window are skipped).
    window_um : float [um]
        Observation window side when the targets carry no field of view (default
        ``output.window_ratio`` D of the calibrated diameter, 50 D).
    correct_orientation
        Raise the deposition kappa of an aligned target so that the visible orientation
        matches (the walk widens it).
    seeds
        Mats per evaluation (fixed seeds: common random numbers).
    seed
        Seeds the list of mat seeds.
    min_portions
        Fewest visible fiber portions per evaluation (sets the layers per mat).
    progress
        Called with a short message after each evaluation.
    image
        The analysed SEM image the targets were measured on, for ``comparison.png``;
        default: an SEMMeasurement's, or the one a measure folder's ``measurement.toml``
        names (:func:`measured_image`).
    rendered_check
        With the image known: render mats of the fitted walk like the image, measure them
        with ``espin measure``, map the measured tortuosity sample to true tortuosity
        quantile by quantile and search again
        (:mod:`~espin.imaging.geometry_calibration.tracer`); then render and measure mats of
        the calibrated config the same way: ``search["tracer"]["rendered_check"]`` gives
        their KS distances and long-range shape against the image's.

    Returns
    -------
    GeometryCalibration
        The calibrated config, the per-distribution match and the search record.

    Raises
    ------
    EspinError
        ConfigError or MeasurementError for bad options or targets, before any work.
    """
    started = time.perf_counter()
    check_options(fit, segment_ratio, max_deviation_deg, seeds, min_portions, window_um, walk)
    if isinstance(targets_or_path, GeometryTargets):
        targets = targets_or_path
    elif hasattr(targets_or_path, "fibers") and hasattr(targets_or_path, "field_of_view_um"):
        targets = GeometryTargets.from_measurement(targets_or_path)
    else:
        targets = GeometryTargets.from_path(targets_or_path)
    if targets.is_empty:
        raise MeasurementError(
            "no targets: give measured fibers (diameter_um, orientation_deg or tortuosity "
            "columns) or typed-in diameter, orientation or tortuosity"
        )
    base_config = _resolve_base(base)
    rve = _base_rve_data(base_config)
    parameters: dict[str, Any] = {}
    warnings: list[str] = []
    notes: list[str] = list(targets.notes)

    # 1. Diameters.
    if targets.has_diameter:
        keys, family_note = _diameter_keys(targets, base_config)
        rve |= keys
        parameters |= {f"rve.{k}": v for k, v in keys.items()}
        if family_note:
            notes.append(family_note)
    calibrated_d = _validated_rve(rve).diameter_um

    # 2. The window and how mats are measured.
    draft = config_from_dict(_with_section(base_config, rve, {}), "(geometry calibration)")
    window, window_source = _window(targets, window_um, draft)
    min_chord = targets.min_chord_um
    if min_chord is None:
        from espin.geometry.statistics import DEFAULT_MIN_CHORD_FRACTION

        min_chord = DEFAULT_MIN_CHORD_FRACTION * window
    seed_list = tuple(int(s) for s in np.random.SeedSequence(seed).generate_state(seeds))
    search_side = SEARCH_SIDE_OVER_WINDOW * window
    base_side = draft.rve.side_um
    check_side = base_side if window <= base_side else search_side
    if window > base_side:
        warnings.append(
            f"the observation window ({window:.4g} um) is larger than the layer of the config "
            f"({base_side:.4g} um): the calibration measured layers of {search_side:.4g} um, while "
            "espin generate with this config measures its whole layer (a smaller window)"
        )
    measurement = VirtualMeasurement(window, float(min_chord), seed_list, 1, targets.contour_length_um)
    if targets.has_orientation:
        orientation, orientation_target, found = _orientation_spec(targets)
        notes += [n for n in found if not n.startswith("warning: ")]
        warnings += [n.removeprefix("warning: ") for n in found if n.startswith("warning: ")]
        rve["orientation"] = orientation
    layers = _layers_per_seed(measurement, rve, search_side, min_portions)
    measurement = measurement.with_layers(layers)
    sampling = _sampling_description(measurement)
    evaluations = 0

    # 3. Tortuosity and long-range shape: the walk.
    image = image if image is not None else measured_image(targets_or_path)
    if image is None and targets.contour_length_um is not None:
        notes.append(
            "no measured image at hand (a fibers.csv, or the image named in "
            "measurement.toml was not found): no tracer correction, rendered check or "
            "comparison.png; the fitted walk is wavier than the image's (docs/geometry_calibration.md)"
        )
    if walk != "auto" and not targets.has_tortuosity:
        notes.append(f"walk = {walk} is not used: the targets have no tortuosity to fit a walk to")
    fitted: WalkFit | None = None
    search_targets = targets  # the tortuosity sample corrected for the tracer's bias
    tracer: dict[str, Any] = {}
    if targets.has_tortuosity:
        start = _validated_rve(rve)
        sr = segment_ratio if segment_ratio is not None else start.segment_length_um / calibrated_d
        largest_segment = SEGMENT_RATIO_MAX_FRACTION * window / calibrated_d
        if largest_segment <= SEGMENT_RATIO_MIN:
            raise ConfigError(
                f"the observation window ({window:.4g} um) is too small to measure tortuosity: "
                f"it must exceed {SEGMENT_RATIO_MIN / SEGMENT_RATIO_MAX_FRACTION:g} D"
            )
        if walk == "auto" and crossing_target(targets) is None:
            notes.append(
                "walk: the targets carry no long-range shape (fibers crossing the image "
                "edge to edge), which alone tells the walks apart: the paper walk is kept"
            )
        dev = next(
            d
            for d in (max_deviation_deg, start.max_deviation_deg, WALK_DEFAULTS["paper"]["max_deviation_deg"])
            if d is not None
        )
        length = next(
            r for r in (start.waviness_length_ratio, WALK_DEFAULTS["smooth"]["waviness_length_ratio"]) if r is not None
        )

        def fit_walks(goal: GeometryTargets) -> WalkFit:
            objective = _Objective(
                measurement, rve, search_side, _tortuosity_target(goal), crossing_target(goal), sr, progress
            )
            return _fit_walks(
                objective, walk, fit, sr, dev, length, largest_segment, segment_ratios, window / calibrated_d
            )

        fitted = fit_walks(targets)
        evaluations += fitted.evaluations
        if image is not None and rendered_check:
            # The tracer reads short pieces more tortuous than they are: measure its bias on
            # renderings of the fitted walk, and search again for the corrected sample.
            if progress is not None:
                progress("rendering the fitted walk and measuring it like the image (tracer bias)")
            draft_rve = _with_walk(rve, fitted)
            draft = config_from_dict(_with_section(base_config, draft_rve, {}), "(geometry calibration)")
            search_targets, bias = tracer_corrected(
                targets, measure_renderings(draft, image), measurement.measure(draft_rve, search_side)["tortuosity"]
            )
            tracer = {"tortuosity_bias": bias, "first_walk": fitted.scores[fitted.chosen].walk}
            # Both None (no tortuosity sample) compare equal, as meant; numpy's stubs refuse None.
            if not np.array_equal(search_targets.tortuosity, targets.tortuosity):  # type: ignore[arg-type]
                fitted = fit_walks(search_targets)
                evaluations += fitted.evaluations
        if fitted.problem:
            warnings.append(fitted.problem)
        rve = _with_walk(rve, fitted)
        keys = fitted.scores[fitted.chosen].walk
        parameters |= {f"rve.{k}": v for k, v in keys.items()}
        parameters["rve.segment_ratio"] = float(rve["segment_ratio"])
        if fitted.chosen == "paper":
            parameters["persistence_ratio"] = persistence_ratio(keys["segment_ratio"], keys["max_deviation_deg"])
        if len(fitted.scores) > 1:
            notes.append(
                "walk: "
                + ", ".join(
                    f"{name} score {sc.score:.3g} (tortuosity KS {sc.ks:.3f}, U-turns "
                    f"{sc.u_turn_fraction:.3f}, straightness {sc.straightness:.4f})"
                    for name, sc in fitted.scores.items()
                )
                + f" -> {fitted.chosen}"
            )

    # 4. Orientation: correct the deposition kappa for the widening by the walk.
    if targets.has_orientation:
        spec = rve["orientation"]
        if isinstance(spec, dict) and correct_orientation:
            vm = spec["von_mises"]
            order = dict(orientation_target.summary)["order"]
            kappa, problem, n = _correct_kappa(
                measurement, rve, check_side, vm["mean_deg"], vm["kappa"], order, progress
            )
            evaluations += n
            spec = {"von_mises": {"mean_deg": vm["mean_deg"], "kappa": kappa}}
            rve["orientation"] = spec
            if problem:
                warnings.append(problem)
        parameters["rve.orientation"] = spec

    # 5. The written config and its match, measured on mats of that config.
    output = {"window_ratio": float(f"{window / calibrated_d:.6g}")}
    config = config_from_dict(
        _with_section(
            base_config,
            rve,
            output,
            _targets_section(search_targets, window, float(min_chord), tracer.get("tortuosity_bias")),
        ),
        "(calibrated)",
    )
    parameters["output.window_ratio"] = output["window_ratio"]
    parameters["fitted"] = _fitted(targets, fit, fitted.chosen if fitted else None)
    seen = measurement.measure(_base_rve_data(config), check_side)
    evaluations += 1
    matches = []
    if targets.has_tortuosity:
        matches.append(_tortuosity_target(search_targets).compare(seen["tortuosity"]))
        means = dict((n, (t, v)) for n, t, v in matches[-1].summary)["mean"]
        if abs(means[1] - means[0]) > TORTUOSITY_MEAN_TOLERANCE:
            warnings.append(
                f"the calibrated mat's mean tortuosity {means[1]:.3f} differs from the target's "
                f"{means[0]:.3f} by more than {TORTUOSITY_MEAN_TOLERANCE:g}: the KS distance "
                "matches the bulk of the distribution, and the walk's tail (fibers curling "
                "within the window) is heavier than the target's"
            )
    if targets.has_orientation:
        matches.append(orientation_target.compare(seen["orientation_deg"]))
    if targets.has_diameter:
        matches.append(_diameter_target(targets).compare(seen["diameter_um"]))
    whole = None
    if targets.has_tortuosity and measurement.piece_lengths_um is not None:
        # What the pieces say of whole fibers across the window (a hand tracing's measure).
        t = VirtualMeasurement(window, float(min_chord), seed_list, layers).measure(_base_rve_data(config), check_side)[
            "tortuosity"
        ]
        evaluations += 1
        # The walk's portions have a long tail (fibers curling inside the window): the median
        # gives the half-normal scale robustly (median = scale * 0.6745).
        if len(t):
            median = float(np.median(t))
            whole = {
                "mean": float(np.mean(t)),
                "median": median,
                "halfnorm_scale_from_median": (median - 1.0) / HALFNORM_MEDIAN,
                "n": int(len(t)),
            }
    if image is not None and rendered_check:
        if progress is not None:
            progress("rendering the calibrated mat and measuring it like the image")
        tracer["rendered_check"] = measure_renderings(config, image).check(targets)
    search = {
        "tracer": tracer or None,
        "window_um": window,
        "window_source": window_source,
        "min_chord_um": float(min_chord),
        "seeds": list(seed_list),
        "layers": layers,
        "search_side_um": search_side,
        "check_side_um": check_side,
        "sampling": measurement.sampling,
        "sampling_description": sampling,
        "whole_portion_tortuosity": whole,
        "evaluations": evaluations,
        "elapsed_s": time.perf_counter() - started,
        "notes": notes,
    }
    for w in warnings:
        log.info("calibration warning: %s", w)
    log.debug("virtual measurement: %s", sampling)
    return GeometryCalibration(
        config,
        base_config,
        targets,
        parameters,
        tuple(matches),
        fitted.valley if fitted else (),
        search,
        tuple(warnings),
        image,
    )


def measured_image(source: Any) -> MeasuredImage | None:
    """The analysed image behind the targets: an SEMMeasurement's, or the one a measure
    folder's ``measurement.toml`` names (None when unknown or not found)."""
    if hasattr(source, "image") and hasattr(source, "um_per_px"):
        return MeasuredImage(
            np.asarray(source.image), float(source.um_per_px), Path(str(getattr(source, "source", "image"))).name
        )
    if isinstance(source, (str, Path)) and Path(source).is_dir():
        from espin.imaging.geometry_calibration.comparison import MeasuredView

        view = MeasuredView.from_measure_folder(source)
        if view is not None:
            return MeasuredImage(view.read(), view.um_per_px, view.path.name)
    return None


def _sampling_description(measurement: VirtualMeasurement) -> str:
    """How the virtual mats are measured, for the report."""
    lengths = measurement.piece_lengths_um
    if lengths is None:
        return "whole fiber portions in the window, edge to edge (the targets carry no piece lengths)"
    return (
        f"length-matched pieces: contour lengths drawn from the {len(lengths)} measured "
        f"pieces (median {np.median(lengths):.3g} um), placed uniformly along the window "
        "portions"
    )
