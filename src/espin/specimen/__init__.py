"""The macro scale: a tensile specimen of the mat, with espin RVEs at its quadrature points (FE^2).

``espin.specimen(source, shape, ...)`` pulls a specimen (strip, ISO 527-2 5A dogbone, strip
with a central hole or an edge notch, or a user mesh) between its grips: a 2-D membrane
finite-element model (:mod:`espin.specimen.membrane`, scikit-fem; total Lagrangian, in-plane F,
thickness an input; mm, N, MPa) under a grip-displacement program
(:mod:`espin.specimen.solver`), with at every quadrature point

* ``model="fe2"``: an espin RVE (:mod:`espin.specimen.rve_points`), solved for the point's F,
  its own plastic history, in parallel on the task pool;
* ``model="surrogate"``: a homogenized law interpolated from RVE runs along stretch paths
  (:mod:`espin.specimen.surrogate`), seconds instead of minutes;
* ``model="neo_hookean"``: a closed-form material (validation of the finite elements).

docs/specimen.md.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
import types
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from espin.core.errors import ConfigError
from espin.specimen.result import SPECIMEN_OUTPUTS, SpecimenResult, reopen_point
from espin.specimen.shapes import SHAPES, Specimen, check_size, points_per_element, read_specimen
from espin.specimen.solver import GRIPS, LATERAL, GripProgram, SpecimenFailed, SpecimenStep

if TYPE_CHECKING:
    from espin.core.parallel import TaskPlace
    from espin.specimen.surrogate import Surrogate

__all__ = [
    "specimen",
    "SpecimenSettings",
    "SpecimenResult",
    "SpecimenStep",
    "SpecimenFailed",
    "Specimen",
    "SHAPES",
    "MODELS",
    "SPECIMEN_OUTPUTS",
    "reopen_point",
    "make_specimen",
]

MODELS = ("fe2", "surrogate", "neo_hookean")
"""Materials at the quadrature points (module docstring)."""

_SMALL_RVE = {"rve.size_ratio": 60.0, "rve.layers": 3}
"""The RVE a generated specimen test uses unless told otherwise (the smallest the FE^2 checks
allow: L/D 60, 3 layers)."""


def make_specimen(shape: str | Path | Specimen, elements_across: int = 4, **options: float) -> Specimen:
    """The specimen geometry: a :data:`SHAPES` name with its options (mm), a mesh file that
    meshio reads, or a :class:`Specimen` (returned as it is)."""
    if isinstance(shape, Specimen):
        if options:
            raise ConfigError(f"shape options {', '.join(options)} apply to the built-in shapes, not to a Specimen")
        return shape
    if isinstance(shape, str) and shape in SHAPES:
        try:
            check_size(shape, elements_across, options)
            return SHAPES[shape](elements_across=elements_across, **options)
        except TypeError as err:
            raise ConfigError(f"shape {shape!r}: {err}") from None
    path = Path(shape)
    if path.suffix == "" and not path.exists():
        raise ConfigError(f"shape = {str(shape)!r}: must be one of {', '.join(SHAPES)} or a mesh file")
    if options:
        raise ConfigError(f"shape options {', '.join(options)} apply to the built-in shapes only")
    return read_specimen(path)


@dataclass(frozen=True)
class SpecimenSettings:
    """How the specimen is tested (the options of :func:`specimen` of the same names), checked
    when made.

    Raises
    ------
    ConfigError
        Naming the option and what it allows.
    """

    model: str = "fe2"
    thickness_mm: float = 0.1
    grips: str = "clamped"
    lateral: str = "fixed"
    rve_seeds: str = "shared"
    rtol: float = 1e-6
    modulus_MPa: float | None = None
    poisson_ratio: float | None = None
    surrogate_reach: float = 3.0

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ConfigError(f"model = {self.model!r}: must be one of {', '.join(MODELS)}")
        if not 0.0 < self.thickness_mm < math.inf:
            raise ConfigError(f"thickness_mm = {self.thickness_mm:g}: must be a finite number > 0 mm")
        if self.grips not in GRIPS:
            raise ConfigError(f"grips = {self.grips!r}: must be one of {', '.join(GRIPS)}")
        if self.lateral not in LATERAL:
            raise ConfigError(f"lateral = {self.lateral!r}: must be one of {', '.join(LATERAL)}")
        if self.rve_seeds not in ("shared", "per_point"):
            raise ConfigError(f"rve_seeds = {self.rve_seeds!r}: must be 'shared' or 'per_point'")
        if not 0.0 < self.rtol < 1.0:
            raise ConfigError(f"rtol = {self.rtol}: must be in (0, 1)")
        if not 1.0 <= self.surrogate_reach < math.inf:
            raise ConfigError(f"surrogate_reach = {self.surrogate_reach:g}: must be a finite number >= 1")
        if self.model == "neo_hookean":
            if self.modulus_MPa is None or self.poisson_ratio is None:
                raise ConfigError("model = 'neo_hookean' needs modulus_MPa and poisson_ratio")
            if not 0.0 < self.modulus_MPa < math.inf:
                raise ConfigError(f"modulus_MPa = {self.modulus_MPa:g}: must be a finite number > 0 MPa")
            if not 0.0 <= self.poisson_ratio < 1.0:
                raise ConfigError(f"poisson_ratio = {self.poisson_ratio}: must be in [0, 1)")


def specimen(
    source: Any = "plla",
    shape: str | Path | Specimen = "holed_strip",
    *,
    model: str = "fe2",
    thickness_mm: float = 0.1,
    max_strain: float = 0.2,
    steps: int = 20,
    grips: str = "clamped",
    lateral: str | None = None,
    elements_across: int = 4,
    shape_options: Mapping[str, float] | None = None,
    rve_seeds: str = "shared",
    rtol: float = 1e-6,
    modulus_MPa: float | None = None,
    poisson_ratio: float | None = None,
    surrogate_reach: float = 3.0,
    surrogate_from: str | Path | None = None,
    allow_surrogate_mismatch: bool = False,
    out: str | Path | None = None,
    overwrite: bool = False,
    workers: int | None = 1,
    scheduler: Any = None,
    blas_threads: int | None = 1,
    security: Any = None,
    figures: bool = True,
    on_step: Callable[[SpecimenStep], None] | None = None,
    progress: bool | None = None,
    report: Callable[[str], None] | None = None,
    **overrides: Any,
) -> SpecimenResult:
    """Pull a specimen of the mat between its grips (module docstring; docs/specimen.md).

    Parameters
    ----------
    source
        The mat: an :class:`espin.RVE`, a saved RVE (``.h5``), a :class:`espin.Config`, a preset
        name or a TOML file (fiber law, loading rate, solver). A generated RVE is L/D 60 with 3
        layers unless ``rve__size_ratio`` / ``rve__layers`` are given. Not used by
        ``model="neo_hookean"``.
    shape
        ``"strip"``, ``"dogbone"`` (ISO 527-2 type 5A), ``"holed_strip"``, ``"notched_strip"``
        (:mod:`espin.specimen.shapes`; their options in ``shape_options``, mm), a mesh file
        (meshio: gmsh, VTU, ...; x is the loading axis, the grips the faces at min and max x) or
        a :class:`Specimen`.
    model
        ``"fe2"``, ``"surrogate"`` or ``"neo_hookean"`` (module docstring).
    thickness_mm
        Specimen thickness [mm]: force = nominal stress x thickness x width.
    max_strain, steps
        Grip strain (grip displacement / grip distance) at the end, in (0, 1], and the
        recorded steps; the grips move at the config's ``loading.strain_rate_per_s`` (the rest of
        its ``[loading]`` section, a test or program of a single RVE, is not used).
    grips
        ``"clamped"`` (u_y = 0 at the grips) or ``"sliding"``.
    lateral
        ``"fixed"``: the outer sides keep their width (u_y = 0; holes and notches stay free);
        ``"free"``: traction-free sides, the real test. In the paper's 2-D fiber model a free
        edge has almost no lateral stiffness (docs/mechanics.md, "Compression-dominated
        states"), so ``"free"`` with ``fe2`` is for small strains and small meshes; with fused
        crossings (``fiber.fused_crossing_fraction`` > 0, the ``plla-bonded`` preset) the mat
        holds its width (docs/mechanics.md, "Fused crossings"). Default (None): ``"free"`` with
        fused crossings, else ``"fixed"``.
    elements_across
        Elements across the narrowest width (the mesh refinement of a built-in shape).
    rve_seeds
        ``"shared"``: one RVE geometry at every point; ``"per_point"``: each point its own
        realization (seeds ``rve.seed``, + 1, ...).
    rtol
        Macro tolerance (max |residual| <= rtol max |nodal force|); the RVEs solve to 1e-3 of
        it. The time steps follow the config's ``solver.time_rtol`` at every point.
    modulus_MPa, poisson_ratio
        ``model="neo_hookean"`` only: small-strain modulus [MPa] and Poisson's ratio.
    surrogate_reach
        ``model="surrogate"``: the RVE paths reach this times ``max_strain``.
    surrogate_from
        ``model="surrogate"``: the ``surrogate_samples.csv`` of an earlier surrogate run of the
        same mat, used instead of running the RVE paths again (seconds instead of minutes). The
        file names its mat: samples of another mat, law or strain rate, or built for a smaller
        grip strain, are refused (:mod:`espin.specimen.surrogate_file`).
    allow_surrogate_mismatch
        Use ``surrogate_from`` samples of another mat or reach anyway (recorded in
        ``specimen.json``).
    out
        Results folder (:mod:`espin.specimen.result`); None: nothing written. A surrogate build
        keeps its finished RVE paths there as it goes: the same call into the same folder after a
        failure or an interruption resumes from them.
    overwrite
        Replace another run's results in ``out`` instead of refusing.
    workers, scheduler, blas_threads, security
        Where the RVE solves run (:class:`espin.core.parallel.TaskPool`).
    figures
        Write the PNG figures.
    on_step
        Called with each recorded step.
    progress
        Show the steps done and the force: in a Jupyter notebook as a bar, elsewhere as a line
        per step on stderr. Default (None): in a notebook only.
    report
        Called with a line as a long phase starts or advances (the RVE's generation, the
        surrogate's build: its plan and each finished RVE path); None: silent.
    **overrides
        Config keys as ``section__key=value``.

    Returns
    -------
    SpecimenResult

    Raises
    ------
    ConfigError
        For a bad option, before any work; SpecimenFailed when a step does not converge (its
        ``steps`` hold the converged ones, the folder the CSV and VTK files up to there).
    """
    from espin.core.config import config_digest
    from espin.core.output_folder import OutputFolder, inputs_digest
    from espin.core.parallel import TaskPlace
    from espin.core.progress import with_progress

    settings = SpecimenSettings(
        model, thickness_mm, grips, lateral or "fixed", rve_seeds, rtol, modulus_MPa, poisson_ratio, surrogate_reach
    )
    on_step = with_progress(
        on_step,
        steps,
        progress,
        lambda step: (step.index, f"grip strain {step.grip_strain:.4g}, force {step.force_N:.4g} N"),
    )
    place = TaskPlace(workers, scheduler, blas_threads, security)
    program = GripProgram(max_strain, steps, 1.0)  # the rate is checked with the config below
    geometry = make_specimen(shape, elements_across, **dict(shape_options or {}))
    if model == "neo_hookean":
        config: Any = None  # else the mat's Config
        rve = None
    else:
        config, rve = _resolve_rve(source, overrides)
        if rve is not None and rve_seeds == "per_point":
            raise ConfigError(
                "rve_seeds = 'per_point' generates a realization per point: give a preset, a "
                "TOML file or a Config, not an RVE"
            )
        program = GripProgram(max_strain, steps, config.loading.strain_rate_per_s)
        if lateral is None and config.fiber.fused_crossing_fraction > 0:  # a mat that holds its width
            settings = dataclasses.replace(settings, lateral="free")
    _check_memory(geometry, model, config, rve)
    samples = None
    if surrogate_from is not None:
        if model != "surrogate":
            raise ConfigError("surrogate_from applies to model = 'surrogate'")
        from espin.specimen.surrogate import read_surrogate

        samples = read_surrogate(surrogate_from, config, max_strain, allow_mismatch=allow_surrogate_mismatch)

    def run(folder: Path | None) -> SpecimenResult:
        return _run(
            geometry,
            program,
            config,
            rve,
            settings,
            place,
            samples,
            folder,
            figures,
            on_step,
            source=surrogate_from,
            report=report,
        )

    if out is None:
        return run(None)
    digest = inputs_digest(
        [surrogate_from] if surrogate_from is not None else [],
        config_digest(config) if config is not None else "",
        repr(geometry),
        program,
        dataclasses.asdict(settings)
        | {"workers": workers, "scheduler": scheduler, "blas_threads": blas_threads, "surrogate_from": surrogate_from},
    )
    resumable = model == "surrogate" and surrogate_from is None  # a build keeps its finished paths
    with OutputFolder.claim(
        out, "specimen", digest, SPECIMEN_OUTPUTS, overwrite=overwrite, resume="same-inputs" if resumable else None
    ):
        return run(Path(out))


def _check_memory(geometry: Specimen, model: str, config, rve) -> None:
    """Refuse, before any work, a specimen whose mesh and (FE^2) RVEs at its points would not fit
    in memory (:func:`espin.specimen.mesh_checks.check_memory`)."""
    from espin.geometry.size_estimate import estimate_size
    from espin.specimen.mesh_checks import check_memory

    dof = 0.0
    if model == "fe2":
        dof = float(rve.network.n_dof) if rve is not None else estimate_size(config).dof
    check_memory(repr(geometry), geometry.n_elements, points_per_element(geometry), dof)


def _resolve_rve(source: Any, overrides: dict[str, Any]):
    """(config, RVE or None) of the mat; a generated one small unless its size is given."""
    from espin.core.config import dotted_overrides
    from espin.mechanics.run import resolve_source

    flat = dotted_overrides(overrides)
    config, rve = resolve_source(source, flat)
    if config.solver.kinematics == "affine":
        raise ConfigError(
            'solver.kinematics = "affine" applies to espin simulate: the specimen solves each RVE '
            'point\'s equilibrium; give solver.kinematics = "equilibrium" (the default)'
        )
    if rve is None:
        small = {k: v for k, v in _SMALL_RVE.items() if k not in flat}
        if small:
            config, _ = resolve_source(config, small)
    return config, rve


def _run(
    geometry: Specimen,
    program: GripProgram,
    config: Any,
    rve: Any,
    settings: SpecimenSettings,
    place: TaskPlace,
    samples: Surrogate | None,
    folder: Path | None,
    figures: bool,
    on_step: Callable[[SpecimenStep], None] | None,
    *,
    source: str | Path | None = None,
    report: Callable[[str], None] | None = None,
) -> SpecimenResult:
    """The run: ``source`` is the samples file of ``samples``; ``report`` gets the lines of the
    phases that take long (the RVE's generation, the surrogate's build)."""
    from espin.geometry.rve import generate
    from espin.geometry.rve_file import save_rve
    from espin.specimen.materials import NeoHookean, PointMaterial
    from espin.specimen.membrane import Membrane
    from espin.specimen.result import SpecimenWriter, points_history
    from espin.specimen.rve_points import RVEPoints, rve_tolerance
    from espin.specimen.solver import run_specimen
    from espin.specimen.surrogate import build_surrogate, surrogate_identity

    start = time.perf_counter()
    membrane = Membrane(geometry.mesh, settings.thickness_mm)
    n = membrane.n_points
    model = settings.model
    callbacks = [c for c in (on_step,) if c is not None]
    writer = None if folder is None else SpecimenWriter(folder, membrane)
    if writer is not None:
        callbacks.insert(0, writer)
    result = SpecimenResult(
        geometry, model, settings.thickness_mm, settings.grips, settings.lateral, [], membrane, config=config
    )
    with place.pool() as pool:
        time_rtol = None
        material: PointMaterial
        if model == "neo_hookean":
            assert settings.modulus_MPa is not None and settings.poisson_ratio is not None  # checked
            material = NeoHookean.from_uniaxial(n, settings.modulus_MPa, settings.poisson_ratio)
        elif samples is not None:  # an earlier run's surrogate: no RVE needed
            result.surrogate = samples
            result.surrogate_source = str(source)
            result.surrogate_mismatches = samples.identity.mismatches(surrogate_identity(config, program.max_strain))
            material = result.surrogate.material(n)
        else:
            if rve is None:
                if report is not None:
                    report(
                        f"specimen: generating the RVE (side {config.rve.side_um:.4g} um, {config.rve.layers} layers)"
                    )
                rve = generate(config)
            if folder is not None:
                save_rve(rve, folder / "rve.h5")
            if model == "surrogate":
                result.surrogate = build_surrogate(
                    rve.network,
                    config,
                    program.max_strain,
                    reach=settings.surrogate_reach,
                    pool=pool,
                    samples_path=None if folder is None else folder / "surrogate_samples.csv",
                    report=report,
                )
                material = result.surrogate.material(n)
            else:
                config = rve_tolerance(config, settings.rtol)
                result.config = config
                networks = (
                    rve.network
                    if settings.rve_seeds == "shared"
                    else [
                        generate(
                            config.model_copy(
                                update={"rve": config.rve.model_copy(update={"seed": config.rve.seed + i})}
                            )
                        ).network
                        for i in range(n)
                    ]
                )
                material = RVEPoints(networks, config, n, pool=pool)
                result.networks = material.networks
                time_rtol = None if config.solver.time_rtol == "off" else config.solver.time_rtol

        def step_done(step: SpecimenStep) -> None:
            result.steps.append(step)
            for callback in callbacks:
                callback(step)

        try:
            run_specimen(
                geometry,
                material,
                program,
                thickness_mm=settings.thickness_mm,
                grips=settings.grips,
                lateral=settings.lateral,
                rtol=settings.rtol,
                time_rtol=time_rtol,
                on_step=step_done,
                membrane=membrane,
            )
        except SpecimenFailed as failure:
            if result.surrogate is None:
                raise
            raise SpecimenFailed(
                f"{failure} (surrogate: its interpolated tangent can be indefinite near zero "
                "strain, on wavy mats most; fewer elements across or the fe2 model may get "
                "through: docs/specimen.md, 'The surrogate's limits')",
                failure.steps,
            ) from None
        finally:
            result.counts.update(
                seconds=time.perf_counter() - start,
                workers=pool.description,
                macro_iterations=sum(s.iterations for s in result.steps),
                time_steps=sum(s.substeps for s in result.steps),
            )
            if isinstance(material, RVEPoints):
                result.point_time, result.point_F = points_history(material)
                result.counts.update(rve_solves=material.solves, rve_iterations=material.rve_iterations)
                result.final_state = material.state
            if result.surrogate is not None:
                result.counts.update(
                    surrogate_seconds=result.surrogate.seconds, surrogate_samples=len(result.surrogate.E)
                )
            if writer is not None:
                writer.trim()
                del result.steps[writer.rows :]  # a step whose row was not written is not kept
            if folder is not None and result.steps:
                result.write(folder, figures=figures)
    return result


class _SpecimenModule(types.ModuleType):
    """``espin.specimen`` is both this package and its function (as ``espin.design``)."""

    def __call__(self, *args: Any, **kwargs: Any) -> SpecimenResult:
        return specimen(*args, **kwargs)


sys.modules[__name__].__class__ = _SpecimenModule
