"""Results of a loading program: the deformation step by step (VTK), the curve (CSV, HDF5).

:class:`SimulationWriter` follows the run step by step: it appends each converged step to
``curve.csv`` (flushed to disk), writes one ``vtk/step_NNNN.vtu`` and keeps the ParaView
collection ``deformation.pvd`` up to date, and rewrites ``results.h5`` every minute, so a
run that is killed keeps its converged steps. :func:`write_results` writes the finished
curve. Every file but the growing ``curve.csv`` is written atomically: a crash leaves the
previous version or nothing, never half a file; ``curve.csv`` may then end on a partial line,
which readers ignore only if it is the last one.

``curve.csv``: a header line, then one row per step (step 0 undeformed). Tensor components
are in the RVE axes (``P12_MPa`` is P_12, i spatial, J reference); ``stress_MPa`` is the
curve's stress in the loading frame and in ``output.stress_measure`` (the 11 component, or
12 for simple shear). Floats have 17 significant digits, so reading them back is exact.

``results.h5`` layout (schema ``espin.results``, version 1)::

    /          attrs: schema, schema_version, config_toml, seed, versions, units
    /steps     time_s, strain, F, P_MPa, P_paper_MPa, kirchhoff_MPa, cauchy_MPa, recruited_fraction,
               yielded_fraction, iterations, factorizations, substeps, residual_uN, stress_MPa
               (n_steps + 1, ...) each with a ``units`` attr; attrs: test, stress_measure
               (a file written before ``kirchhoff_MPa`` existed is read with it as det F
               times ``cauchy_MPa``, the same stress)
    /final     stress_MPa (n_elements,), plastic_stretch (n_elements,), recruited
               (n_elements,) bool, positions_um (n_nodes, 2) relative to the RVE centre
               attrs: step, time_s, strain
"""

from __future__ import annotations

import io
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from espin.core.atomic import atomic_write, atomic_write_bytes
from espin.core.config import Config
from espin.core.errors import RVEFileError
from espin.core.header import Kind, open_checked, read_config, write_header
from espin.core.html import html_table
from espin.geometry.network import Network
from espin.geometry.vtk import write_collection, write_network_vtu
from espin.mechanics.driver import (
    SimulationResult,
    StepRecord,
    curve_columns,
    curve_summary,
    result_from_records,
)
from espin.mechanics.fiber_law import yielded
from espin.mechanics.loading import LoadProgram, load_program

__all__ = [
    "SimulationWriter",
    "write_results",
    "load_results",
    "ResultsFile",
    "PartialResultWarning",
    "SCHEMA",
    "SCHEMA_VERSION",
]

SCHEMA = "espin.results"
SCHEMA_VERSION = 1
RESULTS_INTERVAL_S = 60.0
"""Wall time [s] between two rewrites of ``results.h5`` during a run."""

# SimulationResult attribute -> (dataset in /steps, units)
_STEPS = {
    "time": ("time_s", "s"),
    "strain": ("strain", "1"),
    "F": ("F", "1"),
    "P": ("P_MPa", "MPa"),
    "P_paper": ("P_paper_MPa", "MPa"),
    "kirchhoff": ("kirchhoff_MPa", "MPa"),
    "cauchy": ("cauchy_MPa", "MPa"),
    "recruited_fraction": ("recruited_fraction", "1"),
    "yielded_fraction": ("yielded_fraction", "1"),
    "iterations": ("iterations", "1"),
    "factorizations": ("factorizations", "1"),
    "substeps": ("substeps", "1"),
    "residual": ("residual_uN", "uN"),
}
# StepRecord attribute -> (dataset in /final, units)
_FINAL = {
    "stress": ("stress_MPa", "MPa"),
    "plastic_stretch": ("plastic_stretch", "1"),
    "recruited": ("recruited", "1"),
    "positions": ("positions_um", "um"),
}
_COMPONENTS = ("11", "12", "21", "22")


