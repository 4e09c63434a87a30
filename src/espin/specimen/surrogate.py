"""A homogenized surrogate of the RVE for monotonic loading, built from RVE runs.

The RVE is pulled along straight paths of the right stretch tensor, U(t) = I + t G (G
symmetric, no rotation, its largest component 1), at the loading's strain rate, to t =
``reach`` times the specimen's grip strain (less where U would lose 90 % of a stretch), with
recorded steps growing as the square of their number (dense at the yield knee). Along every
path each recorded step gives a sample of the second Piola-Kirchhoff stress S = F^-1 P against
the Green-Lagrange strain E = (U^2 - I) / 2 (with the yielded and recruited fractions). A
thin-plate-spline radial-basis interpolant (:class:`scipy.interpolate.RBFInterpolator`)
through the samples gives S(E) and the fractions anywhere; then

    P = F S(E(F)),   A_iJkL = delta_ik S_LJ + F_iM dS_MJ/dE_LQ F_kQ,

with dS/dE by central differences of the interpolant. E depends on F through C = F^T F = U^2
only, so the surrogate is frame-indifferent (P(R F) = R P(F) for any rotation R) and, as the
RVE, anisotropic. It is a deformation-theory law: exact on the sampled monotonic paths and an
interpolation between them, with no unloading and no rate effect beyond the sampled rate
(checked against FE^2 in docs/specimen.md).
"""

from __future__ import annotations

import time as time_module
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import RBFInterpolator

from espin.core.config import Config
from espin.core.errors import ConfigError, SolverError
from espin.core.parallel import TaskPool
from espin.geometry.network import Network
from espin.mechanics.driver import run_program
from espin.mechanics.linear_solvers import make_linear_solver
from espin.mechanics.loading import path_program

__all__ = ["Surrogate", "SurrogateMaterial", "build_surrogate", "DEFAULT_PATHS"]

DEFAULT_PATHS = tuple((1.0, lateral, shear) for lateral in (-0.6, -0.3, 0.0, 0.3) for shear in (-0.3, 0.0, 0.3)) + (
    (0.0, 1.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0), (0.5, 1.0, 0.0), (-0.3, 1.0, 0.0))
"""Directions (G11, G22, G12) of the stretch paths U = I + t G, scaled so the largest |G_ij| is
1: stretches along the loading axis with lateral contraction or extension and shear, and
lateral stretch, contraction and shear alone."""

_FIELDS = ("yielded_fraction", "recruited_fraction")
_DIFFERENCE = 1e-6  # step of the central differences of S(E)


def _green(F: np.ndarray) -> np.ndarray:
    """(E11, E22, E12) of F (..., 2, 2)."""
    C = np.einsum("...kI,...kJ->...IJ", F, F)
    return np.stack([0.5 * (C[..., 0, 0] - 1.0), 0.5 * (C[..., 1, 1] - 1.0), 0.5 * C[..., 0, 1]], axis=-1)


def _symmetric(v: np.ndarray) -> np.ndarray:
    """(..., 3) (a11, a22, a12) -> (..., 2, 2)."""
    return np.stack([np.stack([v[..., 0], v[..., 2]], -1), np.stack([v[..., 2], v[..., 1]], -1)], -2)


@dataclass(frozen=True, eq=False)
class _Path:
    network: Network
    config: Config
    time: np.ndarray
    F: np.ndarray


def _run_path(path: _Path) -> dict[str, np.ndarray]:
    """One RVE run along a stretch path (runs in a worker)."""
    result = run_program(path.network, path.config, make_linear_solver(path.config.solver.linear),
                         program=path_program(path.time, path.F))
    return {"F": result.F, "P": result.P, "yielded_fraction": result.yielded_fraction,
            "recruited_fraction": result.recruited_fraction}


