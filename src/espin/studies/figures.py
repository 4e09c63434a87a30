"""Figures of ensemble studies: properties versus RVE size (paper Figs. A.15-A.17), the spread
of the curves (Fig. A.18) and properties versus swept parameters. Stress in MPa, strain in %.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from espin.core.figures import save_figure

__all__ = ["plot_rve_size", "plot_curve_band", "plot_sweep", "parameter_label", "PROPERTY_LABELS"]

PROPERTY_LABELS = {
    "modulus_MPa": ("elastic modulus", "$E$ [MPa]"),
    "yield_stress_MPa": ("yield stress", r"$\sigma_y$ [MPa]"),
    "post_yield_modulus_MPa": ("post-yield modulus", "$H$ [MPa]"),
}

_PARAMETER_LABELS = {
    "rve.volume_fraction": r"volume fraction $\eta$",
    "rve.max_deviation_deg": r"largest turn $\theta^d_{max}$ [deg]",
    "rve.waviness_deg": r"waviness $\sigma_\phi$ [deg]",
    "rve.waviness_length_ratio": "waviness length / $D$",
    "rve.diameter_um": "fiber diameter $D$ [µm]",
    "rve.diameter_sd_um": "diameter sd [µm]",
    "rve.size_ratio": r"RVE size $\tilde L = L / D$",
    "rve.layers": "layers $N_l$",
    "rve.segment_ratio": r"segment $\tilde l_s = l_s / D$",
    "rve.orientation.von_mises.kappa": r"orientation concentration $\kappa$",
    "rve.orientation.von_mises.mean_deg": "mean orientation [deg]",
    "fiber.taut_modulus_MPa": "taut modulus $E_t$ [MPa]",
    "fiber.slack_modulus_MPa": "slack modulus $E_s$ [MPa]",
    "fiber.flow_resistance_MPa": "flow resistance [MPa]",
    "fiber.hardening_exponent": "hardening exponent",
    "loading.direction_deg": "loading direction [deg]",
    "loading.strain_rate_per_s": "strain rate [1/s]",
}


def _legend(key: str, value: object) -> str:
    """``quantity = value unit`` of a swept key for a legend."""
    label = parameter_label(key)
    if label.endswith("]") and " [" in label:
        name, unit = label[:-1].rsplit(" [", 1)
        return f"{name} = {_format(value)} {unit}"
    return f"{label} = {_format(value)}"


def parameter_label(key: str) -> str:
    """The axis label of a swept config key: the quantity and its unit where espin knows it,
    else the key itself."""
    return _PARAMETER_LABELS.get(key, key)


def plot_rve_size(summary: pd.DataFrame, folder: str | Path, *, layers_for_sizes: int,
                  size_for_layers: float, dpi: float = 150.0) -> dict[str, Path]:
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
        for column, (table, x, xlabel) in enumerate((
            (by_size, "rve.size_ratio", rf"RVE size $\tilde L = L / D$  ($N_l$ = {layers_for_sizes})"),
            (by_layers, "rve.layers", rf"layers $N_l$  ($\tilde L$ = {size_for_layers:g})"),
        )):
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
        count = f" {n[0] if len(n) == 1 else f'{n[0]}-{n[-1]}'}" if n else ""
        fig.suptitle(f"{title} versus RVE size (mean ± sd over{count} realizations)")
        files[f"rve_size_{name}"] = save_figure(fig, Path(folder) / f"rve_size_{name.removesuffix('_MPa')}.png", dpi)
    return files


def plot_curve_band(strain: np.ndarray, stress: np.ndarray, path: str | Path, *, label: str = "",
                    dpi: float = 150.0) -> Path:
    """Mean curve (line) and +- one sd (shaded) of stacked curves ``stress`` (n, n_points), Fig. A.18."""
    stress = np.atleast_2d(stress)
    mean = stress.mean(axis=0)
    sd = stress.std(axis=0, ddof=1) if len(stress) > 1 else np.zeros_like(mean)
    fig = Figure(figsize=(5.5, 4.0), layout="constrained")
    ax = fig.subplots()
    ax.fill_between(100 * strain, mean - sd, mean + sd, color="C0", alpha=0.3, lw=0, label="+- sd")
    ax.plot(100 * strain, mean, color="C0", label=f"mean of {len(stress)}")
    ax.set_xlabel("strain [%]")
    ax.set_ylabel("stress [MPa]")
    ax.set_title(f"stress-strain spread over realizations{', ' + label if label else ''}", fontsize=10)
    ax.legend(frameon=False)
    return save_figure(fig, path, dpi)


def plot_sweep(summary: pd.DataFrame, parameters: list[str], folder: str | Path,
               *, dpi: float = 150.0) -> dict[str, Path]:
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
        fig = Figure(figsize=(4.2 * len(parameters), 3.6), layout="constrained")
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
                    label = ", ".join(_legend(p, v) for p, v in zip(others, values)) or None
                    ax.errorbar(group[parameter], group[f"{name}_mean"], yerr=group[f"{name}_sd"].fillna(0.0),
                                marker="o", capsize=3, label=label)
            ax.set_xlabel(parameter_label(parameter))
            ax.set_ylabel(unit)
            if ax.get_legend_handles_labels()[1]:
                ax.legend(frameon=False, fontsize=7)
        n = sorted({int(v) for v in summary["n"]}) if "n" in summary else []
        spread = f"mean ± sd over {n[0] if len(n) == 1 else f'{n[0]}-{n[-1]}'} realizations" if n else "mean ± sd"
        fig.suptitle(f"{title} versus swept parameters ({spread})")
        files[f"sweep_{name}"] = save_figure(fig, Path(folder) / f"sweep_{name.removesuffix('_MPa')}.png", dpi)
    return files


def _format(value: object) -> str:
    """A grid value for a legend: numbers compactly, anything else as text."""
    return f"{value:g}" if isinstance(value, (int, float)) and not isinstance(value, bool) else str(value)
