"""A representative volume element: its configuration, deposited fibers, cross-links, network.

:func:`generate` runs the first half of espin's pipeline:
config -> deposition (fibers) -> cross-links -> network.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from espin.core.config import Config, apply_overrides, load_config
from espin.geometry.crosslinks import Crosslinks, find_crosslinks
from espin.geometry.deposition import deposit
from espin.geometry.mat import FiberMat
from espin.geometry.network import Network, build_network

__all__ = ["RVE", "generate", "resolve_config"]

log = logging.getLogger(__name__)

Progress = Callable[[str, int, int], None]
"""Progress callback: ``progress(stage, done, total)``."""


@dataclass(frozen=True, eq=False)
class RVE:
    """A generated RVE.

    Attributes
    ----------
    config : Config
        The resolved configuration it was generated from (``config.rve.seed`` included).
    mat : FiberMat
        Deposited fibers (polylines).
    crosslinks : Crosslinks
        Fiber intersections in the same or adjacent layers.
    network : Network
        Nodes and elements for the mechanics.
    """

    config: Config
    mat: FiberMat
    crosslinks: Crosslinks
    network: Network


def resolve_config(config: Config | str | Path | None = None, **overrides: Any) -> Config:
    """A validated :class:`Config` from a Config, a preset name, a TOML path or None (plla).

    Keyword overrides use ``section__key`` names, e.g. ``rve__layers=5``.
    """
    flat = {key.replace("__", "."): value for key, value in overrides.items()}
    if isinstance(config, Config):
        return apply_overrides(config, flat) if flat else config
    return load_config("plla" if config is None else config, flat)


def generate(
    config: Config | str | Path | None = None,
    *,
    progress: Progress | None = None,
    **overrides: Any,
) -> RVE:
    """Generate a virtual electrospun mat and its fiber network (paper 3.1.1; docs/model.md sections 1-2).

    Parameters
    ----------
    config
        A :class:`Config`, a preset name (``"plla"``, the default) or a TOML file.
    progress
        Called as ``progress(stage, done, total)`` with stage ``"deposition"`` (per layer),
        ``"crosslinks"`` and ``"network"``.
    **overrides
        Config keys as ``section__key=value``, e.g. ``rve__layers=5, rve__seed=3``.

    Returns
    -------
    RVE
        Same config and seed give the same RVE.

    Examples
    --------
    >>> rve = espin.generate("plla", rve__size_ratio=50, rve__layers=3)
    >>> rve.network.n_dof
    """
    cfg = resolve_config(config, **overrides)
    log.info("depositing %d layers with %s seeding", cfg.rve.layers, cfg.rve.seeding)
    layer_progress = None if progress is None else (lambda done, total: progress("deposition", done, total))
    mat = deposit(cfg.rve, progress=layer_progress)
    crosslinks = find_crosslinks(mat)
    if progress is not None:
        progress("crosslinks", 1, 1)
    network = build_network(mat, crosslinks, cfg.rve.merge_tolerance_um)
    if progress is not None:
        progress("network", 1, 1)
    log.info(
        "%d fibers, %d cross-links (%d merged), %d elements, %d DOF",
        mat.n_fibers, crosslinks.n, network.n_merged, network.n_elements, network.n_dof,
    )
    return RVE(config=cfg, mat=mat, crosslinks=crosslinks, network=network)
