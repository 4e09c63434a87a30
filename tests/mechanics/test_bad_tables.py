"""Bad loading tables (``loading.lateral.transverse_csv``, ``loading.path_csv``), one case each:
an InputError (exit 3) naming the key, the file and the line, never echoing the file; a file
that does not exist is a ConfigError (exit 2), as for every file a config references."""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from conftest import write_case_file
from typer.testing import CliRunner

from espin.core.config import load_config
from espin.core.errors import ConfigError, InputError
from espin.mechanics import loading
from espin.mechanics.loading import load_program

SECRET = "hunter2-topsecret-password-0451"  # a long field: never echoed
PNG = b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x00\x00\x10"

TABLES = {  # key: (columns, three good rows, the program that reads the table)
    "loading.lateral.transverse_csv": (
        ("axial_strain", "transverse_strain"), [(0, 0), (0.05, -0.02), (0.2, -0.1)],
        lambda path: {"lateral": {"transverse_csv": str(path)}, "max_strain": 0.1, "steps": 1}),
    "loading.path_csv": (
        ("time_s", "F11", "F12", "F21", "F22"), [(0, 1, 0, 0, 1), (10, 1.1, 0.05, 0, 0.98), (30, 1.2, 0, 0, 1)],
        lambda path: {"test": "path", "path_csv": str(path)}),
}


def _program(key: str, path: Path):
    options = TABLES[key][2](path)
    return load_program(load_config(None, {f"loading.{k}": v for k, v in options.items()}).loading)


def _table(columns, rows) -> str:
    return ",".join(columns) + "\n" + "".join(",".join(map(str, row)) + "\n" for row in rows)


def _set(rows, row: int, column: int, text: str) -> list[list[str]]:
    """The rows as text with one cell replaced."""
    out = [[str(v) for v in r] for r in rows]
    out[row][column] = text
    return out


def _sparse_over_the_limit(path: Path) -> None:
    with path.open("wb") as stream:  # a hole: nothing written to disk but the last byte
        stream.truncate(loading.MAX_TABLE_BYTES + 1)


def _fifo(path: Path) -> None:
    if not hasattr(os, "mkfifo"):
        pytest.skip("no FIFOs on this platform")
    os.mkfifo(path)


