"""Reading a text file a user gives (a curve, a loading table) without trusting it.

Before a byte is read, the path must be a regular file (not a directory, device, pipe or
socket) of at most :attr:`TextFormat.max_bytes`; the file is opened without blocking and
checked again once open, and at most that many bytes are read. The bytes are decoded as UTF-8
(with or without a byte-order mark), UTF-16 with a byte-order mark, or else Latin-1 (an
instrument's 8-bit export); newlines become ``\\n``. A file holding NUL bytes (binary, or
UTF-16 without a byte-order mark) or other control characters (tab, form feed and line ends
aside) is refused, as is a line longer than :attr:`TextFormat.max_line_chars`.

Every failure raises :attr:`TextFormat.error` (an :class:`~espin.core.errors.InputError`)
naming the file and, where there is one, the line, and saying what was expected. Messages
never echo a file's contents: :func:`shown` is how a message quotes a field, only when it is
short and printable.
"""

from __future__ import annotations

import io
import os
import re
import stat
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from espin.core.errors import InputError

__all__ = [
    "TextFormat",
    "SHOWN_CHARS",
    "check_file",
    "read_bytes",
    "decode",
    "read_text",
    "text_lines",
    "too_large",
    "showable",
    "shown",
    "shown_names",
    "parse_number",
    "missing",
]

SHOWN_CHARS = 20
"""Longest field of a file a message quotes [characters]; longer ones are named by length."""

_CONTROL = re.compile(r"[\x00-\x08\x0b\x0e-\x1f\x7f]")
_OPEN_FLAGS = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0)


def parse_number(text: str) -> float | None:
    """The number ``text`` spells (Python's float syntax: '.' as the decimal mark), or None."""
    try:
        return float(text)
    except ValueError:
        return None


def missing(path: Path) -> bool:
    """Whether nothing exists at ``path``; other failures to look (no permission, a NUL in the
    path) are left to the reader to report."""
    try:
        path.stat()
    except FileNotFoundError:
        return True
    except (OSError, ValueError):
        pass
    return False


@dataclass(frozen=True)
class TextFormat:
    """A kind of text file: its limits, the error it raises and how messages describe it.

    Attributes
    ----------
    what : str
        What the file is, for messages: "a directory, not a <what>" (e.g. ``"curve file"``).
    expected : str
        The format expected, a clause appended to messages about the format (e.g.
        ``"expected a text table (CSV: ...)"``).
    max_bytes : int [bytes]
        Largest file read.
    max_line_chars : int [characters]
        Longest line read.
    error : type of InputError
        The error raised.
    key : str
        The config key or option naming the file; messages then start ``key: path``.
    size_hint, line_hint : str
        Why the byte (line) limit is what it is and what to do, appended to its message.
    """

    what: str
    expected: str
    max_bytes: int
    max_line_chars: int
    error: type[InputError] = InputError
    key: str = ""
    size_hint: str = ""
    line_hint: str = ""

    def where(self, path: Path, line: int | None = None, column: str = "") -> str:
        """``[key: ]path[, line N][, column]``: how a message names the file, the line (1-based)
        and the column (e.g. ``"column 2 (F11)"``)."""
        named = f"{self.key}: {path}" if self.key else str(path)
        if line is not None:
            named += f", line {line}"
        return f"{named}, {column}" if column else named

    def fail(self, path: Path, message: str, line: int | None = None, column: str = "") -> InputError:
        """The error ``where: message`` (:meth:`where`)."""
        return self.error(f"{self.where(path, line, column)}: {message}")


def showable(text: str) -> bool:
    """Whether a message may quote ``text``: at most :data:`SHOWN_CHARS` printable characters."""
    return len(text) <= SHOWN_CHARS and text.isprintable()


def shown(text: str, noun: str = "field") -> str:
    """``text`` as a message may show it: quoted when :func:`showable`, else only its length
    (``a 31-character field``)."""
    return repr(text) if showable(text) else f"a {len(text)}-character {noun}"


def shown_names(names: Sequence[str], most: int = 12) -> str:
    """Column names as a message lists them: each :func:`shown`, the first ``most`` of them."""
    listed = ", ".join(shown(name, "name") for name in names[:most])
    return listed + (f", ... ({len(names)} in all)" if len(names) > most else "")


def too_large(path: Path, fmt: TextFormat, size: str) -> InputError:
    """The error for a file of ``size`` (e.g. ``"70,000,000 bytes"``) over ``fmt.max_bytes``."""
    mib, rest = divmod(fmt.max_bytes, 2**20)
    limit = f"{mib} MiB" if mib and not rest else f"{fmt.max_bytes:,} bytes"
    hint = f": {fmt.size_hint}" if fmt.size_hint else ""
    return fmt.fail(path, f"{size}, over the limit of {limit} for a {fmt.what}{hint}")


