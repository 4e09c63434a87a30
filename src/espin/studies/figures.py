"""Figures of ensemble studies: properties versus RVE size (paper Figs. A.15-A.17), the spread
of the curves (Fig. A.18) and properties versus swept parameters. Stress in MPa, strain in %.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from espin.core.figures import parameter_label, parameter_value, save_figure

__all__ = ["plot_rve_size", "plot_curve_band", "plot_sweep", "parameter_label", "PROPERTY_LABELS"]

PROPERTY_LABELS = {
    "modulus_MPa": ("elastic modulus", "$E$ [MPa]"),
    "yield_stress_MPa": ("yield stress", r"$\sigma_y$ [MPa]"),
    "post_yield_modulus_MPa": ("post-yield modulus", "$H$ [MPa]"),
}


def plot_rve_size(
    summary: pd.DataFrame, folder: str | Path, *, layers_for_sizes: int, size_for_layers: float, dpi: float = 150.0
) -> dict[str, Path]:
    """One figure per property, as the paper's Figs. A.15-A.17.

    Panels: (a) mean +- sd versus L_tilde at ``layers_for_sizes`` layers, (b) versus N_l at
    L_tilde = ``size_for_layers``, (c) and (d) the relative sd (RSD) of (a) and (b), in %.

    Returns
    -------
    dict of str to Path
        ``rve_size_<property>`` -> the PNG written in ``folder``.
    """
    by_size = summary[summary["rve.layers"] == layers_for_sizes].sort_values("rve.size_ratio")
    by_layers = summary[summary["rve.size_ratio"] == size_for_layers].sort_values("rve.layers")
    files = {}
    for name, (title, unit) in PROPERTY_LABELS.items():
        fig = Figure(figsize=(8.0, 6.0), layout="constrained")
        axes = fig.subplots(2, 2)
        for column, (table, x, xlabel) in enumerate(
            (
                (by_size, "rve.size_ratio", rf"RVE size $\tilde L = L / D$  ($N_l$ = {layers_for_sizes})"),
                (by_layers, "rve.layers", rf"layers $N_l$  ($\tilde L$ = {size_for_layers:g})"),
            )
        ):
            top, bottom = axes[0, column], axes[1, column]
            if table.empty:
                top.set_axis_off()
                bottom.set_axis_off()
                continue
            top.errorbar(table[x], table[f"{name}_mean"], yerr=table[f"{name}_sd"], marker="o", capsize=3)
            top.set_ylabel(unit)
            bottom.plot(table[x], 100 * table[f"{name}_rsd"], marker="s")
            bottom.axhline(2.0, color="0.6", lw=0.8, ls="--", label="2 %")
            bottom.set_ylabel("RSD [%]")
            bottom.set_ylim(bottom=0.0)
            bottom.set_xlabel(xlabel)
            if x == "rve.layers":
                for ax in (top, bottom):
                    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
            bottom.legend(frameon=False)
            for ax, letter in ((top, "ab"[column]), (bottom, "cd"[column])):
                ax.set_title(f"{letter})", loc="left", fontsize=10)
        n = sorted({int(v) for v in summary["n"]}) if "n" in summary else []
        spread = f"mean ± sd, n = {n[0] if len(n) == 1 else f'{n[0]}-{n[-1]}'} realizations" if n else "mean ± sd"
        fig.suptitle(f"{title} versus RVE size ({spread})")
        files[f"rve_size_{name}"] = save_figure(fig, Path(folder) / f"rve_size_{name.removesuffix('_MPa')}.png", dpi)
    return files


def plot_curve_band(
    strain: np.ndarray, stress: np.ndarray, path: str | Path, *, label: str = "", dpi: float = 150.0
) -> Path:
    """Mean curve (line) and +- one sample sd (shaded) of stacked curves ``stress`` (n, n_points)
    [MPa] over ``strain`` (dimensionless), Fig. A.18; ``label`` (mathtext allowed) names the
    RVE in the title."""
    stress = np.atleast_2d(stress)
    mean = stress.mean(axis=0)
    sd = stress.std(axis=0, ddof=1) if len(stress) > 1 else np.zeros_like(mean)
    fig = Figure(figsize=(5.5, 4.0), layout="constrained")
    ax = fig.subplots()
    ax.fill_between(
        100 * strain,
        mean - sd,
        mean + sd,
        color="C0",
        alpha=0.3,
        lw=0,
        label=f"mean ± sd, n = {len(stress)} realizations",
    )
    ax.plot(100 * strain, mean, color="C0")
    ax.set_xlabel("strain [%]")
    ax.set_ylabel("stress [MPa]")
    ax.set_title(f"stress-strain spread over realizations{', ' + label if label else ''}", fontsize=10)
    ax.legend(frameon=False, loc="lower right")
    return save_figure(fig, path, dpi)


def plot_sweep(
    summary: pd.DataFrame, parameters: list[str], folder: str | Path, *, dpi: float = 150.0
) -> dict[str, Path]:
    """Each property versus each swept parameter: one figure per property, one panel per parameter.

    In the panel of a parameter, each combination of the other parameters is one line (mean
    +- sd over realizations); beyond six combinations their mean is drawn instead.

    Returns
    -------
    dict of str to Path
        ``sweep_<property>`` -> the PNG written in ``folder``.
    """
    files = {}
    for name, (title, unit) in PROPERTY_LABELS.items():
        fig = Figure(figsize=(max(4.2 * len(parameters), 6.0), 4.0), layout="constrained")
        axes = np.atleast_1d(fig.subplots(1, len(parameters)))
        for ax, parameter in zip(axes, parameters):
            others = [p for p in parameters if p != parameter]
            groups = list(summary.groupby(others, sort=True)) if others else [((), summary)]
            if len(groups) > 6:
                mean = summary.groupby(parameter, sort=True)[f"{name}_mean"].mean()
                ax.plot(mean.index, mean.to_numpy(), marker="o", label=f"mean over {len(groups)} combinations")
            else:
                for values, group in groups:
                    values = values if isinstance(values, tuple) else (values,)
                    group = group.sort_values(parameter)
                    label = ", ".join(parameter_value(p, v) for p, v in zip(others, values)) or None
                    ax.errorbar(
                        group[parameter],
                        group[f"{name}_mean"],
                        yerr=group[f"{name}_sd"].fillna(0.0),
                        marker="o",
                        capsize=3,
                        label=label,
                    )
            ax.set_xlabel(parameter_label(parameter))
            ax.set_ylabel(unit)
            if ax.get_legend_handles_labels()[1]:
                ax.legend(frameon=False, fontsize=7)
        n = sorted({int(v) for v in summary["n"]}) if "n" in summary else []
        spread = f"mean ± sd, n = {n[0] if len(n) == 1 else f'{n[0]}-{n[-1]}'} realizations" if n else "mean ± sd"
        fig.suptitle(f"{title} versus swept parameters\n({spread})", fontsize="medium")
        files[f"sweep_{name}"] = save_figure(fig, Path(folder) / f"sweep_{name.removesuffix('_MPa')}.png", dpi)
    return files
