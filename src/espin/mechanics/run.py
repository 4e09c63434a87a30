"""The tensile test end to end: an RVE (generated or loaded), a loading program, a results folder."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from threadpoolctl import threadpool_limits

from espin.core.config import Config, apply_overrides, config_digest, dotted_overrides, write_config
from espin.core.errors import ConfigError
from espin.core.output_folder import OutputFolder
from espin.core.progress import with_progress
from espin.geometry.network import Network
from espin.geometry.network_file import is_network_file, read_network
from espin.geometry.rve import RVE, generate, resolve_config
from espin.geometry.rve_file import load_rve
from espin.geometry.rve_folder import RVE_OUTPUTS, write_rve_files
from espin.geometry.size_estimate import check_size
from espin.mechanics.driver import SimulationFailed, SimulationResult, StepRecord, run_program
from espin.mechanics.linear_solvers import make_linear_solver
from espin.mechanics.loading import LoadProgram, load_program

if TYPE_CHECKING:  # pragma: no cover
    from espin.mechanics.figures import CurveMarks

__all__ = ["simulate", "resolve_source", "SOLVER_LOG", "SIMULATION_OUTPUTS"]

log = logging.getLogger(__name__)

SOLVER_LOG = "solver.log"
"""File of the output folder that a failed run writes its residual history to."""
SIMULATION_OUTPUTS = (
    "config.toml",
    "curve.csv",
    "results.h5",
    "curve.png",
    "deformed.png",
    "deformation.pvd",
    "vtk/step_*.vtu",
    SOLVER_LOG,
)
"""The files a tensile test writes (glob patterns relative to its folder), besides the RVE's."""


def resolve_source(
    source: RVE | Network | Config | str | Path | None,
    overrides: dict[str, Any],
    config: Config | str | Path | None = None,
) -> tuple[Config, RVE | Network | None]:
    """The run's validated config, and the RVE or network when ``source`` is one (None: to be
    generated).

    ``source`` is an :class:`RVE`, a saved ``.h5`` RVE file, a :class:`Network` or a network
    file made elsewhere (:mod:`espin.geometry.network_file`), a :class:`Config`, a preset name
    or a TOML file (None: ``plla``). ``overrides`` are ``section.key`` values; on a saved or
    given RVE or network only the ``fiber``, ``loading``, ``solver`` and ``output`` sections may
    change. ``config``: with a network, the Config, preset or TOML file whose fiber law,
    loading, solver and output apply (default ``plla``; its ``rve`` section does not).
    """
    if isinstance(source, (str, Path)) and is_network_file(source):
        source = read_network(source)
    if config is not None and not isinstance(source, Network):
        raise ConfigError("a separate config applies to a network file only; give the config as the source")
    if isinstance(source, (str, Path)) and str(source).endswith((".h5", ".hdf5")):
        source = load_rve(source)
    if isinstance(source, (RVE, Network)):
        geometry = sorted(k for k in overrides if k.startswith("rve."))
        if geometry:
            raise ConfigError(
                f"{', '.join(geometry)}: the geometry of a given RVE or network cannot change; generate a "
                "new RVE instead (only fiber, loading, solver and output keys apply)"
            )
        if isinstance(source, Network):
            return resolve_config(config, **overrides), source
        config = apply_overrides(source.config, overrides) if overrides else source.config
        return config, RVE(config, source.mat, source.crosslinks, source.network, source.path)
    return resolve_config(source, **overrides), None


