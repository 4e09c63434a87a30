"""Mats that users bring: the continuation in the slack modulus solves what Newton alone cannot.

A small subset of ``benchmarks/bench_robustness.py`` (which runs the whole sample).
"""

from __future__ import annotations

import numpy as np
import pytest

from espin.geometry.rve import generate
from espin.core.errors import StepNotConverged
from espin.mechanics.equilibrium import EquilibriumSolver
from espin.mechanics.run import simulate

# Case 2 of the robustness sample: a sparse, wavy, polydisperse, slightly aligned mat, with
# the merge tolerance of the time (1e-2 D).
WAVY_SPARSE = dict(rve__volume_fraction=0.0718, rve__max_deviation_deg=35.77, rve__segment_ratio=13.016,
                   rve__diameter_sd_um=0.106, rve__orientation={"von_mises": {"mean_deg": 0.0, "kappa": 2.084}},
                   rve__size_ratio=111.9, rve__layers=7, rve__seed=3, rve__merge_tolerance_ratio=0.01)
# Case 14: dense, wavy, very polydisperse, aligned, 8 layers (L = 60 D instead of 86.4 D).
DENSE_WAVY = dict(rve__volume_fraction=0.3196, rve__max_deviation_deg=38.39, rve__segment_ratio=3.606,
                  rve__diameter_sd_um=0.3039, rve__orientation={"von_mises": {"mean_deg": 0.0, "kappa": 5.288}},
                  rve__size_ratio=60.0, rve__layers=8, rve__seed=15)


@pytest.mark.slow
def test_wavy_sparse_mat_in_simple_shear_converges():
    """Before the continuation, step 2 failed after 12 cuts (35 s); now both steps converge in
    about 6 s. Step 1 needed the continuation (Newton alone stopped at its 200 iterations)
    until the non-monotone node relaxation: Newton alone converges it now (184 iterations)."""
    rve = generate("plla", **WAVY_SPARSE)
    result = simulate(rve, loading__test="simple_shear", loading__max_strain=0.02, loading__steps=2)
    assert len(result.strain) == 3 and result.strain[-1] == pytest.approx(0.02)
    assert result.iterations[1] <= 200  # Newton alone, without the continuation's stages
    assert np.all(np.isfinite(result.P)) and result.stress()[-1] > result.stress()[1] > 0


def test_continuation_ends_at_the_true_model(small_rve, monkeypatch):
    """Forcing the continuation at every step gives the same equilibrium as Newton alone:
    its last solve is the true model (unique here: lateral fixed, elastic-plastic, 2 steps)."""
    common = dict(loading__max_strain=0.02, loading__steps=2)
    plain = simulate(small_rve, **common)
    solve = EquilibriumSolver._solve
    seen = set()

    def newton_fails_once_per_step(self, start, time, *args):
        if time not in seen:
            seen.add(time)
            raise StepNotConverged("forced", history=[1.0, 1.0])
        return solve(self, start, time, *args)

    monkeypatch.setattr(EquilibriumSolver, "_solve", newton_fails_once_per_step)
    continued = simulate(small_rve, **common)
    assert np.all(continued.iterations[1:] > plain.iterations[1:])  # the stages ran
    np.testing.assert_allclose(continued.P, plain.P, rtol=1e-6, atol=1e-9 * np.abs(plain.P).max())


@pytest.mark.slow
def test_merging_close_crosslinks_makes_shear_cheap():
    """Simple shear of a dense wavy mat, one 1 % step: with cross-links closer than 0.1 D
    merged (the default) Newton needs fewer iterations than at 1e-2 D, where elements a few
    hundredths of D long keep it cycling, and the stress differs by less than the mats differ.
    On this case's mat before `lines` seeding was weighted by the square's width (SPEC 1),
    118 against 410; on today's mat 322 against 463 (seeds 1-3: 1.2-2.0 times fewer)."""
    shear = dict(loading__test="simple_shear", loading__max_strain=0.01, loading__steps=1)
    merged = simulate(generate("plla", **DENSE_WAVY), **shear)
    fine = simulate(generate("plla", **(DENSE_WAVY | {"rve__merge_tolerance_ratio": 0.01})), **shear)
    assert merged.iterations[1] < fine.iterations[1]
    assert merged.P[1, 0, 1] > 0 and fine.P[1, 0, 1] > 0
