"""espin: virtual electrospun fiber mats and their mechanics.

Pipeline: (SEM image -> measured distributions -> deposition parameters) -> config ->
deposition (fibers as polylines) -> cross-links -> network -> mechanics -> homogenized stress
-> curves and properties -> (calibration against experiments, ensembles and studies).

Units inside espin: length um, stress MPa, force uN (= MPa um^2), time s, angles rad.
At the user-facing edge (configs, CLI, tables, plots) angles are in degrees.

The top-level names are imported lazily, so ``import espin`` is fast and has no side effects.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_EXPORTS = {
    "Config": "espin.config",
    "load_config": "espin.config",
    "write_config": "espin.config",
    "RVE": "espin.rve",
    "generate": "espin.rve",
    "save_rve": "espin.io.rve_file",
    "load_rve": "espin.io.rve_file",
    "write_rve_folder": "espin.outputs",
    "simulate": "espin.run",
    "load_results": "espin.io.results_file",
    "network_statistics": "espin.statistics",
    "window_tortuosity": "espin.statistics",
    "curve_properties": "espin.properties",
    "simulation_properties": "espin.properties",
    "read_curve": "espin.experiments",
    "average_curves": "espin.experiments",
    "fit": "espin.calibration",
    "sweep": "espin.studies",
    "rve_size_study": "espin.studies",
    "dof_study": "espin.dof_study",
    "measure": "espin.sem",
    "calibrate_geometry": "espin.geometry_calibration",
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'espin' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(__all__)
