"""Bad curve files, one case each: a clear espin error naming the file (and the line), or a
warning where the curve is legitimate but its units look wrong; and the formats read."""

from __future__ import annotations

import os
import re
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import write_case_file
from typer.testing import CliRunner

from espin.analysis import experiments
from espin.analysis.experiments import (
    Curve,
    CurveFileError,
    CurveWarning,
    average_curves,
    read_curve,
)
from espin.core.errors import ConfigError, InputError

PNG = b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x00\x00\x10"
LONG_SECRET = "root:x:0:0:root:/root:/bin/bash"  # must never be echoed by a message


def _sparse_over_the_limit(path: Path) -> None:
    with path.open("wb") as stream:  # a hole: nothing written to disk but the last byte
        stream.seek(experiments.MAX_FILE_BYTES)
        stream.write(b"\n")


def _fifo(path: Path) -> None:
    if not hasattr(os, "mkfifo"):
        pytest.skip("no FIFOs on this platform")
    os.mkfifo(path)


# (id, file contents or a writer, read_curve options, limits to set, error type, message regex)
BAD = [
    ("line over the csv field limit", "strain,stress\n0,0\n" + "1" * 200_000 + ",1\n", {}, {},
     CurveFileError, r"line 3: 200,002 characters, over the limit of 4096"),
    ("more rows than the limit (2 million rows, limit lowered)",
     "strain,stress\n" + "".join(f"{k / 100},{k}\n" for k in range(12)), {}, {"MAX_DATA_ROWS": 10},
     CurveFileError, r"more than 10 data lines, the limit for one curve"),
    ("file over the byte limit (sparse)", _sparse_over_the_limit, {}, {},
     CurveFileError, r"67,108,865 bytes, over the limit of 64 MiB"),
    ("file over a lowered byte limit", "strain,stress\n0,0\n0.01,1\n" * 20, {}, {"MAX_FILE_BYTES": 100},
     CurveFileError, r"specimen_7.csv: 500 bytes, over the limit of 100 bytes for a curve file"),
    ("/dev/zero", Path("/dev/zero"), {}, {}, CurveFileError, r"/dev/zero: not a regular file"),
    ("a FIFO", _fifo, {}, {}, CurveFileError, r"not a regular file \(a device, pipe or socket\)"),
    ("a directory", lambda path: path.mkdir(), {}, {}, CurveFileError, r"a directory, not a curve file"),
    ("multi-character delimiter", "0;0\n0.01;1\n", {"delimiter": ";;"}, {},
     ConfigError, r"delimiter \(--delimiter\): one character"),
    ("letter as delimiter", "0;0\n0.01;1\n", {"delimiter": "e"}, {}, ConfigError, r"not a letter"),
    ("decimal mark not . or ,", "0;0\n0.01;1\n", {"decimal": ";"}, {}, ConfigError, r"decimal \(--decimal\)"),
    ("negative skip_rows", "0;0\n0.01;1\n", {"skip_rows": -1}, {}, ConfigError, r"skip_rows"),
    ("1e400", "0,0\n0.01,1e400\n", {}, {}, CurveFileError,
     r"line 2, field 2 \(stress column 1\): '1e400' is out of range"),
    ("400-digit number", "0,0\n0.01," + "9" * 400 + "\n", {}, {}, CurveFileError,
     r"line 2, field 2 \(stress column 1\): a 400-character field is out of range"),
    ("finite but huge", "0,0\n1e13,1\n", {}, {}, CurveFileError, r"line 2, field 1 .* out of range"),
    ("all-zero stress", "0,0\n0.01,0\n0.02,0\n", {}, {}, CurveFileError, r"no positive stress"),
    ("negative stress", "strain,stress\n0,0\n0.01,-1\n0.02,-2\n", {}, {}, CurveFileError,
     r"no positive stress in the stress column 'stress' \(all 3 values are <= 0\)"),
    ("strain never above 0", "-0.02,1\n-0.01,2\n0,3\n", {}, {}, CurveFileError, r"never rises above 0"),
    ("NaN", "strain,stress\n0,0\n0.01,1\n0.02,NaN\n", {}, {}, CurveFileError,
     r"line 4, field 2 \(stress column 'stress'\): 'NaN' is not a finite number"),
    ("infinity in the strain", "0,0\n-inf,1\n", {}, {}, CurveFileError,
     r"line 2, field 1 \(strain column 0\): '-inf' is not a finite number"),
    ("only a header", "strain,stress\n", {}, {}, CurveFileError,
     r"0 data line\(s\); a curve needs at least 2"),
    ("one data row", "strain,stress\n0.01,1\n", {}, {}, CurveFileError, r"1 data line\(s\)"),
    ("non-monotonic strain", "0,0\n0.02,1\n0.03,2\n0.025,3\n", {}, {}, CurveFileError,
     r"line 4: strain 0.025 does not increase from 0.03 on line 3"),
    ("duplicate strains", "0,0\n0.01,1\n0.01,1\n", {}, {}, CurveFileError,
     r"line 3: strain 0.01 does not increase"),
    ("text in a numeric column", "strain,stress\n0,0\n0.01,abc\n", {}, {}, CurveFileError,
     r"line 3, field 2 \(stress column 'stress'\): 'abc' is not a number"),
    ("empty field", "0,0\n0.01,\n", {}, {}, CurveFileError, r"line 2, field 2 \(stress column 1\): empty"),
    ("mixed delimiters", "strain;stress\n0;0\n0.01,1\n", {}, {}, CurveFileError,
     r"line 3: 1 field\(s\) separated by ';', but the stress column 'stress' is field 2"),
    ("mixed decimal marks", "strain;stress\n0;0\n0.01;1,5\n", {}, {}, CurveFileError,
     r"line 3, field 2 .*'1,5' is not a number .*a decimal comma\?"),
    ("binary file (PNG bytes)", PNG, {}, {}, CurveFileError, r"not a text file \(it holds NUL bytes"),
    ("control characters", "0,0\n0.01,1\x1b[2J\n", {}, {}, CurveFileError, r"line 2: a control character"),
    ("zip archive named .csv", b"PK\x03\x04\x14\x00\x00\x00", {}, {}, CurveFileError, r"a zip archive"),
    ("old .xls workbook", b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1" + b"\x00" * 8, {}, {}, CurveFileError,
     r"old-format Excel \(.xls\)"),
    ("broken UTF-16", b"\xff\xfe0\x00,\x00\x00", {}, {}, CurveFileError, r"not UTF-16"),
    ("empty file", "", {}, {}, CurveFileError, r"no data"),
    ("only comments and blank lines", "# Instron export\n\n  # nothing measured\n", {}, {}, CurveFileError,
     r"no data"),
    ("unbalanced quote", 'strain,stress\n"0,0\n0.01,1\n0.02,2\n', {}, {}, CurveFileError,
     r"line 2: a quoted field does not end on its line"),
    ("missing file", None, {}, {}, CurveFileError, r"cannot read the file"),
    ("a long field is not echoed", "0,0\n0.01," + "x" * 50 + "\n", {}, {}, CurveFileError,
     r"line 2, field 2 \(stress column 1\): a 50-character field is not a number"),
    ("a password file is not echoed", LONG_SECRET + "\ndaemon:x:1:1:daemon:/usr/sbin:/usr/sbin/nologin\n",
     {}, {}, CurveFileError, r"line 1: the header has no column .*\(a 31-character name\)"),
    ("two columns named strain", "strain,Strain,stress_MPa\n0,0,0\n0.01,0.02,1\n", {}, {}, CurveFileError,
     r"line 1: the header names columns 0, 1 alike \('strain', any case\): choose the strain column"),
    ("two columns named as the chosen one", "strain,load,load\n0,0,0\n0.01,1,2\n", {"stress_column": "load"}, {},
     CurveFileError, r"line 1: the header names columns 1, 2 alike"),
    ("a stress column name that is not there", "strain,stress\n0,0\n0.01,1\n", {"stress_column": "load"}, {},
     CurveFileError, r"line 1: no stress column named 'load'"),
]


