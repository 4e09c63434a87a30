"""The design's report: best design, prediction interval, verification, reachability, files.

The 95 % prediction interval of a property is for the **mean of the verification seeds** at
the best design: the surrogate's latent uncertainty there, plus the realization scatter of the
search seeds' mean about the seed mean (the search sees r realizations per design), plus the
scatter of the mean of the ``n`` verification seeds (both from the replicates' pooled sd, with
its few degrees of freedom carried by a Student t draw):

    var = s_surrogate^2 + s_realization^2 (1 / r + 1 / n),

in the surrogate's scale (log for positive properties), by Monte Carlo through the targets
(so a ratio's interval comes out right too). The stresses of a curve target share one draw
per direction: a mat stiffer than the mean is stiffer along the whole curve, and independent
draws would add an RMS deviation the verification mean does not have. The verified value of a
target is that of the verification seeds' mean outputs (a ratio of mean moduli, the RMS
deviation of the mean curve); its sd is over the seeds.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from espin.core.config import Config
from espin.design.search import VERIFY_SEED_OFFSET, DesignRun
from espin.design.targets import STRESS_AT, RatioTarget
from espin.design.variables import constraint_value

__all__ = ["DesignResult", "DESIGN_OUTPUTS", "design_result"]

DESIGN_OUTPUTS = (
    "design.toml",
    "design.json",
    "evaluations.csv",
    "convergence.png",
    "maps.png",
    "verification.png",
    "pareto.png",
    "runs/tasks/*.json",
    "runs/failed/*.json",
    "runs/results.csv",
)
"""The files a design run writes (glob patterns relative to its folder)."""
PI_DRAWS = 4000
"""Monte Carlo draws of the prediction interval."""


@dataclass
class DesignResult:
    """Result of :func:`espin.design.design`.

    Attributes
    ----------
    config : Config
        The best design: the base config with the variables' values (``design.toml``).
    values : dict
        Variable key -> value of the best design.
    targets : dict
        Target label -> {``target``, ``tolerance``, ``predicted``, ``low``, ``high`` (the 95 %
        prediction interval of the verification mean), ``verified`` (mean over the fresh
        seeds), ``verified_sd``, ``inside`` (verified inside the interval), ``met`` (verified
        within tolerance)}.
    reached : bool
        Every target met by the verified mean.
    message : str
        What was found; for a target out of reach, the nearest design and the bounds or
        constraints it presses against.
    binding : list of str
        Variables at a bound and constraints active at the best design.
    evaluations : pandas.DataFrame
        One row per evaluation (id, stage, seed, variables, outputs, objective, pareto).
    tests : int
        Tensile tests the search ran; ``budget`` its budget (the best design's replicates and
        verification, ``run.checks`` tests, come on top).
    seconds : float [s]
        Wall time of the run.
    files : dict
        Written files by role.
    """

    config: Config
    values: dict[str, float]
    targets: dict[str, dict[str, Any]]
    reached: bool
    message: str
    binding: list[str]
    evaluations: pd.DataFrame
    tests: int
    budget: int
    seconds: float
    run: DesignRun
    files: dict[str, Path]

    def __repr__(self) -> str:
        """One line: reached or not, the best values, tests and time."""
        values = ", ".join(f"{k.removeprefix('rve.')} {v:.4g}" for k, v in self.values.items())
        state = "reached" if self.reached else "not reached"
        return f"DesignResult({state}: {values}; {self.tests} tests of {self.budget}, {self.seconds:.0f} s)"

    def _repr_html_(self) -> str:
        from espin.core.html import html_table

        rows = [(k, f"{v:.4g}") for k, v in self.values.items()]
        for label, t in self.targets.items():
            rows.append(
                (
                    label,
                    f"target {t['target']:.4g} ± {100 * t['tolerance']:.0f} %, predicted "
                    f"{t['predicted']:.4g} [{t['low']:.4g}, {t['high']:.4g}], verified "
                    f"{t['verified']:.4g} ± {t['verified_sd']:.2g}",
                )
            )
        rows.append(("result", self.message))
        return html_table("DesignResult", rows)

    def format_table(self) -> str:
        """Plain-text report for the command line."""
        lines = ["best design:"]
        lines += [f"  {k:<36} {v:.6g}" for k, v in self.values.items()]
        n = len(self.run.verification)
        lines.append(f"targets (predicted: 95 % interval of the mean of {n} fresh seeds; verified: their mean ± sd)")
        for label, t in self.targets.items():
            lines.append(
                f"  {label:<36} target {t['target']:<9.4g} ± {100 * t['tolerance']:.3g} %  predicted "
                f"{t['predicted']:<9.4g} [{t['low']:.4g}, {t['high']:.4g}]  verified {t['verified']:.4g} "
                f"± {t['verified_sd']:.2g}  {'met' if t['met'] else 'NOT met'}"
                f"{'' if t['inside'] else '  (outside the interval)'}"
            )
        lines.append(self.message)
        lines.append(
            f"{self.tests} tensile tests of a budget of {self.budget} (+ {self.run.checks} to replicate and "
            f"verify the best), {self.seconds:.0f} s"
        )
        return "\n".join(lines)

    def write(self, folder: str | Path) -> dict[str, Path]:
        """Write ``design.toml``, ``design.json``, ``evaluations.csv`` and the figures."""
        from espin.core.atomic import atomic_write, atomic_write_bytes
        from espin.core.config import write_config
        from espin.design.figures import plot_convergence, plot_maps, plot_pareto, plot_verification

        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        files = {
            "config": write_config(self.config, folder / "design.toml"),
            "evaluations": atomic_write(
                folder / "evaluations.csv", lambda tmp: self.evaluations.to_csv(tmp, index=False)
            ),
            "report": atomic_write_bytes(
                folder / "design.json", json.dumps(self.report(), indent=1, default=_jsonable).encode()
            ),
        }
        files["convergence"] = plot_convergence(self.run, self.evaluations, folder / "convergence.png")
        files["maps"] = plot_maps(self.run, folder / "maps.png")
        files["verification"] = plot_verification(self.run, folder / "verification.png")
        if len(self.run.targets.targets) >= 2:
            files["pareto"] = plot_pareto(self.run, self.evaluations, folder / "pareto.png")
        self.files.update(files)
        return files

    def report(self) -> dict[str, Any]:
        """JSON-ready summary (targets, best values, intervals, verification, message)."""
        from espin.core.version import __version__

        space = self.run.space
        return {
            "espin_version": __version__,
            "reached": self.reached,
            "message": self.message,
            "binding": self.binding,
            "values": self.values,
            "targets": self.targets,
            "variables": [
                {"key": v.key, "low": v.low, "high": v.high, "integer": v.integer, "log": v.log}
                for v in space.variables
            ],
            "constraints": [str(c) for c in space.constraints],
            "tests": self.tests,
            "budget": self.budget,
            "verification_seeds": [e.seed for e in self.run.verification],
            "seconds": self.seconds,
        }


def _jsonable(value: Any) -> Any:
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.bool_):
        return bool(value)
    raise TypeError(f"not JSON: {type(value)}")


def _interval(run: DesignRun) -> dict[str, tuple[float, float, float]]:
    """Target label -> (predicted, low, high) of the verification mean (module docstring)."""
    targets, best = run.targets, run.best
    n = len(run.verification)
    rng = np.random.default_rng(12345)
    draws = {}
    shared: dict[float, np.ndarray] = {}  # one shock per direction for a curve's stresses
    for output in targets.outputs:
        surrogate = run.surrogates[output]
        mean, sd = surrogate.predict(best.unit[None, :])
        s_real, dof = run.realization_sd.get(output, (math.nan, 0))
        s_real = 0.0 if not math.isfinite(s_real) else s_real
        total = math.sqrt(float(sd[0]) ** 2 + s_real**2 * (1.0 / run.realizations + 1.0 / n))
        shocks = rng.standard_t(dof, PI_DRAWS) if dof > 0 else rng.standard_normal(PI_DRAWS)
        if output[0].startswith(STRESS_AT):
            shocks = shared.setdefault(output[1], shocks)
        draws[output] = surrogate.to_property(mean[0] + total * shocks)
    median = {o: run.surrogates[o].median(best.unit[None, :])[0] for o in targets.outputs}
    out = {}
    for t in targets.targets:
        samples = t.achieved(draws)
        out[t.label] = (
            float(t.achieved(median)),
            float(np.quantile(samples, 0.025)),
            float(np.quantile(samples, 0.975)),
        )
    return out


def _pareto(errors: np.ndarray) -> np.ndarray:
    """Rows of |errors| (n, k) not dominated by another row (all NaN rows never are)."""
    a = np.abs(errors)
    ok = np.all(np.isfinite(a), axis=1)
    out = np.zeros(len(a), dtype=bool)
    for i in np.flatnonzero(ok):
        others = a[ok]
        dominated = np.any(np.all(others <= a[i], axis=1) & np.any(others < a[i], axis=1))
        out[i] = not dominated
    return out


def _table(run: DesignRun) -> pd.DataFrame:
    targets = run.targets
    rows = []
    every = run.evaluations + run.verification
    props = {o: np.array([e.outputs.get(o, math.nan) for e in every]) for o in targets.outputs}
    errors = targets.errors(props)
    objective = np.mean(errors**2, axis=1)
    search = np.array([e.stage in ("initial", "search") for e in every])
    pareto = np.zeros(len(every), dtype=bool)
    pareto[search] = _pareto(errors[search])
    for k, e in enumerate(every):
        row: dict[str, Any] = {"id": e.id, "stage": e.stage, "seed": e.seed}
        row.update({v.key: e.values[v.key] for v in run.space.variables})
        row.update({f"{name}@{d:g}": e.outputs.get((name, d), math.nan) for name, d in targets.outputs})
        row.update({f"error_{t.label}": errors[k, j] for j, t in enumerate(targets.targets)})
        row.update({"objective": objective[k], "pareto": bool(pareto[k]), "seconds": e.seconds, "error": e.error})
        rows.append(row)
    return pd.DataFrame(rows)


def _remedy(run: DesignRun) -> str:
    """What lowers the scatter between seeds of this run's mats or its effect on the search."""
    more = f"more realizations per design (--realizations {max(2, 2 * run.realizations)})"
    if run.space.base.rve.sampling == "balanced":
        return f"{more}, a larger RVE (rve.size_ratio, rve.layers)"
    return f"{more}, a larger RVE or balanced sampling (rve.sampling = 'balanced')"


