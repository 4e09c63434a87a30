"""Results files and figures: CSV and HDF5 round trips, streamed VTK series, clear errors.

The results are synthetic (random arrays on a hand-made network): these tests check the
files, not the mechanics.
"""

from __future__ import annotations

import csv
import xml.etree.ElementTree as ET

import h5py
import meshio
import numpy as np
import pytest
from conftest import make_mat

from espin.core.config import load_config
from espin.core.errors import RVEFileError
from espin.geometry.crosslinks import find_crosslinks
from espin.geometry.network import build_network
from espin.mechanics.driver import SimulationResult, StepRecord
from espin.mechanics.figures import plot_curve, plot_deformed
from espin.mechanics.loading import load_program
from espin.mechanics.results_file import SCHEMA_VERSION, SimulationWriter, load_results, write_results

PNG = b"\x89PNG\r\n\x1a\n"
_STACKED = ("time", "strain", "F", "P", "P_paper", "kirchhoff", "cauchy", "recruited_fraction",
            "yielded_fraction", "iterations", "factorizations", "substeps", "residual")


@pytest.fixture(scope="module")
def network():
    mat = make_mat([[(0, 5), (4, 5), (10, 8)], [(3, 0), (3, 10)], [(0, 2), (10, 9)], [(7, 0), (6, 10)]],
                   layers=[0, 0, 1, 1])
    return build_network(mat, find_crosslinks(mat), tolerance=1e-4)


def fake_result(network, seed: int = 0, **overrides) -> tuple[SimulationResult, list[StepRecord]]:
    """A SimulationResult of random numbers on ``network`` (3 steps of the given loading)."""
    rng = np.random.default_rng(seed)
    config = load_config(None, {"loading.max_strain": 0.03, "loading.steps": 3, **overrides})
    program = load_program(config.loading)
    n_el = network.n_elements
    X = network.node_position - network.centre
    records = []
    for k in range(program.n_steps + 1):
        F = program.prescribed_F(program.time[k])
        records.append(StepRecord(
            index=k, time=float(program.time[k]), strain=float(program.strain[k]), F=F,
            P=rng.normal(size=(2, 2)), P_paper=rng.normal(size=(2, 2)), kirchhoff=rng.normal(size=(2, 2)),
            cauchy=rng.normal(size=(2, 2)),
            recruited_fraction=rng.random(), yielded_fraction=rng.random(),
            iterations=int(rng.integers(1, 9)), factorizations=int(rng.integers(1, 9)),
            substeps=int(rng.integers(1, 3)), residual=rng.random() * 1e-9,
            positions=X @ F.T + 0.01 * k * rng.normal(size=X.shape),
            stress=rng.normal(size=n_el) * 10.0,
            plastic_stretch=1.0 + (k > 0) * rng.uniform(0.0, 2e-3, n_el),
            recruited=rng.random(n_el) < 0.5,
        ))
    stacked = {name: np.array([getattr(r, name) for r in records]) for name in _STACKED}
    return SimulationResult(config=config, program=program, final=records[-1], **stacked), records


def test_curve_csv_round_trip(network, tmp_path):
    result, _ = fake_result(network, **{"loading.direction_deg": 30.0})
    path = write_results(result, tmp_path)["curve_csv"]
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    tensors = {"F": result.F, "P": result.P, "paper": result.P_paper, "kirchhoff": result.kirchhoff,
               "cauchy": result.cauchy}
    expected = {"step": np.arange(len(result.time)), "time_s": result.time, "strain": result.strain}
    for prefix, tensor in tensors.items():
        unit = "" if prefix == "F" else "_MPa"
        for i in (0, 1):
            for j in (0, 1):
                expected[f"{prefix}{i + 1}{j + 1}{unit}"] = tensor[:, i, j]
    expected |= {"stress_MPa": result.stress(), "recruited_fraction": result.recruited_fraction,
                 "yielded_fraction": result.yielded_fraction, "iterations": result.iterations,
                 "factorizations": result.factorizations, "substeps": result.substeps,
                 "residual_uN": result.residual}
    assert list(rows[0]) == list(expected)
    assert len(rows) == len(result.time)
    for name, values in expected.items():
        back = np.array([float(row[name]) for row in rows])
        np.testing.assert_allclose(back, values, rtol=1e-12, atol=0, err_msg=name)
    # The curve's stress is in the loading frame, not the RVE axes' P11.
    R = result.program.rotation
    assert np.allclose(expected["stress_MPa"], np.einsum("i,nij,j->n", R[:, 0], result.P, R[:, 0]))
    assert not np.allclose(expected["stress_MPa"], expected["P11_MPa"])
    table = np.loadtxt(path, delimiter=",", skiprows=1)
    assert table.shape == (len(result.time), len(expected))


