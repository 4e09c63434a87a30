"""What a specimen test returns and writes.

Files of a results folder (units mm, N, MPa, s):

- ``force_displacement.csv``: one row per recorded step (appended as the run goes): time,
  grip strain and displacement, grip force, the gauge section's engineering strain and stress,
  its transverse strain (across the section midway between the grips; negative as it
  contracts), macro Newton iterations, cuts and time steps;
- ``fields.pvd`` + ``vtk/step_NNNN.vtu``: the mesh with point data ``displacement_mm`` (for
  ParaView's Warp By Vector) and cell data (element means of the quadrature points):
  Green-Lagrange strain ``E11``, ``E22``, ``E12``, nominal stress ``P11``, ``P12``, ``P21``,
  ``P22`` [MPa], and for RVE materials the ``yielded_fraction`` and ``recruited_fraction``;
- ``force.png`` (force-displacement and gauge stress-strain) and ``specimen.png`` (the
  deformed specimen coloured by P11 at the last step) and ``yielded.png`` for RVE materials;
- ``specimen.json``: the specimen, its dimensions and the run's settings and counts;
- FE^2: ``rve.h5`` (the shared RVE) and ``rve_points.h5`` (per point: reference position, the
  F and time of every time step, and with the shared RVE the final inner node positions and
  plastic stretches), so any point can be reopened as an RVE result (:func:`reopen_point`);
- surrogate: ``surrogate_samples.csv`` (the RVE samples it interpolates, with the identity of
  their mat: :mod:`espin.specimen.surrogate_file`; written as each RVE path finishes;
  ``surrogate_from=`` reuses them in another run of the same mat), and in ``specimen.json`` where
  they came from (``built`` or the file) and any mismatch the run was told to accept.
"""

from __future__ import annotations

import io
import json
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import h5py
import meshio
import numpy as np
from skfem import MeshTri

from espin.core.atomic import atomic_write, atomic_write_bytes
from espin.core.config import Config, config_from_dict, config_to_toml, write_config
from espin.core.errors import RVEFileError
from espin.core.html import html_table
from espin.geometry.network import Network
from espin.geometry.rve_file import load_rve
from espin.geometry.vtk import write_collection
from espin.mechanics.driver import SimulationResult, result_from_records
from espin.mechanics.loading import path_program
from espin.specimen.figures import plot_deformed, plot_force
from espin.specimen.membrane import Membrane
from espin.specimen.rve_points import PointStates, RVEPoints, replay_point
from espin.specimen.shapes import Specimen
from espin.specimen.solver import SpecimenStep
from espin.specimen.surrogate import Surrogate
from espin.specimen.surrogate_file import write_samples

__all__ = ["SpecimenResult", "SpecimenWriter", "SPECIMEN_OUTPUTS", "reopen_point", "CURVE_COLUMNS"]

SPECIMEN_OUTPUTS = (
    "force_displacement.csv",
    "fields.pvd",
    "vtk/step_*.vtu",
    "force.png",
    "specimen.png",
    "yielded.png",
    "specimen.json",
    "config.toml",
    "rve.h5",
    "rve_points.h5",
    "surrogate_samples.csv",
)
"""The files a specimen test writes (glob patterns relative to its folder)."""

CURVE_COLUMNS = (
    "step",
    "time_s",
    "grip_strain",
    "displacement_mm",
    "force_N",
    "gauge_strain",
    "gauge_stress_MPa",
    "gauge_transverse_strain",
    "iterations",
    "cuts",
    "substeps",
)
"""Columns of ``force_displacement.csv``."""


def _green(F: np.ndarray) -> np.ndarray:
    C = np.einsum("...kI,...kJ->...IJ", F, F)
    return 0.5 * (C - np.eye(2))


def _row(step: SpecimenStep) -> str:
    values = (
        step.index,
        step.time,
        step.grip_strain,
        step.displacement_mm,
        step.force_N,
        step.gauge_strain,
        step.gauge_stress_MPa,
        step.gauge_transverse_strain,
        step.iterations,
        step.cuts,
        step.substeps,
    )
    return ",".join(f"{v:d}" if isinstance(v, int) else f"{v:.10g}" for v in values) + "\n"


