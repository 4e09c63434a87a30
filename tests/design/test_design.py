"""espin design: targets and variables parsed and checked, the optimizer on known functions,
and small real design runs (resumable, independent of the worker count, verified inside their
prediction interval)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from espin.core.config import load_config
from espin.core.errors import ConfigError
from espin.design import design
from espin.design.result import design_result
from espin.design.search import run_design
from espin.design.targets import PropertyTarget, RatioTarget, parse_target, parse_targets
from espin.design.variables import DesignSpace, parse_constraint, parse_variable

TINY = {"rve.size_ratio": 40, "rve.layers": 3, "rve.sampling": "balanced", "loading.max_strain": 0.04,
        "loading.steps": 4}


def test_targets_parse_with_tolerances_directions_and_ratios():
    assert parse_target("E=150") == PropertyTarget("modulus_MPa", 150.0, 0.05, 0.0)
    assert parse_target("sigma_y@90=4.5+-3%") == PropertyTarget("yield_stress_MPa", 4.5, 0.03, 90.0)
    assert parse_target("E@0/E@90=3") == RatioTarget("modulus_MPa", 3.0, 0.05, 0.0, 90.0)
    assert parse_target("E@-90=70") == parse_target("E@90=70")  # the same test of a planar mat
    targets = parse_targets({"modulus_MPa": 200, "E@90": 70})
    assert targets.directions == (0.0, 90.0)
    assert targets.outputs == (("modulus_MPa", 0.0), ("modulus_MPa", 90.0))
    # errors are (achieved - target) / (tolerance target); the objective their mean square
    errors = targets.errors({("modulus_MPa", 0.0): np.array(210.0), ("modulus_MPa", 90.0): np.array(70.0)})
    assert errors == pytest.approx([1.0, 0.0])


@pytest.mark.parametrize("text, message", [
    ("E=-5", "target modulus_MPa: must be in (0, inf)"),
    ("Young=5", "unknown property 'Young'"),
    ("E=5+-150%", "tolerance: must be in (0, 1)"),
    ("E@0/sigma_y@90=3", "a ratio compares one property"),
    ("E@0/E@0=3", "the two directions must differ"),
    ("E@0/E@180=3", "the two directions must differ"),
    ("E 150", "write NAME[@DIR]=VALUE"),
])
def test_bad_targets_are_refused_with_the_rule(text, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")):
        parse_target(text)


def test_variables_and_constraints_are_checked_against_the_config():
    base = load_config("plla")
    assert parse_variable("eta=0.1:0.3").key == "rve.volume_fraction"
    assert parse_variable("layers=3:9").integer
    assert parse_variable("kappa=log:0.5:8").log
    with pytest.raises(ConfigError, match="the fiber diameter does not change the stresses"):
        parse_variable("diameter_um=0.2:0.9")
    with pytest.raises(ConfigError, match="variable rve.volume_fraction: bound 1.2 is not allowed"):
        DesignSpace.build(base, ["eta=0.1:1.2"])
    with pytest.raises(ConfigError, match="bounds must be finite with low < high"):
        parse_variable("eta=0.3:0.1")
    space = DesignSpace.build(base, ["eta=0.1:0.3", "diameter_cv=0:0.4"], ["porosity>=0.8"])
    unit = np.array([[0.0, 0.5], [0.5, 0.5], [1.0, 0.5]])  # eta 0.1, 0.2, 0.3
    assert space.feasible(unit).tolist() == [True, True, False]
    assert space.overrides(space.values([0.5, 0.5]))["rve.diameter_sd_um"] == pytest.approx(0.2 * 0.45)
    with pytest.raises(ConfigError, match="unknown quantity 'density'"):
        parse_constraint("density>=3")
    with pytest.raises(ConfigError, match="a design variable is a key of the mat"):
        parse_variable("loading.direction_deg=0:90")
    with pytest.raises(ConfigError, match="as diameter_cv"):
        parse_variable("diameter_sd_um=0:0.2")
    # bounds as a mapping, as the docstring says
    assert [v.key for v in DesignSpace.build(base, {"eta": (0.1, 0.3)}).variables] == ["rve.volume_fraction"]


def _known(function):
    """An evaluator from a known function of the variable values (and the seed, for noise)."""
    def evaluate(space, targets, evaluations, folder, pool):
        for e in evaluations:
            for output, value in function(e.values, e.seed).items():
                e.outputs[output] = value
    return evaluate


def _noise(values, seed, scale):
    """Deterministic noise of relative size ``scale`` for one design and seed."""
    key = int(1e6 * sum(values.values())) % 2**31
    return 1.0 + scale * np.random.default_rng([key, seed]).standard_normal()


@pytest.mark.slow
def test_optimizer_finds_a_known_noisy_optimum_in_two_variables():
    # A smooth anisotropic response with 1 % realization noise: E(eta, kappa), E90(eta, kappa).
    def response(values, seed):
        eta, kappa = values["rve.volume_fraction"], values["rve.orientation.von_mises.kappa"]
        e0 = 1100.0 * eta * (1.0 + 0.15 * kappa)
        e90 = 1100.0 * eta / (1.0 + 0.1 * kappa)
        return {("modulus_MPa", 0.0): e0 * _noise(values, seed, 0.01),
                ("modulus_MPa", 90.0): e90 * _noise(values, seed + 7, 0.01)}

    # target: eta = 0.2, kappa = 4 -> E0 = 352, E0 / E90 = 1.6 * 1.4 = 2.24
    run = run_design(["E=352", "E@0/E@90=2.24"], ["eta=0.1:0.3", "kappa=0:8"], base="plla", budget=40,
                     evaluator=_known(response), seed=3)
    best = run.best.values
    assert best["rve.volume_fraction"] == pytest.approx(0.2, rel=0.05)
    assert best["rve.orientation.von_mises.kappa"] == pytest.approx(4.0, abs=0.6)
    assert run.met and run.tests <= 40
    result = design_result(run)
    assert result.reached and all(t["met"] and t["inside"] for t in result.targets.values())


@pytest.mark.slow
def test_unreachable_target_names_the_binding_bound():
    def response(values, seed):
        return {("modulus_MPa", 0.0): 1000.0 * values["rve.volume_fraction"] * _noise(values, seed, 0.005)}

    result = design_result(run_design(["E=500"], ["eta=0.1:0.3"], base="plla", budget=16,
                                      evaluator=_known(response)))
    assert not result.reached
    assert "rve.volume_fraction = 0.3 (upper bound)" in result.message
    assert result.values["rve.volume_fraction"] > 0.29  # the nearest achievable design
    # a constraint that binds first is named instead
    result = design_result(run_design(["E=500"], ["eta=0.1:0.3"], base="plla", budget=16,
                                      constraints=["porosity>=0.8"], evaluator=_known(response)))
    assert "constraint porosity >= 0.8" in result.message and result.values["rve.volume_fraction"] <= 0.2 + 1e-9


@pytest.mark.slow
def test_competing_targets_give_a_pareto_front(tmp_path):
    # E_0 = 1000 eta and E_90 = 500 eta: E_0 = 200 wants eta 0.2, E_90 = 150 wants eta 0.3.
    def response(values, seed):
        eta = values["rve.volume_fraction"]
        return {("modulus_MPa", 0.0): 1000.0 * eta * _noise(values, seed, 0.002),
                ("modulus_MPa", 90.0): 500.0 * eta * _noise(values, seed + 1, 0.002)}

    result = design_result(run_design(["E=200", "E@90=150"], ["eta=0.1:0.3"], base="plla", budget=24,
                                      evaluator=_known(response)))
    table = result.evaluations
    front = table[table["pareto"]]["rve.volume_fraction"]
    # the trade-off lies between the two targets' own optima; designs outside it are dominated
    assert len(front) >= 2 and front.between(0.195, 0.305).all()
    assert not result.reached
    files = result.write(tmp_path)
    assert files["pareto"].is_file()


def test_budget_and_base_are_checked_before_any_work():
    with pytest.raises(ConfigError, match="budget: 5 tensile tests cannot hold the initial design"):
        run_design(["E=150"], ["eta=0.1:0.3"], budget=5, evaluator=_known(lambda v, s: {}))
    with pytest.raises(ConfigError, match="loading must be loading.test = 'uniaxial'"):
        run_design(["E=150"], ["eta=0.1:0.3"], loading__test="equibiaxial", evaluator=_known(lambda v, s: {}))
    with pytest.raises(ConfigError, match="no point inside the variables' bounds meets them"):
        run_design(["E=150"], ["eta=0.2:0.3"], constraints=["porosity>=0.9"], evaluator=_known(lambda v, s: {}))
    with pytest.raises(ConfigError, match="target yield_strain 0.04: the tests stop at loading.max_strain = 0.03"):
        run_design(["eps_y=0.04"], ["eta=0.1:0.3"], loading__max_strain=0.03, evaluator=_known(lambda v, s: {}))
    with pytest.raises(ConfigError, match="seed: an integer >= 0"):
        run_design(["E=150"], ["eta=0.1:0.3"], seed=-1, evaluator=_known(lambda v, s: {}))
    with pytest.raises(ConfigError, match="the bounds leave only 1 distinct design"):
        run_design(["E=150"], ["layers=2.6:3.4"], evaluator=_known(lambda v, s: {}))


@pytest.mark.slow
def test_mapping_variables_and_the_scatter_message():
    from espin.design.search import prepare_design

    # bounds as a mapping go through the checks design() runs before claiming its folder
    problem = prepare_design(["E=150"], {"eta": (0.1, 0.3)}, base="plla")
    assert [v.key for v in problem.space.variables] == ["rve.volume_fraction"] and len(problem.first) == 6

    # 12 % scatter between seeds against a 5 % tolerance, and a target out of reach: the report
    # names the scatter.
    def response(values, seed):
        return {("modulus_MPa", 0.0): 1000.0 * values["rve.volume_fraction"] * _noise(values, seed, 0.12)}

    result = design_result(run_design(["E=500"], {"eta": (0.1, 0.3)}, base="plla", budget=12, seed=1,
                                      evaluator=_known(response)))
    assert not result.reached and result.values["rve.volume_fraction"] > 0.28
    assert "realization scatter is comparable to the tolerance (modulus_MPa@0" in result.message
    sd, dof = result.run.realization_sd[("modulus_MPa", 0.0)]
    assert dof == 4 and 0.04 < sd < 0.3  # two groups of three distinct seeds: the first and the best design


@pytest.fixture(scope="module")
def small_design(tmp_path_factory):
    folder = tmp_path_factory.mktemp("design") / "run"
    overrides = {k.replace(".", "__"): v for k, v in TINY.items()}
    result = design(["E=150"], ["eta=0.1:0.3"], base="plla", budget=12, folder=folder, workers=1, **overrides)
    return folder, overrides, result


@pytest.mark.slow
def test_small_design_meets_its_target_and_writes_its_files(small_design):
    folder, _, result = small_design
    for name in ("design.toml", "design.json", "evaluations.csv", "convergence.png", "maps.png", "verification.png"):
        assert (folder / name).is_file(), name
    # design.toml runs as it is and is the best design
    assert load_config(folder / "design.toml").rve.volume_fraction == pytest.approx(
        result.values["rve.volume_fraction"])
    target = result.targets["modulus_MPa@0"]
    # The verification mean of 5 fresh seeds falls inside the 95 % prediction interval.
    assert target["low"] <= target["verified"] <= target["high"] and target["inside"]
    assert result.evaluations["stage"].tolist().count("verify") == 5
    assert math.isfinite(result.evaluations["objective"].iloc[0])


@pytest.mark.slow
def test_rerun_repeats_no_tensile_test_with_any_workers(small_design, monkeypatch):
    folder, overrides, result = small_design
    import espin.design.search as search

    def refusing(tasks, folder=None, **options):  # the ensemble may only read finished tests back
        def task_function(task):
            raise AssertionError(f"ran test {task.key} again")
        return ensemble_run(tasks, folder, **options, task_function=task_function)

    ensemble_run = search.run_ensemble
    monkeypatch.setattr(search, "run_ensemble", refusing)
    files = sorted((folder / "runs" / "tasks").glob("*.json"))
    stamps = [f.stat().st_mtime_ns for f in files]
    again = design(["E=150"], ["eta=0.1:0.3"], base="plla", budget=12, folder=folder, workers=2, **overrides)
    assert sorted((folder / "runs" / "tasks").glob("*.json")) == files
    assert [f.stat().st_mtime_ns for f in files] == stamps and not list((folder / "runs").glob("failed/*.json"))
    assert again.values == result.values
    # other inputs in the same folder are refused, not mixed in
    with pytest.raises(ConfigError, match="overwrite"):
        design(["E=160"], ["eta=0.1:0.3"], base="plla", budget=12, folder=folder, workers=1, **overrides)
    # a refused input never touches the folder, even with overwrite
    with pytest.raises(ConfigError, match="budget: 5 tensile tests"):
        design(["E=150"], ["eta=0.1:0.3"], base="plla", budget=5, folder=folder, overwrite=True, **overrides)
    assert sorted((folder / "runs" / "tasks").glob("*.json")) == files


@pytest.mark.slow
def test_same_seed_same_designs_with_two_workers(small_design, tmp_path):
    _, overrides, result = small_design
    parallel = design(["E=150"], ["eta=0.1:0.3"], base="plla", budget=12, folder=tmp_path / "two", workers=2,
                      **overrides)
    columns = ["id", "stage", "seed", "rve.volume_fraction", "modulus_MPa@0"]
    assert parallel.evaluations[columns].equals(result.evaluations[columns])


@pytest.mark.slow
def test_stresses_do_not_depend_on_the_fiber_diameter():
    # Every length is a multiple of D and the RVE volume scales with it: P is unchanged.
    import espin

    curves = [espin.simulate("plla", rve__diameter_um=d, rve__size_ratio=30, rve__layers=2,
                             loading__max_strain=0.06, loading__steps=6).stress() for d in (0.45, 1.8)]
    assert np.max(np.abs(curves[0] - curves[1])) <= 1e-9 * np.max(np.abs(curves[0]))


@pytest.mark.slow
def test_curve_target_recovers_a_known_design():
    from espin.design.targets import CurveTarget

    # The truth: a known design's curve, mean of its own seeds; the search sees only the curve.
    def response(values, seed):
        eta, wav = values["rve.volume_fraction"], values["rve.waviness_deg"]
        strain = np.linspace(0.01, 0.1, 10)
        stress = 40.0 * eta * np.tanh(strain / (0.01 + 0.002 * wav)) * (1.0 + strain)
        return {(f"stress_at_{e:.6g}", 0.0): s * _noise(values, seed, 0.005) for e, s in zip(strain, stress)}

    truth = response({"rve.volume_fraction": 0.17, "rve.waviness_deg": 15.0}, 0)
    strain = np.linspace(0.01, 0.1, 10)
    target = CurveTarget.from_curve(strain, [truth[(f"stress_at_{e:.6g}", 0.0)] for e in strain],
                                    strain_range=(0.01, 0.1), points=10, tolerance=0.02)
    run = run_design([target], ["waviness_deg=0:30", "eta=0.1:0.3"], base="plla", rve__walk="smooth",
                     loading__max_strain=0.1, budget=30, evaluator=_known(response))
    assert run.best.values["rve.volume_fraction"] == pytest.approx(0.17, rel=0.05)
    assert run.best.values["rve.waviness_deg"] == pytest.approx(15.0, abs=2.0)
    with pytest.raises(ConfigError, match="raise it \\(--set loading.max_strain=0.1\\)"):
        run_design([target], ["eta=0.1:0.3"], base="plla", loading__max_strain=0.05, evaluator=_known(response))


@pytest.mark.slow
def test_realizations_per_design_model_the_seed_mean():
    # 6 % scatter between seeds against a 5 % tolerance: each design on 3 seeds, their mean modelled.
    def response(values, seed):
        return {("modulus_MPa", 0.0): 1000.0 * values["rve.volume_fraction"] * _noise(values, seed, 0.06)}

    run = run_design(["E=200"], ["eta=0.1:0.3"], base="plla", budget=45, realizations=3, seed=2,
                     evaluator=_known(response))
    searched = [e for e in run.evaluations if e.stage in ("initial", "search")]
    by_design: dict[float, set[int]] = {}
    for e in searched:
        by_design.setdefault(e.values["rve.volume_fraction"], set()).add(e.seed)
    assert all(seeds == {1, 2, 3} for seeds in by_design.values())  # the same three seeds everywhere
    replicate_seeds = {e.seed for e in run.evaluations if e.stage == "replicate"}
    assert replicate_seeds.isdisjoint({1, 2, 3}) and run.realizations == 3
    assert run.tests <= 45 and (run.tests - 2) % 3 == 0  # 2 replicates, then 3 tests per design
    # the best design's outputs are its seeds' mean, and the truth (eta 0.2) is near
    assert run.best.values["rve.volume_fraction"] == pytest.approx(0.2, rel=0.06)
    with pytest.raises(ConfigError, match="realizations: an integer >= 1"):
        run_design(["E=200"], ["eta=0.1:0.3"], realizations=0, evaluator=_known(response))