def test_results_h5_round_trip(network, tmp_path):
    result, _ = fake_result(network, **{"output.stress_measure": "paper"})
    files = write_results(result, tmp_path)
    back = load_results(files["results_h5"])
    assert back.config == result.config and back.seed == result.config.rve.seed
    assert back.provenance["espin_version"] and back.provenance["units"]
    names = {"time": "time_s", "P": "P_MPa", "P_paper": "P_paper_MPa", "kirchhoff": "kirchhoff_MPa",
             "cauchy": "cauchy_MPa", "residual": "residual_uN"}
    for attr in _STACKED:
        stored = back.steps[names.get(attr, attr)]
        assert np.array_equal(stored, getattr(result, attr)), attr
    assert np.array_equal(back.steps["stress_MPa"], result.stress("paper"))
    final = result.final
    assert np.array_equal(back.final["stress_MPa"], final.stress)
    assert np.array_equal(back.final["plastic_stretch"], final.plastic_stretch)
    assert back.final["recruited"].dtype == bool and np.array_equal(back.final["recruited"], final.recruited)
    assert np.array_equal(back.final["positions_um"], final.positions)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["curve.csv", "results.h5"]


def test_load_results_errors(network, tmp_path):
    with pytest.raises(RVEFileError, match="cannot open"):
        load_results(tmp_path / "missing.h5")
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f.attrs["schema"] = "espin.rve"
    with pytest.raises(RVEFileError, match="not an espin results file"):
        load_results(other)
    result, _ = fake_result(network)
    path = write_results(result, tmp_path)["results_h5"]
    with h5py.File(path, "a") as f:
        f.attrs["schema_version"] = SCHEMA_VERSION + 1
    with pytest.raises(RVEFileError, match="schema version"):
        load_results(path)
    path = write_results(result, tmp_path)["results_h5"]
    with h5py.File(path, "a") as f:
        del f["steps/P_MPa"]
    with pytest.raises(RVEFileError, match="incomplete"):
        load_results(path)


def test_writer_streams_vtk_series(network, tmp_path):
    result, records = fake_result(network)
    threshold = result.config.output.yield_threshold
    writer = SimulationWriter(tmp_path, network, result.config, vtk=True)
    for k, record in enumerate(records):
        writer(record)
        datasets = ET.parse(writer.pvd_path).getroot().findall("./Collection/DataSet")
        assert len(datasets) == k + 1  # the collection is complete after every step
    assert [float(d.get("timestep")) for d in datasets] == [r.time for r in records]
    for dataset, record in zip(datasets, records, strict=True):
        mesh = meshio.read(tmp_path / dataset.get("file"))
        assert np.array_equal(mesh.cells_dict["line"], network.element_nodes)
        # Reference points centred on the RVE, displaced by the point data to the step's.
        assert np.allclose(mesh.points[:, :2], network.node_position - network.centre)
        assert np.allclose(mesh.points[:, :2] + mesh.point_data["displacement_um"][:, :2], record.positions)
        data = {name: value[0] for name, value in mesh.cell_data.items()}
        assert np.allclose(data["axial_force_uN"], record.stress * network.element_area)
        assert np.array_equal(data["stress_MPa"], record.stress)
        assert np.array_equal(data["plastic_stretch"], record.plastic_stretch)
        assert np.array_equal(data["recruited"], record.recruited.astype(np.int8))
        assert np.array_equal(data["yielded"], (record.plastic_stretch - 1.0 > threshold).astype(np.int8))
    assert records[-1].plastic_stretch.max() - 1.0 > threshold  # the yielded flag was exercised
    written = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*") if p.is_file())
    assert written == ["curve.csv", "deformation.pvd"] + [f"vtk/step_{k:04d}.vtu" for k in range(len(records))]


def test_writer_streams_the_curve_as_the_final_write_does(network, tmp_path):
    """After every step curve.csv holds the steps so far, byte for byte what write_results
    writes for them; without VTK nothing else is written."""
    result, records = fake_result(network)
    final = write_results(result, tmp_path / "final")["curve_csv"].read_text().splitlines(keepends=True)
    writer = SimulationWriter(tmp_path / "run", network, result.config, vtk=False)
    for k, record in enumerate(records):
        writer(record)
        assert (tmp_path / "run" / "curve.csv").read_text() == "".join(final[: k + 2])
    assert [p.name for p in (tmp_path / "run").iterdir()] == ["curve.csv"]


