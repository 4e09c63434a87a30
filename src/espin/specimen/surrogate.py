"""A homogenized surrogate of the RVE for monotonic loading, built from RVE runs.

The RVE is pulled along straight paths of the right stretch tensor, U(t) = I + t G (G
symmetric, no rotation, its largest component 1), to t = ``reach`` times the specimen's grip
strain (less where U would lose 90 % of a stretch), with recorded steps growing as the square of
their number (dense at the yield knee), each path at several speeds dt/dtime (0.25 to 16 times
the loading's strain rate: the law is rate-dependent and the points of a specimen strain at
different rates). Every recorded step is a sample of the second Piola-Kirchhoff stress
S = F^-1 P at the Green-Lagrange strain E = (U^2 - I) / 2 (with the yielded and recruited
fractions). At each speed a thin-plate-spline radial-basis interpolant
(:class:`scipy.interpolate.RBFInterpolator`) through its samples gives S(E); between speeds S is
linear in log(speed), a point's speed being how fast its U changes over the time step. Then

    P = F S(E(F)),   A_iJkL = delta_ik S_LJ + F_iM dS_MJ/dE_LQ F_kQ,

with dS/dE by central differences of the interpolant (the speed's change with E included). E
and the speed depend on F through C = F^T F = U^2 only, so the surrogate is frame-indifferent
(P(R F) = R P(F) for any rotation R) and, as the RVE, anisotropic. It is a deformation-theory
law with a rate: exact on the sampled monotonic paths at the sampled speeds and an interpolation
between them, blind to unloading and to a path's history (checked against FE^2 in
docs/specimen.md).
"""

from __future__ import annotations

import time as time_module
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.interpolate import RBFInterpolator

from espin.core.config import Config
from espin.core.errors import ConfigError, InadmissibleState, SolverError
from espin.core.parallel import TaskPool
from espin.geometry.network import Network
from espin.mechanics.driver import run_program
from espin.mechanics.linear_solvers import make_linear_solver
from espin.mechanics.loading import path_program

__all__ = ["Surrogate", "SurrogateMaterial", "build_surrogate", "read_surrogate", "DEFAULT_PATHS", "DEFAULT_SPEEDS",
           "SAMPLE_COLUMNS"]

DEFAULT_PATHS = tuple((1.0, lateral, shear) for lateral in (-0.6, -0.3, 0.0, 0.35, 0.7)
                      for shear in (-0.5, 0.0, 0.5)) + (
    (0.0, 1.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0), (0.5, 1.0, 0.0), (-0.3, 1.0, 0.0))
"""Directions (G11, G22, G12) of the stretch paths U = I + t G, scaled so the largest |G_ij| is
1: stretches along the loading axis with lateral contraction or extension and shear, and
lateral stretch, contraction and shear alone."""

DEFAULT_SPEEDS = (0.25, 1.0, 4.0, 16.0)
"""Path speeds, over the loading's strain rate: each path is run at each (the law is
rate-dependent; in a specimen the points near a hole strain several times faster than the grips)."""

_FIELDS = ("yielded_fraction", "recruited_fraction")
SAMPLE_COLUMNS = ("E11", "E22", "E12", "strain_rate_per_s", "S11_MPa", "S22_MPa", "S12_MPa", *_FIELDS)
"""Columns of a surrogate's samples file (``surrogate_samples.csv``): the Green-Lagrange strain,
the path's speed as a strain rate [1/s], the second Piola-Kirchhoff stress and the fractions."""
_DIFFERENCE = 1e-6  # step of the central differences of S(E)


def _green(F: np.ndarray) -> np.ndarray:
    """(E11, E22, E12) of F (..., 2, 2)."""
    C = np.einsum("...kI,...kJ->...IJ", F, F)
    return np.stack([0.5 * (C[..., 0, 0] - 1.0), 0.5 * (C[..., 1, 1] - 1.0), 0.5 * C[..., 0, 1]], axis=-1)