class SimulationWriter:
    """Write a run's results as it goes, for use as ``run_program(on_step=)``.

    Each call appends the step's row to ``curve.csv`` (the header first; flushed and synced),
    writes ``vtk/step_NNNN.vtu`` (the reference network centred on the RVE with the point
    data ``displacement_um``, for ParaView's Warp By Vector; cell data ``stress_MPa``,
    ``axial_force_uN``, ``chord_strain``, ``plastic_stretch``, ``recruited`` and ``yielded``
    as int8, plus the network's own; field data ``time_s`` and ``strain``) and then rewrites
    ``deformation.pvd``, which indexes every step so far with
    its time [s] as the ParaView timestep; and, when a minute has passed since the last time,
    rewrites ``results.h5`` with every step so far.

    Parameters
    ----------
    folder
        Output folder (created if needed).
    network
        The network being loaded (reference state).
    config
        The run's configuration (``output.yield_threshold`` decides ``yielded``).
    program
        The loading program (its frame gives the curve's stress); default from ``config``.
    vtk
        Write the VTK files.
    run_id
        The run writing the folder, stored in ``results.h5``.
    """

    def __init__(
        self,
        folder: str | Path,
        network: Network,
        config: Config,
        program: LoadProgram | None = None,
        vtk: bool = True,
        run_id: str | None = None,
    ) -> None:
        self.folder = Path(folder)
        self.network = network
        self.config = config
        self.program = program if program is not None else load_program(config.loading)
        self.vtk = vtk
        self.run_id = run_id
        self._threshold = config.output.yield_threshold
        self._steps: list[tuple[float, str]] = []  # (time [s], path relative to folder)
        self._records: list[StepRecord] = []
        self._saved = time.monotonic()

    @property
    def pvd_path(self) -> Path:
        """The ParaView collection file."""
        return self.folder / "deformation.pvd"

    def __call__(self, record: StepRecord) -> None:
        """Append the step to ``curve.csv``, write its ``.vtu`` and the updated ``.pvd``,
        and ``results.h5`` when it is due."""
        self._records.append(record)
        self._append_curve_row(record)
        if self.vtk:
            self._write_vtk(record)
        if time.monotonic() - self._saved >= RESULTS_INTERVAL_S:
            write_results(
                result_from_records(self.config, self.program, self._records),
                self.folder,
                curve=False,
                run_id=self.run_id,
            )
            self._saved = time.monotonic()

    def _append_curve_row(self, record: StepRecord) -> None:
        names, columns, formats = _curve_columns(
            result_from_records(self.config, self.program, [record]), first_step=record.index
        )
        row = ",".join(fmt % np.asarray(column)[0] for fmt, column in zip(formats, columns)) + "\n"
        first = len(self._records) == 1
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            with open(self.folder / "curve.csv", "w" if first else "a", encoding="utf-8") as fh:
                fh.write((",".join(names) + "\n" if first else "") + row)
                fh.flush()
                os.fsync(fh.fileno())
        except OSError as err:
            raise RVEFileError(
                f"cannot write {self.folder / 'curve.csv'}: {err.strerror or err} (a full disk?)"
            ) from None

    def _write_vtk(self, record: StepRecord) -> None:
        name = f"vtk/step_{record.index:04d}.vtu"
        write_network_vtu(
            self.network,
            self.folder / name,
            displacement=record.positions - (self.network.node_position - self.network.centre),
            cell_data={
                "stress_MPa": record.stress,
                "axial_force_uN": record.stress * self.network.element_area,
                "plastic_stretch": record.plastic_stretch,
                "recruited": record.recruited.astype(np.int8),
                "yielded": yielded(record.plastic_stretch, self._threshold).astype(np.int8),
            },
            field_data={"time_s": float(record.time), "strain": float(record.strain)},
        )
        self._steps.append((float(record.time), name))
        write_collection(self.pvd_path, self._steps)


def _curve_columns(result: SimulationResult, first_step: int = 0) -> tuple[list[str], list[np.ndarray], list[str]]:
    """Names, (n,) arrays and printf formats of the CSV columns; steps numbered from ``first_step``."""
    table = curve_columns({attr: getattr(result, attr) for attr in _STEPS}, result.stress(), first_step)
    columns = list(table.values())
    formats = ["%d" if np.issubdtype(np.asarray(c).dtype, np.integer) else "%.17g" for c in columns]
    return list(table), columns, formats


def write_results(
    result: SimulationResult, folder: str | Path, *, curve: bool = True, run_id: str | None = None
) -> dict[str, Path]:
    """Write ``curve.csv`` and ``results.h5`` (layouts in the module docs), atomically.

    Parameters
    ----------
    result
        The recorded loading program.
    folder
        Output folder (created if needed).
    curve
        Write ``curve.csv`` too (False: only ``results.h5``).
    run_id
        The run writing the folder, stored in ``results.h5``.

    Returns
    -------
    dict
        ``{"curve_csv": path, "results_h5": path}`` (without ``curve_csv`` if not written).
    """
    folder = Path(folder)
    written = {}
    if curve:
        names, columns, formats = _curve_columns(result)
        buffer = io.StringIO()
        np.savetxt(buffer, np.column_stack(columns), fmt=formats, delimiter=",", header=",".join(names), comments="")
        written["curve_csv"] = atomic_write_bytes(folder / "curve.csv", buffer.getvalue().encode("utf-8"))

    def write(tmp: Path) -> None:
        with h5py.File(tmp, "w") as f:
            write_header(f, SCHEMA, SCHEMA_VERSION, result.config, run_id)
            g = f.create_group("steps")
            for attr, (name, units) in _STEPS.items():
                g.create_dataset(name, data=getattr(result, attr)).attrs["units"] = units
            stress = g.create_dataset("stress_MPa", data=result.stress())
            stress.attrs["units"] = "MPa"
            stress.attrs["description"] = (
                "curve stress in the loading frame: the 12 component for simple shear, else "
                "the 11 component, of the stress_measure"
            )
            g.attrs.update(test=result.program.test, stress_measure=result.config.output.stress_measure)
            g = f.create_group("final")
            for attr, (name, units) in _FINAL.items():
                g.create_dataset(name, data=getattr(result.final, attr)).attrs["units"] = units
            g.attrs.update(step=result.final.index, time_s=result.final.time, strain=result.final.strain)

    written["results_h5"] = atomic_write(folder / "results.h5", write)
    return written


