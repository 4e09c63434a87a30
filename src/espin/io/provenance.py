"""What every espin output file records about how it was made."""

from __future__ import annotations

import datetime as _dt
import platform

import h5py
import numpy as np
import scipy

import espin

__all__ = ["UNITS", "provenance"]

UNITS = "length um, stress MPa, force uN (MPa um^2), time s, angles rad"


def provenance() -> dict[str, str]:
    """Versions, units and creation time, as string attributes for a file's root."""
    return {
        "espin_version": espin.__version__,
        "numpy_version": np.__version__,
        "scipy_version": scipy.__version__,
        "h5py_version": h5py.__version__,
        "python_version": platform.python_version(),
        "units": UNITS,
        "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
    }
