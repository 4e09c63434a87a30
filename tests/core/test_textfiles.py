"""Reading untrusted text files: file checks, encodings, lines, and messages that never echo."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from espin.core.errors import InputError
from espin.core.textfiles import (
    TextFormat,
    decode,
    read_bytes,
    read_text,
    shown,
    shown_names,
    text_lines,
)

FMT = TextFormat(what="test table", expected="expected a test table", max_bytes=64, max_line_chars=10)


class TableError(InputError):
    """The error a caller chose."""


@pytest.mark.parametrize("data", [
    b"a,b\r\n1,2\r\n",
    b"\xef\xbb\xbfa,b\n1,2\n",
    "a,b\n1,2\n".encode("utf-16"),
    b"\xfe\xff" + "a,b\r1,2\r".encode("utf-16-be"),
])
def test_encodings_and_line_ends_are_read(data):
    assert decode(Path("t.csv"), data, FMT) == "a,b\n1,2\n"


def test_latin1_is_the_fallback():
    assert decode(Path("t.csv"), "°C,µm\n".encode("latin-1"), FMT) == "°C,µm\n"


@pytest.mark.parametrize(("data", "message"), [
    (b"a,b\n\x89PNG\x00\x01", r"t.csv: not a text file \(it holds NUL bytes"),
    (b"a,b\n1,2\x1b[2J\n", r"t.csv, line 2: a control character \(code 0x1b\)"),
    (b"\xff\xfe0\x00,\x00\x00", r"t.csv: starts with a UTF-16 byte-order mark but is not UTF-16"),
])
def test_binary_text_is_refused(data, message):
    with pytest.raises(InputError, match=message):
        decode(Path("t.csv"), data, FMT)


def test_kept_lines_and_the_line_limit():
    text = "# comment\n\nskip\na,b\n  \n1,2\n"
    assert list(text_lines(Path("t.csv"), text, FMT)) == [(3, "skip"), (4, "a,b"), (6, "1,2")]
    assert list(text_lines(Path("t.csv"), text, FMT, skip_rows=3)) == [(4, "a,b"), (6, "1,2")]
    secret = "s3cret-" * 3
    with pytest.raises(InputError, match=r"t.csv, line 2: 21 characters, over the limit of 10") as info:
        list(text_lines(Path("t.csv"), f"a\n{secret}\n", FMT))
    assert secret not in str(info.value)


def test_files_that_are_not_read(tmp_path):
    fmt = TextFormat(what="test table", expected="expected a test table", max_bytes=8, max_line_chars=10,
                     error=TableError, key="test.key", size_hint="cut it")
    with pytest.raises(TableError, match=r"^test.key: .*: a directory, not a test table; expected a test"):
        read_bytes(tmp_path, fmt)
    with pytest.raises(TableError, match=r"cannot read the file \(No such file"):
        read_bytes(tmp_path / "missing.csv", fmt)
    big = tmp_path / "big.csv"
    big.write_text("1,2\n3,4\n5,6\n")
    with pytest.raises(TableError, match=r"big.csv: 12 bytes, over the limit of 8 bytes for a test table: cut it"):
        read_bytes(big, fmt)
    if hasattr(os, "mkfifo"):
        os.mkfifo(tmp_path / "fifo")
        with pytest.raises(TableError, match=r"fifo: not a regular file \(a device, pipe or socket\)"):
            read_bytes(tmp_path / "fifo", fmt)


def test_a_small_file_is_read(tmp_path):
    path = tmp_path / "t.csv"
    path.write_bytes(b"\xef\xbb\xbfa,b\r\n1,2\r\n")
    assert read_text(path, FMT) == "a,b\n1,2\n"


def test_where_names_key_file_line_and_column():
    fmt = TextFormat(what="t", expected="e", max_bytes=1, max_line_chars=1, key="loading.path_csv")
    assert fmt.where(Path("p.csv"), 3, "column 2 (F11)") == "loading.path_csv: p.csv, line 3, column 2 (F11)"
    assert FMT.where(Path("p.csv")) == "p.csv"


def test_shown_quotes_only_short_printable_text():
    assert shown("F11") == "'F11'"
    assert shown("root:x:0:0:root:/root:/bin/bash", "name") == "a 31-character name"
    assert shown("a\x1bb") == "a 3-character field"
    assert shown_names([f"c{k}" for k in range(14)]) == ", ".join(f"'c{k}'" for k in range(12)) + ", ... (14 in all)"
