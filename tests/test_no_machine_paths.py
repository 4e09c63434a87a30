"""No file under src/ or tests/ names a place on one machine: an absolute path outside the clone.

The tests read only the clone and ``../shared`` beside it, both found relative to the clone
(``conftest.SHARED``), so that they run alike on a laptop, a colleague's machine and CI.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MACHINE_ROOTS = {"home", "Users", "root", "work", "mnt", "media", "opt", "srv", "scratch", "data", "shared",
                 "Volumes", "private", "net", "nfs", "gpfs", "lustre", "projects"}
"""First folders of an absolute path where a machine keeps its users' files and data (a path
such as ``/network/loop`` inside an HDF5 file, or ``/bin/bash`` in the text of a test's
passwd-like file, is not one)."""
ABSOLUTE = re.compile(r"(?<![\w.~$}/\\-])/([A-Za-z][\w.-]*)/[\w.*/-]*|(?<![\w\\])[A-Za-z]:\\\\?[\w.]+")
"""A POSIX path of two or more parts from the root, or a Windows path from a drive letter."""


def machine_paths(text: str) -> list[str]:
    """The absolute paths outside the clone that ``text`` names."""
    found = []
    for match in ABSOLUTE.finditer(text):
        first = match[1]
        if first is None or first in MACHINE_ROOTS:
            found.append(match[0])
    return found


def test_the_check_sees_machine_paths():
    assert machine_paths('PLGA = Path("/work/shared/data/sem/PLGA-1500_1.tif")') == ["/work/shared/data/sem/PLGA-1500_1.tif"]
    assert machine_paths("open('/home/me/mats/a.toml')") == ["/home/me/mats/a.toml"]
    assert machine_paths(r'read("C:\\Users\\me\\mat.tif")') != []
    for fine in ('Path("/dev/zero")', '"/tmp/*"', 'f["/network/loop"]', "um/px", "doi.org/10.1016/j.mechmat",
                 "SHARED / 'data' / 'sem'", "../shared/data/sem"):
        assert machine_paths(fine) == [], fine


def test_no_file_under_src_or_tests_names_an_absolute_path_outside_the_clone():
    offenders = []
    for folder in (ROOT / "src", ROOT / "tests"):
        for path in sorted(folder.rglob("*")):  # this file's examples above are not looked at
            if not path.is_file() or path == Path(__file__) or "__pycache__" in path.parts or path.suffix in {".pyc", ".h5", ".png", ".tif"}:
                continue
            try:
                text = path.read_text(encoding="utf-8")
            except UnicodeDecodeError:
                continue  # binary data: no path written by hand
            offenders += [f"{path.relative_to(ROOT)}: {name}" for name in machine_paths(text)]
    assert offenders == [], "\n".join(offenders)
