"""Tensile properties by the testing standards' definitions, on curves whose answers are known."""

from __future__ import annotations

import numpy as np
import pytest

from espin.analysis.properties import CurveError
from espin.analysis.standard_properties import ISO_CHORD_RANGE, standard_properties


def _elastic_plastic_break(n: int = 2001):
    """E = 200 MPa to yield at 1 % (2 MPa), hardening 20 MPa to 10 %, then linear to 30 % of the
    peak at 11 % and a tail: peak 3.8 MPa at 10 %, break (50 % drop) just past 10.5 %."""
    strain = np.linspace(0.0, 0.12, n)
    stress = np.where(strain <= 0.01, 200.0 * strain, 2.0 + 20.0 * (strain - 0.01))
    peak = 2.0 + 20.0 * 0.09
    falling = strain > 0.10
    stress[falling] = peak - (peak * 0.7 / 0.01) * (strain[falling] - 0.10)
    return strain, np.maximum(stress, 0.0), peak


def test_known_curve():
    strain, stress, peak = _elastic_plastic_break()
    p = standard_properties(strain, stress)
    assert p.chord_modulus_MPa == pytest.approx(200.0, rel=1e-9)
    assert p.chord_range == ISO_CHORD_RANGE
    # Offset line 200 (eps - 0.002) meets 2 + 20 (eps - 0.01) at eps = (2 - 0.2 + 0.4) / 180.
    eps = 2.2 / 180.0
    assert p.offset_yield_strain == pytest.approx(eps, abs=1e-6)
    assert p.offset_yield_stress_MPa == pytest.approx(2.0 + 20.0 * (eps - 0.01), abs=1e-4)
    assert p.tensile_strength_MPa == pytest.approx(peak, rel=1e-3)
    assert p.strain_at_strength == pytest.approx(0.10, abs=1e-4)
    # Half the peak is reached at 10 % + 0.5 / 0.7 * 1 %: the last point before it.
    assert p.strain_at_break == pytest.approx(0.10 + 0.01 * 0.5 / 0.7, abs=1e-4)
    assert p.stress_at_break_MPa >= 0.5 * peak
    assert p.note == ""


def test_toe_is_compensated_and_offset_is_a_choice():
    strain, stress, _ = _elastic_plastic_break()
    shifted = strain + 0.005  # a toe: the same curve 0.5 % later, zero stress before
    toe = np.r_[np.linspace(0.0, 0.0049, 50), shifted]
    stress_toe = np.r_[np.zeros(50), stress]
    p = standard_properties(toe, stress_toe, chord_range=(0.006, 0.009))
    assert p.chord_modulus_MPa == pytest.approx(200.0, rel=1e-9)
    assert p.offset_yield_strain == pytest.approx(0.005 + 2.2 / 180.0, abs=1e-6)
    q = standard_properties(strain, stress, offset=0.001)
    assert q.offset_yield_strain == pytest.approx(2.0 / 180.0, abs=1e-6)  # (1.8 + 200 offset) / 180


def test_rising_curve_has_no_strength_and_sparse_curve_no_chord():
    strain = np.linspace(0.0, 0.3, 31)  # espin's simulated curves: 1 % steps, no break
    stress = 200.0 * strain - 300.0 * strain**2
    p = standard_properties(strain, stress)
    assert np.isnan(p.chord_modulus_MPa) and np.isnan(p.offset_yield_stress_MPa)
    assert np.isnan(p.tensile_strength_MPa) and np.isnan(p.strain_at_break)
    assert "no chord modulus" in p.note and "no tensile strength" in p.note
    assert "--chord-range LO:HI" in p.note  # what to do, by the flag's name
    with pytest.raises(CurveError, match="chord range 0.05 % to 0.25 % strain holds 0 point"):
        standard_properties(strain, stress, require_chord=True)
    q = standard_properties(strain, stress, chord_range=(0.0, 0.02))
    assert q.chord_modulus_MPa == pytest.approx(200.0 - 300.0 * 0.02, rel=1e-9)


def test_peak_without_a_break():
    strain = np.linspace(0.0, 0.1, 1001)
    stress = 100.0 * strain * np.exp(-strain / 0.05)  # maximum at 5 %, falls by 26 % to 10 %
    p = standard_properties(strain, stress)
    assert p.strain_at_strength == pytest.approx(0.05, abs=1e-4)
    assert np.isnan(p.strain_at_break) and "does not fall by 50 %" in p.note
    assert not np.isnan(standard_properties(strain, stress, break_drop=0.2).strain_at_break)


@pytest.mark.parametrize("options,match", [
    ({"chord_range": (0.003, 0.001)}, "chord_range"),
    ({"offset": 0.0}, "offset"),
    ({"break_drop": 1.0}, "break_drop"),
])
def test_bad_options_are_refused(options, match):
    strain, stress, _ = _elastic_plastic_break(201)
    with pytest.raises(CurveError, match=match):
        standard_properties(strain, stress, **options)


def test_command_reports_them_beside_the_fit(tmp_path):
    from typer.testing import CliRunner

    from espin.cli import app

    strain, stress, peak = _elastic_plastic_break()
    paths = []
    for k, scale in enumerate((1.0, 1.1)):
        paths.append(tmp_path / f"s{k}.csv")
        np.savetxt(paths[-1], np.c_[100 * strain, scale * stress], delimiter=",", header="strain_%,stress_MPa",
                   comments="")
    result = CliRunner().invoke(app, ["properties", *map(str, paths), "--percent-strain", "-o", str(tmp_path / "p")])
    assert result.exit_code == 0, result.output
    import pandas as pd

    table = pd.read_csv(tmp_path / "p" / "properties.csv").set_index("curve")
    assert table.loc[str(paths[1]), "standard_chord_modulus_MPa"] == pytest.approx(220.0, rel=1e-9)
    assert table.loc[str(paths[0]), "standard_tensile_strength_MPa"] == pytest.approx(peak, rel=1e-3)
    # A stated chord range without points is refused, naming the curve.
    refused = CliRunner().invoke(app, ["properties", str(paths[0]), "--percent-strain", "--chord-range", "0.001:0.002"])
    assert refused.exit_code == 3 and "s0.csv" in refused.output and "chord range" in refused.output


def test_curve_below_the_offset_line_from_the_start_says_so():
    strain = np.linspace(0.0, 0.05, 501)
    stress = 100.0 * strain - 3000.0 * strain**2  # bends at once: chord over 0-2 % is not its slope
    p = standard_properties(strain, stress, chord_range=(0.0, 0.02), offset=1e-4)
    assert np.isnan(p.offset_yield_stress_MPa) and "lies below the chord line" in p.note
    q = standard_properties(strain, -100.0 * strain)  # compression only
    assert "never positive" in q.note


def test_command_prints_each_note_once_below_its_table(tmp_path):
    from typer.testing import CliRunner

    from espin.cli import app

    strain = np.linspace(0.0, 0.3, 301)  # rising to the last point: no strength, no break
    paths = []
    for k in range(3):
        paths.append(tmp_path / f"s{k}.csv")
        np.savetxt(paths[-1], np.c_[strain, (200.0 + k) * np.minimum(strain, 0.03) + 5.0 * strain],
                   delimiter=",", header="strain,stress_MPa", comments="")
    result = CliRunner().invoke(app, ["properties", *map(str, paths)])
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    rows = [line for line in lines if any(f"s{k}.csv" in line for k in range(3)) and "[1]" in line]
    assert len(rows) >= 3  # each curve's row points to the note
    notes = [line for line in lines if line.startswith("  [1] ")]
    assert len(notes) == 1 and "no tensile strength or break" in notes[0]