@pytest.mark.parametrize(("contents", "options", "limits", "error", "message"),
                         [case[1:] for case in BAD], ids=[case[0] for case in BAD])
def test_bad_curve_is_a_clear_error(tmp_path, monkeypatch, contents, options, limits, error, message):
    for name, value in limits.items():
        monkeypatch.setattr(experiments, name, value)
    path = write_case_file(tmp_path / "specimen_7.csv", contents)
    with pytest.raises(error, match=message) as info:
        read_curve(path, **options)
    text = str(info.value)
    if error is CurveFileError:
        assert isinstance(info.value, InputError) and info.value.exit_code == 3
        assert str(path) in text  # names the file
    else:
        assert info.value.exit_code == 2  # a usage error: the option is named instead
    if isinstance(contents, str):  # never echoes more than a short field of the file
        assert not [piece for piece in re.split(r"[\s,;]+", contents) if len(piece) > 20 and piece in text]


def test_workbook_without_openpyxl_says_how_to_install_it(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "openpyxl", None)  # import openpyxl fails
    path = tmp_path / "specimen.xlsx"
    path.write_bytes(_empty_zip())
    with pytest.raises(CurveFileError, match=r'specimen.xlsx: reading an .xlsx workbook needs the optional '
                                             r'package openpyxl: pip install "espin\[xlsx\]"'):
        read_curve(path)


