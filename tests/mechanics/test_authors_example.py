"""The authors' own worked example as a check (data/authors: their network, run and curve).

Their code ran the network affinely (every node at F X), pulled F11 at 1e-2 /s, lowered F22
to hold the homogenized lateral T22 = P F^T at 0.01 MPa, with fiber law Et 2900 MPa, Eb/Et
1e-3, a_p 1e-8 /s, b_p 4.5 MPa, c_p 0. The data stay in ../shared; without it the test skips.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from espin.core.config import config_from_dict
from espin.geometry.network_file import read_network
from espin.mechanics.run import simulate

AUTHORS = Path(__file__).resolve().parents[3] / "shared" / "data" / "authors"
MESH = AUTHORS / "mesh_malla_i_s.txt"
CURVE = AUTHORS / "curve_malla_c_every50.txt"

pytestmark = pytest.mark.skipif(not (MESH.exists() and CURVE.exists()),
                                reason=f"the authors' example is not at {AUTHORS}")

THEIR_RUN = {
    "fiber": {"taut_modulus_MPa": 2900.0, "slack_modulus_MPa": 2.9, "flow_rate_per_s": 1e-8,
              "flow_resistance_MPa": 4.5, "hardening_exponent": 0.0},
    "solver": {"kinematics": "affine", "time_rtol": 1e-5},
    "output": {"stress_measure": "kirchhoff", "figures": False, "vtk": False},
}
"""Their law, affine kinematics, their measure; the plastic flow integrated to 1e-5 (theirs:
explicit steps of 1e-3 s)."""
AT = (0.01, 0.05, 0.10, 0.1995)
"""The strains compared: F11 = 1.01, 1.05, 1.10 and the subsample's last row (1.1995, a row of
every 50 of theirs; 1.20 is not in it)."""


def test_affine_run_reproduces_the_authors_curve():
    program = [{"to_strain": b, "rate_per_s": 1e-2, "steps": max(1, round((b - a) / 0.01))}
               for a, b in zip((0.0, *AT), AT)]
    config = config_from_dict(THEIR_RUN | {"loading": {"lateral": {"stress_MPa": 0.01}, "program": program}})
    result = simulate(MESH, config=config)
    theirs = np.loadtxt(CURVE)
    for strain in AT:
        row = theirs[np.argmin(np.abs(theirs[:, 0] - 1.0 - strain))]
        assert row[0] == pytest.approx(1.0 + strain, abs=1e-12)
        k = int(np.argmin(np.abs(result.strain - strain)))
        assert result.strain[k] == pytest.approx(strain, abs=1e-12)
        tau = result.kirchhoff[k]
        assert tau[0, 0] == pytest.approx(row[4], rel=1e-3), f"T11 at F11 = {1 + strain}"
        assert result.F[k, 1, 1] == pytest.approx(row[3], abs=1e-3), f"F22 at F11 = {1 + strain}"
        assert tau[1, 1] == pytest.approx(0.01, rel=1e-3)  # the lateral target, held
    network = read_network(MESH)
    X = network.node_position - network.centre
    np.testing.assert_array_equal(result.final.positions, X @ result.F[-1].T)  # every node at F X
