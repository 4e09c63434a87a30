"""Write a generated RVE's folder: HDF5 file, resolved config, statistics, figures, VTK.

The statistics grade the mat against the measured targets of its config, measured as they
were measured (:func:`trace_window`, :mod:`espin.geometry.statistics`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from espin.core.atomic import atomic_write_bytes
from espin.core.config import Config, config_digest, write_config
from espin.core.output_folder import OutputFolder
from espin.geometry.mat import FiberMat
from espin.geometry.pieces import sample_pieces, window_crossings, window_runs
from espin.geometry.rve import RVE
from espin.geometry.rve_file import save_rve
from espin.geometry.statistics import (
    NetworkStatistics,
    TracedWindow,
    network_statistics,
    observation_window,
)
from espin.geometry.vtk import write_mat_vtu, write_network_vtu

__all__ = [
    "RVEFolder",
    "write_rve_folder",
    "write_rve_files",
    "trace_window",
    "rve_statistics",
    "RVE_OUTPUTS",
    "PIECE_SEED",
]

RVE_OUTPUTS = (
    "rve.h5",
    "config.toml",
    "statistics.json",
    "statistics.txt",
    "mat.png",
    "statistics.png",
    "fibers.vtu",
    "network.vtu",
)
"""The files an RVE folder may hold (glob patterns relative to it)."""
PIECE_SEED = 20240
"""Seed of the draws of length-matched pieces (:func:`trace_window`): grading is deterministic."""


@dataclass(frozen=True)
class RVEFolder:
    """Files written for one RVE, and its statistics."""

    folder: Path
    statistics: NetworkStatistics
    files: dict[str, Path] = field(default_factory=dict)


def trace_window(mat: FiberMat, config: Config) -> TracedWindow | None:
    """What grading a mat against its config's targets needs beyond the whole window
    portions (:func:`espin.geometry.statistics.grade`).

    When ``targets.contour_length_um`` is given, the mat is measured like the SEM tracer's
    pieces: pieces of those contour lengths cut from its window portions
    (:func:`espin.geometry.pieces.sample_pieces`, draws seeded by :data:`PIECE_SEED`); when
    ``targets.u_turn_fraction`` or ``targets.straightness`` is given, the crossing statistics
    of its window portions (:func:`espin.geometry.pieces.window_crossings`). The window and
    shortest chord are those of :func:`espin.geometry.statistics.observation_window`.

    Returns
    -------
    TracedWindow or None
        None when the targets need neither (or there are none).
    """
    targets = config.targets
    if targets is None:
        return None
    pieces = targets.contour_length_um is not None
    crossings = targets.u_turn_fraction is not None or targets.straightness is not None
    if not (pieces or crossings):
        return None
    origin, side, min_chord = observation_window(config, mat.size)
    runs = window_runs(mat.vertices, mat.fiber_offsets, origin, side)
    traced: dict = {}
    if pieces:
        rng = np.random.default_rng(PIECE_SEED)
        tortuosity, orientation, _ = sample_pieces(runs, np.asarray(targets.contour_length_um), min_chord, rng)
        traced |= {"piece_tortuosity": tortuosity, "piece_orientation": orientation}
    if crossings:
        c = window_crossings(runs, origin, side, min_chord)
        traced |= {"n_crossing": c.n_crossing, "u_turn_fraction": c.u_turn_fraction, "straightness": c.straightness}
    return TracedWindow(**traced)


def rve_statistics(rve: RVE) -> NetworkStatistics:
    """Statistics of an RVE, graded against the measured targets of its config as they were
    measured (:func:`espin.geometry.statistics.network_statistics` with :func:`trace_window`)."""
    return network_statistics(rve.mat, rve.network, rve.config, trace_window(rve.mat, rve.config))


def write_rve_folder(
    rve: RVE,
    folder: str | Path,
    *,
    figures: bool | None = None,
    vtk: bool | None = None,
    overwrite: bool = False,
) -> RVEFolder:
    """Write an RVE's folder, with its ``run.json`` manifest (:mod:`espin.core.output_folder`).

    Parameters
    ----------
    rve
        The generated RVE.
    folder
        Output folder (created if needed). Every file is written atomically.
    figures, vtk
        Write PNG figures / VTK files; default from ``rve.config.output``.
    overwrite
        Replace the files of another run in ``folder`` instead of refusing.

    Returns
    -------
    RVEFolder
        The folder, the statistics and the written paths by name.

    Raises
    ------
    ConfigError
        If ``folder`` holds another run's results and ``overwrite`` is False.
    """
    with OutputFolder.claim(folder, "generate", config_digest(rve.config), RVE_OUTPUTS, overwrite=overwrite) as claimed:
        return write_rve_files(rve, folder, figures=figures, vtk=vtk, run_id=claimed.run_id)


def write_rve_files(
    rve: RVE,
    folder: str | Path,
    *,
    figures: bool | None = None,
    vtk: bool | None = None,
    run_id: str | None = None,
) -> RVEFolder:
    """Write ``rve.h5``, ``config.toml``, ``statistics.json``, ``statistics.txt``, and
    optionally ``mat.png``, ``statistics.png``, ``fibers.vtu``, ``network.vtu`` into a folder
    the caller has claimed (:class:`espin.core.output_folder.OutputFolder`).

    Parameters are those of :func:`write_rve_folder`, and ``run_id``, the claiming run's id,
    stored in ``rve.h5``.
    """
    folder = Path(folder)
    figures = rve.config.output.figures if figures is None else figures
    vtk = rve.config.output.vtk if vtk is None else vtk
    stats = rve_statistics(rve)
    files = {
        "rve": save_rve(rve, folder / "rve.h5", run_id),
        "config": write_config(rve.config, folder / "config.toml"),
        "statistics_json": atomic_write_bytes(
            folder / "statistics.json", json.dumps(stats.summary(), indent=2).encode()
        ),
        "statistics_txt": atomic_write_bytes(folder / "statistics.txt", stats.format_table().encode()),
    }
    if figures:
        from espin.geometry.figures import plot_mat, plot_statistics

        files["mat_png"] = plot_mat(rve.mat, folder / "mat.png")
        files["statistics_png"] = plot_statistics(stats, folder / "statistics.png")
    if vtk:
        files["fibers_vtu"] = write_mat_vtu(rve.mat, folder / "fibers.vtu")
        files["network_vtu"] = write_network_vtu(rve.network, folder / "network.vtu")
    return RVEFolder(folder=folder, statistics=stats, files=files)
