"""Experimental curves from CSV files: formats, bad files, averaging of specimens."""

from __future__ import annotations

import numpy as np
import pytest

from espin.analysis.experiments import (
    AveragedCurve,
    Curve,
    CurveFileError,
    CurveWarning,
    average_curves,
    read_curve,
)
from espin.core.errors import EspinError


def write(tmp_path, text, name="curve.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_plain_two_columns(tmp_path):
    curve = read_curve(write(tmp_path, "0,0\n0.01,2.0\n0.02,4.0\n"))
    assert np.array_equal(curve.strain, [0.0, 0.01, 0.02])
    assert np.array_equal(curve.stress_MPa, [0.0, 2.0, 4.0])
    assert curve.source.endswith("curve.csv")


def test_header_names_delimiters_and_percent(tmp_path):
    text = "# exported by the testing machine\ntime_s;Strain [%];Stress (MPa)\n0;0;0\n1;1.5;3\n2;3,0;6\n"
    # A decimal comma in one field among decimal points is an error: ';' is the detected delimiter.
    with pytest.raises(CurveFileError, match=r"line 5, field 2 \(strain column 'Strain \[%\]'\): '3,0' is "
                                             r"not a number .*a decimal comma\?"):
        read_curve(write(tmp_path, text), strain_column="Strain [%]", stress_column="stress (mpa)")
    path = write(tmp_path, text.replace("3,0", "3.0"))
    curve = read_curve(path, strain_column="Strain [%]", stress_column="stress (mpa)", percent_strain=True)
    assert np.allclose(curve.strain, [0.0, 0.015, 0.03])
    assert np.allclose(curve.stress_MPa, [0.0, 3.0, 6.0])
    by_index = read_curve(path, strain_column=1, stress_column=2, percent_strain=True)
    assert np.array_equal(by_index.strain, curve.strain)


@pytest.mark.parametrize("delimiter", ["\t", " ", ","])
def test_delimiter_detected_and_given(tmp_path, delimiter):
    rows = ["strain stress", "0 0", "0.01 1.5", "0.02 3"]
    text = "\n".join(r.replace(" ", delimiter) for r in rows) + "\n"
    assert np.allclose(read_curve(write(tmp_path, text)).stress_MPa, [0, 1.5, 3])
    assert np.allclose(read_curve(write(tmp_path, text), delimiter=delimiter).strain, [0, 0.01, 0.02])


THREE_COLUMNS = "0,0,0\n1,0.01,2\n2,0.02,4\n"  # time [s], strain, stress [MPa]


@pytest.mark.parametrize("header", [
    "time_s,strain,stress",         # 'stress' is a default name: not column 1 (the strain)
    "time_s,Strain,Stress_MPa",     # default names in any case: not column 0 (the time)
    "Time_s,STRAIN,Stress [MPa]",
    "time_s,strain,stress (MPa)",
])
def test_default_columns_are_found_by_name_in_any_case(tmp_path, header):
    curve = read_curve(write(tmp_path, header + "\n" + THREE_COLUMNS))
    assert np.array_equal(curve.strain, [0.0, 0.01, 0.02])
    assert np.array_equal(curve.stress_MPa, [0.0, 2.0, 4.0])


def test_no_default_by_position_in_a_wide_header(tmp_path):
    path = write(tmp_path, "time_s,extension_mm,load_N\n" + THREE_COLUMNS, "wide.csv")
    with pytest.raises(CurveFileError, match=r"wide.csv, line 1: the header has no column with a "
                       r"default strain name .* 3 columns \('time_s', 'extension_mm', 'load_N'\).*"
                       r"--strain-column") as info:
        read_curve(path)
    assert "time_s" in str(info.value)
    with pytest.raises(CurveFileError, match=r"default stress name \(stress_MPa, .*--stress-column"):
        read_curve(path, strain_column="extension_mm")
    with pytest.warns(CurveWarning) as found:  # a length against a force: said, then read as asked
        curve = read_curve(path, strain_column="extension_mm", stress_column="LOAD_N")
    messages = " ".join(str(w.message) for w in found)
    assert "labelled in mm, a length" in messages and "labelled in N, a force" in messages
    assert np.array_equal(curve.stress_MPa, [0.0, 2.0, 4.0])
    # Two columns keep the positional default whatever their names.
    two = read_curve(write(tmp_path, "extension,load\n0,0\n0.01,2\n", "two.csv"))
    assert np.array_equal(two.strain, [0.0, 0.01]) and np.array_equal(two.stress_MPa, [0.0, 2.0])


@pytest.mark.parametrize(("text", "options", "message"), [
    ("time_s,strain\n0,0\n1,0.01\n", {},
     r"line 1: strain and stress would both be read from column 'strain' \(index 1\)"),
    ("0,0,0\n1,0.01,2\n", {"strain_column": 1}, r"both be read from column 1; .*--stress-column"),
    ("time_s,strain,stress\n0,0,0\n1,0.01,2\n", {"stress_column": "STRAIN"}, "both be read from column 'strain'"),
])
def test_strain_and_stress_in_one_column_is_an_error(tmp_path, text, options, message):
    with pytest.raises(CurveFileError, match=message) as info:
        read_curve(write(tmp_path, text, "same.csv"), **options)
    assert "same.csv" in str(info.value)


def test_skip_rows_preamble(tmp_path):
    text = "Instron 5969\nspecimen 2, width 10 mm\n\nstrain,stress\n0,0\n0.01,1\n"
    curve = read_curve(write(tmp_path, text), skip_rows=2)
    assert np.array_equal(curve.strain, [0.0, 0.01])


@pytest.mark.slow
def test_espin_curve_csv_is_read_by_its_column_names(tmp_path):
    from espin.mechanics.run import simulate

    result = simulate("plla", tmp_path / "run", rve__size_ratio=30, rve__layers=2, loading__steps=4,
                      loading__max_strain=0.04)
    curve = read_curve(tmp_path / "run" / "curve.csv")
    assert np.array_equal(curve.strain, result.strain)  # 17 significant digits: exact
    assert np.array_equal(curve.stress_MPa, result.stress())


@pytest.mark.parametrize(
    ("text", "options", "message"),
    [
        ("", {}, "no data"),
        ("# only a comment\n\n", {}, "no data"),
        ("strain,stress\n", {}, "0 data line"),
        ("0,0\n0.01,abc\n0.02,2\n", {}, r"line 2, field 2 \(stress column 1\): 'abc' is not a number"),
        ("strain,stress\n0,0\n0.01,nan\n", {}, r"line 3, field 2 \(stress column 'stress'\): 'nan' is not a finite"),
        ("0,0\n0.02,1\n0.01,2\n", {}, "line 3: strain 0.01 does not increase from 0.02 on line 2"),
        ("0,0\n0.01,1\n0.01,2\n", {}, "line 3: strain 0.01 does not increase"),
        ("0,0\n0.01\n", {}, "line 2: 1 field"),
        ("strain,stress\n0,0\n0.01,1\n", {"stress_column": "load"}, "line 1: no stress column named 'load'"),
        ("0,0\n0.01,1\n", {"stress_column": "load"}, "no header"),
        ("0,0,0\n0.01,1,1\n", {"stress_column": 5}, "line 1: 3 field"),
    ],
)
def test_bad_files_name_the_line(tmp_path, text, options, message):
    path = write(tmp_path, text, "bad.csv")
    with pytest.raises(CurveFileError, match=message) as info:
        read_curve(path, **options)
    assert "bad.csv" in str(info.value)
    assert isinstance(info.value, EspinError)


def test_missing_and_binary_files(tmp_path):
    with pytest.raises(CurveFileError, match="missing.csv: cannot read the file"):
        read_curve(tmp_path / "missing.csv")
    binary = tmp_path / "curve.xlsx"
    binary.write_bytes(b"PK\x03\x04\xff\xfe\x00")
    with pytest.raises(CurveFileError, match="curve.xlsx: not a readable .xlsx workbook"):
        read_curve(binary)
    binary = binary.with_suffix(".csv")
    binary.write_bytes(b"0,0\n\x00\xff\n")
    with pytest.raises(CurveFileError, match="curve.csv: not a text file"):
        read_curve(binary)


def specimen(scale, end, n=41):
    strain = np.linspace(0.0, end, n)
    return Curve(strain=strain, stress_MPa=scale * (strain + strain**2), source=f"s{scale}")


def test_average_of_analytic_specimens():
    # Stress = k (e + e^2) with k = 1, 2, 3: mean 2 (e + e^2), sample sd (e + e^2) (ddof = 1).
    # Each is sampled on its own grid (spacing h up to 0.025), so specimen k carries the linear
    # interpolation error of k e^2, at most k h^2 / 4 <= 3 * 0.025^2 / 4, which bounds both.
    curves = [specimen(1.0, 0.30), specimen(2.0, 0.25, 51), specimen(3.0, 0.40, 17)]
    average = average_curves(curves)
    e = average.strain
    assert e[0] == 0.0 and e[-1] == 0.25 and len(e) == 101
    assert np.all(average.n == 3)
    exact = e + e**2
    assert np.allclose(average.mean_MPa, 2 * exact, atol=3 * 0.025**2 / 4)
    assert np.allclose(average.sd_MPa, exact, atol=3 * 0.025**2 / 4)
    assert average.sources == ("s1.0", "s2.0", "s3.0")


def test_user_grid_counts_the_covering_specimens():
    curves = [specimen(1.0, 0.30), specimen(3.0, 0.20)]
    average = average_curves(curves, grid=[0.1, 0.2, 0.25, 0.3])
    assert list(average.n) == [2, 2, 1, 1]
    assert np.isnan(average.sd_MPa[2:]).all() and np.isfinite(average.sd_MPa[:2]).all()
    assert average.mean_MPa[-1] == pytest.approx(0.3 + 0.09)
    with pytest.raises(CurveFileError, match="0.5 lies outside"):
        average_curves(curves, grid=[0.1, 0.5])
    with pytest.raises(CurveFileError, match="increasing"):
        average_curves(curves, grid=[0.2, 0.1])


def test_specimens_without_common_range():
    late = Curve(strain=np.array([0.2, 0.3]), stress_MPa=np.array([1.0, 2.0]), source="late")
    with pytest.raises(CurveFileError, match="share no strain range"):
        average_curves([specimen(1.0, 0.1), late])
    with pytest.raises(CurveFileError, match="no curves"):
        average_curves([])


def test_averaged_curve_round_trips(tmp_path):
    average = average_curves([specimen(1.0, 0.3), specimen(2.0, 0.3)], n_points=11)
    path = average.to_csv(tmp_path / "out" / "average.csv")
    assert path.read_text().splitlines()[0] == "strain,mean_MPa,sd_MPa,n"
    back = read_curve(path)
    assert np.array_equal(back.strain, average.strain)
    assert np.array_equal(back.stress_MPa, average.mean_MPa)
    assert isinstance(average, AveragedCurve)
    assert np.array_equal(read_curve(path, stress_column="sd_MPa").stress_MPa, average.sd_MPa)