def _check_mode(path: Path, info: os.stat_result, fmt: TextFormat) -> None:
    """Refuse what is not a regular file of at most ``fmt.max_bytes``."""
    if stat.S_ISDIR(info.st_mode):
        raise fmt.fail(path, f"a directory, not a {fmt.what}; {fmt.expected}")
    if not stat.S_ISREG(info.st_mode):
        raise fmt.fail(path, f"not a regular file (a device, pipe or socket); {fmt.expected}")
    if info.st_size > fmt.max_bytes:
        raise too_large(path, fmt, f"{info.st_size:,} bytes")


def check_file(path: Path, fmt: TextFormat) -> None:
    """Refuse, before reading it, a path that is not a regular file of at most ``fmt.max_bytes``.

    Raises
    ------
    InputError
        ``fmt.error``: the path cannot be looked at (missing, no permission), is a directory,
        device, pipe or socket, or is too large.
    """
    try:
        info = path.stat()
    except (OSError, ValueError) as err:  # ValueError: a NUL in the path
        raise fmt.fail(path, f"cannot read the file ({getattr(err, 'strerror', None) or err})") from None
    _check_mode(path, info, fmt)


def read_bytes(path: Path, fmt: TextFormat) -> bytes:
    """The bytes of a regular file of at most ``fmt.max_bytes``.

    The file is checked (:func:`check_file`), opened without blocking (a pipe put in its place
    meanwhile cannot hang the reader), checked again and read up to the limit.

    Raises
    ------
    InputError
        ``fmt.error``: as :func:`check_file`, or the file cannot be read.
    """
    check_file(path, fmt)
    try:
        with os.fdopen(os.open(path, _OPEN_FLAGS), "rb") as stream:
            _check_mode(path, os.fstat(stream.fileno()), fmt)
            data = stream.read(fmt.max_bytes + 1)
    except OSError as err:
        raise fmt.fail(path, f"cannot read the file ({err.strerror or err})") from None
    if len(data) > fmt.max_bytes:
        raise too_large(path, fmt, f"more than {fmt.max_bytes:,} bytes")
    return data


def decode(path: Path, data: bytes, fmt: TextFormat) -> str:
    """The text of a file's bytes (encodings in the module docs), newlines as ``\\n``.

    Raises
    ------
    InputError
        ``fmt.error``: the bytes hold NUL bytes or other control characters (naming the first
        one's line), or start with a UTF-16 byte-order mark but are not UTF-16.
    """
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        try:
            text = data.decode("utf-16")
        except UnicodeDecodeError:
            raise fmt.fail(path, f"starts with a UTF-16 byte-order mark but is not UTF-16; {fmt.expected}") from None
    elif b"\x00" in data:
        raise fmt.fail(
            path,
            "not a text file (it holds NUL bytes: an image or other binary file, "
            f"or UTF-16 without a byte-order mark?); {fmt.expected}",
        )
    else:
        try:
            text = data.decode("utf-8-sig")
        except UnicodeDecodeError:
            text = data.decode("latin-1")  # never fails: an instrument's 8-bit export
    text = text.replace("\r\n", "\n").replace("\r", "\n")
    control = _CONTROL.search(text)
    if control:
        line = text.count("\n", 0, control.start()) + 1
        raise fmt.fail(
            path, f"a control character (code {ord(control.group()):#04x}), so not a text file; {fmt.expected}", line
        )
    return text


def read_text(path: Path, fmt: TextFormat) -> str:
    """The decoded text of a file: :func:`read_bytes`, then :func:`decode`."""
    return decode(path, read_bytes(path, fmt), fmt)


def text_lines(path: Path, text: str, fmt: TextFormat, *, skip_rows: int = 0) -> Iterator[tuple[int, str]]:
    """The 1-based number and text (without the newline) of each line of ``text`` that is not
    blank, not a comment (first non-blank character ``#``) and not one of the first
    ``skip_rows``; lazily, so a reader can stop at its own limit of lines.

    Raises
    ------
    InputError
        ``fmt.error``: a kept line is longer than ``fmt.max_line_chars``.
    """
    for number, line in enumerate(io.StringIO(text), start=1):
        stripped = line.strip()
        if number <= skip_rows or not stripped or stripped.startswith("#"):
            continue
        line = line.rstrip("\n")
        if len(line) > fmt.max_line_chars:
            hint = f": {fmt.line_hint}" if fmt.line_hint else ""
            raise fmt.fail(
                path,
                f"{len(line):,} characters, over the limit of {fmt.max_line_chars} for a line of a {fmt.what}{hint}",
                number,
            )
        yield number, line
