"""The stress measures, the lateral stress target and affine kinematics, against what is known
exactly: a grid of straight fibers (whose equilibrium is affine) and the identities between the
measures."""

from __future__ import annotations

import numpy as np
import pytest

from espin.core.config import ConfigError, config_from_dict
from espin.mechanics.driver import run_program
from espin.mechanics.linear_solvers import make_linear_solver
from tests.conftest import grid_network

E_T = 3000.0  # MPa
N = 4  # fibers each way
SIZE, D = 10.0, 0.2  # um
AREA = np.pi * D**2 / 4.0


def _run(network, **sections):
    base = {"fiber": {"flow_rate_per_s": 0.0}, "loading": {"max_strain": 0.04, "steps": 4}}
    for key, value in sections.items():
        base[key] = base.get(key, {}) | value
    return run_program(network, config_from_dict(base), make_linear_solver("superlu"))


def _stress_tolerance(result, network) -> float:
    """The solver's tolerance on a free stress component [MPa]: rtol max |P| + atol E_t phi
    (phi: fiber volume fraction; docs/model.md section 4), at the largest stretch (Kirchhoff)."""
    phi = float(np.sum(network.element_area * network.element_contour_length)) / network.reference_volume
    return (1e-6 * np.abs(result.P).max() + 1e-8 * E_T * phi) * np.abs(result.F).max()


def _fiber_stress(stretch: np.ndarray) -> np.ndarray:
    """Engineering stress of a straight elastic fiber [MPa] (taut above stretch 1, else E_b)."""
    return np.where(stretch >= 1.0, E_T * (stretch - 1.0), 3.0 * (stretch - 1.0))