class SpecimenWriter:
    """Write a specimen test as it goes (``on_step`` of :func:`espin.specimen.solver.run_specimen`):
    the step's ``.vtu``, then the CSV row (flushed and synced), then the updated ``fields.pvd``;
    :meth:`trim` after an interruption removes a ``.vtu`` whose row was not written, so the CSV
    and the VTK series always hold the same steps."""

    def __init__(self, folder: Path, membrane: Membrane, vtk: bool = True) -> None:
        self.folder = Path(folder)
        self.membrane = membrane
        self.vtk = vtk
        self._vtk_steps: list[tuple[float, str]] = []
        self.rows = 0

    def __call__(self, step: SpecimenStep) -> None:
        path = self.folder / "force_displacement.csv"
        name = f"vtk/step_{step.index:04d}.vtu"
        if self.vtk:
            write_step_vtu(self.membrane, step, self.folder / name)
        try:
            with open(path, "w" if step.index == 0 else "a", encoding="utf-8") as fh:
                fh.write((",".join(CURVE_COLUMNS) + "\n" if step.index == 0 else "") + _row(step))
                fh.flush()
                os.fsync(fh.fileno())
        except OSError as err:
            raise RVEFileError(f"cannot write {path}: {err.strerror or err} (a full disk?)") from None
        self.rows = step.index + 1
        if self.vtk:
            self._vtk_steps.append((step.time, name))
            write_collection(self.folder / "fields.pvd", self._vtk_steps)

    def trim(self) -> None:
        """Remove the ``.vtu`` files of steps without a CSV row (a run interrupted between the two)
        and list in ``fields.pvd`` only the steps the CSV holds."""
        if not self.vtk:
            return
        for path in (self.folder / "vtk").glob("step_*.vtu"):
            if path.stem[5:].isdigit() and int(path.stem[5:]) >= self.rows:
                path.unlink(missing_ok=True)
        if len(self._vtk_steps) > self.rows:
            self._vtk_steps = self._vtk_steps[: self.rows]
            write_collection(self.folder / "fields.pvd", self._vtk_steps)


def element_fields(membrane: Membrane, step: SpecimenStep) -> dict[str, np.ndarray]:
    """Element means of the step's point fields (module docstring)."""
    E = membrane.element_mean(_green(step.F))
    P = membrane.element_mean(step.P)
    fields = {"E11": E[:, 0, 0], "E22": E[:, 1, 1], "E12": E[:, 0, 1]}
    fields.update({f"P{i + 1}{j + 1}": P[:, i, j] for i in range(2) for j in range(2)})
    fields.update({name: membrane.element_mean(values) for name, values in step.fields.items()})
    return fields


def write_step_vtu(membrane: Membrane, step: SpecimenStep, path: Path) -> Path:
    """One step's mesh and fields as a ``.vtu`` [mm]."""
    mesh = membrane.mesh
    dofs_x, dofs_y = membrane.basis.nodal_dofs
    points = np.column_stack([mesh.p.T, np.zeros(mesh.nvertices)])
    displacement = np.column_stack([step.u[dofs_x], step.u[dofs_y], np.zeros(mesh.nvertices)])
    kind = "triangle" if isinstance(mesh, MeshTri) else "quad"
    grid = meshio.Mesh(
        points,
        [(kind, mesh.t.T)],
        point_data={"displacement_mm": displacement},
        cell_data={k: [v] for k, v in element_fields(membrane, step).items()},
    )
    return atomic_write(path, lambda tmp: meshio.write(tmp, grid, file_format="vtu"))