@dataclass(frozen=True, eq=False)
class Surrogate:
    """Samples of the RVE's response along stretch paths and their interpolant.

    Attributes
    ----------
    E : (m, 3) float64
        Green-Lagrange strains (E11, E22, E12) of the samples.
    S : (m, 3) float64 [MPa]
        Second Piola-Kirchhoff stresses (S11, S22, S12).
    fields : dict of (m,) float64
        Yielded and recruited fractions.
    paths : (k, 3) float64
        The path directions (G11, G22, G12).
    seconds : float [s]
        Wall time of the RVE runs.
    """

    E: np.ndarray
    S: np.ndarray
    fields: dict[str, np.ndarray]
    paths: np.ndarray
    seconds: float

    def __post_init__(self) -> None:
        values = np.column_stack([self.S] + [self.fields[name] for name in _FIELDS])
        object.__setattr__(self, "_interpolant", RBFInterpolator(self.E, values, kernel="thin_plate_spline"))

    def _values(self, E: np.ndarray) -> np.ndarray:
        return self._interpolant(E)

    def stress(self, F: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """P (n, 2, 2) [MPa], A (n, 2, 2, 2, 2) [MPa] and the fractions at F (n, 2, 2)."""
        E = _green(F)
        n = len(E)
        probes = [E]
        for c in range(3):
            for sign in (1.0, -1.0):
                shifted = E.copy()
                shifted[:, c] += sign * _DIFFERENCE
                probes.append(shifted)
        values = self._values(np.concatenate(probes)).reshape(7, n, -1)
        S = _symmetric(values[0, :, :3])
        # dS/dE_c for c = (11, 22, 12); E12 is one value standing for E12 and E21.
        dS = [_symmetric((values[1 + 2 * c, :, :3] - values[2 + 2 * c, :, :3]) / (2.0 * _DIFFERENCE))
              for c in range(3)]
        D = np.zeros((n, 2, 2, 2, 2))  # dS_MJ / dE_LQ, symmetric in LQ
        D[:, :, :, 0, 0] = dS[0]
        D[:, :, :, 1, 1] = dS[1]
        D[:, :, :, 0, 1] = D[:, :, :, 1, 0] = 0.5 * dS[2]
        P = F @ S
        A = (np.einsum("ik,nLJ->niJkL", np.eye(2), S)
             + np.einsum("niM,nMJLQ,nkQ->niJkL", F, D, F))
        fields = {name: np.clip(values[0, :, 3 + i], 0.0, 1.0) for i, name in enumerate(_FIELDS)}
        return P, A, fields

    def material(self, n_points: int) -> SurrogateMaterial:
        """The surrogate as the material of ``n_points`` quadrature points."""
        return SurrogateMaterial(self, n_points)


class SurrogateMaterial:
    """A :class:`Surrogate` at quadrature points (a
    :class:`espin.specimen.materials.PointMaterial` without history)."""

    def __init__(self, surrogate: Surrogate, n_points: int) -> None:
        self.surrogate = surrogate
        self.n_points = n_points
        self._trial: dict[str, np.ndarray] = {name: np.zeros(n_points) for name in _FIELDS}
        self._fields = dict(self._trial)

    def evaluate(self, F: np.ndarray, time: float) -> tuple[np.ndarray, np.ndarray]:
        P, A, self._trial = self.surrogate.stress(F)
        return P, A

    def time_error(self) -> float:
        return 0.0

    def commit(self) -> None:
        self._fields = dict(self._trial)

    def rollback(self) -> None:
        pass

    def fields(self) -> dict[str, np.ndarray]:
        return dict(self._fields)


def build_surrogate(network: Network, config: Config, max_strain: float, *, reach: float = 3.0, steps: int = 24,
                    paths: Sequence[tuple[float, float, float]] = DEFAULT_PATHS,
                    pool: TaskPool | None = None) -> Surrogate:
    """Run the RVE along stretch paths and build the surrogate (module docstring).

    Parameters
    ----------
    network, config
        The RVE and its fiber law, solver and loading rate (``loading.strain_rate_per_s``).
    max_strain
        The specimen's largest grip strain; the paths reach a stretch of ``reach`` times it.
    reach
        How far beyond the grip strain the samples go (stress concentrations strain more).
    steps
        Recorded steps per path.
    paths
        Directions (G11, G22, G12) of U = I + t G.
    pool
        Where the RVE runs go (default: this process).

    Raises
    ------
    ConfigError
        For a bad option; SolverError when an RVE run fails.
    """
    if not 0.0 < max_strain <= 1.0:
        raise ConfigError(f"max_strain = {max_strain}: must be in (0, 1]")
    if not reach >= 1.0:
        raise ConfigError(f"reach = {reach}: must be >= 1")
    if int(steps) != steps or steps < 2:
        raise ConfigError(f"steps = {steps}: must be an integer >= 2")
    G = np.array(paths, dtype=float)
    if G.ndim != 2 or G.shape[1] != 3 or len(G) < 3 or np.any(np.abs(G).max(axis=1) == 0.0):
        raise ConfigError("paths: at least three non-zero directions (G11, G22, G12) are needed")
    G /= np.abs(G).max(axis=1, keepdims=True)
    shape = np.linspace(0.0, 1.0, steps + 1) ** 2  # dense at small strain: the yield knee
    tasks = []
    for g in G:
        # to reach x the grip strain, but U stays positive definite: its smallest eigenvalue >= 0.1
        smallest = np.linalg.eigvalsh(_symmetric(g)).min()
        t = min(reach * max_strain, 0.9 / -smallest if smallest < 0.0 else np.inf) * shape
        tasks.append(_Path(network, config, t / config.loading.strain_rate_per_s,
                           np.eye(2) + t[:, None, None] * _symmetric(g)[None]))
    pool = pool or TaskPool(workers=1)
    start = time_module.perf_counter()
    runs: list[dict[str, np.ndarray] | None] = [None] * len(tasks)
    for outcome in pool.map(_run_path, tasks):
        if not outcome.ok:
            raise SolverError(f"surrogate path {tuple(G[outcome.index])}: {outcome.error}")
        runs[outcome.index] = outcome.value
    seconds = time_module.perf_counter() - start
    F = np.concatenate([r["F"][1:] for r in runs])
    P = np.concatenate([r["P"][1:] for r in runs])
    S_full = np.linalg.solve(F, P)
    S = np.column_stack([S_full[:, 0, 0], S_full[:, 1, 1], 0.5 * (S_full[:, 0, 1] + S_full[:, 1, 0])])
    E = np.vstack([np.zeros(3), _green(F)])
    S = np.vstack([np.zeros(3), S])
    fields = {name: np.r_[0.0, np.concatenate([r[name][1:] for r in runs])] for name in _FIELDS}
    return Surrogate(E, S, fields, G, seconds)
