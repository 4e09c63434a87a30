"""Inverse design: the microstructure that gives target mechanical properties (paper 4.3).

``espin.design(targets, variables, ...)`` searches the deposition parameters of a virtual mat
(volume fraction, orientation, waviness, diameter spread, layers ...) within bounds and
constraints so that its tensile properties (modulus, yield stress, post-yield modulus, yield
strain, in one or more directions, and their ratios) meet the targets: Bayesian optimization
with Gaussian-process surrogates (:mod:`espin.design.search`), the best design verified on
fresh seeds (:mod:`espin.design.result`). docs/design.md.
"""

from __future__ import annotations

import sys
import types
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

from espin.core.config import Config
from espin.design.result import DESIGN_OUTPUTS, DesignResult, design_result
from espin.design.search import DesignRun, Evaluation, prepare_design, run_design
from espin.design.targets import DesignTargets, PropertyTarget, RatioTarget, parse_targets
from espin.design.variables import Constraint, DesignVariable

__all__ = [
    "design",
    "DesignResult",
    "DesignTargets",
    "PropertyTarget",
    "RatioTarget",
    "DesignVariable",
    "Constraint",
    "Evaluation",
    "DESIGN_OUTPUTS",
    "parse_targets",
]


def design(
    targets: Iterable[str | PropertyTarget | RatioTarget] | Mapping[str, float] | DesignTargets,
    variables: Iterable[str | tuple[str, float, float] | DesignVariable] | Mapping[str, tuple[float, float]],
    *,
    base: Config | str | Path | None = "plla",
    constraints: Iterable[str | Constraint] = (),
    budget: int = 60,
    batch: int = 2,
    initial: int | None = None,
    replicates: int = 3,
    verify: int = 5,
    seed: int = 0,
    realizations: int = 1,
    folder: str | Path | None = None,
    workers: int | None = 1,
    scheduler: Any = None,
    blas_threads: int | None = 1,
    security: Any = None,
    overwrite: bool = False,
    on_batch: Callable[[list[Evaluation], Evaluation], None] | None = None,
    **overrides: Any,
) -> DesignResult:
    """Find the microstructure whose tensile properties meet the targets.

    Parameters
    ----------
    targets
        ``["E=200", "sigma_y=6+-3%", "E@0/E@90=3"]`` (:mod:`espin.design.targets`), a mapping
        ``{"modulus_MPa": 200}``, or target objects. Tolerances are relative (default 5 %).
    variables
        ``["eta=0.1:0.3", "kappa=0:8"]``, ``{"rve.volume_fraction": (0.1, 0.3)}`` or
        :class:`DesignVariable` objects (:mod:`espin.design.variables`).
    base
        Config, preset or TOML holding everything not searched: the fiber law (e.g. the
        ``fitted.toml`` of ``espin fit``), the RVE size and sampling, the loading (uniaxial;
        its lateral condition is the targets'). ``**overrides`` as ``section__key``.
    constraints
        ``["porosity>=0.8", "diameter_cv<=0.3"]``.
    budget
        Tensile tests the search may run (one design in one direction on one seed is one
        test); the best design's ``replicates - 1`` replicates and ``verify`` fresh seeds (x
        directions) come on top. The search stops early when the best design is within half
        of every tolerance.
    batch
        Designs proposed and run together per round (in parallel on the workers).
    initial
        Designs of the initial Sobol' sample (default 2 d + 2, at least 6).
    replicates
        Seeds run at the first initial design and at the best design to measure the
        realization scatter (>= 2).
    verify
        Fresh seeds the best design is verified on (>= 2).
    seed
        Seed of the initial sample, candidates and surrogate restarts (the mats' seeds are
        the base config's ``rve.seed``, + 1, ... for realizations and replicates, + 100000
        ... to verify).
    realizations
        Seeds every searched design runs on (the surrogates model their mean; each costs
        ``realizations`` tests per direction). 1 (common random numbers on one seed) unless
        the report says the scatter between seeds is comparable to the tolerance: then 2-4.
    folder
        Results folder: ``design.toml``, ``design.json``, ``evaluations.csv``, figures, and
        ``runs/`` (every tensile test; a rerun with the same inputs repeats none).
    workers, scheduler, blas_threads, security
        Where the tests run (:class:`espin.core.parallel.TaskPool`).
    overwrite
        Replace another run's results in ``folder`` instead of refusing.
    on_batch
        Called after each round with its evaluations and the best design so far. Default: in
        a Jupyter notebook, a bar of the budget's tests done; elsewhere nothing.

    Returns
    -------
    DesignResult

    Raises
    ------
    ConfigError
        For invalid targets, variables, bounds, constraints or budget, before any work.
    """
    from espin.core.config import config_digest
    from espin.core.output_folder import OutputFolder, inputs_digest
    from espin.core.parallel import TaskPlace

    place = TaskPlace(workers, scheduler, blas_threads, security)
    counts: dict[str, Any] = dict(
        budget=budget,
        batch=batch,
        initial=initial,
        replicates=replicates,
        verify=verify,
        seed=seed,
        realizations=realizations,
    )
    # every input is checked before the folder is claimed (a refused input never touches it)
    problem = prepare_design(targets, variables, base=base, constraints=constraints, **counts, **overrides)
    targets, space = problem.targets, problem.space
    options: dict[str, Any] = dict(
        base=space.base,
        constraints=space.constraints,
        place=place,
        **counts,
        on_batch=on_batch or _notebook_bar(budget, len(targets.directions)),
    )
    if folder is None:
        return design_result(run_design(targets, space.variables, folder=None, **options))
    # A rerun with the same inputs resumes (its finished tests are read back), with any workers;
    # other inputs are refused.
    digest = inputs_digest(
        [],
        config_digest(space.base),
        [repr(t) for t in targets.targets],
        [repr(v) for v in space.variables],
        [str(c) for c in space.constraints],
        counts,
    )
    with OutputFolder.claim(folder, "design", digest, DESIGN_OUTPUTS, overwrite=overwrite, resume="same-inputs"):
        result = design_result(run_design(targets, space.variables, folder=Path(folder), **options))
        result.write(folder)
    return result


__all__ += ["DesignRun", "design_result", "run_design"]


def _notebook_bar(budget: int, directions: int) -> Callable[[list[Evaluation], Evaluation], None] | None:
    """In a notebook, a bar of the budget's tensile tests done, with the best design so far."""
    from espin.core.progress import NotebookProgress, in_notebook

    if not in_notebook():
        return None
    bar = NotebookProgress(budget, "test")
    done = 0

    def show(evaluations: list[Evaluation], best: Evaluation) -> None:
        nonlocal done
        done += len(evaluations) * directions
        bar.update(
            done, "best so far: " + ", ".join(f"{k.removeprefix('rve.')} {v:.4g}" for k, v in best.values.items())
        )

    return show


class _DesignModule(types.ModuleType):
    """``espin.design`` is both this package and its function: calling the module runs
    :func:`design` (importing ``espin.design.targets`` binds the package to ``espin.design``)."""

    def __call__(self, *args: Any, **kwargs: Any) -> DesignResult:
        return design(*args, **kwargs)


sys.modules[__name__].__class__ = _DesignModule
