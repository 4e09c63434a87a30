"""FE^2 on tiny meshes with a small RVE (L/D 60, 3 layers): the patch test against a single RVE,
the macro tangent against finite differences, Newton's quadratic convergence, commit and
rollback of the RVE states, reopening a point, and the surrogate's invariance and tangent."""

from __future__ import annotations

import numpy as np
import pytest

import espin
from espin.core.errors import ConfigError, InputError
from espin.specimen.membrane import Membrane
from espin.specimen.rve_points import RVEPoints, rve_tolerance
from espin.specimen.shapes import strip
from espin.specimen.solver import GripProgram, run_specimen
from espin.specimen.surrogate import build_surrogate

MACRO_RTOL = 1e-6
T = 0.1


@pytest.fixture(scope="module")
def rve():
    return espin.generate("plla", rve__size_ratio=60, rve__layers=3)


def _points(rve, membrane: Membrane) -> RVEPoints:
    return RVEPoints(rve.network, rve_tolerance(rve.config, MACRO_RTOL), membrane.n_points)


def test_rve_tolerance_is_a_thousandth_of_the_macro_one(rve):
    config = rve_tolerance(rve.config, MACRO_RTOL)
    assert config.solver.rtol <= 1e-3 * MACRO_RTOL and config.solver.atol <= 1e-3 * MACRO_RTOL


def test_patch_test_lateral_fixed_reproduces_the_single_rve(rve, monkeypatch):
    """Every boundary node follows x = diag(1 + e, 1) X: each point must be the single RVE's test
    (lateral fixed), with the same time steps chosen by the same local-error rule (the single
    RVE's without the rejection of steps at their predictor, which the specimen's march does
    not foresee)."""
    from espin.mechanics.driver import _ProgramSteps

    monkeypatch.setattr(_ProgramSteps, "estimate", lambda self, start, end: 0.0)
    specimen = strip(20.0, 10.0, elements_across=1)
    membrane = Membrane(specimen.mesh, T)
    points = _points(rve, membrane)
    steps = run_specimen(specimen, points, GripProgram(0.03, 2, rve.config.loading.strain_rate_per_s),
                         thickness_mm=T, time_rtol=rve.config.solver.time_rtol, membrane=membrane,
                         affine_F=lambda e: np.diag([1.0 + e, 1.0]))
    single = espin.simulate(rve, loading__max_strain=0.03, loading__steps=2, loading__lateral="fixed")
    for k, step in enumerate(steps):
        assert np.ptp(step.F, axis=0).max() < 1e-9
        assert step.P[:, 0, 0] == pytest.approx(np.full(membrane.n_points, single.P[k, 0, 0]), rel=1e-3, abs=1e-9)
        assert step.force_N == pytest.approx(single.P[k, 0, 0] * 10.0 * T, rel=1e-3, abs=1e-9)
    assert [s.substeps for s in steps[1:]] == list(single.substeps[1:])


