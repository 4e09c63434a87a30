"""Figures of a design run: convergence, property maps from the surrogates, verification."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from espin.core.figures import parameter_label, save_figure
from espin.design.search import DesignRun
from espin.design.targets import STRESS_AT, CurveTarget, RatioTarget

__all__ = ["plot_convergence", "plot_maps", "plot_verification", "plot_pareto", "PROPERTY_SYMBOLS"]

PROPERTY_SYMBOLS = {
    "modulus_MPa": ("$E$", "MPa"),
    "yield_stress_MPa": (r"$\sigma_y$", "MPa"),
    "post_yield_modulus_MPa": ("$H$", "MPa"),
    "yield_strain": (r"$\varepsilon_y$", ""),
}
"""Symbol and unit of each property in the figures."""


def _output_label(name: str, direction: float) -> str:
    if name.startswith(STRESS_AT):
        return f"stress at {100 * float(name.removeprefix(STRESS_AT)):.3g} %, {direction:g}° [MPa]"
    symbol, unit = PROPERTY_SYMBOLS[name]
    return f"{symbol} at {direction:g}°" + (f" [{unit}]" if unit else "")


def _target_label(target: Any) -> str:
    """A target's quantity in the figures: ``$E$ at 0°``, ``$E$ at 0° / $E$ at 90°``, ``curve at 0°``."""
    if isinstance(target, CurveTarget):
        return f"curve at {target.direction_deg:g}°"
    symbol = PROPERTY_SYMBOLS[target.name][0]
    if isinstance(target, RatioTarget):
        return f"{symbol} at {target.direction_deg:g}° / {symbol} at {target.over_direction_deg:g}°"
    return f"{symbol} at {target.direction_deg:g}°"


def plot_convergence(run: DesignRun, table: pd.DataFrame, path: str | Path) -> Path:
    """Objective of each evaluation and the best so far against the tensile tests run.

    The objective is the mean squared normalized error (1: a target exactly at its tolerance);
    the grey band marks where every target alone is within tolerance.
    """
    from matplotlib.figure import Figure

    search = table[table["stage"].isin(["initial", "search", "replicate"])].reset_index(drop=True)
    n_dir = len(run.targets.directions)
    tests = (np.arange(len(search)) + 1) * n_dir
    objective = search["objective"].to_numpy(dtype=float)
    finite = np.where(np.isfinite(objective), objective, np.nan)
    mask = search["stage"].isin(["initial", "search"]).to_numpy()
    best = np.fmin.accumulate(np.where(mask, finite, np.inf))
    fig = Figure(figsize=(6.4, 4.2))
    ax = fig.subplots()
    for stage, marker in (("initial", "s"), ("replicate", "^"), ("search", "o")):
        rows = search["stage"].to_numpy() == stage
        ax.semilogy(tests[rows], finite[rows], marker, ms=5, ls="none", alpha=0.7, label=f"{stage} design")
    ax.semilogy(tests, np.where(np.isfinite(best), best, np.nan), "k-", lw=1.5, label="best so far")
    low, high = ax.get_ylim()
    low = min(low, 0.1)  # the band shows whatever the data's range
    ax.axhspan(low, 1.0, color="0.9", zorder=0, label="within tolerance")
    ax.set_ylim(low, high)
    ax.set_xlabel("tensile tests run")
    ax.set_ylabel(r"objective: mean of $((x - x_t) / (\mathrm{tol}\; x_t))^2$")
    ax.set_title(f"design search: {len(search)} evaluations ({run.tests} tests in the budget)")
    ax.legend(loc="best", fontsize="small")
    return save_figure(fig, path, dpi=150)