Maker = Callable[[tuple, list], object]
# (id, contents from (columns, rows): text, bytes, a writer or a fixed path; limits to set; message regex)
BAD: list[tuple[str, Maker, dict, str]] = [
    ("binary file", lambda c, r: PNG, {}, r"not a text file \(it holds NUL bytes"),
    ("NUL byte in a line", lambda c, r: _table(c, r).replace("\n0", "\n\x000", 1).encode(), {},
     r"not a text file \(it holds NUL bytes"),
    ("control character", lambda c, r: _table(c, r) + "\x1b[2J\n", {}, r"line 5: a control character"),
    ("Latin-1 byte in a cell", lambda c, r: _table(c, _set(r, 1, 1, "1\xe9")).encode("latin-1"), {},
     r"line 3, column 2 \(\w+\): not a number"),
    ("/dev/zero", lambda c, r: Path("/dev/zero"), {}, r"/dev/zero: not a regular file"),
    ("a directory", lambda c, r: Path.mkdir, {}, r"a directory, not a loading table; expected a CSV table"),
    ("a FIFO", lambda c, r: _fifo, {}, r"not a regular file \(a device, pipe or socket\)"),
    ("file over the byte limit (sparse)", lambda c, r: _sparse_over_the_limit, {},
     r"16,777,217 bytes, over the limit of 16 MiB for a loading table"),
    ("over-long line", lambda c, r: _table(c, _set(r, 1, 1, "1" * 5000)), {},
     r"line 3: 5,0\d\d characters, over the limit of 4096 for a line of a loading table"),
    ("passwd-like file", lambda c, r: f"root:x:0:0:{SECRET}:/root:/bin/bash\nbin:x:1:1::/:\n", {},
     r"line 1: the header lacks column\(s\) .*\(its columns are a 58-character name\)"),
    ("secret in a cell", lambda c, r: _table(c, _set(r, 1, 1, SECRET[:12])), {},
     r"line 3, column 2 \(\w+\): not a number"),
    ("NaN", lambda c, r: _table(c, _set(r, 2, 1, "nan")), {}, r"line 4, column 2 \(\w+\): NaN"),
    ("infinity", lambda c, r: _table(c, _set(r, 1, 1, "-inf")), {}, r"line 3, column 2 \(\w+\): infinite"),
    ("overflow", lambda c, r: _table(c, _set(r, 1, 1, "1e400")), {}, r"line 3, column 2 \(\w+\): infinite"),
    ("huge value", lambda c, r: _table(c, _set(r, 1, 1, "1e13")), {}, r"line 3, column 2 .*: 1e\+13; .*at most 1e\+12"),
    ("empty cell", lambda c, r: _table(c, _set(r, 1, 1, "")), {}, r"line 3, column 2 \(\w+\): empty"),
    ("missing column", lambda c, r: _table(c[:-1], [row[:-1] for row in r]), {},
     r"line 1: the header lacks column\(s\) \w+ \(its columns are '"),
    ("no header", lambda c, r: _table([str(v) for v in r[0]], r[1:]), {},
     r"line 1: the header lacks .*it holds numbers, not column names"),
    ("repeated column", lambda c, r: _table(c + c[-1:], [row + row[-1:] for row in r]), {},
     r"line 1: the header names column \w+ 2 times"),
    ("short row", lambda c, r: _table(c, r) + "40\n", {}, r"line 5: 1 field\(s\), but the header puts \w+ in column"),
    ("unbalanced quote", lambda c, r: _table(c, _set(r, 1, 1, '"1')), {}, r"line 3: not a line of CSV"),
    ("only a header", lambda c, r: _table(c, []), {}, r"0 data row\(s\); a table needs at least 2"),
    ("one row", lambda c, r: _table(c, r[:1]), {}, r"1 data row\(s\); a table needs at least 2"),
    ("empty file", lambda c, r: "", {}, r"no header and no data"),
    ("first column not increasing", lambda c, r: _table(c, [r[0], r[2], r[1]]), {},
     r"line 4, column 1 \(\w+\): \S+ does not increase from \S+ on line 3; \w+ must increase strictly"),
    ("more rows than the limit (lowered)", lambda c, r: _table(c, r), {"MAX_TABLE_ROWS": 2},
     r"line 4: more than 2 data rows"),
]


@pytest.mark.parametrize("key", list(TABLES))
@pytest.mark.parametrize(("make", "limits", "message"), [case[1:] for case in BAD], ids=[case[0] for case in BAD])
def test_bad_table_is_a_clear_input_error(tmp_path, monkeypatch, key, make, limits, message):
    for name, value in limits.items():
        monkeypatch.setattr(loading, name, value)
    columns, rows, _ = TABLES[key]
    contents = make(columns, rows)
    path = write_case_file(tmp_path / "table.csv", contents)
    with pytest.raises(InputError, match=message) as info:
        _program(key, path)
    text = str(info.value)
    assert info.value.exit_code == 3
    assert text.startswith(f"{key}: {path}")  # names the key and the file
    assert SECRET not in text and SECRET[:12] not in text
    if isinstance(contents, str):  # never echoes more than a short field of the file
        assert not [piece for piece in re.split(r"[\s,:]+", contents) if len(piece) > 20 and piece in text]


def test_path_with_det_F_not_positive_names_the_line(tmp_path):
    path = tmp_path / "path.csv"
    path.write_text("time_s,F11,F12,F21,F22\n0,1,0,0,1\n10,1,0,0,1\n20,0,1,1,0\n")
    with pytest.raises(InputError, match=r"path.csv, line 4: det F = -1; every F must have det F > 0"):
        _program("loading.path_csv", path)