@pytest.mark.parametrize("kinematics", ["equilibrium", "affine"])
def test_grid_stresses_in_every_measure(kinematics):
    """Pulled along x with F22 = 1, only the x fibers carry load: P11 = N A t / (L D) with
    t = E_t (F11 - 1); Eq. 17 equals P for straight fibers; Kirchhoff = P F^T = det F Cauchy."""
    result = _run(grid_network(N, SIZE, D), solver={"kinematics": kinematics})
    F11 = result.F[:, 0, 0]
    P11 = N * AREA * _fiber_stress(F11) / (SIZE * D)
    np.testing.assert_allclose(result.P[:, 0, 0], P11, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(result.P_paper, result.P, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(result.kirchhoff, result.P @ np.transpose(result.F, (0, 2, 1)), rtol=1e-9, atol=1e-12)
    det = np.linalg.det(result.F)[:, None, None]
    np.testing.assert_allclose(result.kirchhoff, det * result.cauchy, rtol=1e-12, atol=1e-15)
    assert result.stress("kirchhoff")[-1] == pytest.approx(P11[-1] * F11[-1], rel=1e-9)


@pytest.mark.parametrize("kinematics", ["equilibrium", "affine"])
@pytest.mark.parametrize("measure", ["nominal", "kirchhoff"])
def test_lateral_stress_target_on_the_grid(kinematics, measure):
    """lateral = {stress_MPa = s}: the y fibers hold s. Nominal: N A E_t (F22 - 1) / (L D) = s;
    Kirchhoff: that times F22 = s. F12 stays 0 and the x fibers do not notice."""
    s = 0.5  # MPa
    network = grid_network(N, SIZE, D)
    result = _run(network, loading={"lateral": {"stress_MPa": s}},
                  solver={"kinematics": kinematics}, output={"stress_measure": measure})
    c = N * AREA * E_T / (SIZE * D)  # MPa per unit lateral strain
    # nominal: c (F22 - 1) = s; Kirchhoff: c (F22 - 1) F22 = s
    F22 = 1.0 + s / c if measure == "nominal" else (1.0 + np.sqrt(1.0 + 4.0 * s / c)) / 2.0
    np.testing.assert_allclose(result.F[:, 1, 1], F22, rtol=1e-7)
    assert np.all(result.F[:, 0, 1] == 0.0) and np.all(result.F[:, 1, 0] == 0.0)
    held = result.P if measure == "nominal" else result.kirchhoff
    np.testing.assert_allclose(held[:, 1, 1], s, rtol=0.0, atol=_stress_tolerance(result, network))
    np.testing.assert_allclose(result.P[:, 0, 0], N * AREA * _fiber_stress(result.F[:, 0, 0]) / (SIZE * D),
                               rtol=1e-7, atol=1e-12)


def test_lateral_target_in_a_rotated_frame(small_rve):
    """Loading at 30 deg: the Kirchhoff tau'22 of the loading frame is held at the target, and
    the equilibrium and affine runs both hold it."""
    for kinematics in ("equilibrium", "affine"):
        result = _run(small_rve.network, loading={"lateral": {"stress_MPa": 0.02}, "direction_deg": 30.0,
                                                  "max_strain": 0.02, "steps": 2},
                      solver={"kinematics": kinematics}, output={"stress_measure": "kirchhoff"})
        local = result.loading_frame(result.kirchhoff)
        np.testing.assert_allclose(local[:, 1, 1], 0.02, rtol=0.0, atol=_stress_tolerance(result, small_rve.network))
        assert result.loading_frame(result.F)[-1, 1, 1] < 1.0  # the mat contracts laterally


def test_affine_is_stiffer_than_equilibrium(small_rve):
    """The affine network model bounds the equilibrated one from above (lateral fixed), and its
    recorded residual is the inner nodes' force imbalance (zero only at equilibrium)."""
    affine = _run(small_rve.network, solver={"kinematics": "affine"})
    relaxed = _run(small_rve.network)
    assert np.all(affine.P[1:, 0, 0] > relaxed.P[1:, 0, 0])
    assert np.all(affine.residual[1:] > 1e3 * relaxed.residual[1:].max())
    assert np.all(affine.iterations == 0) and np.all(affine.factorizations == 0)
    # equilibrated: tau - P F^T = (1 / V0) sum over inner nodes of r_n (x) x_n, bounded by the residual
    net = small_rve.network
    bound = net.n_inner * relaxed.residual[:, None, None] * np.abs(relaxed.final.positions).max() / net.reference_volume
    PFt = relaxed.P @ np.transpose(relaxed.F, (0, 2, 1))
    assert np.all(np.abs(relaxed.kirchhoff - PFt) <= bound)
    assert np.abs(relaxed.kirchhoff - relaxed.P_paper).max() > 1e-3 * np.abs(relaxed.P).max()  # not Eq. 17


def test_bad_combinations_are_refused_before_work():
    with pytest.raises(ConfigError, match="stress_measure"):
        config_from_dict({"loading": {"lateral": {"stress_MPa": 0.01}}, "output": {"stress_measure": "paper"}})
    with pytest.raises(ConfigError, match="bending_modulus_MPa"):
        config_from_dict({"solver": {"kinematics": "affine"}, "fiber": {"bending_modulus_MPa": 3000.0}})
    with pytest.raises(ConfigError, match="loading.lateral"):
        config_from_dict({"loading": {"test": "equibiaxial", "lateral": {"stress_MPa": 0.01}}})


def _write_plain(path, network, **changes):
    """The plain HDF5 network format of ``network`` (docs/mechanics.md), with datasets changed."""
    import h5py

    data = {"nodes/position_um": network.node_position,
            "nodes/border": np.arange(network.n_nodes) >= network.n_inner,
            "segments/nodes": network.element_nodes, "segments/diameter_um": network.element_diameter,
            "segments/l0_um": network.element_length, "segments/tortuosity": network.element_tortuosity,
            "segments/plastic_stretch": np.ones(network.n_elements)} | changes
    with h5py.File(path, "w") as f:
        f.attrs.update(side_um=network.size, layer_thickness_um=network.thickness, layers=network.n_layers)
        for name, values in data.items():
            if values is not None:
                f[name] = values
    return path


def test_a_network_in_the_plain_format_runs_as_the_same_network(small_rve, tmp_path):
    """An espin network written in the plain format and read back gives the same curve; a bad
    dataset is refused naming it."""
    from espin.core.errors import InputError
    from espin.geometry.network_file import read_network
    from espin.mechanics.run import simulate

    net = small_rve.network
    path = _write_plain(tmp_path / "net.h5", net)
    read = read_network(path)
    np.testing.assert_array_equal(read.element_nodes, net.element_nodes)
    np.testing.assert_allclose(read.element_tortuosity, net.element_tortuosity, rtol=1e-15)
    kw = {"loading": {"max_strain": 0.02, "steps": 2}}
    ours = _run(net, **kw)
    theirs = simulate(path, config=config_from_dict({"fiber": {"flow_rate_per_s": 0.0}} | kw))
    np.testing.assert_allclose(theirs.P, ours.P, rtol=1e-12, atol=1e-12)
    with pytest.raises(InputError, match="tortuosity"):
        read_network(_write_plain(tmp_path / "bad.h5", net, **{"segments/tortuosity": np.full(net.n_elements, 0.5)}))
    with pytest.raises(InputError, match="l0"):
        read_network(_write_plain(tmp_path / "bad2.h5", net, **{"segments/l0_um": 1.1 * net.element_length}))
    with pytest.raises(InputError, match="segments/diameter_um"):
        read_network(_write_plain(tmp_path / "bad3.h5", net, **{"segments/diameter_um": None}))


def test_the_authors_format_is_read_with_its_checks(tmp_path):
    """A small network in the authors' text format: nodes renumbered inner first, positions from
    the square's corner, tortuosity and plastic stretch kept; a broken segment is refused."""
    from espin.core.errors import InputError
    from espin.geometry.network_file import read_network

    text = """*Parametros
    0.10000000E+0002
    0.50000000E+0000
         2
*Coordenadas
         4
           0 1   -0.50000000E+0001    0.00000000E+0000   -0.50000000E+0001    0.00000000E+0000
           1 2    0.00000000E+0000    0.00000000E+0000    0.00000000E+0000    0.00000000E+0000
           2 1    0.50000000E+0001    0.00000000E+0000    0.50000000E+0001    0.00000000E+0000
           3 1    0.00000000E+0001    0.50000000E+0001    0.00000000E+0001    0.50000000E+0001
*Fibras
         3
           0    0.50000000E+0000    0.50000000E+0001    0.11000000E+0001    0.10000000E+0001    F    0    1
           1    0.50000000E+0000    0.50000000E+0001    0.10000000E+0001    0.12000000E+0001    F    1    2
           2    0.50000000E+0000    0.50000000E+0001    0.10000000E+0001    0.10000000E+0001    F    1    3
"""
    path = tmp_path / "malla.txt"
    path.write_text(text)
    net = read_network(path)
    assert net.n_inner == 1 and net.n_nodes == 4 and net.reference_volume == pytest.approx(100.0 * 2 * 0.5)
    np.testing.assert_allclose(net.node_position[0], [5.0, 5.0])  # the cross-link, first
    np.testing.assert_allclose(net.element_tortuosity, [1.1, 1.0, 1.0])
    np.testing.assert_allclose(net.initial_plastic_stretch, [1.0, 1.2, 1.0])
    assert net.element_fiber.tolist() == [0, 0, 1]
    path.write_text(text.replace("F    1    3", "T    1    3"))
    with pytest.raises(InputError, match="segment 2 is marked broken"):
        read_network(path)


@pytest.mark.parametrize("kinematics", ["equilibrium", "affine"])
def test_a_network_that_starts_stretched_plastically(kinematics):
    """A network read with plastic stretch lamp = 1.1 on every segment (elastic law): the x
    fibers of the grid stay slack until F11 = 1.1, t = E_b (F11 / 1.1 - 1), then taut."""
    from dataclasses import replace

    net = grid_network(N, SIZE, D)
    net = replace(net, element_plastic_stretch=np.full(net.n_elements, 1.1))
    result = _run(net, loading={"max_strain": 0.12, "steps": 4}, solver={"kinematics": kinematics})
    e = result.F[:, 0, 0] / 1.1
    t = np.where(e >= 1.0, E_T * (e - 1.0), 3.0 * (e - 1.0))
    np.testing.assert_allclose(result.P[:, 0, 0], N * AREA * t / (SIZE * D), rtol=1e-7, atol=1e-9)
