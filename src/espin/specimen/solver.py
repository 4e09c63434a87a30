"""Pull on a specimen: the grip-displacement program and the macro Newton iterations.

The left grip is held, the right one moves along x by d(t) = grip strain(t) x grip length, at
the loading's strain rate (the fiber law is rate-dependent: a step of grip strain is a time
step of the same size for every quadrature point). Grips are ``clamped`` (u_y = 0 on both grip
faces) or ``sliding`` (u_y free but at one node, so the specimen contracts freely and a
homogeneous material stretches homogeneously). ``lateral = "fixed"`` holds u_y = 0 on the outer
sides too (the boundary chains that meet the grips; a hole and a notch stay free): the width
cannot change.

Each step is solved by Newton's method on the free DOF with the materials' tangent: the first
iterate comes from the last converged tangent and the grip increment (no material call), then
K du = -r until max |r| <= rtol max |f| over the DOF (the grip reactions set the scale; the
scale is at least the force of 1e-6 of the strain at the tangent of the step). A step whose
materials fail, or whose Newton iterations stall or exceed ``max_iterations``, is cut in half
(time and grip displacement together) and the materials roll back to the last converged state;
after ``max_cuts`` halvings in a row the run stops with :class:`SpecimenFailed`; a step that
converged easily lets the next one double. With ``time_rtol`` the time steps also follow the
largest local error of the points' plastic update (rejected steps roll back too), never longer
right after a cut than the cut step. A material's state is committed only when the macro step
has converged and been accepted.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from skfem import Basis, ElementQuad1, ElementTriP1, MeshTri

from espin.core.errors import ConfigError, SolverError
from espin.mechanics.time_steps import StepSizeControl, split
from espin.specimen.materials import PointMaterial
from espin.specimen.membrane import Membrane
from espin.specimen.shapes import Specimen

log = logging.getLogger(__name__)

__all__ = ["SpecimenStep", "SpecimenFailed", "GripProgram", "run_specimen", "GRIPS", "LATERAL"]

MAX_TIME_STEPS_PER_STEP = 10_000
"""Time steps (accepted, rejected or cut) one recorded step may take before the run fails."""
_EASY = 0.2  # of the iteration limit: a sub-step that converged in fewer may let the next double

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

    def __init__(self, membrane: Membrane, specimen: Specimen, grips: str, lateral: str,
                 affine_F: Callable[[float], np.ndarray] | None) -> None:
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


class _Extensometer:
    """u_x at the gauge marks on the centre line: (u(x_c + L_g / 2) - u(x_c - L_g / 2)) / L_g."""

    def __init__(self, membrane: Membrane, specimen: Specimen) -> None:
        mesh = specimen.mesh
        scalar = Basis(mesh, ElementTriP1() if isinstance(mesh, MeshTri) else ElementQuad1())
        centre = 0.5 * (mesh.p[0].min() + mesh.p[0].max())
        half = 0.5 * specimen.gauge_length_mm
        y = 0.5 * (mesh.p[1].min() + mesh.p[1].max())
        self.probes = scalar.probes(np.array([[centre - half, centre + half], [y, y]]))
        self.dofs_x = membrane.basis.nodal_dofs[0]
        self.length = specimen.gauge_length_mm

    def strain(self, u: np.ndarray) -> float:
        ends = self.probes @ u[self.dofs_x]
        return float((ends[1] - ends[0]) / self.length)


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
        When a step does not converge after ``max_cuts`` halvings.
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
    control = None if time_rtol is None else StepSizeControl(time_rtol)

    u = np.zeros(membrane.n_dofs)
    F = membrane.deformation_gradient(u)
    P, A = material.evaluate(F, 0.0)
    material.commit()
    f = membrane.internal_force(P)
    K = membrane.tangent(A)
    steps: list[SpecimenStep] = []

    def record(index: int, time: float, strain: float, counts: tuple[int, int, int], history: list[float]):
        force = float(f[constraints.moving].sum())
        step = SpecimenStep(index, time, strain, strain * specimen.grip_length_mm, force, gauge.strain(u),
                            force / area, *counts, history, u.copy(), F, P, material.fields())
        steps.append(step)
        if on_step is not None:
            on_step(step)

    record(0, 0.0, 0.0, (0, 0, 0), [])
    strain_now, time_now = 0.0, 0.0
    increment: float | None = None  # the sub-step in grip strain, carried between recorded steps
    for index, target in enumerate(program.strain[1:], start=1):
        iterations, cuts, substeps, history = 0, 0, 0, []
        in_a_row = 0  # halvings since the last converged sub-step
        smallest = 1e-9 * (target - strain_now)
        attempts = 0
        while strain_now < target - 1e-12 * target:
            attempts += 1
            h = split(target - strain_now, increment)
            if attempts > MAX_TIME_STEPS_PER_STEP or h < smallest:
                raise SpecimenFailed(
                    f"step {index} of {program.steps} (grip strain {strain_now:.4g}): the time steps the "
                    f"points' local error asks for fell below {smallest:.3g} in grip strain (or exceeded "
                    f"{MAX_TIME_STEPS_PER_STEP:,}); the plastic flow is too fast to follow: check "
                    "fiber.flow_rate_per_s and fiber.flow_resistance_MPa, or raise solver.time_rtol", steps)
            next_strain = target if h == target - strain_now else strain_now + h
            next_time = time_now + h / program.strain_rate_per_s
            try:
                solved = _newton(membrane, material, constraints, u, f, K, constraints.values(next_strain),
                                 next_time, rtol, max_iterations)
            except _NotConverged as failure:
                iterations += failure.iterations
                material.rollback()
                cuts += 1
                in_a_row += 1
                if in_a_row > max_cuts:
                    raise SpecimenFailed(
                        f"step {index} of {program.steps} (grip strain {next_strain:.4g}) did not converge "
                        f"after {max_cuts} halvings in a row: {failure.reason}. Try more steps, or a smaller "
                        "max_strain", steps) from None
                increment = 0.5 * h
                log.info("grip strain %.4g: step cut to %.3g (%s)", next_strain, increment, failure.reason)
                continue
            iterations += solved[5]
            # grow again after an easy step, as a single RVE's driver does; never beyond a halving's size
            # right after a cut
            grown = 2.0 * h if solved[5] <= _EASY * max_iterations else h
            increment = h if in_a_row else grown
            if control is not None:
                accepted, wanted = control.judge(h / program.strain_rate_per_s, material.time_error())
                increment = min(wanted * program.strain_rate_per_s, h if in_a_row else np.inf)
                if not accepted:
                    material.rollback()
                    log.debug("grip strain %.4g: time step rejected (local error %.3g), next %.3g", next_strain,
                              material.time_error(), increment)
                    continue
            in_a_row = 0
            material.commit()
            u, F, P, f, K, _, history = solved
            strain_now, time_now = next_strain, next_time
            substeps += 1
        record(index, time_now, float(target), (iterations, cuts, substeps), history)
    return steps


class _NotConverged(Exception):
    def __init__(self, reason: str, iterations: int):
        super().__init__(reason)
        self.reason = reason
        self.iterations = iterations


def _newton(membrane: Membrane, material: PointMaterial, constraints: _Constraints, u0: np.ndarray,
            f0: np.ndarray, K0: sp.csr_matrix, prescribed: np.ndarray, time: float, rtol: float,
            max_iterations: int):
    """One (sub-)step from the converged (u0, f0, K0) to the ``prescribed`` values; returns the
    new state, the iterations and the residual history."""
    free, dofs = constraints.free, constraints.dofs
    u = u0.copy()
    step = prescribed - u0[dofs]
    u[dofs] += step
    K_ff = K0[free][:, free]
    u[free] += spla.spsolve(K_ff.tocsc(), -(f0[free] + K0[free][:, dofs] @ step))
    # The residual scale: at least the force that 1e-6 of the increment makes at this tangent.
    floor = 1e-6 * float(np.max(np.abs(K0[:, dofs] @ step), initial=0.0))
    history: list[float] = []
    for iteration in range(max_iterations + 1):
        try:
            F = membrane.deformation_gradient(u)
            P, A = material.evaluate(F, time)
        except (ArithmeticError, SolverError) as err:
            raise _NotConverged(f"the material failed ({type(err).__name__}: {err})", iteration) from None
        f = membrane.internal_force(P)
        norm = float(np.max(np.abs(f[free]), initial=0.0))
        history.append(norm)
        if norm <= rtol * max(float(np.max(np.abs(f))), floor):
            return u, F, P, f, membrane.tangent(A), iteration, history
        if not np.isfinite(norm) or (iteration >= 4 and norm > history[-4]):
            break
        if iteration == max_iterations:
            break
        K = membrane.tangent(A)
        u[free] -= spla.spsolve(K[free][:, free].tocsc(), f[free])
    raise _NotConverged(f"Newton stalled (max |r| {history[0]:.3g} -> {history[-1]:.3g} N in "
                        f"{len(history) - 1} iterations)", len(history) - 1)