def test_broken_workbook(tmp_path):
    path = tmp_path / "specimen.xlsx"
    path.write_bytes(b"PK\x03\x04 not really a zip")
    with pytest.raises(CurveFileError, match=r"specimen.xlsx: not a readable .xlsx workbook"):
        read_curve(path)


def _empty_zip() -> bytes:
    import io
    import zipfile

    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("xl/workbook.xml", "<workbook/>")
    return buffer.getvalue()


def _workbook_bytes(tmp_path: Path, rows: dict[str, object] | None = None) -> bytes:
    """An .xlsx file: header in row 3 (B, C), points below with a blank row 5."""
    import openpyxl

    book = openpyxl.Workbook()
    sheet = book.active
    cells = {"A1": "Instron 5969", "B3": "Strain", "C3": "Stress [MPa]", "B4": 0.0, "C4": 0.0,
             "B6": 0.01, "C6": 1.5, "B7": 0.02, "C7": 3.0} | (rows or {})
    for name, value in cells.items():
        sheet[name] = value
    path = tmp_path / "written.xlsx"
    book.save(path)
    return path.read_bytes()


def test_workbook_first_sheet_rows_and_errors(tmp_path):
    pytest.importorskip("openpyxl")
    path = tmp_path / "specimen.xlsx"
    path.write_bytes(_workbook_bytes(tmp_path))
    curve = read_curve(path, skip_rows=1)
    assert np.array_equal(curve.strain, [0.0, 0.01, 0.02])
    assert np.array_equal(curve.stress_MPa, [0.0, 1.5, 3.0])
    path.write_bytes(_workbook_bytes(tmp_path, {"C6": "n/a"}))
    with pytest.raises(CurveFileError, match=r"specimen.xlsx, row 6, column C \(stress column 'Stress "
                                             r"\[MPa\]'\): 'n/a' is not a number"):
        read_curve(path, skip_rows=1)


