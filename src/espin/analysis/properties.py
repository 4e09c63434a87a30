"""Mechanical properties from a stress-strain curve: elastic modulus, yield, post-yield modulus.

The paper's PLLA mats (and espin's ``plla`` RVE) are linear to about 3 % strain, then yield,
then harden nearly linearly to 30 % (docs/model.md section 7). Their properties come from a bilinear
description of the curve:

* **elastic modulus** E, the initial slope;
* **post-yield modulus** H, the slope of the hardening line;
* **yield point** (yield strain, yield stress), the intersection of the elastic line and the
  post-yield line.

The fit, in three steps (the same for simulated and experimental curves):

1. **Knee.** A continuous two-segment ("hinge") least-squares fit,
   ``s(e) = a + E_h min(e, b) + H max(e - b, 0)``, over every point of the curve: for a given
   breakpoint b the three coefficients are linear least squares; b is optimized by a grid over
   the strain range (each line keeps at least three points) and a bounded refinement around the
   best grid point. Least squares over the whole curve averages the noise of hundreds of points,
   and the search over b is global, so noise cannot trap it in a local minimum. The hinge's
   second line is the post-yield line (slope H).
2. **Elastic line.** A least-squares line through the points below a fraction
   (``elastic_fraction``, default 1/2) of the knee strain (at least three points when the knee
   has them). On a sharp knee this is the hinge's first line; on a rounded knee (a smooth
   transition, as in real mats) the hinge's first line is a secant through the knee, up to
   30 % below the initial slope, while the window keeps the initial slope that the paper calls
   the elastic modulus.
3. **Yield** is where the elastic line meets the post-yield line.

Offset and toe region: both lines carry their own intercept, so a curve that does not start at
(0, 0) (a preload, a shifted strain origin) gives the same moduli and yield stress. The yield
strain is measured from the strain at which the elastic line crosses zero stress (toe
compensation, as in ASTM D638 appendix X1); that strain is reported as ``strain_offset``, so the
yield strain in the curve's own strain axis is ``yield_strain + strain_offset``. A concave toe
(slack taken up at the start of a test) is not a straight line: leave it out with
``strain_range``.

No clear yield: the result then has ``has_yield=False``, NaN yield quantities and post-yield
modulus, the modulus of one straight line fitted to all points, and a ``note`` saying why:
fewer than six points; a bilinear fit no better than a straight line (F statistic of the two
extra parameters below 20: a straight line with noise rarely exceeds 10 with an optimized
breakpoint); the best breakpoint at an end of the data; a post-yield slope above
``max_slope_ratio`` (default 1/2) of the elastic modulus (nearly equal slopes, or a stiffening
curve); a non-positive initial slope; or lines that meet outside the data. A constant stress
(to a relative 1e-9; e.g. all zero: a wrong column, or a mat that carries no load) gives
``modulus_MPa = 0`` and a NaN ``strain_offset`` and ``r_squared``: a flat line has no zero
crossing (nor has a line flat to rounding, whose offset is NaN too).

Units: strain dimensionless (engineering, 0.01 = 1 %), stress and moduli MPa.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import minimize_scalar

from espin.core.errors import InputError

if TYPE_CHECKING:  # pragma: no cover
    from espin.mechanics.driver import SimulationResult

__all__ = [
    "CurveError",
    "CurveProperties",
    "check_curve",
    "curve_properties",
    "simulation_properties",
    "curve_marks",
    "summarize_properties",
    "bilinear_stress",
    "plot_bilinear_fits",
]

_MIN_POINTS_PER_LINE = 3
_MIN_F_STATISTIC = 20.0
_GRID_POINTS = 200
_ROUNDING = 1e-9


class CurveError(InputError):
    """A stress-strain curve cannot be analysed (too short, not finite, strain decreasing)."""


@dataclass(frozen=True)
class CurveProperties:
    """Properties of one stress-strain curve from its bilinear fit (module docs).

    Attributes
    ----------
    modulus_MPa : float [MPa]
        Elastic modulus E, the initial slope.
    yield_stress_MPa : float [MPa]
        Stress where the elastic and post-yield lines meet; NaN without a clear yield.
    yield_strain : float
        Strain of that point, measured from ``strain_offset``; NaN without a clear yield.
    post_yield_modulus_MPa : float [MPa]
        Slope H of the post-yield line; NaN without a clear yield.
    has_yield : bool
        Whether the curve shows a clear yield.
    r_squared : float
        Coefficient of determination of the reported bilinear curve (elastic line up to the
        yield point, post-yield line after it; one straight line without a yield).
    note : str
        Why there is no clear yield, or a caveat about the fit; empty when there is none.
    strain_offset : float
        Strain at which the elastic line crosses zero stress (toe compensation).
    """

    modulus_MPa: float
    yield_stress_MPa: float
    yield_strain: float
    post_yield_modulus_MPa: float
    has_yield: bool
    r_squared: float
    note: str
    strain_offset: float = 0.0

    def as_dict(self) -> dict[str, float | bool | str]:
        """The properties by field name (floats, bool, str)."""
        return asdict(self)


def bilinear_stress(props: CurveProperties, strain: ArrayLike) -> np.ndarray:
    """Stress [MPa] of the reported bilinear curve at ``strain`` (the curve's own strain axis).

    The elastic line up to the yield point, the post-yield line after it; the elastic line
    alone when the curve has no clear yield.
    """
    e = np.asarray(strain, dtype=float) - props.strain_offset
    elastic = props.modulus_MPa * e
    if not props.has_yield:
        return elastic
    plastic = props.yield_stress_MPa + props.post_yield_modulus_MPa * (e - props.yield_strain)
    return np.where(e <= props.yield_strain, elastic, plastic)


def _line(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Least-squares (intercept, slope)."""
    slope, intercept = np.polyfit(x, y, 1)
    return float(intercept), float(slope)


def _hinge(x: np.ndarray, y: np.ndarray, b: float) -> tuple[float, np.ndarray]:
    """Continuous two-segment fit with breakpoint b: (SSE, [a, E_h, H])."""
    design = np.column_stack([np.ones_like(x), np.minimum(x, b), np.maximum(x - b, 0.0)])
    coef = np.linalg.lstsq(design, y, rcond=None)[0]
    residual = y - design @ coef
    return float(residual @ residual), coef


def _best_breakpoint(x: np.ndarray, y: np.ndarray) -> float:
    """Breakpoint of the least-squares hinge: global grid, then bounded refinement."""
    lo, hi = x[_MIN_POINTS_PER_LINE - 1], x[-_MIN_POINTS_PER_LINE]
    grid = np.linspace(lo, hi, _GRID_POINTS)
    sse = np.array([_hinge(x, y, b)[0] for b in grid])
    i = int(np.argmin(sse))
    left, right = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    if right <= left:
        return float(grid[i])
    found = minimize_scalar(
        lambda b: _hinge(x, y, b)[0], bounds=(left, right), method="bounded", options={"xatol": 1e-9 * (hi - lo)}
    )
    return float(found.x) if found.fun <= sse[i] else float(grid[i])


def _r_squared(y: np.ndarray, model: np.ndarray) -> float:
    total = float(np.sum((y - y.mean()) ** 2))
    if total == 0.0:
        return math.nan
    return 1.0 - float(np.sum((y - model) ** 2)) / total


def check_curve(strain: ArrayLike, stress: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """The curve as float arrays, checked: 1-D of one length, finite, strain not decreasing.

    Raises
    ------
    CurveError
        Naming the first point that breaks a rule.
    """
    try:
        x = np.asarray(strain, dtype=float)
        y = np.asarray(stress, dtype=float)
    except (TypeError, ValueError) as err:
        raise CurveError(f"strain and stress must be arrays of numbers ({err})") from None
    if x.ndim != 1 or x.shape != y.shape:
        raise CurveError(f"strain and stress must be 1-D arrays of one length, got shapes {x.shape} and {y.shape}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        bad = int(np.flatnonzero(~(np.isfinite(x) & np.isfinite(y)))[0])
        raise CurveError(f"point {bad} of the curve is not finite (strain {x[bad]}, stress {y[bad]} MPa)")
    if np.any(np.diff(x) < 0):
        bad = int(np.flatnonzero(np.diff(x) < 0)[0]) + 1
        raise CurveError(
            f"strain decreases at point {bad} ({x[bad - 1]:.6g} -> {x[bad]:.6g}): properties need a "
            "monotonic loading curve (cut unloading parts off)"
        )
    return x, y


def _no_yield(x: np.ndarray, y: np.ndarray, note: str) -> CurveProperties:
    """One straight line through all points, no yield quantities.

    The strain offset is NaN when the line is flat to rounding (its zero crossing would be
    rounding noise far outside the data).
    """
    intercept, slope = _line(x, y)
    flat = abs(slope) * float(np.ptp(x)) <= _ROUNDING * float(np.abs(y).max())
    offset = math.nan if flat else -intercept / slope
    return CurveProperties(
        modulus_MPa=slope,
        yield_stress_MPa=math.nan,
        yield_strain=math.nan,
        post_yield_modulus_MPa=math.nan,
        has_yield=False,
        r_squared=_r_squared(y, intercept + slope * x),
        note=note,
        strain_offset=offset,
    )


def _elastic_window(x: np.ndarray, knee: float, fraction: float) -> np.ndarray:
    """Mask of the points the elastic line is fitted on (module docs, step 2).

    At least three points when the knee has them, and always two distinct strains (repeated
    strains at the start of a curve would leave the line's slope undetermined).
    """
    window = x <= x[0] + fraction * (knee - x[0])
    before_knee = int(np.count_nonzero(x <= knee))
    wanted = min(_MIN_POINTS_PER_LINE, before_knee)
    if np.count_nonzero(window) < wanted:
        window = np.arange(len(x)) < wanted
    if len(np.unique(x[window])) < 2:
        window = x <= x[x > x[0]][0]  # up to the second distinct strain (x has two or more)
    return window


def _check_strain_range(strain_range: object) -> tuple[float, float]:
    """(lo, hi) of a ``strain_range`` option, None as -inf / inf."""
    rule = "strain_range must be (min, max) strains with min < max, either None"
    if not isinstance(strain_range, (tuple, list)) or len(strain_range) != 2:
        raise CurveError(f"{rule}, got {strain_range!r}")
    bounds = []
    for value, default in zip(strain_range, (-math.inf, math.inf)):
        if value is None:
            bounds.append(default)
            continue
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise CurveError(f"{rule}, got {strain_range!r}") from None
        if not math.isfinite(number):
            raise CurveError(f"{rule} (finite numbers), got {strain_range!r}")
        bounds.append(number)
    lo, hi = bounds
    if not lo < hi:
        raise CurveError(f"{rule}, got {strain_range!r}")
    return lo, hi


def _constant_stress(x: np.ndarray, y: np.ndarray) -> CurveProperties:
    """The result for a stress that is constant to rounding (module docs, "No clear yield")."""
    return CurveProperties(
        modulus_MPa=0.0,
        yield_stress_MPa=math.nan,
        yield_strain=math.nan,
        post_yield_modulus_MPa=math.nan,
        has_yield=False,
        r_squared=math.nan,
        note=f"the stress is constant ({float(np.mean(y)):.4g} MPa at all {len(x)} points): "
        "no elastic slope and no yield (a wrong stress column, or no load carried?)",
        strain_offset=math.nan,
    )


def _scaled(props: CurveProperties, scale: float) -> CurveProperties:
    """``props`` of a stress divided by ``scale``, back in MPa (strains and R^2 unchanged)."""
    stresses = ("modulus_MPa", "yield_stress_MPa", "post_yield_modulus_MPa")
    return CurveProperties(**(props.as_dict() | {name: getattr(props, name) * scale for name in stresses}))


def curve_properties(
    strain: ArrayLike,
    stress: ArrayLike,
    *,
    strain_range: tuple[float | None, float | None] | None = None,
    elastic_fraction: float = 0.5,
    max_slope_ratio: float = 0.5,
) -> CurveProperties:
    """Elastic modulus, yield point and post-yield modulus of a stress-strain curve (docs/model.md section 7).

    The bilinear fit is described in the module docs: a least-squares hinge locates the knee
    and gives the post-yield line, a line through the initial part of the curve gives the
    elastic modulus, and yield is where the two lines meet.

    Parameters
    ----------
    strain : (n,) array_like
        Engineering strain (0.01 = 1 %), non-decreasing (a monotonic loading).
    stress : (n,) array_like [MPa]
        Stress at each strain.
    strain_range
        ``(min, max)`` strain of the points to fit (either may be None); default all. Use it to
        leave out a toe region or the failure of a specimen.
    elastic_fraction
        The elastic line is fitted on the points below this fraction of the knee strain,
        in (0, 1].
    max_slope_ratio
        A yield needs a post-yield modulus at most this fraction of the elastic modulus,
        in (0, 1).

    Returns
    -------
    CurveProperties

    Raises
    ------
    CurveError
        If the arrays are not 1-D arrays of numbers of one length, hold NaN or infinities, the
        strain decreases, or fewer than two distinct strains lie in ``strain_range``; or an
        option is out of its range.

    Notes
    -----
    A stress that is constant (to a relative 1e-9) gives ``has_yield=False``,
    ``modulus_MPa=0``, NaN ``strain_offset`` and ``r_squared`` and a note; fewer than six
    points give one straight line and a note. The fit runs on the stress divided by a power
    of two near its largest magnitude (an exact scaling), so tiny or huge stresses neither
    underflow nor overflow.
    """
    if not 0.0 < elastic_fraction <= 1.0:
        raise CurveError(f"elastic_fraction must be in (0, 1], got {elastic_fraction}")
    if not 0.0 < max_slope_ratio < 1.0:
        raise CurveError(f"max_slope_ratio must be in (0, 1), got {max_slope_ratio}")
    x, y = check_curve(strain, stress)
    if strain_range is not None:
        lo, hi = _check_strain_range(strain_range)
        keep = (x >= lo) & (x <= hi)
        x, y = x[keep], y[keep]
    distinct = len(np.unique(x))
    if distinct < 2:
        within = "" if strain_range is None else f" within strain_range {tuple(strain_range)!r}"
        raise CurveError(f"a curve needs at least two distinct strains{within} to fit, got {distinct}")
    largest = float(np.abs(y).max())
    if np.ptp(y) <= _ROUNDING * largest:  # also an all-zero stress
        return _constant_stress(x, y)
    scale = math.ldexp(1.0, math.frexp(largest)[1] - 1)  # a power of two: y / scale is exact
    return _scaled(_bilinear_fit(x, y / scale, scale, elastic_fraction, max_slope_ratio), scale)


def _bilinear_fit(
    x: np.ndarray, y: np.ndarray, scale: float, elastic_fraction: float, max_slope_ratio: float
) -> CurveProperties:
    """:func:`curve_properties` of a checked curve whose stress is divided by ``scale``.

    The result is in the divided units too; notes quote stresses in MPa (times ``scale``).
    """
    if len(x) < 2 * _MIN_POINTS_PER_LINE:
        return _no_yield(x, y, f"only {len(x)} points: too few to fit two lines (need 6)")

    line_sse = float(np.sum((y - np.polyval(np.polyfit(x, y, 1), x)) ** 2))
    knee = _best_breakpoint(x, y)
    hinge_sse, (a, knee_slope, post_slope) = _hinge(x, y, knee)
    # Rounding floor of the residuals, so an exact straight line is not a "significant" hinge
    # (max |y| is in [1, 2) here, so the floor is never zero).
    hinge_sse = max(hinge_sse, len(x) * (_ROUNDING * float(np.abs(y).max())) ** 2)
    f_statistic = (line_sse - hinge_sse) / 2.0 / (hinge_sse / (len(x) - 4))
    if f_statistic < _MIN_F_STATISTIC:
        return _no_yield(x, y, "a bilinear fit is no better than a straight line: no clear yield")
    margin = 1e-6 * (x[-1] - x[0])  # the bounded refinement stops just short of a bound
    if knee <= x[_MIN_POINTS_PER_LINE - 1] + margin or knee >= x[-_MIN_POINTS_PER_LINE] - margin:
        return _no_yield(x, y, f"the best breakpoint ({knee:.4g}) lies at an end of the data: no clear yield")

    window = _elastic_window(x, knee, elastic_fraction)
    elastic_intercept, modulus = _line(x[window], y[window])
    if modulus <= 0.0:
        return _no_yield(x, y, f"the initial slope ({modulus * scale:.4g} MPa) is not positive")
    if post_slope > max_slope_ratio * modulus:
        return _no_yield(
            x,
            y,
            f"the post-yield slope ({post_slope * scale:.4g} MPa) is {post_slope / modulus:.0%} "
            f"of the initial slope ({modulus * scale:.4g} MPa), above {max_slope_ratio:.0%}: no clear "
            "yield",
        )
    post_intercept = a + (knee_slope - post_slope) * knee
    yield_at = (post_intercept - elastic_intercept) / (modulus - post_slope)
    if not x[0] < yield_at < x[-1]:
        return _no_yield(x, y, f"the elastic and post-yield lines meet at strain {yield_at:.4g}, outside the data")

    offset = -elastic_intercept / modulus
    props = CurveProperties(
        modulus_MPa=modulus,
        yield_stress_MPa=float(elastic_intercept + modulus * yield_at),
        yield_strain=float(yield_at - offset),
        post_yield_modulus_MPa=float(post_slope),
        has_yield=True,
        r_squared=math.nan,
        note="",
        strain_offset=offset,
    )
    return _with_r_squared(props, x, y)


def _with_r_squared(props: CurveProperties, x: np.ndarray, y: np.ndarray) -> CurveProperties:
    fields: dict[str, Any] = props.as_dict() | {"r_squared": _r_squared(y, bilinear_stress(props, x))}
    return CurveProperties(**fields)


def simulation_properties(result: SimulationResult, measure: str | None = None, **options) -> CurveProperties:
    """:func:`curve_properties` of a simulated curve (``result.strain``, ``result.stress()``).

    Parameters
    ----------
    result
        A monotonic loading program's result (:func:`espin.simulate`).
    measure
        ``"nominal"``, ``"paper"`` or ``"kirchhoff"`` (default: the run's ``output.stress_measure``).
    **options
        Passed on to :func:`curve_properties`.
    """
    return curve_properties(result.strain, result.stress(measure), **options)


def curve_marks(result: SimulationResult) -> CurveProperties | None:
    """The bilinear fit that a simulation's ``curve.png`` marks (E, yield point, H), or None
    where the curve has none: a ``path`` program (drawn against time), or a curve that
    :func:`curve_properties` refuses (e.g. one that unloads).

    Pass it as ``curve_marks`` to :func:`espin.mechanics.run.simulate`.
    """
    if result.program.test == "path":
        return None
    try:
        return simulation_properties(result)
    except CurveError:
        return None


_SUMMARY_FIELDS = ("modulus_MPa", "yield_stress_MPa", "yield_strain", "post_yield_modulus_MPa", "r_squared")


def summarize_properties(props: Sequence[CurveProperties]) -> dict[str, dict[str, float]]:
    """Mean, sample sd (ddof = 1) and count of each property over specimens.

    Yield quantities are summarized over the specimens with a clear yield only (``n`` says how
    many); the sd is NaN for fewer than two values.

    Returns
    -------
    dict
        ``{field: {"mean": ..., "sd": ..., "n": ...}}`` for modulus_MPa, yield_stress_MPa,
        yield_strain, post_yield_modulus_MPa and r_squared.
    """
    summary = {}
    for name in _SUMMARY_FIELDS:
        values = np.array([getattr(p, name) for p in props], dtype=float)
        values = values[np.isfinite(values)]
        summary[name] = {
            "mean": float(values.mean()) if len(values) else math.nan,
            "sd": float(values.std(ddof=1)) if len(values) > 1 else math.nan,
            "n": len(values),
        }
    return summary


def plot_bilinear_fits(
    curves: Sequence[tuple[str, ArrayLike, ArrayLike, CurveProperties]],
    path: str | Path,
    *,
    band: tuple[ArrayLike, ArrayLike, ArrayLike] | None = None,
    band_n: int | None = None,
    dpi: float = 150.0,
) -> Path:
    """Draw stress-strain curves with their bilinear fits and yield points.

    Each curve is a solid line; its elastic line (dashed), post-yield line (dotted) and yield
    point (open circle) are drawn in the same colour as on ``curve.png``
    (:func:`espin.mechanics.figures.draw_marks`), and its legend entry states E, the yield
    point and H (E alone without a clear yield). The legend sits below the axes.

    Parameters
    ----------
    curves
        ``(label, strain, stress [MPa], properties)`` for each curve.
    path
        Image file (format from the suffix), written atomically.
    band
        ``(strain, mean [MPa], sd [MPa])`` of averaged specimens, drawn as a grey band of
        mean ± sd.
    band_n
        Number of specimens averaged in ``band``, stated in its legend entry.
    dpi
        Resolution.

    Returns
    -------
    Path
    """
    from matplotlib.figure import Figure

    from espin.core.figures import save_figure
    from espin.mechanics.figures import draw_marks, mark_labels

    fig = Figure(figsize=(7.0, 5.2 + 0.2 * len(curves)), layout="constrained")
    ax = fig.subplots()
    if band is not None:
        band_strain, mean, sd = (np.asarray(v, dtype=float) for v in band)
        n = "" if band_n is None else f", n = {band_n}"
        ax.fill_between(100 * band_strain, mean - sd, mean + sd, color="0.85", label=f"mean ± sd{n}")
    for k, (label, strain, stress, props) in enumerate(curves):
        colour = f"C{k % 10}"
        strain = np.asarray(strain, dtype=float)
        marks = ", ".join(text for text in mark_labels(props) if text is not None)
        ax.plot(100 * strain, stress, color=colour, lw=1.2, label=f"{label}: {marks}")
        draw_marks(ax, props, float(strain[-1]), color=colour, labelled=False)
    ax.set_xlabel("strain [%]")
    ax.set_ylabel("stress [MPa]")
    ax.set_title(
        "curves (solid): elastic line (dashed), yield point (circle), post-yield line (dotted)", fontsize="small"
    )
    ax.set_xlim(left=0.0)
    ax.set_ylim(bottom=0.0)
    fig.legend(loc="outside lower center", fontsize="small")
    return save_figure(fig, path, dpi)
