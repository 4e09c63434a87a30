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
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.interpolate import RBFInterpolator

from espin.core.config import Config
from espin.core.errors import ConfigError, InadmissibleState, InputError, SolverError
from espin.core.parallel import TaskPool
from espin.core.progress import clock
from espin.geometry.network import Network
from espin.mechanics.driver import SimulationFailed, run_program
from espin.mechanics.linear_solvers import make_linear_solver
from espin.mechanics.loading import path_program
from espin.specimen.surrogate_file import SampleIdentity, mat_identity, read_samples, write_samples

__all__ = [
    "Surrogate",
    "SurrogateMaterial",
    "build_surrogate",
    "read_surrogate",
    "DEFAULT_PATHS",
    "DEFAULT_SPEEDS",
    "sample_rows",
]

DEFAULT_PATHS = tuple(
    (1.0, lateral, shear) for lateral in (-0.6, -0.3, 0.0, 0.35, 0.7) for shear in (-0.5, 0.0, 0.5)
) + ((0.0, 1.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0), (0.5, 1.0, 0.0), (-0.3, 1.0, 0.0))
"""Directions (G11, G22, G12) of the stretch paths U = I + t G, scaled so the largest |G_ij| is
1: stretches along the loading axis with lateral contraction or extension and shear, and
lateral stretch, contraction and shear alone."""

DEFAULT_SPEEDS = (0.25, 1.0, 4.0, 16.0)
"""Path speeds, over the loading's strain rate: each path is run at each (the law is
rate-dependent; in a specimen the points near a hole strain several times faster than the grips)."""

_FIELDS = ("yielded_fraction", "recruited_fraction")
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
    stretch: np.ndarray
    U: np.ndarray
    strain_rate_per_s: float


def _run_path(path: _Path) -> np.ndarray | _PathFailure:
    """One RVE run along a stretch path (runs in a worker): its rows of the samples file (without
    the path column), one per recorded step.

    A step that does not converge gives a :class:`_PathFailure`: which step, at which stretch
    of the path (the stretch parameter t of U = I + t G) and why.
    """
    try:
        result = run_program(
            path.network,
            path.config,
            make_linear_solver(path.config.solver.linear),
            program=path_program(path.time, path.U, strain=path.stretch),
        )
    except SimulationFailed as failure:
        return _PathFailure(
            f"step {failure.step} of {failure.n_steps} (path strain {failure.strain:.4g}, time "
            f"{failure.time:.4g} s) did not converge: {failure.reason}",
            float(failure.strain),
        )
    return sample_rows(
        result.F[1:], result.P[1:], path.strain_rate_per_s, result.yielded_fraction[1:], result.recruited_fraction[1:]
    )


