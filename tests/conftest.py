"""Shared fixtures: small RVEs (tests use small RVEs; big ones belong to benchmarks)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from espin.geometry.mat import FiberMat

SHARED = Path(__file__).resolve().parents[2] / "shared"
"""The project's shared data, beside the clone (``../shared``): only what a clone's parent holds,
never a path of one machine."""


def needs_shared(*files: Path) -> pytest.MarkDecorator:
    """Skip a test (or a module, as ``pytestmark``) unless every one of ``files`` (under
    :data:`SHARED`) exists; the reason names the missing ones."""
    missing = [str(f) for f in files if not f.is_file()]
    return pytest.mark.skipif(bool(missing), reason="needs ../shared beside the clone; missing: " + ", ".join(missing))


def make_mat(fibers: list[list[tuple[float, float]]], layers: list[int], size: float = 10.0,
             diameter: float = 0.1, n_layers: int | None = None) -> FiberMat:
    """A FiberMat from explicit polylines (hand-built fixtures)."""
    counts = [len(f) for f in fibers]
    return FiberMat(
        vertices=np.array([p for f in fibers for p in f], dtype=float),
        fiber_offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
        fiber_layer=np.array(layers, dtype=np.int64),
        fiber_diameter=np.full(len(fibers), diameter),
        size=size,
        thickness=diameter,
        n_layers=n_layers if n_layers is not None else max(layers) + 1,
    )


def grid_network(n: int = 4, size: float = 10.0, diameter: float = 0.2):
    """n horizontal and n vertical straight fibers crossing on a regular grid (one layer)."""
    from espin.geometry.crosslinks import find_crosslinks
    from espin.geometry.network import build_network

    c = (np.arange(n) + 0.5) * size / n
    fibers = [[(0.0, y), (size, y)] for y in c] + [[(x, 0.0), (x, size)] for x in c]
    mat = make_mat(fibers, [0] * (2 * n), size=size, diameter=diameter)
    return build_network(mat, find_crosslinks(mat), 1e-6)


@pytest.fixture(scope="session")
def small_rve():
    """A small plla-like RVE (L = 40 D, 3 layers), generated once per test session."""
    import espin.geometry.rve

    return espin.geometry.rve.generate("plla", rve__size_ratio=40, rve__layers=3)


def write_case_file(path: Path, contents: object) -> Path:
    """A bad-input case's file at ``path``: ``contents`` is text, bytes, a writer called with
    the path, a fixed path such as ``/dev/zero`` (the case is skipped where it does not
    exist), or None (nothing written)."""
    if isinstance(contents, Path):
        if not contents.exists():
            pytest.skip(f"no {contents} on this platform")
        return contents
    if isinstance(contents, str):
        path.write_text(contents, encoding="utf-8")
    elif isinstance(contents, bytes):
        path.write_bytes(contents)
    elif contents is not None:
        contents(path)
    return path


@pytest.fixture
def measure_app():
    """A typer app with the ``measure`` command (and a second one, which keeps ``measure`` a
    subcommand), for CliRunner."""
    import typer

    from espin.cli.measure import register

    app = typer.Typer()
    register(app)
    app.command("noop")(lambda: None)
    return app