def _noisy(run: DesignRun) -> str:
    """The targets whose outputs scatter between seeds by more than half the tolerance
    (relative sd), as ``modulus_MPa@0 11 % against 5 %``; empty when none do."""
    out = []
    for t in run.targets.targets:
        if isinstance(t, RatioTarget) or t.name == "curve":
            continue
        s, _ = run.realization_sd.get((t.name, t.direction_deg), (math.nan, 0))
        if math.isfinite(s) and s > 0.5 * t.tolerance:
            out.append(f"{t.label} {100 * s:.2g} % between seeds against {100 * t.tolerance:.3g} %")
    return ", ".join(out)


def _binding(run: DesignRun) -> list[str]:
    space, best = run.space, run.best
    out = space.at_bounds(best.unit)
    for c in space.constraints:
        value = constraint_value(space.base, best.values, c.quantity)
        if abs(value - c.bound) <= 0.02 * max(abs(c.bound), 1e-12):
            out.append(f"constraint {c} (at {value:.4g})")
    return out


def design_result(run: DesignRun) -> DesignResult:
    """The report of a finished :class:`DesignRun`."""
    targets = run.targets
    interval = _interval(run)
    verified = {o: np.array([e.outputs.get(o, math.nan) for e in run.verification]) for o in targets.outputs}
    rows: dict[str, dict[str, Any]] = {}
    with np.errstate(all="ignore"):
        mean_outputs = {o: np.nanmean(v) if np.any(np.isfinite(v)) else math.nan for o, v in verified.items()}
    for t in targets.targets:
        achieved = t.achieved(verified)
        achieved = achieved[np.isfinite(achieved)]
        mean = float(t.achieved(mean_outputs))
        sd = float(achieved.std(ddof=1)) if len(achieved) > 1 else math.nan
        predicted, low, high = interval[t.label]
        rows[t.label] = {
            "target": t.value,
            "tolerance": t.tolerance,
            "predicted": predicted,
            "low": low,
            "high": high,
            "verified": mean,
            "verified_sd": sd,
            "n_verified": int(len(achieved)),
            "inside": bool(low <= mean <= high),
            "met": t.meets(mean),
            "ratio": isinstance(t, RatioTarget),
        }
    reached = all(r["met"] for r in rows.values())
    binding = _binding(run)
    if reached:
        message = (
            f"all {len(rows)} targets met by the mean of {len(run.verification)} fresh seeds "
            f"(seeds from {run.best.seed + VERIFY_SEED_OFFSET}, never used by the search)"
        )
    else:
        missed = [label for label, r in rows.items() if not r["met"]]
        if run.met:
            scatter = ", ".join(
                f"{name}@{d:g} {100 * s:.2g} %" for (name, d), (s, _) in run.realization_sd.items() if math.isfinite(s)
            )
            message = (
                f"target(s) {', '.join(missed)} not met by the fresh seeds' mean although the search seed's "
                f"mat met them: one realization differs from the seeds' mean (scatter between seeds: "
                f"{scatter}); give a larger budget (the search then aims at the tolerance's middle), "
                f"{_remedy(run)}, or a wider tolerance"
            )
        else:
            where = (
                ("; it presses against " + ", ".join(binding))
                if binding
                else "; no bound or constraint is active: a larger budget may get closer"
            )
            message = (
                f"target(s) {', '.join(missed)} not met: this is the nearest design found within the bounds{where}"
            )
        noisy = _noisy(run)
        if noisy:
            message += (
                f". The realization scatter is comparable to the tolerance ({noisy}): use {_remedy(run)}, or "
                "widen the tolerance"
            )
    config = run.space.config(run.best.unit)
    return DesignResult(
        config,
        dict(run.best.values),
        rows,
        reached,
        message,
        binding,
        _table(run),
        run.tests,
        run.budget,
        run.seconds,
        run,
        {},
    )
