"""The package shows its pipeline: stage subpackages in layers, no import cycles.

The layers are import-linter contracts in ``pyproject.toml``; these tests run them, look for
cycles in the whole import graph (imports inside functions and under ``TYPE_CHECKING``
included) and keep the top level small.
"""

from __future__ import annotations

import logging
import re
import tomllib
from pathlib import Path

import grimp
import numpy as np
import pytest
from importlinter.cli import lint_imports
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

import espin

ROOT = Path(__file__).parents[1]
PACKAGE = Path(espin.__file__).parent
STAGES = {"core", "geometry", "mechanics", "analysis", "studies", "imaging", "cli"}


@pytest.fixture(scope="module")
def graph() -> grimp.ImportGraph:
    return grimp.build_graph("espin", exclude_type_checking_imports=False, cache_dir=None)


def test_import_contracts_are_kept(capsys):
    # import-linter configures logging and disables the loggers that exist: give them back.
    loggers = [lg for lg in logging.root.manager.loggerDict.values() if isinstance(lg, logging.Logger)]
    disabled = [lg.disabled for lg in loggers]
    try:
        code = lint_imports(config_filename=str(ROOT / "pyproject.toml"), no_cache=True, no_logo=True)
    finally:
        for logger, was in zip(loggers, disabled):
            logger.disabled = was
    assert code == 0, capsys.readouterr().out


def test_contracts_keep_import_linter_defaults():
    contracts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    assert {c["type"] for c in contracts} == {"layers", "independence"}
    for contract in contracts:
        assert "ignore_imports" not in contract, contract["name"]
        assert "exclude_type_checking_imports" not in contract, contract["name"]
    # Every stage and every subpackage of a stage is a layer (exhaustive) of some contract.
    containers = {c for contract in contracts for c in contract.get("containers", [])}
    assert all(contract.get("exhaustive") for contract in contracts if contract["type"] == "layers")
    packages = {".".join(p.parent.relative_to(PACKAGE.parent).parts) for p in PACKAGE.rglob("__init__.py")}
    for package in packages - containers:
        assert package.rsplit(".", 1)[0] in containers, f"{package} is in no contract"


def test_no_import_cycles(graph):
    modules = sorted(graph.modules)
    index = {m: i for i, m in enumerate(modules)}
    edges = [(index[a], index[b]) for a in modules for b in graph.find_modules_directly_imported_by(a)]
    rows, cols = np.array(edges).T
    adjacency = coo_matrix((np.ones(len(edges)), (rows, cols)), shape=(len(modules),) * 2)
    _, label = connected_components(adjacency, directed=True, connection="strong")
    cycles = [[modules[i] for i in np.flatnonzero(label == k)] for k in np.unique(label)
              if np.count_nonzero(label == k) > 1]
    assert cycles == []


def test_top_level_holds_the_stages_and_at_most_eight_modules():
    modules = [p.name for p in PACKAGE.glob("*.py") if p.name != "__init__.py"]
    packages = {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").exists()}
    assert len(modules) <= 8, modules
    assert STAGES <= packages, STAGES - packages


def test_modules_are_imported_by_name_except_the_lazy_public_api():
    dynamic = re.compile(r"import_module\(\s*[\"']espin")
    found = [str(p.relative_to(PACKAGE)) for p in PACKAGE.rglob("*.py")
             if p != PACKAGE / "__init__.py" and dynamic.search(p.read_text())]
    assert found == []


def test_public_api_resolves():
    for name in espin.__all__:
        assert getattr(espin, name) is not None, name


def test_file_schemas_did_not_move_with_the_modules():
    """Files written before the layout change are still recognised: schema names are data."""
    from espin.imaging.geometry_calibration.result import SCHEMA as CALIBRATION
    from espin.imaging.measurement import SCHEMA as MEASUREMENT
    from espin.geometry.rve_file import SCHEMA as RVE
    from espin.mechanics.results_file import SCHEMA as RESULTS

    assert (RVE, RESULTS, MEASUREMENT, CALIBRATION) == (
        "espin.rve", "espin.results", "espin.sem.measurement/1", "espin.geometry_calibration")
