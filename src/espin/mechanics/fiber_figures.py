"""Stress-stretch curve of one fiber (paper Fig. 6): slack, recruitment, yield, hardening."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from espin.mechanics.fiber_law import YIELD_THRESHOLD
from espin.mechanics.single_fiber import FiberHistory

__all__ = ["plot_single_fiber"]


def plot_single_fiber(
    history: FiberHistory,
    path: str | Path,
    *,
    rate_per_s: float | None = None,
    dpi: int = 150,
) -> Path:
    """Write the stress-stretch curve of a pulled fiber as a PNG (paper Fig. 6).

    The recruitment stretch lambda_r is marked, and so is the first yielded point
    (lambda_p - 1 > 1e-3); an inset enlarges the slack branch, whose stress is small on the
    scale of the taut one.

    Parameters
    ----------
    history
        Result of :func:`espin.mechanics.single_fiber.pull_fiber`.
    path
        PNG file to write (atomically).
    rate_per_s
        If given, the plateau estimate b_p asinh(rate / a_p) [MPa] of a fiber pulled at this
        stretch rate [1/s] is drawn (docs/model.md section 3).
    dpi
        Resolution.

    Returns
    -------
    Path
        The written file.
    """
    from matplotlib.figure import Figure

    from espin.core.figures import save_figure

    law, lam_r = history.law, max(history.tortuosity, 1.0)
    fig = Figure(figsize=(6.0, 4.2), layout="constrained")
    ax = fig.add_subplot()
    ax.plot(history.stretch, history.stress, color="C0", lw=1.8, label="fiber")
    ax.axvline(lam_r, color="0.4", ls=":", lw=1, label=rf"recruitment $\lambda_r$ = {lam_r:.3g}")
    first_yield = np.flatnonzero(history.plastic_stretch - 1.0 > YIELD_THRESHOLD)
    if first_yield.size:
        k = first_yield[0]
        ax.plot(
            history.stretch[k],
            history.stress[k],
            "o",
            color="C3",
            label=rf"yield ($\lambda_p - 1 > {YIELD_THRESHOLD:g}$)",
        )
    if rate_per_s is not None and law.flow_rate > 0:
        plateau = law.flow_resistance * np.arcsinh(rate_per_s / law.flow_rate)
        ax.axhline(
            plateau, color="C2", ls="--", lw=1, label=rf"$b_p\,\mathrm{{asinh}}(\dot\lambda / a_p)$ = {plateau:.3g} MPa"
        )
    ax.set_xlabel(r"stretch $\lambda = l / l_0$")
    ax.set_ylabel("engineering stress $t$ [MPa]")
    ax.set_title(
        rf"single fiber: $E_t$ = {law.taut_modulus:g} MPa, $E_b$ = {law.slack_modulus:g} MPa, "
        rf"$a_p$ = {law.flow_rate:g} 1/s, $b_p$ = {law.flow_resistance:g} MPa, "
        rf"$c_p$ = {law.hardening_exponent:g}",
        fontsize=8,
    )
    ax.legend(loc="lower left", bbox_to_anchor=(0.36, 0.04), fontsize=8)
    ax.grid(alpha=0.3)

    slack = (history.stretch <= lam_r + 0.25 * (lam_r - 1.0)) & ~history.recruited
    if lam_r > 1.0 and slack.sum() > 1:
        inset = ax.inset_axes((0.38, 0.45, 0.3, 0.3))
        inset.plot(history.stretch[slack], history.stress[slack], color="C0")
        inset.axvline(lam_r, color="0.4", ls=":", lw=1)
        inset.set_title(r"slack branch ($E_b$)", fontsize=7)
        inset.set_xlabel(r"$\lambda$", fontsize=7, labelpad=1)
        inset.set_ylabel("$t$ [MPa]", fontsize=7, labelpad=1)
        inset.tick_params(labelsize=6)
    return save_figure(fig, path, dpi)