@dataclass(frozen=True, eq=False, repr=False)
class ResultsFile:
    """The content of a ``results.h5`` file.

    Attributes
    ----------
    config : Config
        The resolved configuration of the run.
    seed : int
        The RVE's random seed.
    provenance : dict[str, str]
        Versions, units, creation time and the ``run_id`` of the run that wrote it.
    steps : dict[str, numpy.ndarray]
        The datasets of ``/steps`` by name (``time_s``, ``P_MPa``, ...; module docs).
    final : dict[str, numpy.ndarray]
        The datasets of ``/final`` by name (``stress_MPa``, ``positions_um``, ...).
    status : str or None
        The status of its folder's run (``run.json``): ``complete``, ``running`` (a partial
        result: the run was killed or is still going), ``failed``, ``mixed`` (the folder's
        manifest names another run) or ``unknown`` (unreadable manifest); None without one.
    """

    config: Config
    seed: int
    provenance: dict[str, str]
    steps: dict[str, np.ndarray]
    final: dict[str, np.ndarray]
    status: str | None = None

    def to_dataframe(self) -> Any:
        """The curve as a pandas DataFrame, one row per step (step 0 undeformed), with the
        columns of ``curve.csv`` (:func:`espin.mechanics.driver.curve_columns`; stresses
        [MPa], time [s], residual [uN]); ``stress_MPa`` is the stored curve stress."""
        import pandas as pd

        steps = {attr: self.steps[name] for attr, (name, _) in _STEPS.items()}
        return pd.DataFrame(curve_columns(steps, self.steps["stress_MPa"]))

    def _summary(self) -> dict[str, str]:
        summary = curve_summary(
            self.config.loading.test, self.config.output.stress_measure, self.steps["strain"], self.steps["stress_MPa"]
        )
        summary["elements"] = str(len(self.final["stress_MPa"]))
        summary["nodes"] = str(len(self.final["positions_um"]))
        summary["seed"] = str(self.seed)
        summary["status"] = "no run.json" if self.status is None else self.status
        return summary

    def __repr__(self) -> str:
        """One line: test, steps, max strain, peak and last curve stress [MPa], elements, seed,
        run status."""
        s = self._summary()
        return (
            f"ResultsFile({s['test']}, {s['steps']} steps, max strain {s['max strain']}, "
            f"peak {s['peak stress']}, last {s['last stress']} ({s['stress']}), {s['elements']} elements, "
            f"seed {s['seed']}, {s['status']})"
        )

    def _repr_html_(self) -> str:
        """The key numbers as an HTML table (Jupyter)."""
        summary = self._summary()
        summary |= {key: self.provenance[key] for key in ("run_id", "espin_version") if key in self.provenance}
        return html_table("ResultsFile", list(summary.items()))


class PartialResultWarning(UserWarning):
    """A results file holds less than a complete run, or belongs to another run than its folder."""


_TENSOR = (None, 2, 2)
# /steps dataset -> (kind, shape, meaning, checks)
_STEP_CHECKS: dict[str, tuple[Kind, tuple, str, dict]] = {
    "strain": ("float", (None,), "the load parameter of each step", {}),
    "F": ("float", _TENSOR, "the deformation gradient of each step", {}),
    "P_MPa": ("float", _TENSOR, "the nominal stress of each step [MPa]", {}),
    "P_paper_MPa": ("float", _TENSOR, "the paper's Eq. 17 stress of each step [MPa]", {}),
    "kirchhoff_MPa": ("float", _TENSOR, "the Kirchhoff stress of each step [MPa]", {}),
    "cauchy_MPa": ("float", _TENSOR, "the Cauchy stress of each step [MPa]", {}),
    "recruited_fraction": ("float", (None,), "the recruited fiber fraction of each step", {"low": 0, "high": 1}),
    "yielded_fraction": ("float", (None,), "the yielded fiber fraction of each step", {"low": 0, "high": 1}),
    "iterations": ("int", (None,), "Newton iterations per step", {"low": 0}),
    "factorizations": ("int", (None,), "factorizations per step", {"low": 0}),
    "substeps": ("int", (None,), "time steps per step", {"low": 0}),
    "residual_uN": ("float", (None,), "the final residual of each step [uN]", {"low": 0}),
    "stress_MPa": ("float", (None,), "the curve's stress of each step [MPa]", {}),
}