@pytest.mark.slow
def test_patch_test_free_edge_reproduces_the_single_rve(rve, tmp_path, monkeypatch):
    """The single RVE under uniaxial stress (lateral free: F12 and F22 found by P12 = P22 = 0, one time
    step) gives F(t); the strip's boundary follows it, so every point solves the same RVE problem.
    Started as that RVE driven through the same F (test "path") is, from the affine warm start, the
    points agree with it to the solver's tolerance. Against the mixed-control run they agree to
    0.1 % (measured 0.028 %). The points' own predictor (dz/dF) starts them elsewhere, and in lateral
    compression the RVE has more than one equilibrium (buckled chains): they then land 0.17 % from
    the path run (with 2 steps to 1 % the path and mixed-control runs land 0.33 % apart,
    docs/specimen.md), all on the same one."""
    import espin.specimen.rve_points as rve_points

    single = espin.simulate(rve, loading__max_strain=0.01, loading__steps=1, loading__lateral="free",
                            solver__time_rtol="off")
    path_csv = tmp_path / "path.csv"
    rows = [",".join(f"{v:.17g}" for v in (t, *F.ravel())) for t, F in zip(single.time, single.F)]
    path_csv.write_text("time_s,F11,F12,F21,F22\n" + "\n".join(rows) + "\n")
    same_F = espin.simulate(rve, loading__test="path", loading__path_csv=path_csv, solver__time_rtol="off")
    specimen = strip(20.0, 10.0, elements_across=1)
    membrane = Membrane(specimen.mesh, T)

    def affine(e: float) -> np.ndarray:
        return np.array([[np.interp(e, single.strain, single.F[:, i, j]) for j in range(2)] for i in range(2)])

    def strip_run():
        steps = run_specimen(specimen, _points(rve, membrane), GripProgram(0.01, 1, rve.config.loading.strain_rate_per_s),
                             thickness_mm=T, membrane=membrane, affine_F=affine)
        return steps[-1]

    scale = same_F.P[-1, 0, 0]
    predicted = strip_run()
    assert np.ptp(predicted.P, axis=0).max() < 1e-9
    np.testing.assert_allclose(predicted.P, np.broadcast_to(same_F.P[-1], predicted.P.shape), rtol=0, atol=5e-3 * scale)
    monkeypatch.setattr(rve_points, "_predictor", lambda inner, reference, sensitivity, dF: inner + reference @ dF.T)
    last = strip_run()
    assert single.F[-1, 1, 1] < 1.0  # it contracted
    assert np.ptp(last.P, axis=0).max() < 1e-9
    np.testing.assert_allclose(last.P, np.broadcast_to(same_F.P[-1], last.P.shape), rtol=0, atol=1e-6 * scale)
    assert last.P[:, 0, 0] == pytest.approx(np.full(membrane.n_points, single.P[-1, 0, 0]), rel=1e-3)
    assert np.abs(last.P[:, 1, 1]).max() < 1e-3 * single.P[-1, 0, 0]
    assert last.force_N == pytest.approx(single.P[-1, 0, 0] * 10.0 * T, rel=1e-3)


def test_macro_tangent_matches_finite_differences_and_newton_converges_quadratically(rve):
    specimen = strip(20.0, 5.0, elements_across=1)
    membrane = Membrane(specimen.mesh, T)
    points = _points(rve, membrane)
    # clamped grips and fixed sides on an anisotropic RVE (P12 != 0 at F12 = 0): the strip shears unevenly
    steps = run_specimen(specimen, points, GripProgram(0.03, 1, rve.config.loading.strain_rate_per_s),
                         thickness_mm=T, membrane=membrane, lateral="fixed", rtol=1e-9)
    history = steps[-1].residual_history
    # quadratic: each residual at most a constant times the square of the one before, at the end
    rates = [np.log(history[k + 1] / history[k]) / np.log(history[k] / history[k - 1])
             for k in range(1, len(history) - 1)]
    print("macro residual history [N]:", history)
    assert len(history) >= 3 and max(rates) > 1.7, history

    u = steps[-1].u
    time = steps[-1].time + 1.0  # a time step: the plastic flow enters the tangent
    du = np.random.default_rng(3).standard_normal(membrane.n_dofs) * 1e-3

    def force(v):
        P, A = points.evaluate(membrane.deformation_gradient(v), time)
        return membrane.internal_force(P), A

    _, A = force(u)
    K = membrane.tangent(A)
    h = 1e-3
    fd = (force(u + h * du)[0] - force(u - h * du)[0]) / (2 * h)
    assert np.linalg.norm(fd - K @ du) < 1e-3 * np.linalg.norm(K @ du)
    points.rollback()


def test_states_change_only_on_commit(rve):
    specimen = strip(20.0, 5.0, elements_across=1)
    membrane = Membrane(specimen.mesh, T)
    points = _points(rve, membrane)
    before = points.state
    F = np.tile(np.diag([1.05, 1.0]), (membrane.n_points, 1, 1))
    P, _ = points.evaluate(F, 10.0)
    points.rollback()
    assert points.state is before and len(points.history_F) == 0
    again, _ = points.evaluate(F, 10.0)
    assert np.array_equal(P, again)  # from the same committed state
    points.commit()
    assert points.state.time == 10.0 and np.array_equal(points.state.F, F)
    assert max(p.max() for p in points.state.plastic_stretch) > 1.0  # it flowed over the 10 s step
    assert len(points.history_F) == 1 and points.fields()["yielded_fraction"].max() > 0.0