def test_writer_saves_results_at_intervals(network, tmp_path, monkeypatch):
    """results.h5 is rewritten with the steps so far once the interval has passed."""
    import espin.mechanics.results_file as results_file

    result, records = fake_result(network)
    monkeypatch.setattr(results_file, "RESULTS_INTERVAL_S", 0.0)
    writer = SimulationWriter(tmp_path, network, result.config, vtk=False)
    for record in records[:3]:
        writer(record)
    saved = load_results(tmp_path / "results.h5")
    assert np.array_equal(saved.steps["time_s"], [r.time for r in records[:3]])
    assert np.array_equal(saved.final["positions_um"], records[2].positions)


@pytest.mark.parametrize("overrides", [
    {},
    {"loading.lateral": "free", "output.stress_measure": "paper"},
    {"loading.lateral": {"poisson_ratio": 0.3}, "loading.direction_deg": 45.0},
    {"loading.test": "simple_shear"},
])
@pytest.mark.slow
def test_figures_written(network, tmp_path, overrides):
    result, records = fake_result(network, **overrides)
    curve = plot_curve(result, tmp_path / "curve.png")
    start = plot_deformed(network, records[0], tmp_path / "start.png")
    end = plot_deformed(network, records[-1], tmp_path / "end.png", outline=False)
    for path in (curve, start, end):
        assert path.read_bytes()[:8] == PNG
    assert sorted(p.name for p in tmp_path.iterdir()) == ["curve.png", "end.png", "start.png"]


def _damage(f, name, value):
    del f[name]
    f[name] = value


# (dataset, damage given the original array, text of the message)
DAMAGED_RESULTS = [
    ("steps/P_MPa", lambda a: np.where(np.arange(a.size).reshape(a.shape) == 5, np.nan, a), "not finite"),
    ("steps/recruited_fraction", lambda a: a + 2.0, "steps/recruited_fraction"),
    ("steps/yielded_fraction", lambda a: -a - 1.0, "steps/yielded_fraction"),
    ("steps/iterations", lambda a: -a - 1, "steps/iterations"),
    ("steps/iterations", lambda a: a.astype(float) + 0.5, "steps/iterations"),
    ("steps/strain", lambda a: a[:-1], "steps/strain"),
    ("steps/F", lambda a: a[:, :1], "steps/F"),
    ("steps/time_s", lambda a: -a - 1.0, "steps/time_s"),
    ("steps/residual_uN", lambda a: np.full(a.shape, np.inf), "steps/residual_uN"),
    ("steps/stress_MPa", lambda a: np.array(["x"] * a.size, dtype="S1"), "steps/stress_MPa"),
    ("final/plastic_stretch", lambda a: np.zeros_like(a), "final/plastic_stretch"),
    ("final/recruited", lambda a: a[:-1], "final/recruited"),
    ("final/positions_um", lambda a: a[:, :1], "final/positions_um"),
]


@pytest.mark.parametrize("name, damage, message", DAMAGED_RESULTS,
                         ids=[f"{n}-{k}" for k, (n, _, _) in enumerate(DAMAGED_RESULTS)])
def test_damaged_results_file_is_refused_naming_the_dataset(network, tmp_path, name, damage, message):
    result, _ = fake_result(network)
    path = write_results(result, tmp_path)["results_h5"]
    with h5py.File(path, "a") as f:
        _damage(f, name, damage(f[name][()]))
    with pytest.raises(RVEFileError, match=message) as err:
        load_results(path)
    assert str(path) in str(err.value)


def test_results_of_a_partial_or_mixed_folder_are_read_with_a_warning(network, tmp_path):
    from espin.core.output_folder import OutputFolder
    from espin.mechanics.results_file import PartialResultWarning

    result, _ = fake_result(network)
    claimed = OutputFolder.claim(tmp_path / "run", "simulate", "x", ["results.h5"])
    write_results(result, claimed.path, run_id=claimed.run_id)
    with pytest.warns(PartialResultWarning, match="running"):
        assert load_results(claimed.path).status == "running"  # a folder is read as its results.h5
    claimed.finish()
    assert load_results(claimed.path / "results.h5").status == "complete"
    write_results(result, claimed.path, run_id="another")
    with pytest.warns(PartialResultWarning, match="mixed folder"):
        assert load_results(claimed.path).status == "mixed"


def test_a_results_file_from_before_the_kirchhoff_stress_reads_it_from_cauchy(network, tmp_path):
    """A results.h5 written before /steps/kirchhoff_MPa existed is read with it as det F times
    the Cauchy stress (the same stress)."""
    import h5py

    result, _ = fake_result(network)
    path = write_results(result, tmp_path)["results_h5"]
    with h5py.File(path, "a") as f:
        del f["steps/kirchhoff_MPa"]
    back = load_results(path)
    np.testing.assert_allclose(back.steps["kirchhoff_MPa"],
                               np.linalg.det(result.F)[:, None, None] * result.cauchy, rtol=1e-15)