def load_results(path: str | Path) -> ResultsFile:
    """Read a file written by :func:`write_results`, or the ``results.h5`` of a results folder.

    Every dataset is checked (type, shape, finite values, fractions in [0, 1], counts >= 0,
    one row per step throughout) before it is used. A file whose folder's ``run.json`` says
    the run is not complete, or names another run, is read with a
    :class:`PartialResultWarning`.

    Parameters
    ----------
    path
        A ``results.h5`` file, or the folder ``espin simulate`` wrote (its ``results.h5`` is
        read).

    Raises
    ------
    RVEFileError
        If the file is missing (a folder without ``results.h5``: naming the folder),
        unreadable, not an espin results file, of another schema version, incomplete, or
        holds values outside these rules (naming the dataset).
    """
    import warnings

    from espin.core.header import file_error, read_dataset

    path = Path(path)
    if path.is_dir():
        if not (path / "results.h5").exists():
            raise file_error(
                path,
                "",
                "is a folder without results.h5",
                "a results.h5 file or the folder espin simulate wrote, which holds results.h5",
            )
        path = path / "results.h5"
    with open_checked(path, SCHEMA, SCHEMA_VERSION, "results") as f:
        config = read_config(f, path)
        time_s = read_dataset(
            f, "steps/time_s", kind="float", shape=(None,), low=0.0, meaning="the time of each step [s]"
        )
        n = len(time_s)
        steps = {"time_s": time_s}
        for name, (kind, shape, meaning, checks) in _STEP_CHECKS.items():
            if name == "kirchhoff_MPa" and name not in f["steps"]:  # a file from before it was written
                continue
            steps[name] = read_dataset(f, f"steps/{name}", kind=kind, shape=(n, *shape[1:]), meaning=meaning, **checks)
        if "kirchhoff_MPa" not in steps:
            steps["kirchhoff_MPa"] = np.linalg.det(steps["F"])[:, None, None] * steps["cauchy_MPa"]
        stress = read_dataset(
            f, "final/stress_MPa", kind="float", shape=(None,), meaning="the final stress of each element [MPa]"
        )
        m = len(stress)
        final = {
            "stress_MPa": stress,
            "plastic_stretch": read_dataset(
                f,
                "final/plastic_stretch",
                kind="float",
                shape=(m,),
                positive=True,
                meaning="the final plastic stretch of each element",
            ),
            "recruited": read_dataset(
                f, "final/recruited", kind="bool", shape=(m,), meaning="whether each element is recruited"
            ),
            "positions_um": read_dataset(
                f, "final/positions_um", kind="float", shape=(None, 2), meaning="the final node positions [um]"
            ),
        }
        if n == 0:
            raise file_error(path, "dataset steps/time_s", "is empty", "at least the undeformed step")
        info = {k: str(v) for k, v in f.attrs.items() if k not in ("schema", "schema_version", "config_toml", "seed")}
    status, problem = _folder_status(path, info.get("run_id"))
    if problem:
        warnings.warn(f"{path}: {problem}", PartialResultWarning, stacklevel=2)
    return ResultsFile(config=config, seed=config.rve.seed, provenance=info, steps=steps, final=final, status=status)


def _folder_status(path: Path, run_id: str | None) -> tuple[str | None, str | None]:
    """The status of the run of the file's folder (None without ``run.json``; ``mixed`` when
    it names another run), and why the file may not be a complete result (or None)."""
    from espin.core.errors import ConfigError
    from espin.core.output_folder import read_manifest

    try:
        manifest = read_manifest(path.parent)
    except ConfigError:
        return "unknown", "its folder's run.json is unreadable, so the file may be partial"
    if manifest is None:
        return None, None
    if run_id is not None and manifest.run_id != run_id:
        return "mixed", (
            f"written by run {run_id}, but its folder's run.json names run {manifest.run_id}: a mixed folder"
        )
    if manifest.partial:
        return manifest.status, (
            f"a partial result: its folder's run.json says the run is {manifest.status} (killed, failed or still going)"
        )
    return manifest.status, None