def _mapped_outputs(targets: Any) -> list[tuple[str, float]]:
    """The outputs drawn in the maps: every property, and three strains of each curve target."""
    out = []
    for t in targets.targets:
        if isinstance(t, CurveTarget):
            picks = sorted({0, len(t.outputs) // 2, len(t.outputs) - 1})
            out += [t.outputs[k] for k in picks]
        else:
            out += list(t.outputs)
    return list(dict.fromkeys(out))


def plot_maps(run: DesignRun, path: str | Path) -> Path:
    """Each targeted property against each variable, from the surrogate through the best design
    (the other variables held at their best values): median and 95 % band of the surrogate,
    evaluated designs (projected), the target and its tolerance, the best design."""
    from matplotlib.figure import Figure

    space, targets = run.space, run.targets
    outputs = _mapped_outputs(targets)
    evaluated = [e for e in run.evaluations if e.stage in ("initial", "search")]
    n_rows, n_cols = len(outputs), space.dimension
    fig = Figure(figsize=(max(3.2 * n_cols + 0.6, 7.0), 2.6 * n_rows + 1.2))
    axes = fig.subplots(n_rows, n_cols, squeeze=False)
    grid = np.linspace(0.0, 1.0, 101)
    target_of = {(t.name, t.direction_deg): t for t in targets.targets if not isinstance(t, (RatioTarget, CurveTarget))}
    for i, output in enumerate(outputs):
        surrogate = run.surrogates[output]
        for j, variable in enumerate(space.variables):
            ax = axes[i, j]
            unit = np.repeat(run.best.unit[None, :], len(grid), axis=0)
            unit[:, j] = grid
            mean, sd = surrogate.predict(unit)
            x = (
                np.asarray(variable.value(grid), dtype=float)
                if not variable.integer
                else variable.low + grid * (variable.high - variable.low)
            )
            ax.fill_between(
                x,
                surrogate.to_property(mean - 1.96 * sd),
                surrogate.to_property(mean + 1.96 * sd),
                color="C0",
                alpha=0.2,
                lw=0,
                label="surrogate 95 %",
            )
            ax.plot(x, surrogate.to_property(mean), "C0-", lw=1.2, label="surrogate median")
            ax.plot(
                [e.values[variable.key] for e in evaluated],
                [e.outputs.get(output, math.nan) for e in evaluated],
                "k.",
                ms=4,
                label="evaluated (projected)",
            )
            ax.plot(
                run.best.values[variable.key], run.best.outputs.get(output, math.nan), "r*", ms=10, label="best design"
            )
            target = target_of.get(output)
            if target is not None:
                ax.axhspan(
                    target.value * (1 - target.tolerance),
                    target.value * (1 + target.tolerance),
                    color="C2",
                    alpha=0.25,
                    lw=0,
                    label="target ± tolerance",
                )
            if i == n_rows - 1:
                ax.set_xlabel(parameter_label(variable.key))
            if j == 0:
                ax.set_ylabel(_output_label(*output))
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=3, fontsize="small", bbox_to_anchor=(0.5, 0.0))
    fig.suptitle("properties against each variable through the best design (surrogate)", fontsize="medium")
    height = 2.6 * n_rows + 1.2
    fig.tight_layout(rect=(0, 0.75 / height, 1, 1 - 0.35 / height))
    return save_figure(fig, path, dpi=150)


def plot_verification(run: DesignRun, path: str | Path) -> Path:
    """The best design's curves on the fresh seeds, per direction, with the target yield
    points and moduli drawn where they are targets."""
    from matplotlib.figure import Figure

    directions = run.targets.directions
    fig = Figure(figsize=(5.6 * len(directions), 4.2))
    axes = fig.subplots(1, len(directions), squeeze=False)
    for ax, direction in zip(axes[0], directions):
        for k, e in enumerate(run.verification):
            if direction in e.curves:
                strain, stress = e.curves[direction]
                ax.plot(
                    100 * np.asarray(strain),
                    stress,
                    color="C0",
                    lw=1,
                    alpha=0.8,
                    label=f"best design, {len(run.verification)} fresh seeds" if k == 0 else None,
                )
        for t in run.targets.targets:
            if isinstance(t, RatioTarget) or t.direction_deg != direction:
                continue
            if isinstance(t, CurveTarget):
                ax.plot(100 * np.asarray(t.strain), t.stress_MPa, "ko", ms=4, label=f"target curve ({t.source})")
            elif t.name == "modulus_MPa":
                line = np.linspace(0.0, 0.02, 2)
                ax.plot(100 * line, t.value * line, "C2--", lw=1.2, label=f"target $E$ = {t.value:.4g} MPa")
            elif t.name == "yield_stress_MPa":
                ax.axhline(t.value, color="C3", ls=":", lw=1.2, label=rf"target $\sigma_y$ = {t.value:.4g} MPa")
        ax.set_xlabel("strain [%]")
        ax.set_ylabel("stress [MPa]")
        ax.set_title(f"loading at {direction:g}°")
        ax.legend(loc="lower right", fontsize="small")
    return save_figure(fig, path, dpi=150)


def plot_pareto(run: DesignRun, table: pd.DataFrame, path: str | Path) -> Path:
    """The designs' absolute normalized errors for the first two targets (1 = at the tolerance),
    the Pareto front (designs no other beats on every target) joined, the best design starred:
    where two targets compete, the front is the trade-off on offer."""
    from matplotlib.figure import Figure

    first, second = run.targets.targets[:2]
    search = table[table["stage"].isin(["initial", "search"])]
    x = search[f"error_{first.label}"].abs().to_numpy(dtype=float)
    y = search[f"error_{second.label}"].abs().to_numpy(dtype=float)
    front = search["pareto"].to_numpy(dtype=bool)
    fig = Figure(figsize=(5.6, 4.6))
    ax = fig.subplots()
    ax.fill_between([0.0, 1.0], 0.0, 1.0, color="0.9", lw=0, zorder=0, label="both within tolerance")
    ax.plot(x[~front], y[~front], "k.", ms=5, alpha=0.6, label="evaluated design")
    order = np.argsort(x[front])
    ax.plot(x[front][order], y[front][order], "C3o-", ms=5, lw=1, label="Pareto front")
    best = search["id"].to_numpy() == run.best.id
    ax.plot(x[best], y[best], "C0*", ms=14, label="best design")
    ax.set_xscale("symlog", linthresh=1.0)
    ax.set_yscale("symlog", linthresh=1.0)
    ax.set_xlabel(f"|error| of {_target_label(first)} / tolerance")
    ax.set_ylabel(f"|error| of {_target_label(second)} / tolerance")
    n_front = int(np.count_nonzero(front))
    ax.set_title(f"{n_front} design{'s' * (n_front != 1)} on the Pareto front of two targets")
    ax.legend(loc="lower right", fontsize="small")
    return save_figure(fig, path, dpi=150)