def test_the_first_trial_of_a_time_step_follows_the_last_step_in_time(rve):
    """Steady straining past the yield knee in small steps: the warm start of a new time step
    moved along the last step's motion (the plastic flow goes on) lies closer to the solution
    than the last solution moved by dz/dF alone."""
    rate = rve.config.loading.strain_rate_per_s
    points = RVEPoints(rve.network, rve_tolerance(rve.config, MACRO_RTOL), 2)
    F = lambda e: np.array([np.diag([1.0 + e, 1.0 - 0.3 * e]), [[1.0 + e, 0.2 * e], [0.0, 1.0]]])  # noqa: E731
    points.evaluate(F(0.0), 0.0)
    points.commit()
    for e in (0.03, 0.031, 0.032):
        points.evaluate(F(e), e / rate)
        points.commit()
    e, time = 0.033, 0.033 / rate
    along_time = points._guess(F(e), time)
    last = points.state
    along_F = [(w.ravel() + S @ (F_p - F_l).ravel()).reshape(w.shape)
               for w, S, F_p, F_l in zip(last.inner, last.sensitivity, F(e), last.F)]
    points.evaluate(F(e), time)
    for w, guess, first_order in zip(points._trial.inner, along_time, along_F):
        assert np.sqrt(np.mean((guess - w) ** 2)) < 0.5 * np.sqrt(np.mean((first_order - w) ** 2))


@pytest.mark.slow
def test_specimen_folder_and_reopened_point(rve, tmp_path):
    out = tmp_path / "run"
    result = espin.specimen(rve, strip(20.0, 5.0, elements_across=1), max_strain=0.02, steps=2, out=out)
    for name in ("force_displacement.csv", "fields.pvd", "vtk/step_0002.vtu", "force.png", "specimen.png",
                 "yielded.png", "specimen.json", "rve.h5", "rve_points.h5"):
        assert (out / name).is_file(), name
    table = result.to_dataframe()
    assert list(table["force_N"]) == pytest.approx(list(result.force_N))
    reopened = espin.specimen.reopen_point(out, 2)
    last = result.steps[-1]
    assert len(reopened.time) == len(set(reopened.time)) == result.counts["time_steps"] + 1  # each step once
    assert reopened.strain[-1] == pytest.approx(reopened.F[-1, 0, 0] - 1.0)
    assert 'timestep="0.0"' in (out / "fields.pvd").read_text()
    assert np.allclose(reopened.F[-1], last.F[2], atol=1e-14)
    assert np.allclose(reopened.P[-1], last.P[2], rtol=1e-6, atol=1e-9)
    assert np.allclose(reopened.final.plastic_stretch, result.final_state.plastic_stretch[2], rtol=1e-9)
    with pytest.raises(ConfigError, match="overwrite"):
        espin.specimen(rve, strip(20.0, 5.0, elements_across=1), max_strain=0.02, steps=2, out=out)


@pytest.mark.parametrize("options, match", [
    (dict(model="fem"), "model"), (dict(lateral="loose"), "lateral"), (dict(grips="glued"), "grips"),
    (dict(thickness_mm=-1.0), "thickness_mm"), (dict(shape="hexagon"), "shape"),
    (dict(model="neo_hookean"), "modulus_MPa"), (dict(shape_options={"radius_mm": 1.0}), "radius_mm"),
    (dict(max_strain=2.0), "max_strain"), (dict(rve_seeds="some"), "rve_seeds"),
    ({"solver.kinematics": "affine"}, "solver.kinematics"),
])
def test_bad_options_are_refused_before_any_work(options, match, tmp_path):
    out = tmp_path / "never"
    with pytest.raises(ConfigError, match=match):
        espin.specimen("plla", **{"shape": "strip", **options}, out=out)
    assert not out.exists()