# --------------------------------------------------------------------------------------------
# Units: a warning naming the file where the curve may be right, a refusal where it cannot be
# --------------------------------------------------------------------------------------------
WARNED = [
    ("percent read as fractions", "strain,stress\n0,0\n1.5,3\n3,6\n", {},
     r"largest strain is 3, i.e. 300 %.*--percent-strain"),
    ("a percent header read as fractions", "Strain [%],Stress [MPa]\n0,0\n0.5,3\n0.9,6\n", {},
     r"the header names it in percent: if it is in percent, pass --percent-strain"),
    ("fractions read as percent", "strain,stress\n0,0\n0.01,3\n0.02,6\n", {"percent_strain": True},
     r"ends at 0.02 % strain: if it holds fractions .* leave --percent-strain out"),
    ("stress in kPa", "strain,Stress (kPa)\n0,0\n0.01,3000\n", {},
     r"labelled in kPa, but espin reads stress in MPa"),
    ("stress in Pa, unlabelled", "0,0\n0.01,3e6\n", {}, r"stresses up to 3e\+06 MPa .* Pa or kPa\?"),
    ("extension in mm", "extension_mm,stress\n0,0\n0.5,3\n", {}, r"labelled in mm, a length"),
]


@pytest.mark.parametrize(("text", "options", "message"), [case[1:] for case in WARNED],
                         ids=[case[0] for case in WARNED])
def test_units_that_look_wrong_are_warned_about(tmp_path, text, options, message):
    path = tmp_path / "specimen_3.csv"
    path.write_text(text)
    with pytest.warns(CurveWarning) as found:
        curve = read_curve(path, **options)
    messages = [str(w.message) for w in found]
    assert any(re.search(message, m) for m in messages), messages
    assert all(m.startswith(f"{path}: ") for m in messages)
    assert curve.strain.size >= 2  # read as asked