def sample_rows(
    F: np.ndarray, P: np.ndarray, strain_rate_per_s: float, yielded: np.ndarray, recruited: np.ndarray
) -> np.ndarray:
    """Rows (E11, E22, E12, strain rate [1/s], S11, S22, S12 [MPa], yielded and recruited
    fractions) of recorded steps with deformation gradients F (n, 2, 2) and nominal stresses P
    (n, 2, 2) [MPa]."""
    S_full = np.linalg.solve(F, P)
    S = np.column_stack([S_full[:, 0, 0], S_full[:, 1, 1], 0.5 * (S_full[:, 0, 1] + S_full[:, 1, 0])])
    return np.column_stack([_green(F), np.full(len(F), strain_rate_per_s), S, yielded, recruited])


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
        Wall time of the RVE runs (0 for samples read from a file).
    identity : SampleIdentity
        Whose samples these are and how they were built (the samples file's header).
    runs : dict of int to (steps, 9) float64
        The samples path by path, as the samples file holds them
        (:mod:`espin.specimen.surrogate_file`).

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
    identity: SampleIdentity
    runs: dict[int, np.ndarray]

    def __post_init__(self) -> None:
        values = np.column_stack([self.S] + [self.fields[name] for name in _FIELDS])
        origin = np.all(self.E == 0.0, axis=1)
        interpolants = [
            RBFInterpolator(
                self.E[(self.speed == v) | origin], values[(self.speed == v) | origin], kernel="thin_plate_spline"
            )
            for v in self.speeds
        ]
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

    def stress(
        self, F: np.ndarray, U_start: np.ndarray | None = None, dt: float = 0.0
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
            crushed = np.linalg.det(np.eye(2) + 2.0 * _symmetric(E_all)) <= 0.0
            if np.any(crushed):  # J so small that a probe of dS/dE inverts the point
                raise InadmissibleState(f"det F near 0 at {len(np.unique(np.nonzero(crushed)[0] % n))} point(s)")
            change = _stretch(E_all) - np.concatenate([U_start] * 7)
            speed = np.abs(change).max(axis=(1, 2)) / (dt * self.strain_rate_per_s)
        values = self._values(E_all, np.maximum(speed, 1e-12)).reshape(7, n, -1)
        S = _symmetric(values[0, :, :3])
        # dS/dE_c for c = (11, 22, 12); E12 is one value standing for E12 and E21.
        dS = [_symmetric((values[1 + 2 * c, :, :3] - values[2 + 2 * c, :, :3]) / (2.0 * _DIFFERENCE)) for c in range(3)]
        D = np.zeros((n, 2, 2, 2, 2))  # dS_MJ / dE_LQ, symmetric in LQ
        D[:, :, :, 0, 0] = dS[0]
        D[:, :, :, 1, 1] = dS[1]
        D[:, :, :, 0, 1] = D[:, :, :, 1, 0] = 0.5 * dS[2]
        P = F @ S
        A = np.einsum("ik,nLJ->niJkL", np.eye(2), S) + np.einsum("niM,nMJLQ,nkQ->niJkL", F, D, F)
        fields = {name: np.clip(values[0, :, 3 + i], 0.0, 1.0) for i, name in enumerate(_FIELDS)}
        return P, A, fields

    def material(self, n_points: int) -> SurrogateMaterial:
        """The surrogate as the material of ``n_points`` quadrature points."""
        return SurrogateMaterial(self, n_points)

    @classmethod
    def from_runs(
        cls, identity: SampleIdentity, runs: dict[int, np.ndarray], paths: np.ndarray, seconds: float = 0.0
    ) -> Surrogate:
        """The surrogate of the finished paths ``runs`` of a build (rows as in the samples file)
        and the unstrained origin."""
        table = np.concatenate([runs[k] for k in sorted(runs)])
        speed = np.concatenate([np.full(len(runs[k]), identity.speeds[k // identity.directions]) for k in sorted(runs)])
        fields = {name: np.r_[0.0, table[:, 7 + i]] for i, name in enumerate(_FIELDS)}
        return cls(
            np.vstack([np.zeros(3), table[:, :3]]),
            np.vstack([np.zeros(3), table[:, 4:7]]),
            np.r_[1.0, speed],
            fields,
            paths,
            identity.speeds,
            identity.strain_rate_per_s,
            seconds,
            identity,
            dict(runs),
        )


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


@dataclass(frozen=True)
class _PathFailure:
    """A path whose RVE run did not converge: the message and the path strain it reached."""

    message: str
    strain: float


def build_surrogate(
    network: Network,
    config: Config,
    max_strain: float,
    *,
    reach: float = 3.0,
    steps: int = 24,
    paths: Sequence[tuple[float, float, float]] = DEFAULT_PATHS,
    speeds: Sequence[float] = DEFAULT_SPEEDS,
    pool: TaskPool | None = None,
    samples_path: str | Path | None = None,
    report: Callable[[str], None] | None = None,
) -> Surrogate:
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
    samples_path
        The samples file (:mod:`espin.specimen.surrogate_file`), written again as each path
        finishes; the finished paths it already holds for this very build (an interrupted or failed
        earlier run) are used instead of run again. None: nothing written or reused.
    report
        Called with a line when the build starts and when each path finishes (the command line
        repeats the last one while a path runs: :func:`espin.cli.common.off_terminal_lines`);
        None: silent.

    Raises
    ------
    ConfigError
        For a bad option; SolverError when an RVE run fails (the path, the strain it reached, why,
        what to try, and where the finished paths are kept).
    """
    if not 0.0 < max_strain <= 1.0:
        raise ConfigError(f"max_strain = {max_strain:g}: must be in (0, 1]")
    if not reach >= 1.0:
        raise ConfigError(f"reach = {reach:g}: must be >= 1")
    if int(steps) != steps or steps < 2:
        raise ConfigError(f"steps = {steps}: must be an integer >= 2")
    G = np.array(paths, dtype=float)
    if G.ndim != 2 or G.shape[1] != 3 or len(G) < 3 or np.any(np.abs(G).max(axis=1) == 0.0):
        raise ConfigError("paths: at least three non-zero directions (G11, G22, G12) are needed")
    rates = sorted(float(v) for v in speeds)
    if not rates or rates[0] <= 0.0 or len(set(rates)) != len(rates):
        raise ConfigError(
            f"speeds = {', '.join(f'{v:g}' for v in speeds)}: distinct positive factors of the strain rate are needed"
        )
    G /= np.abs(G).max(axis=1, keepdims=True)
    rate = config.loading.strain_rate_per_s
    identity = SampleIdentity(
        *mat_identity(config), rate, float(max_strain), float(reach), int(steps), len(G), tuple(rates)
    )
    shape = np.linspace(0.0, 1.0, steps + 1) ** 2  # dense at small strain: the yield knee
    tasks, ends = [], []
    for speed in rates:
        for g in G:
            # to reach x the grip strain, but U stays positive definite: its smallest eigenvalue >= 0.1
            smallest = np.linalg.eigvalsh(_symmetric(g)).min()
            t = min(reach * max_strain, 0.9 / -smallest if smallest < 0.0 else np.inf) * shape
            U = np.eye(2) + t[:, None, None] * _symmetric(g)[None]
            tasks.append(_Path(network, config, t / (speed * rate), t, U, speed * rate))
            ends.append(t[-1])
    runs = _kept_runs(samples_path, identity, report)
    todo = [k for k in range(len(tasks)) if k not in runs]
    pool = pool or TaskPool(workers=1)
    start = time_module.perf_counter()

    def name(k: int) -> str:
        g = G[k % len(G)]
        return (
            f"path {k + 1} of {len(tasks)} (U = I + t G, G = ({g[0]:g}, {g[1]:g}, {g[2]:g}), to t = "
            f"{ends[k]:.3g}, at {rates[k // len(G)]:g} x the strain rate)"
        )

    def status() -> str:
        elapsed = time_module.perf_counter() - start
        finished = len(runs) - (len(tasks) - len(todo))
        left = f", about {clock(elapsed / finished * (len(todo) - finished))} left" if finished else ""
        return f"surrogate: {len(runs)} of {len(tasks)} RVE paths done{left}"

    say = report or (lambda line: None)
    say(
        f"surrogate: {len(tasks)} RVE paths ({len(G)} directions x {len(rates)} speeds, {steps} steps each, to "
        f"{reach:g} x the grip strain {max_strain:g}) on {pool.description}"
        + (f"; {len(runs)} finished paths reused from {samples_path}" if runs else "")
    )
    for outcome in pool.map(_run_path, [tasks[k] for k in todo]):
        k = todo[outcome.index]
        if not outcome.ok or isinstance(outcome.value, _PathFailure):
            raise SolverError(_failure(name(k), outcome, ends[k], identity, len(runs), samples_path)) from None
        runs[k] = outcome.value
        if samples_path is not None:
            write_samples(Path(samples_path), identity, runs)
        say(f"{status()}: {name(k)} in {outcome.seconds:.0f} s")
    return Surrogate.from_runs(identity, runs, G, time_module.perf_counter() - start)


def _kept_runs(
    samples_path: str | Path | None, identity: SampleIdentity, report: Callable[[str], None] | None
) -> dict[int, np.ndarray]:
    """The finished paths of this build already in ``samples_path`` (none when there is no file or
    it is of another build, which the build then replaces, saying so)."""
    if samples_path is None or not Path(samples_path).is_file():
        return {}
    kept = read_samples(samples_path)
    if kept.identity != identity:
        if report is not None:
            report(
                f"surrogate: {samples_path} holds the paths of another build (another mat or settings); starting again"
            )
        return {}
    return dict(kept.runs)


def _failure(
    name: str, outcome, end: float, identity: SampleIdentity, finished: int, samples_path: str | Path | None
) -> str:
    """The message of a failed path: which, where, why, what to try and what is kept."""
    failure = outcome.value if isinstance(outcome.value, _PathFailure) else None
    why = failure.message if failure is not None else str(outcome.error).removeprefix("SolverError: ")
    grip = identity.max_strain
    if failure is not None and failure.strain > grip:
        reach = np.floor(9.0 * failure.strain / grip) / 10.0
        advice = (
            f"a smaller reach (--surrogate-reach {reach:g}: the paths go to {identity.reach:g} x the grip "
            f"strain, this one failed at {failure.strain / grip:.2g} x)"
            if reach >= 1.0
            else f"a smaller --max-strain (below {failure.strain:.3g})"
        )
    elif failure is not None:
        advice = f"a smaller --max-strain (this path failed at strain {failure.strain:.3g}, below the grip strain)"
    else:
        advice = "a smaller --max-strain or --surrogate-reach"
    kept = (
        f"; the {finished} finished paths are kept in {samples_path} (the same command into the same folder "
        "resumes from them)"
        if samples_path is not None and finished
        else ""
    )
    return (
        f"surrogate: the RVE run along {name} failed: {why}. Try {advice}, or --model fe2 (each point's RVE "
        f"follows its own path){kept}"
    )


def read_surrogate(path: str | Path, config: Config, max_strain: float, allow_mismatch: bool = False) -> Surrogate:
    """A surrogate from the samples file of an earlier run (``surrogate_samples.csv``), for a
    specimen of the mat ``config`` pulled to the grip strain ``max_strain``.

    Parameters
    ----------
    path
        The samples file (:mod:`espin.specimen.surrogate_file`).
    config
        The run's mat: the samples must be of it (config digest, law and strain rate).
    max_strain
        The run's grip strain: at most the one the samples were built for.
    allow_mismatch
        Use samples of another mat or build anyway (the user knows why); the mismatch is still
        recorded (:attr:`Surrogate.identity` against the run's).

    Raises
    ------
    ConfigError
        When the file is missing, or its samples are not of this mat or reach (unless
        ``allow_mismatch``).
    InputError
        When the file is not a whole samples file (:func:`espin.specimen.surrogate_file.read_samples`).
    """
    samples = read_samples(path)
    if not samples.complete:
        raise InputError(
            f"surrogate_from: {path}: holds {len(samples.runs)} of the build's "
            f"{samples.identity.n_paths} paths (an interrupted build); rerun that build (the same "
            "command into the same folder) to finish it"
        )
    mismatches = samples.identity.mismatches(surrogate_identity(config, max_strain))
    if mismatches and not allow_mismatch:
        raise ConfigError(
            f"surrogate_from: {path}: " + "; ".join(mismatches) + ". Build the surrogate for this "
            "mat (without --surrogate-from), or pass --allow-surrogate-mismatch to use these samples "
            "anyway"
        )
    return Surrogate.from_runs(samples.identity, samples.runs, np.zeros((0, 3)))


def surrogate_identity(config: Config, max_strain: float) -> SampleIdentity:
    """The identity a build of the mat ``config`` for the grip strain ``max_strain`` would have
    (default paths, speeds, reach and steps; only the mat, the strain rate and the strain are
    compared with a file's)."""
    return SampleIdentity(
        *mat_identity(config),
        config.loading.strain_rate_per_s,
        float(max_strain),
        3.0,
        24,
        len(DEFAULT_PATHS),
        DEFAULT_SPEEDS,
    )
