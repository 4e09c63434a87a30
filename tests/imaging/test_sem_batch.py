"""espin measure on a batch: images.csv, pooled.toml and its cluster bootstrap, failures,
reruns, the output-folder policy, the CLI with a folder and with several files."""

from __future__ import annotations

import json
import tomllib

import numpy as np
import pandas as pd
import pytest
from PIL import Image
from typer.testing import CliRunner

import espin.geometry.rve
from espin.core.errors import ConfigError
from espin.imaging.batch import (IMAGE_COLUMNS, _Sample, image_files, measure_batch,
                                 pooled_statistics)
from espin.imaging.pores import PoreStructure
from espin.imaging.synthetic import render_sem

D = 0.45


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """Three small synthetic SEM images (PNG) and a file that is not an image."""
    path = tmp_path_factory.mktemp("sem")
    for seed in (1, 2, 3):
        mat = espin.geometry.rve.generate("plla", rve__size_ratio=40, rve__layers=2, rve__seed=seed,
                                          rve__max_deviation_deg=20.0).mat
        rendered = render_sem(mat, side_um=24 * D, layers=2, seed=seed)
        Image.fromarray(np.round(rendered.image * 255).astype(np.uint8)).save(path / f"mat{seed}.png")
    (path / "broken.tif").write_bytes(b"not an image")
    (path / "notes.txt").write_text("not measured: not an image suffix")
    return path, rendered.um_per_px


@pytest.fixture(scope="module")
def batch(folder, tmp_path_factory):
    """:func:`measure_batch` on the folder: its result, output folder and progress calls."""
    path, um_per_px = folder
    out = tmp_path_factory.mktemp("batch") / "out"
    seen = []
    result = measure_batch([path], out, um_per_px=um_per_px, figures=False,
                           progress=lambda i, n, row: seen.append((i, n, row["status"])))
    return result, out, seen


@pytest.mark.slow
def test_images_csv_has_a_row_per_image_and_the_failure(batch, folder):
    result, out, seen = batch
    table = pd.read_csv(out / "images.csv", keep_default_na=False, na_values=[""])
    assert list(table.columns) == list(IMAGE_COLUMNS)
    assert [p.split("/")[-1] for p in table["file"]] == ["broken.tif", "mat1.png", "mat2.png", "mat3.png"]
    assert table["status"].tolist() == ["failed", "ok", "ok", "ok"]
    assert "not a readable" in table["error"][0] and np.isnan(table["n_fibers"][0])
    assert seen == [(1, 4, "failed"), (2, 4, "ok"), (3, 4, "ok"), (4, 4, "ok")]
    assert result.n_failed == 1 and result.pooled["n_measured"] == 3
    for _, row in table[table["status"] == "ok"].iterrows():
        fibers = pd.read_csv(out / row["folder"] / "fibers.csv")
        assert row["n_fibers"] == len(fibers) and row["um_per_px"] == pytest.approx(folder[1])
        assert row["diameter_mean_um"] == pytest.approx(_population(fibers).mean(), rel=1e-5)
        assert row["tortuosity_mean"] == pytest.approx(fibers["tortuosity"].mean(), rel=1e-5)
        assert 0.2 < row["porosity"] < 0.95 and row["n_junctions"] > 0
        assert row["rows_analysed"] == "0:192"
        assert json.loads((out / row["folder"] / "run.json").read_text())["status"] == "complete"
    assert not (out / "broken").exists()
    assert json.loads((out / "run.json").read_text())["status"] == "partial"  # one image failed


def test_cli_folder_reruns_the_same_batch(batch, folder, tmp_path, measure_app):
    """``espin measure FOLDER``: progress lines, the tables, and the same files as the first run."""
    _, out, _ = batch
    path, um_per_px = folder
    again = tmp_path / "again"
    run = CliRunner().invoke(measure_app, ["measure", str(path), "--um-per-px", str(um_per_px),
                                           "--no-figures", "-o", str(again)])
    assert run.exit_code == 0, run.output
    assert "[1/4] broken.tif: not measured" in run.output and "[2/4] mat1.png: " in run.output
    assert "pooled over 3 images" in run.output and "porosity" in run.output
    for name in ["images.csv", "pooled.toml", "mat2/fibers.csv", "mat2/measurement.toml"]:
        assert (again / name).read_bytes() == (out / name).read_bytes(), name


def _population(fibers: pd.DataFrame) -> pd.Series:
    """The diameters the batch pools: of the fully visible fibers."""
    return fibers["diameter_um"][fibers["visible"].astype(bool)].dropna()


