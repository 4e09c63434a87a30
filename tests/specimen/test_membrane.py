"""The specimen's finite elements with a closed-form material: tangent, patch test, small-strain
limit, mesh convergence and the stress concentration at a hole (no RVEs)."""

from __future__ import annotations

import re

import numpy as np
import pytest
from scipy.optimize import brentq

from espin.core.errors import ConfigError, StepNotConverged
from espin.specimen.materials import NeoHookean
from espin.specimen.membrane import Membrane
from espin.specimen.shapes import holed_strip, strip
from espin.specimen.solver import GripProgram, run_specimen

E, NU, T = 100.0, 0.3, 0.1


def _uniaxial_P11(material: NeoHookean, stretch: float) -> float:
    """P11 of the neo-Hookean membrane under uniaxial stress (P22 = 0), solved by a root finder."""
    def P22(lateral: float) -> float:
        return material.evaluate(np.diag([stretch, lateral])[None], 0.0)[0][0, 1, 1]

    lateral = brentq(P22, 0.3, 1.0 + 1e-9)
    return float(material.evaluate(np.diag([stretch, lateral])[None], 0.0)[0][0, 0, 0])


def test_material_tangent_matches_finite_differences():
    material = NeoHookean(3, 1.5, 2.5)
    F = np.eye(2) + 0.2 * np.random.default_rng(1).standard_normal((3, 2, 2))
    P, A = material.evaluate(F, 0.0)
    h = 1e-6
    for k in range(2):
        for L in range(2):
            dF = np.zeros((2, 2))
            dF[k, L] = h
            fd = (material.evaluate(F + dF, 0.0)[0] - material.evaluate(F - dF, 0.0)[0]) / (2 * h)
            assert np.allclose(fd, A[:, :, :, k, L], rtol=1e-7, atol=1e-7)


def test_assembled_tangent_matches_finite_differences_of_the_forces():
    specimen = holed_strip(elements_across=2)
    membrane = Membrane(specimen.mesh, T)
    material = NeoHookean.from_uniaxial(membrane.n_points, E, NU)
    rng = np.random.default_rng(2)
    u = 0.05 * rng.standard_normal(membrane.n_dofs)
    du = rng.standard_normal(membrane.n_dofs)

    def force(v):
        return membrane.internal_force(material.evaluate(membrane.deformation_gradient(v), 0.0)[0])

    K = membrane.tangent(material.evaluate(membrane.deformation_gradient(u), 0.0)[1])
    h = 1e-6
    fd = (force(u + h * du) - force(u - h * du)) / (2 * h)
    assert np.allclose(fd, K @ du, rtol=1e-6, atol=1e-8 * np.abs(K @ du).max())
    assert abs(force(np.zeros(membrane.n_dofs))).max() == 0.0  # no stress undeformed


@pytest.mark.parametrize("grips, lateral", [("sliding", "free"), ("clamped", "fixed")])
def test_patch_test_homogeneous_strip(grips, lateral):
    """Sliding grips with free sides: uniaxial stress; clamped grips with fixed sides: F = diag(lambda, 1).
    Both are homogeneous, so every point has the same F and the force is P11 w t."""
    specimen = strip(20.0, 5.0, elements_across=2)
    membrane = Membrane(specimen.mesh, T)
    material = NeoHookean.from_uniaxial(membrane.n_points, E, NU)
    steps = run_specimen(specimen, material, GripProgram(0.3, 3, 1.0), thickness_mm=T, grips=grips,
                         lateral=lateral, membrane=membrane)
    last = steps[-1]
    assert np.ptp(last.F, axis=0).max() < 1e-10
    assert last.F[0, 0, 0] == pytest.approx(1.3, abs=1e-12)
    if lateral == "free":
        expected = _uniaxial_P11(material, 1.3)
        assert last.F[0, 1, 1] < 0.95
    else:
        expected = material.evaluate(np.diag([1.3, 1.0])[None], 0.0)[0][0, 0, 0]
        assert last.F[0, 1, 1] == pytest.approx(1.0, abs=1e-12)
    assert last.force_N == pytest.approx(expected * 5.0 * T, rel=1e-9)
    assert last.gauge_strain == pytest.approx(0.3, rel=1e-9)
    assert last.gauge_stress_MPa == pytest.approx(expected, rel=1e-9)
    # homogeneous: the transverse extensometer reads the points' lateral strain
    assert last.gauge_transverse_strain == pytest.approx(last.F[0, 1, 1] - 1.0, abs=1e-10)