def _stretch(E: np.ndarray) -> np.ndarray:
    """The right stretch tensor U = sqrt(I + 2 E) of (..., 3) Green-Lagrange strains, (..., 2, 2)."""
    C = np.eye(2) + 2.0 * _symmetric(E)
    root = np.sqrt(np.linalg.det(C))[..., None, None]
    return (C + root * np.eye(2)) / np.sqrt(np.trace(C, axis1=-2, axis2=-1)[..., None, None] + 2.0 * root)


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
    """Samples of the RVE's response along stretch paths at several speeds, and their interpolant.

    Attributes
    ----------
    E : (m, 3) float64
        Green-Lagrange strains (E11, E22, E12) of the samples.
    S : (m, 3) float64 [MPa]
        Second Piola-Kirchhoff stresses (S11, S22, S12).
    speed : (m,) float64
        The path speed of each sample, over ``strain_rate_per_s`` (one of ``speeds``).
    fields : dict of (m,) float64
        Yielded and recruited fractions.
    paths : (k, 3) float64
        The path directions (G11, G22, G12).
    speeds : tuple of float
        The path speeds run, increasing.
    strain_rate_per_s : float [1/s]
        The loading's strain rate (speed 1).
    seconds : float [s]
        Wall time of the RVE runs.

    At a point, S is interpolated in E at each speed (thin-plate splines through that speed's
    samples) and linearly in log(speed) between the two speeds around the point's own, clamped to
    the speeds run. A point's speed is max |U - U_n| / dt over the components of its stretch
    tensor's change over the time step, over ``strain_rate_per_s`` (a path's speed on its own
    samples); without a time step, 1.
    """

    E: np.ndarray
    S: np.ndarray
    speed: np.ndarray
    fields: dict[str, np.ndarray]
    paths: np.ndarray
    speeds: tuple[float, ...]
    strain_rate_per_s: float
    seconds: float

    def __post_init__(self) -> None:
        values = np.column_stack([self.S] + [self.fields[name] for name in _FIELDS])
        origin = np.all(self.E == 0.0, axis=1)
        interpolants = [RBFInterpolator(self.E[(self.speed == v) | origin], values[(self.speed == v) | origin],
                                        kernel="thin_plate_spline") for v in self.speeds]
        object.__setattr__(self, "_interpolants", interpolants)

    def _values(self, E: np.ndarray, speed: np.ndarray) -> np.ndarray:
        """Interpolated (S11, S22, S12, fractions) at strains E (n, 3) and speeds (n,)."""
        levels = np.log(np.asarray(self.speeds))
        # _interpolants: set by __post_init__ (not a field, so not compared, copied or shown)
        at = np.stack([interpolant(E) for interpolant in self._interpolants])  # type: ignore[attr-defined]
        if len(levels) == 1:
            return at[0]
        x = np.clip(np.log(speed), levels[0], levels[-1])
        upper = np.clip(np.searchsorted(levels, x, side="right"), 1, len(levels) - 1)
        weight = ((x - levels[upper - 1]) / (levels[upper] - levels[upper - 1]))[:, None]
        rows = np.arange(len(E))
        return (1.0 - weight) * at[upper - 1, rows] + weight * at[upper, rows]

    def stress(self, F: np.ndarray, U_start: np.ndarray | None = None, dt: float = 0.0
               ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """P (n, 2, 2) [MPa], A (n, 2, 2, 2, 2) [MPa] and the fractions at F (n, 2, 2), over a time
        step ``dt`` [s] from stretch tensors ``U_start`` (n, 2, 2) (None or dt = 0: at speed 1).

        The tangent includes the change of the speed with F."""
        J = np.linalg.det(F)
        if np.any(J <= 0.0):
            raise InadmissibleState(f"det F <= 0 at {int(np.sum(J <= 0.0))} point(s)")
        E = _green(F)
        n = len(E)
        probes = [E]
        for c in range(3):
            for sign in (1.0, -1.0):
                shifted = E.copy()
                shifted[:, c] += sign * _DIFFERENCE
                probes.append(shifted)
        E_all = np.concatenate(probes)
        if U_start is None or dt <= 0.0:
            speed = np.ones(len(E_all))
        else:
            change = _stretch(E_all) - np.concatenate([U_start] * 7)
            speed = np.abs(change).max(axis=(1, 2)) / (dt * self.strain_rate_per_s)
        values = self._values(E_all, np.maximum(speed, 1e-12)).reshape(7, n, -1)
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

    def table(self) -> np.ndarray:
        """The samples as rows of :data:`SAMPLE_COLUMNS`."""
        return np.column_stack([self.E, self.speed * self.strain_rate_per_s, self.S,
                                *(self.fields[name] for name in _FIELDS)])


class SurrogateMaterial:
    """A :class:`Surrogate` at quadrature points (a :class:`espin.specimen.materials.PointMaterial`):
    each point keeps its stretch tensor U and time at the last converged step, from which the
    speed of the next step follows."""

    def __init__(self, surrogate: Surrogate, n_points: int) -> None:
        self.surrogate = surrogate
        self.n_points = n_points
        self.symmetric_tangent = False  # dS/dE by differences of an interpolant: not a potential's
        self._U = np.tile(np.eye(2), (n_points, 1, 1))
        self._time = 0.0
        self._trial: tuple[np.ndarray, float, dict[str, np.ndarray]] | None = None
        self._fields = {name: np.zeros(n_points) for name in _FIELDS}

    def evaluate(self, F: np.ndarray, time: float) -> tuple[np.ndarray, np.ndarray]:
        P, A, fields = self.surrogate.stress(F, self._U, time - self._time)
        self._trial = (_stretch(_green(F)), time, fields)
        return P, A

    def time_error(self) -> float:
        return 0.0

    def commit(self) -> None:
        if self._trial is not None:
            self._U, self._time, self._fields = self._trial
            self._trial = None

    def rollback(self) -> None:
        self._trial = None

    def fields(self) -> dict[str, np.ndarray]:
        return dict(self._fields)


def build_surrogate(network: Network, config: Config, max_strain: float, *, reach: float = 3.0, steps: int = 24,
                    paths: Sequence[tuple[float, float, float]] = DEFAULT_PATHS,
                    speeds: Sequence[float] = DEFAULT_SPEEDS, pool: TaskPool | None = None) -> Surrogate:
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
    speeds
        Path speeds dt/dtime over the loading's strain rate; every path runs at each.
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
    rates = sorted(float(v) for v in speeds)
    if not rates or rates[0] <= 0.0 or len(set(rates)) != len(rates):
        raise ConfigError(f"speeds = {tuple(speeds)}: distinct positive factors of the strain rate are needed")
    G /= np.abs(G).max(axis=1, keepdims=True)
    shape = np.linspace(0.0, 1.0, steps + 1) ** 2  # dense at small strain: the yield knee
    tasks, task_speed = [], []
    rate = config.loading.strain_rate_per_s
    for speed in rates:
        for g in G:
            # to reach x the grip strain, but U stays positive definite: its smallest eigenvalue >= 0.1
            smallest = np.linalg.eigvalsh(_symmetric(g)).min()
            t = min(reach * max_strain, 0.9 / -smallest if smallest < 0.0 else np.inf) * shape
            tasks.append(_Path(network, config, t / (speed * rate), np.eye(2) + t[:, None, None] * _symmetric(g)[None]))
            task_speed.append(speed)
    pool = pool or TaskPool(workers=1)
    start = time_module.perf_counter()
    runs: list[Any] = [None] * len(tasks)  # each task's dict of arrays, all set below
    for outcome in pool.map(_run_path, tasks):
        if not outcome.ok:
            raise SolverError(f"surrogate path {tuple(G[outcome.index % len(G)])} at speed "
                              f"{task_speed[outcome.index]:g}: {outcome.error}")
        runs[outcome.index] = outcome.value
    seconds = time_module.perf_counter() - start
    F = np.concatenate([r["F"][1:] for r in runs])
    P = np.concatenate([r["P"][1:] for r in runs])
    S_full = np.linalg.solve(F, P)
    S = np.column_stack([S_full[:, 0, 0], S_full[:, 1, 1], 0.5 * (S_full[:, 0, 1] + S_full[:, 1, 0])])
    E = np.vstack([np.zeros(3), _green(F)])
    S = np.vstack([np.zeros(3), S])
    speed = np.r_[1.0, np.repeat(task_speed, [len(r["F"]) - 1 for r in runs])]
    fields = {name: np.r_[0.0, np.concatenate([r[name][1:] for r in runs])] for name in _FIELDS}
    return Surrogate(E, S, speed, fields, G, tuple(rates), rate, seconds)


def read_surrogate(path: str | Path, strain_rate_per_s: float) -> Surrogate:
    """A surrogate from the samples file of an earlier run (``surrogate_samples.csv``), for a
    loading at ``strain_rate_per_s`` [1/s] (the samples' speeds are relative to it).

    Raises
    ------
    ConfigError
        When the file is missing or is not a samples file.
    """
    import pandas as pd

    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"surrogate samples {path}: no such file (a surrogate run's surrogate_samples.csv)")
    try:
        table = pd.read_csv(path)
    except (ValueError, OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"surrogate samples {path}: cannot read it as CSV ({err})") from None
    missing = [c for c in SAMPLE_COLUMNS if c not in table.columns]
    values = table.reindex(columns=SAMPLE_COLUMNS).to_numpy(dtype=float, na_value=np.nan)
    if missing or len(table) < 10 or not np.all(np.isfinite(values)):
        raise ConfigError(f"surrogate samples {path}: expected the columns {', '.join(SAMPLE_COLUMNS)} with "
                          f"finite numbers{' (missing: ' + ', '.join(missing) + ')' if missing else ''}")
    speed = values[:, 3] / strain_rate_per_s
    origin = np.all(values[:, :3] == 0.0, axis=1)
    speeds = tuple(sorted(set(np.round(speed[~origin], 12))))
    speed = np.where(origin, 1.0, np.round(speed, 12))
    return Surrogate(values[:, :3], values[:, 4:7], speed, {name: values[:, 7 + i] for i, name in enumerate(_FIELDS)},
                     np.zeros((0, 3)), speeds, strain_rate_per_s, 0.0)