def test_pooled_statistics_and_bootstrap_intervals(batch):
    _, out, _ = batch
    pooled = tomllib.loads((out / "pooled.toml").read_text())
    table = pd.read_csv(out / "images.csv")
    ok = table[table["status"] == "ok"]
    fibers = pd.concat([pd.read_csv(out / f / "fibers.csv") for f in ok["folder"]])
    assert pooled["n_images"] == 4 and pooled["n_measured"] == 3 and pooled["n_failed"] == 1
    assert pooled["bootstrap"]["resamples"] == 2000 and pooled["bootstrap"]["unit"] == "image"
    d = pooled["diameter"]
    population = _population(fibers)
    assert d["n_fibers"] == len(population)
    assert d["population"] == "fully visible fibers (visible True)"
    assert 0 < len(population) < fibers["diameter_um"].notna().sum()  # the hidden ones left out
    assert d["mean_um"] == pytest.approx(population.mean(), rel=1e-5)
    assert d["image_sd_of_mean_um"] == pytest.approx(np.std(ok["diameter_mean_um"], ddof=1))
    for section, key in [("diameter", "mean_um"), ("diameter", "median_um"),
                         ("tortuosity", "mean"), ("porosity", "porosity"),
                         ("intersections", "density_per_um2"), ("orientation", "coherency_mean")]:
        lo, hi = pooled[section][f"ci95_{key}"]
        assert lo <= pooled[section][key] <= hi, (section, key)
        assert lo < hi, (section, key)  # three different images: the interval is not a point
    # resampling whole images: the pooled mean stays between the images' own means
    lo, hi = d["ci95_mean_um"]
    assert ok["diameter_mean_um"].min() - 1e-12 <= lo and hi <= ok["diameter_mean_um"].max() + 1e-12
    # equal areas: the area-weighted porosity is the mean of the images' porosities
    assert pooled["porosity"]["porosity"] == pytest.approx(ok["porosity"].mean())
    assert pooled["intersections"]["n_junctions"] == ok["n_junctions"].sum()


def test_interrupted_batch_is_marked_partial(folder, tmp_path):
    path, um_per_px = folder
    out = tmp_path / "out"

    def stop(i, n, row):
        if i == 2:  # killed after broken.tif (failed) and mat1.png
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        measure_batch([path], out, um_per_px=um_per_px, figures=False, progress=stop)
    assert json.loads((out / "run.json").read_text())["status"] == "failed"
    assert (out / "mat1" / "fibers.csv").exists()
    assert not (out / "images.csv").exists() and not (out / "pooled.toml").exists()


@pytest.mark.parametrize("options, match", [
    ({"um_per_px": -1.0}, "um_per_px must be"),
    ({}, "mat1.png: no scale"),
    ({"um_per_px": 0.05, "max_bend": 30.0}, "measure has no option max_bend"),
])
def test_option_errors_stop_before_any_work(folder, tmp_path, options, match):
    with pytest.raises(ConfigError, match=match):
        measure_batch([folder[0]], tmp_path / "out", **options)
    assert not (tmp_path / "out").exists()


def test_image_files_of_folders_and_files(folder, tmp_path):
    path, _ = folder
    assert [p.name for p in image_files([path])] == ["broken.tif", "mat1.png", "mat2.png", "mat3.png"]
    assert image_files([path / "mat2.png", path, path / "mat1.png"])[:2] == [path / "mat2.png",
                                                                             path / "broken.tif"]
    with pytest.raises(ConfigError, match="holds no image"):
        image_files([tmp_path])


def _sample(diameters, porosity, area, junctions):
    structure = PoreStructure(porosity=porosity, pore_diameter_um=np.array([1.0, 2.0]),
                              pore_inscribed_um=np.array([0.5, 1.0]), n_pores_on_border=0,
                              area_um2=area, n_junctions=junctions, fiber_length_um=100.0)
    d = np.asarray(diameters, float)
    return _Sample(diameter_um=d, orientation_deg=np.full(len(d), 170.0), tortuosity=np.ones(len(d)),
                   structure=structure, coherency=0.5, n_crossing=0, u_turn_fraction=np.nan)


