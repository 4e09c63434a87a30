"""How big a virtual mat and its tensile test will be, from the config alone, before any work.

Counts follow from the fiber length each layer holds. A layer of side L and thickness D at
volume fraction eta holds fibers of total volume eta L^2 D; a fiber of diameter d has
cross-section pi d^2 / 4, so the layer holds a fiber length

    Lambda = eta L^2 D / (pi E[d^2] / 4),   E[d^2] = D^2 + sd^2 (truncation neglected),

that is rho = Lambda / L^2 per unit area. Straight fibers cross the square along chords of
mean length pi L / 4 (Cauchy-Crofton), which gives the fibers per layer, and the segments are
Lambda / l_s per layer. Cross-links are the crossings of fibers in the same layer (rho^2 / pi
per unit area for isotropic fibers) and between adjacent layers (2 rho^2 / pi); isotropic
fibers cross the most for a given length, so this is an upper bound for aligned mats. Each
cross-link becomes a node of two DOF (merging makes a few fewer).

Memory is the peak resident size of ``espin simulate`` (default program, figures and VTK
written), measured with ``benchmarks/bench_memory.py``: about 200 MiB for Python, the
libraries and the figures, then 3.4-3.7 kB per DOF (PARDISO, 4.7k to 143k DOF), plus the
deposition's arrays per segment. The estimate is 1.1-1.4 times the measured peak on that
benchmark's mats (docs/performance.md): within 2x, erring high.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from espin.core.config import Config
from espin.core.errors import ConfigError

__all__ = ["SizeEstimate", "estimate_size", "check_size", "available_memory", "MIN_FIBERS_PER_LAYER"]

BASE_BYTES = 200 * 2**20
"""Python, numpy, scipy, matplotlib, the solver and espin imported [bytes]."""
BYTES_PER_DOF = 4.5e3
"""Peak memory per degree of freedom of a tensile test [bytes] (measured 3.9-4.1 kB)."""
BYTES_PER_SEGMENT = 2.0e3
"""Deposition and cross-link search per fiber segment [bytes]."""
MIN_FIBERS_PER_LAYER = 3.0
"""Fewer fibers per layer and one fiber can overshoot the layer's volume fraction by a third
or more. The sparsest mats of the supported ranges (docs/mechanics.md: volume fraction 0.05,
L/D 60, diameter CV 0.7) hold 3.3.

It also gives a network: with N straight isotropic fibers per layer, an average fiber has
rho L / 2 = pi N / 8 cross-links within its layer (1.2 at N = 3) and twice as many with
each adjacent layer. Aligned fibers cross less; a mat left without a free node is refused by
:func:`espin.geometry.rve.generate` after its (then cheap) deposition."""


@dataclass(frozen=True)
class SizeEstimate:
    """Expected size of a virtual mat and the memory its tensile test needs.

    Attributes
    ----------
    fibers_per_layer : float
        Fibers in one layer.
    fibers : float
        Fibers in all layers.
    segments : float
        Fiber segments in all layers.
    crosslinks : float
        Cross-links (within and between adjacent layers).
    dof : float
        Degrees of freedom of the network.
    memory_bytes : float
        Peak memory of a tensile test [bytes].
    """

    fibers_per_layer: float
    fibers: float
    segments: float
    crosslinks: float
    dof: float
    memory_bytes: float

    @property
    def crosslinks_per_fiber(self) -> float:
        """Cross-links on an average fiber (each cross-link joins two fibers)."""
        return 2.0 * self.crosslinks / self.fibers if self.fibers > 0 else 0.0

    def describe(self) -> str:
        """One line: the counts and the memory, rounded."""
        return (
            f"about {self.fibers:,.0f} fibers, {self.segments:,.0f} segments, "
            f"{self.crosslinks:,.0f} cross-links, {self.dof:,.0f} DOF, "
            f"{_gib(self.memory_bytes)} of memory"
        )


def estimate_size(config: Config) -> SizeEstimate:
    """The size of ``config``'s mat and the peak memory of its tensile test (module docs).

    Parameters
    ----------
    config
        A validated run configuration.

    Returns
    -------
    SizeEstimate
    """
    rve = config.rve
    side, diameter = rve.side_um, rve.diameter_um
    length = rve.volume_fraction * side**2 * diameter / (math.pi * (diameter**2 + rve.diameter_sd_um**2) / 4.0)
    per_layer = length / (math.pi * side / 4.0)
    rho = length / side**2
    crossings = side**2 * rho**2 / math.pi * (rve.layers + 2.0 * (rve.layers - 1))
    segments = rve.layers * (length / rve.segment_length_um + per_layer)
    dof = 2.0 * crossings
    memory = BASE_BYTES + BYTES_PER_DOF * dof + BYTES_PER_SEGMENT * segments
    return SizeEstimate(per_layer, rve.layers * per_layer, segments, crossings, dof, memory)


def available_memory() -> int:
    """Memory available to a new process now [bytes] (Linux: MemAvailable)."""
    import psutil

    return int(psutil.virtual_memory().available)


def check_size(config: Config, *, allow_large: bool = False, available: int | None = None) -> SizeEstimate:
    """Refuse, before any work, a mat the generator cannot make or the machine cannot hold.

    Parameters
    ----------
    config
        A validated run configuration.
    allow_large
        Go on even when the estimated memory exceeds what is available.
    available
        Memory to compare with [bytes]; default :func:`available_memory`.

    Returns
    -------
    SizeEstimate

    Raises
    ------
    ConfigError
        When a layer would hold fewer than 3 fibers (too few for its volume fraction and for
        a network), or the tensile test would need more memory than is available; the
        message names the keys to change and gives the estimate and the limit.
    """
    size = estimate_size(config)
    rve = config.rve
    where = (
        f"rve.volume_fraction = {rve.volume_fraction:g}, layer side {rve.side_um:g} um "
        f"(rve.size_ratio = {rve.side_um / rve.diameter_um:g}), rve.diameter_um = {rve.diameter_um:g}, "
        f"rve.diameter_sd_um = {rve.diameter_sd_um:g}"
    )
    if size.fibers_per_layer < MIN_FIBERS_PER_LAYER:
        raise ConfigError(
            f"a layer would hold about {size.fibers_per_layer:.2g} fibers ({where}); at least "
            f"{MIN_FIBERS_PER_LAYER:g} are needed for its volume fraction to be met and for a network: raise "
            "rve.size_ratio or rve.volume_fraction, or lower rve.diameter_sd_um"
        )
    limit = available_memory() if available is None else available
    if size.memory_bytes > limit and not allow_large:
        raise ConfigError(
            f"this mat needs {size.describe()}, more than the {_gib(limit)} available now "
            f"(rve.size_ratio = {rve.side_um / rve.diameter_um:g}, rve.layers = {rve.layers}, "
            f"rve.segment_ratio = {rve.segment_length_um / rve.diameter_um:g}, "
            f"rve.volume_fraction = {rve.volume_fraction:g}): make the RVE smaller, or try anyway "
            "with --allow-large (generate, simulate, study; allow_large=True in Python)"
        )
    return size


def _gib(n_bytes: float) -> str:
    return f"{n_bytes / 2**30:,.2f} GiB" if n_bytes < 1e24 else f"{n_bytes:.2g} bytes"
