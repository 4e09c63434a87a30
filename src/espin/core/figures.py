"""PNG figures (matplotlib, Agg backend, no pyplot state): one module per subject."""

from __future__ import annotations

from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from espin.core.atomic import atomic_write

__all__ = ["save_figure"]


def save_figure(fig: Figure, path: str | Path, dpi: float) -> Path:
    """Render ``fig`` with the Agg canvas and write it atomically; format from the suffix."""
    FigureCanvasAgg(fig)
    fmt = Path(path).suffix.lstrip(".").lower() or "png"
    return atomic_write(path, lambda tmp: fig.savefig(tmp, format=fmt, dpi=dpi))