def test_small_strain_limit_is_the_uniaxial_modulus():
    specimen = strip(20.0, 5.0, elements_across=1)
    membrane = Membrane(specimen.mesh, T)
    material = NeoHookean.from_uniaxial(membrane.n_points, E, NU)
    steps = run_specimen(specimen, material, GripProgram(1e-5, 1, 1.0), thickness_mm=T, grips="sliding",
                         lateral="free", membrane=membrane, rtol=1e-10)
    assert steps[-1].gauge_stress_MPa / 1e-5 == pytest.approx(E, rel=1e-4)
    assert -steps[-1].F[0, 1, 1] + 1.0 == pytest.approx(NU * 1e-5, rel=1e-3)


def test_holed_strip_converges_with_the_mesh_and_concentrates_stress_at_the_hole():
    forces, peaks = [], []
    for across in (4, 8, 16):
        specimen = holed_strip(elements_across=across)
        membrane = Membrane(specimen.mesh, T)
        material = NeoHookean.from_uniaxial(membrane.n_points, E, NU)
        last = run_specimen(specimen, material, GripProgram(0.01, 1, 1.0), thickness_mm=T, membrane=membrane,
                            lateral="free")[-1]
        forces.append(last.force_N)
        points = membrane.point_coordinates()
        far = np.abs(points[:, 0]) > 15.0
        peak = int(np.argmax(last.P[:, 0, 0]))
        peaks.append(last.P[peak, 0, 0] / np.mean(last.P[far, 0, 0]))
        # the largest P11 sits at the hole's edge, above or below it (across the load)
        assert np.hypot(*points[peak]) < 1.5 + 5.0 / across
        assert abs(points[peak, 1]) > abs(points[peak, 0])
    # monotone convergence from above (a displacement-based model is too stiff), differences shrinking
    assert forces[0] > forces[1] > forces[2]
    assert forces[1] - forces[2] < 0.7 * (forces[0] - forces[1])
    assert peaks[0] < peaks[1] < peaks[2]  # the refined mesh resolves more of the concentration
    assert peaks[2] > 2.0


def test_bad_options_are_refused():
    specimen = strip(elements_across=1)
    membrane = Membrane(specimen.mesh, T)
    material = NeoHookean.from_uniaxial(membrane.n_points, E, NU)
    with pytest.raises(ConfigError, match="lateral"):
        run_specimen(specimen, material, GripProgram(0.1, 1, 1.0), thickness_mm=T, lateral="loose")
    with pytest.raises(ConfigError, match="thickness_mm"):
        run_specimen(specimen, material, GripProgram(0.1, 1, 1.0), thickness_mm=0.0)
    with pytest.raises(ConfigError, match="max_strain"):
        GripProgram(1.5, 1, 1.0)
    with pytest.raises(ConfigError, match="steps"):
        GripProgram(0.1, 0, 1.0)
    with pytest.raises(ConfigError, match="poisson_ratio"):
        NeoHookean.from_uniaxial(1, E, 1.0)


def test_cli_runs_a_closed_form_dogbone_and_keeps_its_folder(tmp_path):
    from typer.testing import CliRunner

    from espin.cli import app

    out = tmp_path / "dog"
    args = ["specimen", "--shape", "dogbone", "--model", "neo_hookean", "--modulus", "100", "--poisson", "0.3",
            "--steps", "2", "--max-strain", "0.1", "--lateral", "free", "-o", str(out)]
    done = CliRunner().invoke(app, args)
    assert done.exit_code == 0, done.output
    assert "SpecimenResult(" not in done.output  # a summary for people, not a Python repr
    assert re.search(r"^grip force +\d", done.output, flags=re.M), done.output
    table = np.loadtxt(out / "force_displacement.csv", delimiter=",", skiprows=1)
    assert table.shape == (3, 11) and table[-1, 4] > table[1, 4] > 0.0
    # the gauge section (4 mm wide) strains more than the grips' 10 %: the wide ends barely stretch
    assert table[-1, 5] > 0.11
    again = CliRunner().invoke(app, args)
    assert again.exit_code != 0 and "overwrite" in again.output
    bad = CliRunner().invoke(app, ["specimen", "--shape-option", "hole_diameter_mm", "-o", str(tmp_path / "x")])
    assert bad.exit_code != 0 and "NAME=VALUE" in bad.output and not (tmp_path / "x").exists()


class _Fussy(NeoHookean):
    """A neo-Hookean material that fails on time steps longer than ``longest`` [s] and reports a local
    error ``error`` (a stand-in for RVEs whose Newton fails or whose plastic flow is too fast)."""

    def __init__(self, n_points: int, longest: float, error: float = 0.0):
        super().__init__(n_points, 40.0, 20.0)
        self.longest, self.error, self.committed = longest, error, 0.0
        self.trial = 0.0

    def evaluate(self, F, time):
        if time - self.committed > self.longest:
            raise StepNotConverged("step too long")
        self.trial = time
        return super().evaluate(F, time)

    def time_error(self):
        return self.error

    def commit(self):
        self.committed = self.trial


