"""Figure of a calibration (paper Fig. 13): measured and fitted curves, and the fiber they imply.

Built with ``matplotlib.figure.Figure`` and the Agg canvas, written atomically. Stress in MPa,
strain and stretch in %.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, cast

import numpy as np
from matplotlib.figure import Figure

from espin.analysis.calibration.curves import FittedCurve
from espin.core.config import Config
from espin.core.figures import parameter_label, parameter_value, save_figure

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.axes import Axes

__all__ = ["Fit", "plot_fit"]


class Fit(Protocol):
    """What the figure draws of a fit (:class:`espin.analysis.calibration.result.FitResult`)."""

    @property
    def curves(self) -> Sequence[FittedCurve]: ...
    @property
    def seeds(self) -> Sequence[int]: ...
    @property
    def config(self) -> Config: ...
    @property
    def r_squared(self) -> float: ...
    @property
    def values(self) -> Mapping[str, float]: ...
    @property
    def eta_profile(self) -> np.ndarray | None: ...


FIBER_STEPS = 400
"""Steps of the single-fiber pull (backward Euler; fine enough to be step-independent)."""


def _curves(ax: Axes, result: Fit) -> None:
    """Measured curves (with their sd band) and the model (with its realization band)."""
    for k, curve in enumerate(result.curves):
        x = 100.0 * curve.strain
        rate = f"{curve.strain_rate_per_s:.3g} 1/s"
        if curve.sd_MPa is not None:
            ax.fill_between(
                x,
                curve.stress_MPa - curve.sd_MPa,
                curve.stress_MPa + curve.sd_MPa,
                color="0.8",
                linewidth=0,
                label="measured, mean ± sd of the specimens" if k == 0 else None,
            )
        ax.plot(x, curve.stress_MPa, "o", color="k", markersize=3, markerfacecolor="none", label=f"measured, {rate}")
        model, model_sd = cast(np.ndarray, curve.model_MPa), cast(np.ndarray, curve.model_sd_MPa)  # a fit's curves
        ax.fill_between(x, model - model_sd, model + model_sd, color=f"C{k}", alpha=0.25, linewidth=0)
        ax.plot(
            x,
            model,
            color=f"C{k}",
            label=f"model, {rate} (mean ± sd, n = {len(result.seeds)} RVE{'s' if len(result.seeds) != 1 else ''})",
        )
    ax.set_xlabel("strain [%]")
    ax.set_ylabel(f"mat stress ({result.config.output.stress_measure}) [MPa]")
    ax.set_xlim(left=0.0)
    ax.set_ylim(bottom=0.0)
    ax.set_title(f"mat: $R^2$ = {result.r_squared:.4f}")
    ax.legend(fontsize="small")


def _fiber(ax: Axes, result: Fit) -> None:
    """The fitted fiber law pulled alone at each curve's strain rate (a straight fiber)."""
    from espin.mechanics.fiber_law import FiberLaw
    from espin.mechanics.single_fiber import constant_rate_history, pull_fiber

    law = FiberLaw.from_config(result.config.fiber)
    for k, curve in enumerate(result.curves):
        history = pull_fiber(law, *constant_rate_history(1.0 + curve.max_strain, curve.strain_rate_per_s, FIBER_STEPS))
        ax.plot(
            100.0 * (history.stretch - 1.0),
            history.stress,
            color=f"C{k}",
            label=f"strain rate {curve.strain_rate_per_s:.3g} 1/s",
        )
    ax.set_xlabel(r"fiber stretch $\lambda - 1$ [%]")
    ax.set_ylabel("fiber stress $t$ [MPa]")
    ax.set_xlim(left=0.0)
    ax.set_ylim(bottom=0.0)
    ax.set_title("single fiber, fitted law")
    ax.legend(fontsize="small")


def _profile(ax: Axes, result: Fit) -> None:
    """Least SSE at each eta visited (the profile the eta search walked); an eta where the fit
    failed (SSE inf) is a dotted vertical line."""
    eta, sse = cast(np.ndarray, result.eta_profile).T  # drawn only with a profile
    finite = np.isfinite(sse)
    ax.plot(eta[finite], sse[finite], "o-", color="k", markersize=3)
    for k, failed in enumerate(eta[~finite]):
        ax.axvline(failed, color="0.5", linestyle=":", linewidth=0.8, label="fit failed" if k == 0 else None)
    best = result.values["rve.volume_fraction"]
    ax.axvline(best, color="C3", linewidth=0.8, label=rf"fitted $\eta$ = {best:.4g}")
    ax.set_yscale("log")
    ax.set_xlabel(parameter_label("rve.volume_fraction"))
    ax.set_ylabel("least SSE [MPa$^2$]")
    ax.set_title(r"profile over $\eta$")
    ax.legend(fontsize="small")


def plot_fit(result: Fit, path: str | Path, *, dpi: float = 150.0) -> Path:
    """Draw a calibration like the paper's Fig. 13.

    Panels: the measured curve(s) with their sd band and the fitted model (mean over the RVE
    realizations, with their sd band); the stress-stretch curve of one straight fiber with the
    fitted law, pulled at each curve's strain rate; and, when eta was fitted, the least SSE at
    each eta visited.

    Parameters
    ----------
    result
        The fit.
    path
        Output file; the format follows the suffix (``.png`` by default).
    dpi
        Resolution of raster output.

    Returns
    -------
    Path
        The written file.
    """
    panels = [_curves, _fiber] + ([_profile] if result.eta_profile is not None else [])
    fig = Figure(figsize=(4.5 * len(panels), 4.5), layout="constrained")
    for k, draw in enumerate(panels):
        draw(fig.add_subplot(1, len(panels), k + 1), result)
    names = ", ".join(parameter_value(key, value) for key, value in result.values.items())
    fig.suptitle(names, fontsize="medium")
    return save_figure(fig, path, dpi)
