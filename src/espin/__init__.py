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

from espin.core.version import __version__

_EXPORTS = {
    "Config": "espin.core.config",
    "load_config": "espin.core.config",
    "write_config": "espin.core.config",
    "RVE": "espin.geometry.rve",
    "generate": "espin.geometry.rve",
    "save_rve": "espin.geometry.rve_file",
    "load_rve": "espin.geometry.rve_file",
    "write_rve_folder": "espin.geometry.rve_folder",
    "simulate": "espin.mechanics.run",
    "load_results": "espin.mechanics.results_file",
    "network_statistics": "espin.geometry.statistics",
    "window_tortuosity": "espin.geometry.statistics",
    "curve_properties": "espin.analysis.properties",
    "simulation_properties": "espin.analysis.properties",
    "read_curve": "espin.analysis.experiments",
    "average_curves": "espin.analysis.experiments",
    "fit": "espin.analysis.calibration",
    "sweep": "espin.studies.sweeps",
    "rve_size_study": "espin.studies.sweeps",
    "dof_study": "espin.studies.dof",
    "measure": "espin.imaging.measurement",
    "calibrate_geometry": "espin.imaging.geometry_calibration",
    "design": "espin.design",
    "specimen": "espin.specimen",
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str) -> Any:
    if name in ("design", "specimen"):  # the package, callable as its function (espin.design(...))
        return importlib.import_module(f"espin.{name}")
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'espin' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(__all__)