def test_pooled_statistics_weighting_and_reproducibility():
    samples = [_sample([1.0, 1.0, 1.0], 0.2, 100.0, 10), _sample([3.0], 0.6, 300.0, 90)]
    pooled = pooled_statistics(samples)
    assert pooled["diameter"]["mean_um"] == pytest.approx(1.5)  # each fiber once
    assert pooled["diameter"]["image_sd_of_mean_um"] == pytest.approx(np.std([1.0, 3.0], ddof=1))
    assert pooled["porosity"]["porosity"] == pytest.approx((20 + 180) / 400)  # area-weighted
    assert pooled["intersections"]["density_per_um2"] == pytest.approx(100 / 400)
    lo, hi = pooled["diameter"]["ci95_mean_um"]
    assert lo == pytest.approx(1.0) and hi == pytest.approx(3.0)  # all of one image or the other
    assert pooled["orientation"]["axial_mean_deg"] == pytest.approx(170.0)
    assert pooled["orientation"]["resultant_length"] == pytest.approx(1.0)
    assert np.isnan(pooled["crossing"]["u_turn_fraction"])
    assert pooled_statistics(samples) == pooled  # fixed seed
    assert pooled_statistics(samples, seed=1)["diameter"]["ci95_median_um"] is not None
    single = pooled_statistics(samples[:1])
    assert single["diameter"]["ci95_mean_um"] == [1.0, 1.0] and np.isnan(single["porosity"]["image_sd"])


def test_cli_folder_default_and_several_files(folder, tmp_path, measure_app, monkeypatch):
    path, um_per_px = folder
    monkeypatch.chdir(tmp_path)
    files = CliRunner().invoke(measure_app, ["measure", str(path / "mat1.png"), str(path / "mat3.png"),
                                             "--um-per-px", str(um_per_px), "--no-figures", "-q"])
    assert files.exit_code == 0, files.output
    out = tmp_path / f"{path.name}_measure"  # default: <the images' folder name>_measure
    assert pd.read_csv(out / "images.csv")["folder"].tolist() == ["mat1", "mat3"]
    assert (out / "mat3" / "fibers.csv").exists()
    assert files.output.strip() == ""  # -q: no progress, no table
    # the output-folder policy: another run's folder is refused, unless overwrite
    again = CliRunner().invoke(measure_app, ["measure", str(path), "--um-per-px", str(um_per_px)])
    assert again.exit_code == 2 and "another measure-batch run" in again.output
    with pytest.raises(ConfigError, match="another measure-batch run"):
        measure_batch([path / "mat2.png"], out, um_per_px=um_per_px, figures=False)
    result = measure_batch([path / "mat2.png"], out, um_per_px=um_per_px, figures=False,
                           overwrite=True)
    assert result.images["folder"].tolist() == ["mat2"]
    assert not (out / "mat1").exists()  # the earlier run's image folders were cleared

    broken = CliRunner().invoke(measure_app, ["measure", str(path / "broken.tif"), str(path / "broken.tif"),
                                              str(path / "notes.txt"), "--um-per-px", "0.05", "-o", "bad"])
    assert broken.exit_code == 3 and "none of the 2 images could be measured" in broken.output


@pytest.mark.slow
def test_cli_single_image_writes_the_orientation_map_and_porosity(folder, tmp_path, measure_app):
    path, um_per_px = folder
    out = tmp_path / "one"
    run = CliRunner().invoke(measure_app, ["measure", str(path / "mat2.png"), "--um-per-px",
                                           str(um_per_px), "-o", str(out)])
    assert run.exit_code == 0, run.output
    assert {p.name for p in out.iterdir()} == {"fibers.csv", "measurement.toml", "histograms.png",
                                               "overlay.png", "orientation_map.png", "run.json"}
    assert "porosity" in run.output and "intersections" in run.output
    overlay = np.asarray(Image.open(out / "overlay.png"))
    assert overlay.shape[1] == 1000 and overlay.shape[0] > 1000  # drawn at 1000 px, key below


def test_folder_names_differ_ignoring_case():
    from pathlib import Path

    from espin.imaging.batch import _folder_names

    names = _folder_names([Path("x/a.tif"), Path("y/A.png"), Path("x/b.tif"), Path("y/c.tif"), Path("z/c.tif")])
    assert names == ["a_tif", "A_png", "b", "c_tif_4", "c_tif_5"]
    assert len({n.casefold() for n in names}) == len(names)


def test_an_unexpected_error_on_one_image_is_reported_and_the_batch_goes_on(folder, tmp_path, monkeypatch):
    import functools
    from pathlib import Path

    import espin.imaging.batch as batch_module

    path, um_per_px = folder
    real = batch_module.measure

    @functools.wraps(real)  # the batch reads measure's options from its signature
    def flaky(image, **options):
        if Path(image).name == "mat2.png":
            raise RuntimeError("a bug")
        return real(image, **options)

    monkeypatch.setattr(batch_module, "measure", flaky)
    result = measure_batch([path / "mat1.png", path / "mat2.png"], tmp_path / "out", um_per_px=um_per_px, figures=False)
    table = pd.read_csv(tmp_path / "out" / "images.csv", keep_default_na=False, na_values=[""])
    assert table["status"].tolist() == ["ok", "failed"]
    assert table["error"][1] == "unexpected RuntimeError: a bug (please report it)"
    assert result.pooled["n_measured"] == 1