def test_plausible_units_give_no_warning(tmp_path):
    path = tmp_path / "fine.csv"
    path.write_text("Strain [%];Stress [MPa]\n0;0\n1,5;3\n3,0;6\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        curve = read_curve(path, percent_strain=True)
    assert np.allclose(curve.strain, [0.0, 0.015, 0.03])


def test_averaging_percent_with_fractions_is_refused():
    strain = np.linspace(0.0, 0.3, 7)
    fraction = Curve(strain=strain, stress_MPa=10 * strain, source="fraction.csv")
    percent = Curve(strain=100 * strain, stress_MPa=10 * strain, source="percent.csv")
    with pytest.raises(CurveFileError, match=r"differ by a factor of 100: percent.csv ends at strain 30, "
                                             r"fraction.csv at 0.3.*percent and others in fractions"):
        average_curves([fraction, percent])
    shorter = Curve(strain=strain / 19, stress_MPa=10 * strain, source="short.csv")
    assert average_curves([fraction, shorter]).n.min() == 2  # a factor of 19: still averaged


# --------------------------------------------------------------------------------------------
# Formats read: decimal comma, encodings, line ends, quoted names
# --------------------------------------------------------------------------------------------
GOOD = [
    ("decimal comma, semicolons", b"0,01;1,5\n0,02;3\n", {}),
    ("decimal comma, tabs and header", b"Strain\tStress [MPa]\n0,01\t1,5\n0,02\t3,0\n", {}),
    ("decimal comma, spaces", b"0,01 1,5\n0,02 3\n", {}),
    ("decimal comma given", b"0,01;1,5\n0,02;3\n", {"decimal": ",", "delimiter": ";"}),
    ("UTF-8 with BOM", "\ufeffstrain,stress\n0.01,1.5\n0.02,3\n".encode(), {}),
    ("UTF-16 LE with BOM", b"\xff\xfe" + "strain,stress\n0.01,1.5\n0.02,3\n".encode("utf-16-le"), {}),
    ("UTF-16 BE with BOM", b"\xfe\xff" + "strain,stress\n0.01,1.5\n0.02,3\n".encode("utf-16-be"), {}),
    ("Latin-1 export", "Dehnung µm/m;Spannung\n0,01;1,5\n0,02;3\n".encode("latin-1"),
     {"strain_column": 0, "stress_column": 1}),
    ("CRLF line ends", b"strain,stress\r\n0.01,1.5\r\n0.02,3\r\n", {}),
    ("CR line ends", b"strain,stress\r0.01,1.5\r0.02,3\r", {}),
    ("quoted names with commas", b'"time, s","strain","stress, MPa"\n0,0.01,1.5\n1,0.02,3\n',
     {"stress_column": "stress, MPa"}),
]


@pytest.mark.parametrize(("data", "options"), [case[1:] for case in GOOD], ids=[case[0] for case in GOOD])
def test_formats_that_are_read(tmp_path, data, options):
    path = tmp_path / "specimen.csv"
    path.write_bytes(data)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        curve = read_curve(path, **options)
    assert np.allclose(curve.strain, [0.01, 0.02]) and np.allclose(curve.stress_MPa, [1.5, 3.0])


def test_a_curve_at_the_row_limit_is_read(tmp_path, monkeypatch):
    monkeypatch.setattr(experiments, "MAX_DATA_ROWS", 5)
    path = tmp_path / "five.csv"
    path.write_text("strain,stress\n" + "".join(f"{k / 100},{k}\n" for k in range(1, 6)))
    assert read_curve(path).strain.size == 5
    path.write_text("".join(f"{k / 100},{k}\n" for k in range(1, 7)))  # no header: 6 points
    with pytest.raises(CurveFileError, match="more than 5 data lines"):
        read_curve(path)


# --------------------------------------------------------------------------------------------
# espin properties: exit code 3 and one line, never a traceback
# --------------------------------------------------------------------------------------------
def _properties(*args: object):
    from espin.cli import app

    return CliRunner().invoke(app, ["properties", *map(str, args)])


@pytest.mark.parametrize(("name", "contents", "message"), [
    ("image.csv", PNG, "not a text file"),
    ("folder", None, "a directory, not a curve file"),
    ("nan.csv", b"strain,stress\n0,0\n0.01,nan\n", "line 3, field 2"),
    ("zero.csv", b"strain,stress\n0,0\n0.01,0\n", "no positive stress"),
    ("long.csv", b"0,0\n" + b"7" * 200_000 + b",1\n", "line 2: 200,002 characters"),
])
def test_properties_command_bad_file_exit_3(tmp_path, name, contents, message):
    path = tmp_path / name
    if contents is None:
        path.mkdir()
    else:
        path.write_bytes(contents)
    result = _properties(path)
    assert result.exit_code == 3, result.output
    assert isinstance(result.exception, SystemExit) and "Traceback" not in result.output
    assert f"error: {path}" in result.output and message in result.output
    assert "7777777777777777777777" not in result.output


def test_properties_command_units(tmp_path):
    strain = np.linspace(0.0, 0.06, 13)
    stress = np.minimum(200 * strain, 6.0) + 5 * np.maximum(strain - 0.03, 0.0)
    for name, column in (("fraction.csv", strain), ("percent.csv", 100 * strain)):
        np.savetxt(tmp_path / name, np.c_[column, stress], delimiter=",", header="strain,stress", comments="")
    mixed = _properties(tmp_path / "fraction.csv", tmp_path / "percent.csv")
    assert mixed.exit_code == 3 and "differ by a factor of 100" in mixed.output
    assert "warning: " + str(tmp_path / "percent.csv") in mixed.output and "--percent-strain" in mixed.output
    assert "Traceback" not in mixed.output
    usage = _properties(tmp_path / "fraction.csv", "--delimiter", ";;")
    assert usage.exit_code == 2 and "--delimiter" in usage.output
    comma = tmp_path / "comma.csv"
    comma.write_text("".join(f"{100 * e:.6g};{s:.6g}\n".replace(".", ",") for e, s in zip(strain, stress)))
    result = _properties(comma, "--percent-strain", "--decimal", ",")
    assert result.exit_code == 0, result.output
    assert "200" in result.output and "warning" not in result.output