def simulate(
    source: RVE | Network | Config | str | Path | None = None,
    out: str | Path | None = None,
    *,
    config: Config | str | Path | None = None,
    on_step: Callable[[StepRecord], None] | None = None,
    threads: int | None = None,
    overwrite: bool = False,
    allow_large: bool = False,
    curve_marks: Callable[[SimulationResult], CurveMarks | None] | None = None,
    progress: bool | None = None,
    **overrides: Any,
) -> SimulationResult:
    """Pull on a virtual mat and record its stress-strain response (docs/model.md sections 3-6).

    Parameters
    ----------
    source
        An :class:`RVE`, a saved RVE file (``.h5``), a :class:`Network` or a network file made
        elsewhere (docs/mechanics.md), a :class:`Config`, a preset name or a TOML file; default
        the ``plla`` preset (generated).
    out
        Results folder. When given: ``run.json`` (the manifest, ``running`` until the run
        ends), ``config.toml``, ``curve.csv`` (one row per converged step, appended as the
        run goes), ``results.h5`` (rewritten every minute and at the end), the VTK series
        ``deformation.pvd`` (+ ``vtk/``), ``curve.png``, ``deformed.png`` and, for a
        generated RVE, ``rve.h5`` with its statistics and figures.
    config
        With a network: the :class:`Config`, preset or TOML file whose fiber law, loading,
        solver and output apply (default ``plla``; its ``rve`` section does not apply).
    on_step
        Called with each converged :class:`StepRecord` (e.g. for a progress display).
    threads
        Threads for BLAS / MKL (PARDISO) during the run; default the library's own choice.
    overwrite
        Replace the results of another run in ``out`` instead of refusing.
    allow_large
        Generate the RVE even when its tensile test is estimated to need more memory than is
        available.
    curve_marks
        Gives the bilinear fit (E, yield point, H) that ``curve.png`` marks, or None for no
        marks (e.g. :func:`espin.analysis.properties.curve_marks`: the fit belongs to the
        analysis stage, above this one). Default: no marks.
    progress
        Show the steps done, the strain reached and the time left: in a Jupyter notebook as a
        bar updated in place, elsewhere as one line per step on stderr. Default (None): in a
        notebook only.
    **overrides
        Config keys as ``section__key=value``, e.g. ``loading__max_strain=0.1``.

    Returns
    -------
    SimulationResult

    Raises
    ------
    ConfigError
        For an invalid configuration, an RVE too large for the memory available, or an
        ``out`` folder holding another run's results (before any work starts).
    SimulationFailed
        When a step cannot converge: one line says which step, why and what to try; the
        results folder then holds the curve and results of the steps that converged and
        ``solver.log``, the residual history of the last attempt.
    """
    config, rve = resolve_source(source, dotted_overrides(overrides), config)
    program = load_program(config.loading)  # its tables are read and checked before any work
    if rve is None:
        check_size(config, allow_large=allow_large)  # before the folder is claimed
    on_step = with_progress(
        on_step, program.n_steps, progress, lambda record: (record.index, f"strain {record.strain:.4f}")
    )
    if out is None:
        return _run(config, rve, program, None, on_step, threads, allow_large, curve_marks)
    outputs = SIMULATION_OUTPUTS + (RVE_OUTPUTS if rve is None else ())
    with OutputFolder.claim(
        out,
        "simulate",
        config_digest(config),
        outputs,
        overwrite=overwrite,
        inputs=[rve.path] if isinstance(rve, RVE) and rve.path is not None else [],
    ) as claimed:
        return _run(config, rve, program, claimed, on_step, threads, allow_large, curve_marks)


def _run(
    config: Config,
    rve: RVE | Network | None,
    program: LoadProgram,
    claimed: OutputFolder | None,
    on_step: Callable[[StepRecord], None] | None,
    threads: int | None,
    allow_large: bool,
    curve_marks: Callable[[SimulationResult], CurveMarks | None] | None = None,
) -> SimulationResult:
    """Generate the RVE if needed, run the program, write the claimed folder."""
    folder = None if claimed is None else claimed.path
    run_id = None if claimed is None else claimed.run_id
    callbacks = [c for c in (on_step,) if c is not None]
    if rve is None:
        rve = generate(config, allow_large=allow_large)
        if folder is not None:
            write_rve_files(rve, folder, run_id=run_id)
    elif folder is not None:
        write_config(config, folder / "config.toml")
    network = rve if isinstance(rve, Network) else rve.network
    if folder is not None:
        from espin.mechanics.results_file import SimulationWriter

        callbacks.append(SimulationWriter(folder, network, config, program, vtk=config.output.vtk, run_id=run_id))

    def step_done(record: StepRecord) -> None:
        for callback in callbacks:
            callback(record)

    linear = make_linear_solver(config.solver.linear)
    try:
        with threadpool_limits(limits=threads):
            result = run_program(network, config, linear, program, on_step=step_done)
    except SimulationFailed as failure:
        if folder is not None:
            from espin.core.atomic import atomic_write_bytes

            failure.log_path = atomic_write_bytes(folder / SOLVER_LOG, failure.details().encode("utf-8"))
            if failure.partial is not None:
                from espin.mechanics.results_file import write_results

                write_results(failure.partial, folder, run_id=run_id)  # the steps that converged are kept
                log.info("wrote the %d converged steps to %s", len(failure.partial.time) - 1, folder)
        raise
    if folder is not None:
        from espin.mechanics.results_file import write_results

        write_results(result, folder, run_id=run_id)
        if config.output.figures:
            from espin.mechanics.figures import plot_curve, plot_deformed

            marks = None if curve_marks is None else curve_marks(result)
            plot_curve(result, folder / "curve.png", marks=marks)
            plot_deformed(network, result.final, folder / "deformed.png")
    return result