def test_cut_steps_grow_again_and_the_run_ends():
    specimen = strip(20.0, 5.0, elements_across=1)
    membrane = Membrane(specimen.mesh, T)
    material = _Fussy(membrane.n_points, longest=0.05)
    steps = run_specimen(specimen, material, GripProgram(0.5, 5, 1.0), thickness_mm=T, membrane=membrane)
    assert [s.grip_strain for s in steps] == pytest.approx([0.0, 0.1, 0.2, 0.3, 0.4, 0.5])
    assert steps[1].cuts >= 1
    assert sum(s.substeps for s in steps) <= 15  # 0.1 steps need 2-3 sub-steps of <= 0.05, not ever more


def test_time_steps_that_shrink_forever_stop_the_run():
    from espin.specimen.solver import SpecimenFailed

    specimen = strip(20.0, 5.0, elements_across=1)
    membrane = Membrane(specimen.mesh, T)
    material = _Fussy(membrane.n_points, longest=np.inf, error=np.inf)
    with pytest.raises(SpecimenFailed, match="below the smallest"):
        run_specimen(specimen, material, GripProgram(0.1, 1, 1.0), thickness_mm=T, membrane=membrane,
                     time_rtol=1e-3)


class _Buggy(NeoHookean):
    """A neo-Hookean material with a bug: it raises ValueError on its second evaluation."""

    def __init__(self, n_points: int):
        super().__init__(n_points, 40.0, 20.0)
        self.calls = 0

    def evaluate(self, F, time):
        self.calls += 1
        if self.calls > 1:
            raise ValueError("operands could not be broadcast together")
        return super().evaluate(F, time)


def test_a_bug_in_the_material_stops_the_run_instead_of_cutting_steps():
    specimen = strip(20.0, 5.0, elements_across=1)
    membrane = Membrane(specimen.mesh, T)
    material = _Buggy(membrane.n_points)
    with pytest.raises(ValueError, match="broadcast"):
        run_specimen(specimen, material, GripProgram(0.1, 1, 1.0), thickness_mm=T, membrane=membrane)
    assert material.calls == 2  # no cut, no retry


def test_lateral_fixed_holds_the_sides_but_not_the_notch():
    from espin.specimen.shapes import notched_strip

    specimen = notched_strip(elements_across=2)
    membrane = Membrane(specimen.mesh, T)
    material = NeoHookean.from_uniaxial(membrane.n_points, E, NU)
    last = run_specimen(specimen, material, GripProgram(0.05, 1, 1.0), thickness_mm=T, membrane=membrane,
                        lateral="fixed")[-1]
    mesh = specimen.mesh
    u_y = last.u[membrane.basis.nodal_dofs[1]]
    notch = np.unique(mesh.facets[:, mesh.boundaries["notch"]])
    sides = np.flatnonzero(np.isclose(np.abs(mesh.p[1]), 5.0))
    assert np.abs(u_y[sides]).max() == 0.0
    assert np.abs(u_y[notch]).max() > 1e-4  # the notch root moves
    # the transverse extensometer spans the net section at the notch, which contracts
    assert last.gauge_transverse_strain < -1e-4


def test_the_specimen_holds_its_sides_free_with_fused_crossings(monkeypatch):
    """Default sides: free for a mat with fused crossings (plla-bonded), fixed for the paper's."""
    import espin.specimen as specimen_module

    seen = []
    monkeypatch.setattr(specimen_module, "_run", lambda geometry, program, config, rve, settings, *a, **k:
                        seen.append(settings.lateral))
    for source in ("plla-bonded", "plla"):
        specimen_module.specimen(source, "strip", model="surrogate", elements_across=1)
    specimen_module.specimen("plla-bonded", "strip", model="surrogate", elements_across=1, lateral="fixed")
    assert seen == ["free", "fixed", "fixed"]


def test_a_singular_surrogate_tangent_cuts_the_step_instead_of_crashing():
    import scipy.sparse as sp

    from espin.core.errors import StepFailureKind
    from espin.specimen.solver import _MacroSolves

    singular = sp.csr_matrix(np.array([[1.0, 1.0], [1.0, 1.0]]))  # SuperLU's LU: exactly singular
    with pytest.raises(StepNotConverged) as failure:
        _MacroSolves(symmetric=False).factorize(singular)(np.ones(2))
    assert failure.value.kind == StepFailureKind.SINGULAR
