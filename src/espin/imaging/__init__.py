"""Measuring electrospun fiber mats on SEM images (``espin measure``), and SEM-like test images.

- :func:`measure` -> :class:`SEMMeasurement`: scale (given, or from the scale bar), fiber
  segmentation, tracing through crossings, local diameters, orientation (structure tensor:
  dominant direction and coherency; per-fiber end-to-end axes), tortuosity (contour /
  end-to-end length, paper section 2.2), fitted distributions; ``.write(folder)`` writes
  ``fibers.csv``, ``measurement.toml``, ``histograms.png`` and ``overlay.png``.
- :func:`read_fibers_csv`: a validated per-fiber table (written by ``measure`` or by hand).
- :func:`render_sem` -> :class:`SyntheticSEM`: an SEM-like image of a virtual mat with its
  ground truth (:mod:`espin.imaging.synthetic`).

Names are imported lazily (``import espin.imaging`` is cheap).
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "measure": "espin.imaging.measurement",
    "SEMMeasurement": "espin.imaging.measurement",
    "read_fibers_csv": "espin.geometry.fibers_csv",
    "FIBER_COLUMNS": "espin.geometry.fibers_csv",
    "render_sem": "espin.imaging.synthetic",
    "SyntheticSEM": "espin.imaging.synthetic",
    "SEMError": "espin.imaging.errors",
    "read_image": "espin.imaging.image",
    "detect_scale_bar": "espin.imaging.scale",
    "ScaleBar": "espin.imaging.scale",
}

__all__ = list(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'espin.imaging' has no attribute {name!r}")
