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

import numpy as np

from espin.core.config import Config, apply_overrides, dotted_overrides, load_config
from espin.core.errors import ConfigError
from espin.core.html import html_table
from espin.geometry.crosslinks import Crosslinks, find_crosslinks
from espin.geometry.deposition import deposit
from espin.geometry.mat import FiberMat
from espin.geometry.network import Network, build_network
from espin.geometry.size_estimate import check_size

__all__ = ["RVE", "generate", "resolve_config"]

log = logging.getLogger(__name__)

Progress = Callable[[str, int, int], None]
"""Progress callback: ``progress(stage, done, total)``."""

VOLUME_FRACTION_RTOL = 0.1
"""A mat whose mean layer volume fraction is further than this from the target is reported."""


@dataclass(frozen=True, eq=False, repr=False)
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
    path : Path or None
        The file it was loaded from (:func:`espin.geometry.rve_file.load_rve`); None for a
        generated RVE.
    """

    config: Config
    mat: FiberMat
    crosslinks: Crosslinks
    network: Network
    path: Path | None = None

    def __repr__(self) -> str:
        """One line: size (L/D, side L [um]), layers, fibers, cross-links, nodes, DOF,
        elements (segments), seed and sampling."""
        rve, network = self.config.rve, self.network
        return (
            f"RVE(L/D {rve.side_um / rve.diameter_um:.4g}, side {rve.side_um:.4g} um, {self.mat.n_layers} layers, "
            f"{self.mat.n_fibers} fibers, {self.crosslinks.n} cross-links, {network.n_nodes} nodes, "
            f"{network.n_dof} DOF, {network.n_elements} elements, seed {rve.seed}, {rve.sampling} sampling)"
        )

    def _repr_html_(self) -> str:
        """The key numbers as an HTML table (Jupyter)."""
        rve, network = self.config.rve, self.network
        rows = [
            ("L/D", f"{rve.side_um / rve.diameter_um:.4g}"),
            ("side L", f"{rve.side_um:.4g} um"),
            ("fiber diameter D", f"{rve.diameter_um:.4g} +- {rve.diameter_sd_um:.3g} um"),
            ("volume fraction (target)", f"{rve.volume_fraction:.4g}"),
            ("layers", str(self.mat.n_layers)),
            ("fibers", str(self.mat.n_fibers)),
            ("cross-links", f"{self.crosslinks.n} ({network.n_merged} merged)"),
            ("nodes", f"{network.n_nodes} ({network.n_inner} inner, {network.n_border} border)"),
            ("DOF", str(network.n_dof)),
            ("elements", str(network.n_elements)),
            ("seed", str(rve.seed)),
            ("sampling", rve.sampling),
        ]
        if self.path is not None:
            rows.append(("file", str(self.path)))
        return html_table("RVE", rows)


def resolve_config(config: Config | str | Path | None = None, **overrides: Any) -> Config:
    """A validated :class:`Config` from a Config, a preset name, a TOML path or None (plla).

    Keyword overrides use ``section__key`` names, e.g. ``rve__layers=5`` (or dotted keys
    through ``**{"rve.layers": 5}``).
    """
    flat = dotted_overrides(overrides)
    if isinstance(config, Config):
        return apply_overrides(config, flat) if flat else config
    return load_config("plla" if config is None else config, flat)


def generate(
    config: Config | str | Path | None = None,
    *,
    progress: Progress | None = None,
    allow_large: bool = False,
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
    allow_large
        Go on when the estimated memory of the tensile test exceeds what is available
        (:func:`espin.geometry.size_estimate.check_size`).
    **overrides
        Config keys as ``section__key=value``, e.g. ``rve__layers=5, rve__seed=3``.

    Returns
    -------
    RVE
        Same config and seed give the same RVE.

    Raises
    ------
    ConfigError
        Before any work, for a mat too sparse to form a network or too large for the memory
        available; after the deposition, for a mat without a single free node.

    Examples
    --------
    >>> rve = espin.generate("plla", rve__size_ratio=50, rve__layers=3)
    >>> rve.network.n_dof
    """
    cfg = resolve_config(config, **overrides)
    size = check_size(cfg, allow_large=allow_large)
    log.info("expecting %s", size.describe())
    log.info("depositing %d layers with %s seeding, %s sampling", cfg.rve.layers, cfg.rve.seeding, cfg.rve.sampling)
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
        mat.n_fibers,
        crosslinks.n,
        network.n_merged,
        network.n_elements,
        network.n_dof,
    )
    _check_generated(cfg, mat, network)
    return RVE(config=cfg, mat=mat, crosslinks=crosslinks, network=network)


def _check_generated(config: Config, mat: FiberMat, network: Network) -> None:
    """Refuse a mat without free nodes; warn when its volume fraction misses the target."""
    if network.n_dof == 0:
        raise ConfigError(
            f"the mat has {mat.n_fibers} fibers and no cross-link between them, so nothing to "
            f"solve for (rve.volume_fraction = {config.rve.volume_fraction:g}, rve.orientation "
            f"{config.rve.orientation}): raise rve.volume_fraction or rve.size_ratio, or "
            "spread the orientations"
        )
    achieved = float(np.mean(mat.layer_volume_fraction()))
    target = config.rve.volume_fraction
    if abs(achieved - target) > VOLUME_FRACTION_RTOL * target:
        log.warning(
            "the mat's volume fraction is %.3g against rve.volume_fraction = %.3g "
            "(few, thick fibers per layer): raise rve.size_ratio or lower rve.diameter_sd_um",
            achieved,
            target,
        )