@dataclass(eq=False)
class SpecimenResult:
    """A specimen test: its steps, settings and (FE^2) what reopens a point's RVE.

    Attributes
    ----------
    specimen : Specimen
    model : str
        ``"fe2"``, ``"surrogate"`` or ``"neo_hookean"``.
    thickness_mm : float
    grips, lateral : str
    steps : list of SpecimenStep
    membrane : Membrane
    config : Config or None
        The RVEs' config (None for the closed-form material).
    networks : list of Network
        FE^2: the network of every point (the same object when shared); else empty.
    point_time, point_F : ndarray
        FE^2: time [s] (k,) and F (k, n_points, 2, 2) of every time step (for replays).
    surrogate : Surrogate or None
    surrogate_source : str
        ``"built"`` (this run ran the RVE paths) or the samples file it read.
    surrogate_mismatches : list of str
        How the samples read differ from this run's mat, when the run was told to accept it.
    final_state : PointStates or None
        FE^2: the points' RVE states at the last converged step.
    counts : dict
        Wall times [s], RVE solves and iterations, macro iterations, workers.
    folder : Path or None
    """

    specimen: Specimen
    model: str
    thickness_mm: float
    grips: str
    lateral: str
    steps: list[SpecimenStep]
    membrane: Membrane
    config: Config | None = None
    networks: list[Network] = field(default_factory=list)
    point_time: np.ndarray | None = None
    point_F: np.ndarray | None = None
    surrogate: Surrogate | None = None
    surrogate_source: str = "built"
    surrogate_mismatches: list[str] = field(default_factory=list)
    counts: dict[str, Any] = field(default_factory=dict)
    folder: Path | None = None
    final_state: PointStates | None = None

    @property
    def force_N(self) -> np.ndarray:
        return np.array([s.force_N for s in self.steps])

    @property
    def displacement_mm(self) -> np.ndarray:
        return np.array([s.displacement_mm for s in self.steps])

    def to_dataframe(self) -> Any:
        """The force-displacement table (the columns of ``force_displacement.csv``)."""
        import pandas as pd

        return pd.read_csv(io.StringIO(",".join(CURVE_COLUMNS) + "\n" + "".join(_row(s) for s in self.steps)))

    def point_result(self, point: int) -> SimulationResult:
        """FE^2: the RVE of quadrature ``point`` driven again through its F history (the same
        time steps), as a single RVE's :class:`espin.mechanics.driver.SimulationResult`."""
        if self.point_F is None or self.config is None or self.point_time is None:
            raise ValueError(f"a {self.model} run has no RVEs at its points")
        if not 0 <= point < self.membrane.n_points:
            raise ValueError(f"point = {point}: must be in [0, {self.membrane.n_points - 1}]")
        return _replay(self.networks[point], self.config, self.point_time, self.point_F[:, point])

    def _summary(self) -> dict[str, str]:
        last = self.steps[-1]
        return {
            "specimen": repr(self.specimen),
            "model": self.model,
            "boundary": f"grips {self.grips}, lateral {self.lateral}",
            "thickness": f"{self.thickness_mm:g} mm",
            "quadrature points": str(self.membrane.n_points),
            "grip strain": f"{last.grip_strain:.4g}",
            "grip force": f"{last.force_N:.4g} N",
            "gauge stress / strain": f"{last.gauge_stress_MPa:.4g} MPa at {last.gauge_strain:.4g}",
            "wall time": f"{self.counts.get('seconds', float('nan')):.1f} s",
        }

    def __repr__(self) -> str:
        return "SpecimenResult(" + ", ".join(f"{k}: {v}" for k, v in self._summary().items()) + ")"

    def format_summary(self) -> str:
        """The result in plain lines, one ``name  value`` each (what ``espin specimen`` prints)."""
        rows = self._summary()
        width = max(map(len, rows))
        return "\n".join(f"{name:<{width}}  {value}" for name, value in rows.items())

    def _repr_html_(self) -> str:
        return html_table("SpecimenResult", list(self._summary().items()))

    def write(self, folder: Path, figures: bool = True) -> None:
        """The files written at the end of a run (the CSV and VTK series are written as it goes)."""
        self.folder = Path(folder)
        _write_json(self, self.folder / "specimen.json")
        if self.config is not None:
            write_config(self.config, self.folder / "config.toml")
        if self.point_F is not None:
            _write_points(self, self.folder / "rve_points.h5")
        if self.surrogate is not None:
            write_samples(self.folder / "surrogate_samples.csv", self.surrogate.identity, self.surrogate.runs)
        if figures:
            self.plot(self.folder)

    def plot(self, folder: Path) -> None:
        """``force.png``, ``specimen.png`` and (RVE materials) ``yielded.png``."""
        title = f"{self.specimen.name}, {self.model}, grips {self.grips}, lateral {self.lateral}"
        plot_force(self.steps, folder / "force.png", title)
        last = self.steps[-1]
        fields = element_fields(self.membrane, last)
        where = (
            f"{title}: grip strain {100 * last.grip_strain:.3g} %, gauge {100 * last.gauge_strain:.3g} % "
            f"along, {100 * last.gauge_transverse_strain:.3g} % across"
        )
        dofs = tuple(self.membrane.basis.nodal_dofs)
        plot_deformed(self.membrane.mesh, last.u, dofs, fields["P11"], "P11", folder / "specimen.png", where)
        if "yielded_fraction" in fields:
            plot_deformed(
                self.membrane.mesh,
                last.u,
                dofs,
                fields["yielded_fraction"],
                "yielded_fraction",
                folder / "yielded.png",
                where,
            )