@pytest.mark.parametrize(("key", "rows", "message"), [
    ("loading.path_csv", [(0, 1.05, 0, 0, 1), (10, 1.1, 0, 0, 1)], r"line 2: the first F is not the identity"),
    ("loading.lateral.transverse_csv", [(0, 0), (0.05, -0.02)],
     r"line 3: the table covers axial strains 0 to 0.05, but the loading program goes from 0 to 0.1"),
    ("loading.lateral.transverse_csv", [(0.01, -0.1), (0.2, -0.2)],
     r"line 2: the table covers axial strains 0.01 to 0.2, but the loading program goes from 0"),
    ("loading.lateral.transverse_csv", [(-0.1, 0.02), (0.2, -0.02)],
     r"line 2: the transverse strain at zero axial strain is 0.006667, not 0"),
], ids=["path not from the identity", "transverse table too short", "transverse table not from 0",
        "transverse strain not 0 at 0"])
def test_a_table_that_would_jump_or_be_extrapolated_is_refused(tmp_path, key, rows, message):
    """A silent jump at the start or a held value past the table's end is an error."""
    path = tmp_path / "table.csv"
    path.write_text(_table(TABLES[key][0], rows))
    with pytest.raises(InputError, match=message):
        _program(key, path)


@pytest.mark.parametrize("key", list(TABLES))
def test_missing_file_is_a_config_error(tmp_path, key):
    with pytest.raises(ConfigError, match=rf"^{key}: the file it references does not exist: .*nothing.csv"):
        _program(key, tmp_path / "nothing.csv")


@pytest.mark.parametrize("key", list(TABLES))
@pytest.mark.parametrize("encode", [
    lambda text: b"\xef\xbb\xbf" + text.encode(),  # UTF-8 byte-order mark before the header
    lambda text: text.encode("utf-16"),
    lambda text: ("# Messung bei 23 \xb0C\n\n" + text.replace("\n", "\r\n")).encode("latin-1"),
    lambda text: text.replace("\n", "\n,,,,\n", 1).encode(),  # an empty row of a spreadsheet
], ids=["UTF-8 BOM", "UTF-16", "Latin-1 comment, CRLF", "empty row"])
def test_tables_that_are_read(tmp_path, key, encode):
    columns, rows, _ = TABLES[key]
    path = tmp_path / "table.csv"
    path.write_bytes(encode(_table(columns, rows)))
    values, lines = loading.read_table(path, columns, key)
    assert np.array_equal(values, rows) and lines.size == 3


# --------------------------------------------------------------------------------------------
# espin simulate: a bad table is exit 3 (a missing one exit 2), one line, no output folder
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("contents", "code", "message"), [
    (f"root:x:0:0:{SECRET}:/root:/bin/bash\n".encode(), 3, "the header lacks column(s)"),
    (b"axial_strain,transverse_strain\n0,0\n0.1,nan\n", 3, "line 3, column 2 (transverse_strain): NaN"),
    (None, 2, "the file it references does not exist"),
], ids=["passwd-like", "NaN", "missing"])
def test_simulate_with_a_bad_table(tmp_path, monkeypatch, contents, code, message):
    from espin.cli import app

    monkeypatch.chdir(tmp_path)
    if contents is not None:
        (tmp_path / "bad.csv").write_bytes(contents)
    result = CliRunner().invoke(app, [
        "simulate", "plla", "--set", "rve.size_ratio=30", "--set", "rve.layers=2",
        "--set", 'loading.lateral={transverse_csv="bad.csv"}', "-o", "out"])
    assert result.exit_code == code, result.output
    assert isinstance(result.exception, SystemExit) and "Traceback" not in result.output
    assert "loading.lateral.transverse_csv" in result.output and "bad.csv" in result.output
    assert message in result.output and SECRET not in result.output
    assert not (tmp_path / "out").exists()