@pytest.mark.slow
def test_surrogate_is_frame_indifferent_rate_dependent_and_its_tangent_is_consistent(rve):
    surrogate = build_surrogate(rve.network, rve.config, 0.05, reach=1.0, steps=4, speeds=(1.0, 4.0),
                                paths=[(1.0, 0.0, 0.0), (1.0, -0.5, 0.0), (0.0, 1.0, 0.0), (1.0, 0.0, 0.5)])
    F = np.array([[[1.03, 0.01], [0.0, 0.99]], [[1.02, 0.0], [0.005, 1.0]]])
    start = np.array([[[1.02, 0.004], [0.004, 0.995]], [[1.015, 0.001], [0.001, 1.0]]])  # U a step before
    rate = rve.config.loading.strain_rate_per_s
    dt = 0.01 / (2.0 * rate)  # about speed 2 for point 0
    P, A, fields = surrogate.stress(F, start, dt)
    theta = 0.7
    R = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    P_rotated, _, _ = surrogate.stress(R @ F, start, dt)
    assert np.allclose(P_rotated, R @ P, atol=1e-10)
    h = 1e-6
    for k in range(2):
        for L in range(2):
            dF = np.zeros((2, 2))
            dF[k, L] = h
            fd = (surrogate.stress(F + dF, start, dt)[0] - surrogate.stress(F - dF, start, dt)[0]) / (2 * h)
            assert np.allclose(fd, A[:, :, :, k, L], rtol=1e-4, atol=1e-4 * np.abs(A).max())
    # faster is stiffer past yield (the fiber law's rate), and between the speeds run
    slow = surrogate.stress(F, start, 100.0 * dt)[0][0, 0, 0]
    fast = surrogate.stress(F, start, 0.01 * dt)[0][0, 0, 0]
    assert slow < P[0, 0, 0] < fast
    # at its samples the interpolant is the RVE: S = F^-1 P of the sampled states (speed 1: no step)
    sample = int(np.flatnonzero(surrogate.speed == 1.0)[3])
    E = surrogate.E[sample]
    C = np.eye(2) + 2 * np.array([[E[0], E[2]], [E[2], E[1]]])
    w, V = np.linalg.eigh(C)
    U = V @ np.diag(np.sqrt(w)) @ V.T
    S = np.linalg.solve(U, surrogate.stress(U[None])[0][0])
    assert np.allclose([S[0, 0], S[1, 1], S[0, 1]], surrogate.S[sample], rtol=1e-6, atol=1e-8)
    assert set(fields) == {"yielded_fraction", "recruited_fraction"}


@pytest.mark.slow
def test_per_point_realizations_differ_and_the_shared_rve_is_one():
    shared = espin.specimen("plla", strip(20.0, 5.0, elements_across=1), max_strain=0.01, steps=1,
                            rve__size_ratio=30, rve__layers=2)
    own = espin.specimen("plla", strip(20.0, 5.0, elements_across=1), max_strain=0.01, steps=1,
                         rve__size_ratio=30, rve__layers=2, rve_seeds="per_point")
    assert len({id(n) for n in shared.networks}) == 1
    assert len({(n.n_elements, float(n.node_position.sum())) for n in own.networks}) == own.membrane.n_points
    # point 0 of the per-point run is the shared RVE's seed: the same mat
    assert own.networks[0].n_elements == shared.networks[0].n_elements
    assert own.force_N[-1] != pytest.approx(shared.force_N[-1], rel=1e-6)


@pytest.mark.slow
def test_a_surrogate_runs_again_from_its_samples(rve, tmp_path):
    from espin.specimen.surrogate_file import write_samples

    built = build_surrogate(rve.network, rve.config, 0.02, reach=1.0, steps=3, speeds=(1.0, 4.0),
                            paths=[(1.0, 0.0, 0.0), (1.0, -0.5, 0.0), (0.0, 1.0, 0.0), (1.0, 0.0, 0.5)])
    samples = write_samples(tmp_path / "surrogate_samples.csv", built.identity, built.runs)
    specimen = strip(20.0, 5.0, elements_across=1)
    membrane = Membrane(specimen.mesh, T)
    direct = run_specimen(specimen, built.material(membrane.n_points),
                          GripProgram(0.02, 2, rve.config.loading.strain_rate_per_s), thickness_mm=T,
                          membrane=membrane, lateral="fixed")
    again = espin.specimen(rve, specimen, model="surrogate", max_strain=0.02, steps=2, out=tmp_path / "b",
                           surrogate_from=samples)
    assert np.allclose(again.force_N, [s.force_N for s in direct], rtol=1e-9)
    assert not (tmp_path / "b" / "rve.h5").exists()
    assert (tmp_path / "b" / "surrogate_samples.csv").read_bytes() == samples.read_bytes()
    with pytest.raises(InputError, match="surrogate_from.*specimen.json"):
        espin.specimen(rve, "strip", model="surrogate", surrogate_from=tmp_path / "b" / "specimen.json")