def _replay(network: Network, config: Config, times: np.ndarray, F: np.ndarray) -> SimulationResult:
    records = replay_point(network, config, times, F)
    return result_from_records(config, path_program(times, F, strain=F[:, 0, 0] - 1.0), records)


def _write_json(result: SpecimenResult, path: Path) -> None:
    spec = result.specimen
    data = {
        "specimen": spec.name,
        "dimensions_mm": spec.dimensions,
        "grip_length_mm": spec.grip_length_mm,
        "gauge_length_mm": spec.gauge_length_mm,
        "gauge_width_mm": spec.gauge_width_mm,
        "elements": spec.n_elements,
        "quadrature_points": result.membrane.n_points,
        "thickness_mm": result.thickness_mm,
        "model": result.model,
        "grips": result.grips,
        "lateral": result.lateral,
        "counts": result.counts,
        "mesh_notes": list(spec.notes),
    }
    if result.surrogate is not None:
        identity = result.surrogate.identity
        data["surrogate_samples"] = {
            "config_digest": identity.config_digest,
            "law": identity.law,
            "strain_rate_per_s": identity.strain_rate_per_s,
            "max_strain": identity.max_strain,
            "source": result.surrogate_source,
            "mismatches": result.surrogate_mismatches,
        }
    atomic_write_bytes(path, json.dumps(data, indent=1, default=float).encode("utf-8"))


def _write_points(result: SpecimenResult, path: Path) -> None:
    points = result.membrane.point_coordinates()

    def write(tmp: Path) -> None:
        with h5py.File(tmp, "w") as h5:
            h5.attrs["config_toml"] = config_to_toml(cast(Config, result.config))  # an FE^2 run has one
            h5.attrs["shared_network"] = len({id(n) for n in result.networks}) == 1
            h5["reference_mm"] = points
            h5["time_s"] = result.point_time
            h5.create_dataset("F", data=result.point_F, compression="gzip")
            state = result.final_state
            if state is not None and h5.attrs["shared_network"]:
                h5.create_dataset("final/inner_um", data=np.stack(state.inner), compression="gzip")
                h5.create_dataset("final/plastic_stretch", data=np.stack(state.plastic_stretch), compression="gzip")

    atomic_write(path, write)


def reopen_point(folder: str | Path, point: int) -> SimulationResult:
    """The RVE at quadrature ``point`` of an FE^2 results folder, driven again through its saved
    F history with the same time steps (``rve.h5`` and ``rve_points.h5``), as a single RVE's
    :class:`espin.mechanics.driver.SimulationResult` (its ``final`` record holds the node
    positions, element stresses and plastic stretches).

    Raises
    ------
    RVEFileError
        When the folder holds no FE^2 results or the point does not exist.
    """
    folder = Path(folder)
    if not (folder / "rve_points.h5").is_file() or not (folder / "rve.h5").is_file():
        raise RVEFileError(f"{folder}: no rve_points.h5 and rve.h5 (only an FE^2 specimen run writes them)")
    with h5py.File(folder / "rve_points.h5", "r") as h5:
        n = h5["F"].shape[1]
        if not h5.attrs["shared_network"]:
            raise RVEFileError(f"{folder}: per-point RVEs are not saved; reopen works on a shared RVE")
        if not 0 <= point < n:
            raise RVEFileError(f"point = {point}: must be in [0, {n - 1}]")
        config = config_from_dict(tomllib.loads(h5.attrs["config_toml"]), f"{folder / 'rve_points.h5'}")
        times = h5["time_s"][()]
        F = h5["F"][:, point]
    return _replay(load_rve(folder / "rve.h5").network, config, times, F)


def points_history(points: RVEPoints) -> tuple[np.ndarray, np.ndarray]:
    """(time [s] (k,), F (k, n_points, 2, 2)) of every committed time step of the points."""
    return np.array(points.history_time), np.stack(points.history_F)
