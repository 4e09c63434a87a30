"""Pull on a specimen: the grip-displacement program and the macro Newton iterations.

The left grip is held, the right one moves along x by d(t) = grip strain(t) x grip length, at
the loading's strain rate (the fiber law is rate-dependent: a step of grip strain is a time
step of the same size for every quadrature point). Grips are ``clamped`` (u_y = 0 on both grip
faces) or ``sliding`` (u_y free but at one node, so the specimen contracts freely and a
homogeneous material stretches homogeneously). ``lateral = "fixed"`` holds u_y = 0 on the outer
sides too (the boundary chains that meet the grips; a hole and a notch stay free): the width
cannot change.

Each time step is solved by Newton's method on the free DOF with the materials' tangent: the
first iterate comes from the last converged tangent and the grip increment (no material call),
then K du = -r until max |r| <= rtol max |f| over the DOF (the grip reactions set the scale; the
scale is at least the force of 1e-6 of the strain at the tangent of the step). The time steps
are taken by the march (:mod:`espin.mechanics.march`, time = grip strain / strain rate): a step
whose materials fail (:class:`~espin.core.errors.StepNotConverged`), or whose Newton iterations
stall or exceed ``max_iterations``, is cut in half and the materials roll back to the last
converged state; after ``max_cuts`` halvings in a row the run stops with
:class:`SpecimenFailed`; with ``time_rtol`` the steps also follow the largest local error of
the points' plastic update (rejected steps roll back too). A material's state is committed
only when the macro step has converged and been accepted. Any other exception a material
raises is a bug and stops the run.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from skfem import Basis, ElementQuad1, ElementTriP1, MeshTri

from espin.core.errors import ConfigError, SolverError, StepFailureKind, StepNotConverged
from espin.mechanics.linear_solvers import make_linear_solver
from espin.mechanics.march import MarchFailed, ReportTally, StepPolicy, march
from espin.specimen.materials import PointMaterial
from espin.specimen.membrane import Membrane
from espin.specimen.mesh_checks import inside_cells
from espin.specimen.shapes import Specimen

log = logging.getLogger(__name__)

__all__ = ["SpecimenStep", "SpecimenFailed", "GripProgram", "MacroStep", "run_specimen", "GRIPS", "LATERAL"]

GRIPS = ("clamped", "sliding")
LATERAL = ("free", "fixed")


@dataclass(frozen=True)
class GripProgram:
    """Monotonic grip strain from 0 to ``max_strain`` in ``steps`` equal steps at a constant rate.

    Attributes
    ----------
    max_strain : float
        Final grip strain (grip displacement / grip length), in (0, 1].
    steps : int
        Recorded steps (>= 1); a step may be cut into smaller ones when it does not converge.
    strain_rate_per_s : float
        Grip strain rate [1/s] (the time step is the strain step divided by it).
    """

    max_strain: float
    steps: int
    strain_rate_per_s: float

    def __post_init__(self) -> None:
        if not 0.0 < self.max_strain <= 1.0:
            raise ConfigError(f"max_strain = {self.max_strain}: must be in (0, 1]")
        if int(self.steps) != self.steps or self.steps < 1:
            raise ConfigError(f"steps = {self.steps}: must be an integer >= 1")
        if not self.strain_rate_per_s > 0.0:
            raise ConfigError(f"strain_rate_per_s = {self.strain_rate_per_s}: must be > 0 1/s")

    @property
    def strain(self) -> np.ndarray:
        """Grip strain at the recorded steps, from 0 (step 0)."""
        return np.linspace(0.0, self.max_strain, self.steps + 1)


@dataclass(frozen=True, eq=False)
class SpecimenStep:
    """One converged, recorded step of the specimen.

    Attributes
    ----------
    index : int
        Step number (0: undeformed).
    time : float [s]
    grip_strain : float
        Grip displacement / grip length.
    displacement_mm : float
        Grip displacement d [mm].
    force_N : float
        Force on the moving grip along x [N] (its reaction).
    gauge_strain : float
        Engineering strain of the gauge length (extensometer on the centre line).
    gauge_stress_MPa : float
        Force / (gauge width x thickness) [MPa].
    gauge_transverse_strain : float
        Engineering strain across the gauge section, midway between the grips (a transverse
        extensometer over the material's width there: the gauge width, or the net width at a
        notch); negative when the specimen contracts.
    iterations, cuts, substeps : int
        Macro Newton iterations of the step (all attempts), its halvings and the time steps it took.
    residual_history : list of float [N]
        max |r| over the free DOF at each Newton iteration of the step's last sub-step.
    u : (n_dofs,) float64 [mm]
        Nodal displacements (scikit-fem's DOF order).
    F, P : (n_points, 2, 2) float64 [-, MPa]
        Deformation gradient and nominal stress at every quadrature point.
    fields : dict of (n_points,) float64
        The material's per-point scalars (e.g. yielded and recruited fractions).
    """

    index: int
    time: float
    grip_strain: float
    displacement_mm: float
    force_N: float
    gauge_strain: float
    gauge_stress_MPa: float
    gauge_transverse_strain: float
    iterations: int
    cuts: int
    substeps: int
    residual_history: list[float]
    u: np.ndarray
    F: np.ndarray
    P: np.ndarray
    fields: dict[str, np.ndarray] = field(default_factory=dict)


class SpecimenFailed(SolverError):
    """A macro step did not converge after all its cuts; ``steps`` holds the converged ones."""

    def __init__(self, message: str, steps: list[SpecimenStep]):
        super().__init__(message)
        self.steps = steps


def _outer_side_nodes(specimen: Specimen) -> np.ndarray:
    """Nodes of the free-edge chains that meet a grip (the outer sides; holes and a tagged
    ``notch`` boundary excluded)."""
    mesh = specimen.mesh
    facets = mesh.facets
    edge = np.asarray(specimen.mesh.boundaries["edge"])
    grip_nodes = np.unique(facets[:, np.r_[mesh.boundaries["grip_left"], mesh.boundaries["grip_right"]]])
    n = mesh.nvertices
    a, b = facets[0, edge], facets[1, edge]
    graph = sp.coo_matrix((np.ones(len(edge)), (a, b)), shape=(n, n))
    _, label = sp.csgraph.connected_components(graph, directed=False)
    edge_nodes = np.unique(facets[:, edge])
    sides = np.unique(label[np.intersect1d(edge_nodes, grip_nodes)])
    held = edge_nodes[np.isin(label[edge_nodes], sides)]
    if "notch" in mesh.boundaries:  # a notch stays free (the corners of its mouth are on the sides)
        notch = mesh.boundaries["notch"]
        held = np.setdiff1d(held, np.setdiff1d(facets[:, notch], facets[:, np.setdiff1d(edge, notch)]))
    return held


class _Constraints:
    """Which DOF are prescribed and their values at a grip strain."""

    def __init__(
        self,
        membrane: Membrane,
        specimen: Specimen,
        grips: str,
        lateral: str,
        affine_F: Callable[[float], np.ndarray] | None,
    ) -> None:
        if grips not in GRIPS:
            raise ConfigError(f"grips = {grips!r}: must be one of {', '.join(GRIPS)}")
        if lateral not in LATERAL:
            raise ConfigError(f"lateral = {lateral!r}: must be one of {', '.join(LATERAL)}")
        mesh = specimen.mesh
        dofs_x, dofs_y = membrane.basis.nodal_dofs
        self.length = specimen.grip_length_mm
        self.affine_F = affine_F

        def nodes(name: str) -> np.ndarray:
            return np.unique(mesh.facets[:, mesh.boundaries[name]])

        left, right = nodes("grip_left"), nodes("grip_right")
        self.moving = dofs_x[right]
        if affine_F is not None:
            boundary = mesh.boundary_nodes()
            self.dofs = np.concatenate([dofs_x[boundary], dofs_y[boundary]])
            self.reference = mesh.p[:, boundary]
        else:
            fixed_y = [left, right] if grips == "clamped" else [left[[np.argmin(np.abs(mesh.p[1, left]))]]]
            if lateral == "fixed":
                fixed_y.append(_outer_side_nodes(specimen))
            self.dofs = np.unique(np.concatenate([dofs_x[left], self.moving, dofs_y[np.concatenate(fixed_y)]]))
            self.is_moving = np.isin(self.dofs, self.moving)
        self.free = np.setdiff1d(np.arange(membrane.basis.N), self.dofs)

    def values(self, strain: float) -> np.ndarray:
        """Prescribed values of ``dofs`` [mm] at grip strain ``strain``."""
        if self.affine_F is not None:
            return ((self.affine_F(strain) - np.eye(2)) @ self.reference).ravel()
        return np.where(self.is_moving, strain * self.length, 0.0)


_TRANSVERSE_TRIALS = 200
"""Half-widths tried for the transverse extensometer, from W_g / 2 down toward 0."""


class _Extensometer:
    """u_x at the gauge marks on the centre line: (u(x_c + L_g / 2) - u(x_c - L_g / 2)) / L_g;
    and across: u_y at marks y_c +- h at x_c, h the largest half-width up to W_g / 2 whose
    marks both lie on the material (the net section at a notch),
    (u_y(y_c + h) - u_y(y_c - h)) / (2 h); NaN for a mesh with no material across x_c."""

    def __init__(self, membrane: Membrane, specimen: Specimen) -> None:
        mesh = specimen.mesh
        scalar = Basis(mesh, ElementTriP1() if isinstance(mesh, MeshTri) else ElementQuad1())
        centre = 0.5 * (mesh.p[0].min() + mesh.p[0].max())
        half = 0.5 * specimen.gauge_length_mm
        y = 0.5 * (mesh.p[1].min() + mesh.p[1].max())
        self.probes = scalar.probes(np.array([[centre - half, centre + half], [y, y]]))
        self.dofs_x = membrane.basis.nodal_dofs[0]
        self.dofs_y = membrane.basis.nodal_dofs[1]
        self.length = specimen.gauge_length_mm
        heights = 0.5 * specimen.gauge_width_mm * np.linspace(1.0, 0.0, _TRANSVERSE_TRIALS, endpoint=False)
        marks = np.concatenate(
            [np.column_stack([np.full_like(heights, centre), y + sign * heights]) for sign in (1, -1)]
        )
        on = inside_cells(mesh.p, mesh.t, marks).reshape(2, -1).all(axis=0)
        self.height = float(heights[np.argmax(on)])
        self.across = (
            scalar.probes(np.array([[centre, centre], [y - self.height, y + self.height]])) if on.any() else None
        )

    def strain(self, u: np.ndarray) -> float:
        ends = self.probes @ u[self.dofs_x]
        return float((ends[1] - ends[0]) / self.length)

    def transverse_strain(self, u: np.ndarray) -> float:
        if self.across is None:
            return float("nan")
        ends = self.across @ u[self.dofs_y]
        return float((ends[1] - ends[0]) / (2.0 * self.height))


@dataclass(frozen=True, eq=False)
class MacroStep:
    """A converged macro Newton solve of one time step.

    Attributes
    ----------
    u : (n_dofs,) float64 [mm]
        Nodal displacements.
    F, P : (n_points, 2, 2) float64 [-, MPa]
        Deformation gradient and nominal stress at the quadrature points.
    f : (n_dofs,) float64 [N]
        Internal nodal forces (reactions on the prescribed DOF).
    K : (n_dofs, n_dofs) sparse [N/mm]
        The tangent at the solution (the next step's predictor).
    iterations, factorizations : int
        Newton iterations and linear factorizations.
    history : list of float [N]
        max |r| over the free DOF at each iteration.
    """

    u: np.ndarray
    F: np.ndarray
    P: np.ndarray
    f: np.ndarray
    K: sp.csr_matrix
    iterations: int
    factorizations: int
    history: list[float]


class _MacroSolves:
    """Factorizations of the free block of the macro tangent: espin's symmetric solvers (PARDISO or
    SuperLU, the pattern analysed once per run) for a material with a symmetric tangent, else
    SuperLU's LU with partial pivoting."""

    def __init__(self, symmetric: bool) -> None:
        self.linear = make_linear_solver("auto") if symmetric else None

    def factorize(self, K: sp.csr_matrix) -> Callable[[np.ndarray], np.ndarray]:
        """The solve of K x = b, as a function of b."""
        if K.shape[0] == 0:  # every DOF prescribed (a patch test on one element)
            return np.copy
        if self.linear is not None:
            return self.linear.factorize(K.tocsr()).solve
        try:
            return spla.splu(K.tocsc()).solve
        except RuntimeError as exc:  # "Factor is exactly singular": the step is cut
            raise StepNotConverged(
                f"LU factorization of the {K.shape[0]}-unknown macro tangent failed: {exc}", StepFailureKind.SINGULAR
            ) from exc


class _GripSteps:
    """The specimen under its grip program as a :class:`~espin.mechanics.march.StepProblem`:
    time t is grip strain / strain rate, each attempt one macro Newton solve."""

    def __init__(
        self,
        membrane: Membrane,
        material: PointMaterial,
        constraints: _Constraints,
        program: GripProgram,
        rtol: float,
        max_iterations: int,
        start: MacroStep,
    ) -> None:
        self.membrane, self.material, self.constraints, self.program = membrane, material, constraints, program
        self.rtol, self.iteration_limit = rtol, max_iterations
        self.state = start
        self.solves = _MacroSolves(material.symmetric_tangent)

    def attempt(self, start: float, end: float) -> MacroStep:
        strain = end * self.program.strain_rate_per_s
        return _newton(
            self.membrane,
            self.material,
            self.constraints,
            self.solves,
            self.state,
            self.constraints.values(strain),
            end,
            self.rtol,
            self.iteration_limit,
        )

    def error(self, trial: MacroStep) -> float:
        return self.material.time_error()

    def commit(self, trial: MacroStep) -> None:
        self.material.commit()
        self.state = trial

    def rollback(self) -> None:
        self.material.rollback()


def run_specimen(
    specimen: Specimen,
    material: PointMaterial,
    program: GripProgram,
    *,
    thickness_mm: float,
    grips: str = "clamped",
    lateral: str = "free",
    rtol: float = 1e-6,
    time_rtol: float | None = None,
    max_iterations: int = 25,
    max_cuts: int = 8,
    affine_F: Callable[[float], np.ndarray] | None = None,
    on_step: Callable[[SpecimenStep], None] | None = None,
    membrane: Membrane | None = None,
) -> list[SpecimenStep]:
    """Run the grip program on the specimen (module docstring).

    Parameters
    ----------
    specimen
        Geometry and mesh [mm].
    material
        The material at the membrane's quadrature points (``material.n_points`` of them, in
        :class:`Membrane` order).
    program
        Grip strain steps and rate.
    thickness_mm
        Specimen thickness [mm].
    grips, lateral
        Boundary conditions (module docstring).
    rtol
        Macro tolerance: max |r| over free DOF <= rtol max |f|.
    time_rtol
        Largest relative local error of the plastic update at any point per time step
        (:func:`espin.mechanics.time_steps.local_error`): a step over it is done again, smaller,
        and the next step follows it, as in a single RVE's test. None: the program's steps,
        halved only when Newton fails.
    max_iterations
        Newton iterations per (sub-)step before it is cut.
    max_cuts
        Halvings in a row before the run stops.
    affine_F
        The patch test: every boundary node follows x = F(grip strain) X (grips and lateral
        are then ignored); None: the grips.
    on_step
        Called with each recorded step as it converges.
    membrane
        The finite-element space (default: built on the specimen's mesh).

    Returns
    -------
    list of SpecimenStep
        Step 0 (undeformed) and every recorded step.

    Raises
    ------
    SpecimenFailed
        When a step does not converge after ``max_cuts`` halvings in a row, or its time steps
        fall below the smallest.
    """
    if not thickness_mm > 0.0:
        raise ConfigError(f"thickness_mm = {thickness_mm}: must be > 0 mm")
    if not 0.0 < rtol < 1.0:
        raise ConfigError(f"rtol = {rtol}: must be in (0, 1)")
    membrane = membrane or Membrane(specimen.mesh, thickness_mm)
    if material.n_points != membrane.n_points:
        raise ConfigError(f"the material has {material.n_points} points, the mesh {membrane.n_points}")
    constraints = _Constraints(membrane, specimen, grips, lateral, affine_F)
    gauge = _Extensometer(membrane, specimen)
    area = specimen.gauge_width_mm * thickness_mm

    u = np.zeros(membrane.n_dofs)
    F = membrane.deformation_gradient(u)
    P, A = material.evaluate(F, 0.0)
    material.commit()
    f = membrane.internal_force(P)
    problem = _GripSteps(
        membrane,
        material,
        constraints,
        program,
        rtol,
        max_iterations,
        MacroStep(u, F, P, f, membrane.tangent(A), 0, 0, []),
    )
    steps: list[SpecimenStep] = []

    def record(index: int, time: float, state: MacroStep, counts: tuple[int, int, int], history: list[float]):
        strain = float(program.strain[index])
        force = float(state.f[constraints.moving].sum())
        step = SpecimenStep(
            index,
            time,
            strain,
            strain * specimen.grip_length_mm,
            force,
            gauge.strain(state.u),
            force / area,
            gauge.transverse_strain(state.u),
            *counts,
            history,
            state.u.copy(),
            state.F,
            state.P,
            material.fields(),
        )
        steps.append(step)
        if on_step is not None:
            on_step(step)

    def reached(tally: ReportTally[MacroStep]) -> None:
        assert tally.trial is not None
        counts = (tally.iterations, tally.cuts, tally.substeps)
        record(tally.index, tally.time, tally.trial, counts, tally.trial.history)

    record(0, 0.0, problem.state, (0, 0, 0), [])
    try:
        march(
            problem,
            program.strain[1:] / program.strain_rate_per_s,
            StepPolicy(time_rtol=time_rtol, max_cuts=max_cuts),
            on_report=reached,
        )
    except MarchFailed as stopped:
        raise SpecimenFailed(_failure_message(stopped, program, max_cuts), steps) from None
    return steps


def _failure_message(stopped: MarchFailed, program: GripProgram, max_cuts: int) -> str:
    """Where the grip program stopped, why, and what to try."""
    failure = stopped.failure
    strain = stopped.time * program.strain_rate_per_s
    where = f"step {stopped.tally.index} of {program.steps} (grip strain {strain:.4g})"
    if failure.kind == StepFailureKind.STIFF:
        return (
            f"{where}: {failure.reason}; the plastic flow is too fast to follow: check fiber.flow_rate_per_s "
            "and fiber.flow_resistance_MPa, or raise solver.time_rtol"
        )
    return (
        f"{where} did not converge after {max_cuts} halvings in a row: {failure.reason}. Try more steps, or a "
        "smaller max_strain"
    )


def _newton(
    membrane: Membrane,
    material: PointMaterial,
    constraints: _Constraints,
    solves: _MacroSolves,
    start: MacroStep,
    prescribed: np.ndarray,
    time: float,
    rtol: float,
    max_iterations: int,
) -> MacroStep:
    """One time step from the converged ``start`` to the ``prescribed`` values at ``time``.

    Raises
    ------
    StepNotConverged
        When the material cannot follow (its own failure, passed on) or Newton stalls.
    """
    free, dofs = constraints.free, constraints.dofs
    u = start.u.copy()
    step = prescribed - start.u[dofs]
    u[dofs] += step
    K0 = start.K
    u[free] += solves.factorize(K0[free][:, free])(-(start.f[free] + K0[free][:, dofs] @ step))
    factorizations = 1
    # The residual scale: at least the force that 1e-6 of the increment makes at this tangent.
    floor = 1e-6 * float(np.max(np.abs(K0[:, dofs] @ step), initial=0.0))
    history: list[float] = []
    for iteration in range(max_iterations + 1):
        F = membrane.deformation_gradient(u)
        P, A = material.evaluate(F, time)
        f = membrane.internal_force(P)
        norm = float(np.max(np.abs(f[free]), initial=0.0))
        history.append(norm)
        if norm <= rtol * max(float(np.max(np.abs(f))), floor):
            return MacroStep(u, F, P, f, membrane.tangent(A), iteration, factorizations, history)
        if not np.isfinite(norm) or (iteration >= 4 and norm > history[-4]) or iteration == max_iterations:
            break
        K = membrane.tangent(A)
        u[free] -= solves.factorize(K[free][:, free])(f[free])
        factorizations += 1
    raise StepNotConverged(
        f"Newton stalled (max |r| {history[0]:.3g} -> {history[-1]:.3g} N in {len(history) - 1} iterations)",
        history=history,
        factorizations=factorizations,
    )
