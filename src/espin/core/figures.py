"""PNG figures (matplotlib, Agg backend, no pyplot state): one module per subject; here the
writer and the names of config quantities that every stage's figures share (docs/model.md)."""

from __future__ import annotations

from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from espin.core.atomic import atomic_write

__all__ = ["save_figure", "parameter_label", "parameter_value"]

_PARAMETER_LABELS = {
    "rve.volume_fraction": r"volume fraction $\eta$",
    "rve.max_deviation_deg": r"largest turn $\theta^d_{max}$ [deg]",
    "rve.waviness_deg": r"waviness $\sigma_\phi$ [deg]",
    "rve.waviness_length_ratio": "waviness length / $D$",
    "rve.diameter_um": "fiber diameter $D$ [µm]",
    "rve.diameter_sd_um": "diameter sd [µm]",
    "diameter_cv": "diameter CV (sd / $D$)",
    "rve.size_ratio": r"RVE size $\tilde L = L / D$",
    "rve.layers": "layers $N_l$",
    "rve.segment_ratio": r"segment $\tilde l_s = l_s / D$",
    "rve.orientation.von_mises.kappa": r"orientation concentration $\kappa$",
    "rve.orientation.von_mises.mean_deg": "mean orientation [deg]",
    "fiber.taut_modulus_MPa": "taut modulus $E_t$ [MPa]",
    "fiber.slack_modulus_MPa": "slack modulus $E_b$ [MPa]",
    "fiber.flow_rate_per_s": "flow rate $a_p$ [1/s]",
    "fiber.flow_resistance_MPa": "flow resistance $b_p$ [MPa]",
    "fiber.hardening_exponent": "hardening exponent $c_p$",
    "loading.direction_deg": "loading direction [deg]",
    "loading.strain_rate_per_s": r"strain rate $\dot\varepsilon$ [1/s]",
}


def save_figure(fig: Figure, path: str | Path, dpi: float) -> Path:
    """Render ``fig`` with the Agg canvas and write it atomically; format from the suffix."""
    FigureCanvasAgg(fig)
    fmt = Path(path).suffix.lstrip(".").lower() or "png"
    return atomic_write(path, lambda tmp: fig.savefig(tmp, format=fmt, dpi=dpi))


def parameter_label(key: str) -> str:
    """The axis label of a config key (``section.key``): the quantity, its symbol of
    docs/model.md and its unit where espin knows them, else the key itself."""
    return _PARAMETER_LABELS.get(key, key)


def parameter_value(key: str, value: object) -> str:
    """``quantity = value unit`` of a config key for a legend or title, e.g.
    ``"flow resistance $b_p$ = 5 MPa"``; numbers compactly, anything else as text."""
    text = f"{value:.4g}" if isinstance(value, (int, float)) and not isinstance(value, bool) else str(value)
    label = parameter_label(key)
    if label.endswith("]") and " [" in label:
        name, unit = label[:-1].rsplit(" [", 1)
        return f"{name} = {text} {unit}"
    return f"{label} = {text}"
