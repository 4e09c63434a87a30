"""Figures of every stage: E and the yield point marked on curve.png, and the text of every
figure typeset (µm with a mu, symbols in mathtext, error bars that say what they are).

The figures are caught where they are saved (``save_figure``) and their text is read back from
the matplotlib objects; nothing is rendered.
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from matplotlib.figure import Figure


@pytest.fixture
def caught(monkeypatch) -> list[Figure]:
    """The figures passed to ``save_figure`` (none is written)."""
    import espin.analysis.calibration.figures
    import espin.core.figures
    import espin.design.figures
    import espin.geometry.figures
    import espin.imaging.figures
    import espin.mechanics.figures
    import espin.specimen.figures
    import espin.studies.figures

    figures: list[Figure] = []

    def catch(fig: Figure, path, dpi) -> Path:
        figures.append(fig)
        return Path(path)

    for module in (espin.core.figures, espin.analysis.calibration.figures, espin.geometry.figures,
                   espin.imaging.figures, espin.mechanics.figures, espin.studies.figures, espin.design.figures,
                   espin.specimen.figures):
        monkeypatch.setattr(module, "save_figure", catch)
    return figures


@pytest.fixture(scope="module")
def pulled():
    """A small RVE pulled to 10 % in 20 steps: it yields (about 3 %) and hardens."""
    import espin.geometry.rve
    from espin.mechanics.run import simulate

    rve = espin.geometry.rve.generate("plla", rve__size_ratio=40, rve__layers=3)
    return rve, simulate(rve, loading__max_strain=0.1, loading__steps=20)


def texts(fig: Figure) -> list[str]:
    """Every piece of text of a figure: titles, axis labels, legends, free text, suptitle."""
    found = [t.get_text() for t in fig.texts]
    if fig._suptitle is not None:
        found.append(fig._suptitle.get_text())
    for legend in fig.legends:
        found += [t.get_text() for t in legend.get_texts()]
    for ax in fig.axes:
        found += [ax.get_xlabel(), ax.get_ylabel(), *(ax.get_title(loc) for loc in ("left", "center", "right"))]
        found += [t.get_text() for t in ax.texts]
        if ax.get_legend() is not None:
            found += [t.get_text() for t in ax.get_legend().get_texts()]
    return [t for t in found if t]


def legend_labels(fig: Figure) -> list[str]:
    labels = [t.get_text() for legend in fig.legends for t in legend.get_texts()]
    return labels + [t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()]


_PLAIN = [
    (r"\bum\b", "micrometres as 'um' (µm)"),
    (r"\+-", "'+-' (±)"),
    (r"\^", "a power outside mathtext"),
    (r"\b(eta|kappa|lambda|sigma|N_l|E_p)\b", "a symbol spelled out outside mathtext"),
    (r"\((µm|MPa|%|deg|s|1/s)\)", "a unit in round brackets (square brackets are used)"),
]


def untypeset(text: str) -> list[str]:
    """What in ``text`` breaks the figure conventions, outside its $...$ parts."""
    plain = re.sub(r"\$[^$]*\$", "", text)
    return [why for pattern, why in _PLAIN if re.search(pattern, plain)]


# curve.png: E and the yield point


def test_curve_marks_label_E_yield_and_H_in_a_legend_outside_the_axes(pulled, caught, tmp_path):
    from espin.analysis.properties import curve_marks
    from espin.mechanics.figures import plot_curve

    _, result = pulled
    props = curve_marks(result)
    assert props is not None and props.has_yield
    plot_curve(result, tmp_path / "curve.png", marks=props)
    fig = caught[-1]
    labels = legend_labels(fig)
    assert f"$E$ = {props.modulus_MPa:.3g} MPa" in labels
    assert (rf"$\sigma_y$ = {props.yield_stress_MPa:.3g} MPa at {100 * props.yield_strain:.3g} %"
            in labels)
    assert f"$H$ = {props.post_yield_modulus_MPa:.3g} MPa" in labels
    assert fig.legends and all(ax.get_legend() is None for ax in fig.axes)  # below the axes, not on the data
    # The yield point is drawn where the fit puts it, on the curve's own strain axis [%].
    ax = fig.axes[0]
    point = next(line for line in ax.get_lines() if line.get_label().startswith(r"$\sigma_y$"))
    assert point.get_xdata()[0] == pytest.approx(100 * (props.yield_strain + props.strain_offset))
    assert point.get_ydata()[0] == pytest.approx(props.yield_stress_MPa)
    # The elastic line starts at zero stress and has the slope E.
    elastic = next(line for line in ax.get_lines() if line.get_label().startswith("$E$"))
    x, y = elastic.get_xdata(), elastic.get_ydata()
    assert y[0] == pytest.approx(0.0, abs=1e-9)
    assert (y[1] - y[0]) / ((x[1] - x[0]) / 100) == pytest.approx(props.modulus_MPa)


def test_curve_without_yield_marks_only_E_and_without_marks_nothing(pulled, caught, tmp_path):
    from espin.analysis.properties import curve_marks
    from espin.mechanics.figures import plot_curve

    _, result = pulled
    flat = replace(curve_marks(result), has_yield=False, yield_stress_MPa=np.nan, yield_strain=np.nan,
                   post_yield_modulus_MPa=np.nan)
    plot_curve(result, tmp_path / "curve.png", marks=flat)
    labels = legend_labels(caught[-1])
    assert any(label.startswith("$E$ = ") for label in labels)
    assert not any(label.startswith((r"$\sigma_y$", "$H$")) for label in labels)
    plot_curve(result, tmp_path / "curve.png")
    assert not any(label.startswith(("$E$", r"$\sigma_y$", "$H$")) for label in legend_labels(caught[-1]))


def test_simulate_folder_curve_png_is_marked_through_curve_marks(caught, tmp_path):
    """``simulate(..., curve_marks=...)`` (as ``espin simulate`` calls it) marks curve.png; the
    mechanics stage itself does not fit."""
    import espin.geometry.rve
    from espin.analysis.properties import curve_marks
    from espin.mechanics.run import simulate

    rve = espin.geometry.rve.generate("plla", rve__size_ratio=25, rve__layers=2)
    result = simulate(rve, tmp_path / "run", curve_marks=curve_marks, loading__max_strain=0.06,
                      loading__steps=12, output__vtk=False)
    curve = caught[0]  # curve.png, then deformed.png
    props = curve_marks(result)
    assert f"$E$ = {props.modulus_MPa:.3g} MPa" in legend_labels(curve)


def test_properties_figure_states_E_yield_and_H_of_each_curve_and_the_band_n(caught, tmp_path):
    from espin.analysis.properties import curve_properties, plot_bilinear_fits

    strain = np.linspace(0.0, 0.3, 121)
    curves = []
    for k, scale in enumerate((0.9, 1.0, 1.1)):
        stress = scale * np.where(strain < 0.03, 200 * strain, 6.0 + 5.0 * (strain - 0.03))
        curves.append((f"spec{k + 1}", strain, stress, curve_properties(strain, stress)))
    straight = 100 * strain
    curves.append(("straight", strain, straight, curve_properties(strain, straight)))
    plot_bilinear_fits(curves, tmp_path / "properties.png", band=(strain, curves[1][2], 0.1 * curves[1][2]),
                       band_n=3)
    labels = legend_labels(caught[-1])
    props = curves[0][3]
    assert (f"spec1: $E$ = {props.modulus_MPa:.3g} MPa, $\\sigma_y$ = {props.yield_stress_MPa:.3g} MPa "
            f"at {100 * props.yield_strain:.3g} %, $H$ = {props.post_yield_modulus_MPa:.3g} MPa") in labels
    assert "straight: $E$ = 100 MPa" in labels  # no yield: E alone
    assert "mean ± sd, n = 3" in labels


# every figure: units and symbols typeset


def test_untypeset_finds_what_it_should():
    assert untypeset("diameter [um]") and untypeset("mean +- sd") and untypeset("R^2 = 1")
    assert untypeset("volume fraction eta") and untypeset("x (µm)") and untypeset("N_l = 3")
    assert not untypeset(r"volume fraction $\eta$, $R^2$ = 1, $N_l$ = 3, x [µm], mean ± sd")


def _fake_fit(config):
    from espin.analysis.calibration.curves import FittedCurve

    strain = np.linspace(0.002, 0.1, 30)
    stress = 6.0 * np.tanh(strain / 0.03)
    curve = FittedCurve(5e-3, strain, stress, sd_MPa=0.1 * stress, model_MPa=1.02 * stress,
                        model_sd_MPa=0.05 * stress)
    return SimpleNamespace(curves=[curve], seeds=[1, 2], config=config, r_squared=0.99,
                           values={"rve.volume_fraction": 0.19, "fiber.flow_resistance_MPa": 5.0},
                           eta_profile=np.array([[0.15, 3.0], [0.19, 1.0], [0.23, np.inf]]))


def _figures_of_every_stage(pulled, tmp_path) -> None:
    """Draw every figure espin writes, small."""
    import espin.geometry.rve
    from espin.analysis.calibration.figures import plot_fit
    from espin.analysis.properties import curve_marks, curve_properties, plot_bilinear_fits
    from espin.geometry.figures import plot_mat, plot_statistics
    from espin.geometry.statistics import network_statistics
    from espin.imaging.figures import save_histograms, save_orientation_map, save_overlay
    from espin.imaging.geometry_calibration.comparison import save_comparison
    from espin.imaging.measurement import measure
    from espin.imaging.synthetic import render_sem
    from espin.mechanics.fiber_figures import plot_single_fiber
    from espin.mechanics.fiber_law import FiberLaw
    from espin.mechanics.figures import plot_curve, plot_deformed
    from espin.mechanics.single_fiber import constant_rate_history, pull_fiber
    from espin.studies.dof import plot_dof_study
    from espin.studies.figures import plot_curve_band, plot_rve_size, plot_sweep

    rve, result = pulled
    plot_mat(rve.mat, tmp_path / "mat.png", window=network_statistics(rve.mat, rve.network, rve.config).window)
    plot_statistics(network_statistics(rve.mat, rve.network, rve.config), tmp_path / "statistics.png")
    plot_curve(result, tmp_path / "curve.png", marks=curve_marks(result))
    plot_deformed(rve.network, result.final, tmp_path / "deformed.png")
    law = FiberLaw.from_config(rve.config.fiber)
    plot_single_fiber(pull_fiber(law, *constant_rate_history(1.2, 1e-3, 60), tortuosity=1.05),
                      tmp_path / "fiber.png", rate_per_s=1e-3)

    strain, stress = result.strain, result.stress()
    plot_bilinear_fits([("curve", strain, stress, curve_properties(strain, stress))], tmp_path / "p.png")
    plot_fit(_fake_fit(rve.config), tmp_path / "fit.png")

    mat = espin.geometry.rve.generate("plla", rve__size_ratio=40, rve__layers=2, rve__seed=4,
                                      rve__max_deviation_deg=20.0).mat
    rendered = render_sem(mat, side_um=15.0, layers=2, seed=4)
    measured = measure(rendered.image, um_per_px=rendered.um_per_px)
    for draw in (save_histograms, save_overlay, save_orientation_map):
        draw(measured, tmp_path / "m.png")
    save_comparison(rendered.image, rendered.image, rendered.um_per_px, tmp_path / "c.png", "measured", "rendered")

    props = {f"{name}_{stat}": value for name in ("modulus_MPa", "yield_stress_MPa", "post_yield_modulus_MPa")
             for stat, value in (("mean", 1.0), ("sd", 0.1), ("rsd", 0.1))}
    sizes = pd.DataFrame([{"rve.size_ratio": s, "rve.layers": n, "n": 3, **props}
                          for s, n in ((20, 2), (30, 2), (30, 3))])
    plot_rve_size(sizes, tmp_path, layers_for_sizes=2, size_for_layers=30)
    plot_sweep(sizes, ["rve.size_ratio", "rve.layers"], tmp_path)
    plot_curve_band(strain, np.stack([stress, 1.1 * stress]), tmp_path / "band.png",
                    label=r"$\tilde L$ = 40, $N_l$ = 3")
    dof = pd.DataFrame([{"size_ratio": s, "layers": n, "seed": seed, "espin_dof": s * s * n / 5 + seed,
                         "beam_dof": s * s * n + seed, "ratio": 5.0 + seed / 10}
                        for s in (10, 20, 30) for n in (2, 3) for seed in (1, 2)])
    plot_dof_study(dof, tmp_path / "dof.png")

    from espin.design.figures import plot_convergence, plot_maps, plot_pareto, plot_verification
    from espin.design.result import design_result
    from espin.design.search import run_design

    def evaluate(space, targets, evaluations, folder, pool):  # a known anisotropic response
        for e in evaluations:
            eta, kappa = e.values["rve.volume_fraction"], e.values["rve.orientation.von_mises.kappa"]
            e.outputs.update({("modulus_MPa", 0.0): 1100.0 * eta * (1 + 0.15 * kappa) * (1 + 0.001 * e.seed % 7),
                              ("modulus_MPa", 90.0): 1100.0 * eta / (1 + 0.1 * kappa)})
            e.curves = {d: (list(strain), list(stress)) for d in (0.0, 90.0)}

    designed = design_result(run_design(["E=352", "E@0/E@90=2.24"], ["eta=0.1:0.3", "kappa=0:8"], budget=22,
                                        evaluator=evaluate))
    plot_convergence(designed.run, designed.evaluations, tmp_path / "convergence.png")
    plot_maps(designed.run, tmp_path / "maps.png")
    plot_verification(designed.run, tmp_path / "verification.png")
    plot_pareto(designed.run, designed.evaluations, tmp_path / "pareto.png")

    import espin.specimen

    pulled_specimen = espin.specimen(shape="holed_strip", model="neo_hookean", modulus_MPa=100.0, poisson_ratio=0.3,
                                     max_strain=0.05, steps=2, elements_across=2)
    pulled_specimen.plot(tmp_path)  # force.png, specimen.png


@pytest.mark.slow
def test_every_figure_types_units_and_symbols(pulled, caught, tmp_path):
    _figures_of_every_stage(pulled, tmp_path)
    assert len(caught) == 25
    problems = [f"{text!r}: {why}" for fig in caught for text in texts(fig) for why in untypeset(text)]
    assert not problems, "\n".join(problems)
    # Every error bar says what it is: mean ± sd and n, in the figure's titles or legends.
    for fig in caught:
        bars = any(c.__class__.__name__ == "ErrorbarContainer" for ax in fig.axes for c in ax.containers)
        if bars:
            joined = " ".join(texts(fig))
            assert "mean ± sd" in joined and re.search(r"\bn = \d", joined), joined


@pytest.mark.slow
def test_no_figure_cuts_off_a_label(pulled, caught, tmp_path):
    # Every title, axis label and legend text lies inside its figure once drawn (comparison.png's
    # x label did not).
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    _figures_of_every_stage(pulled, tmp_path)
    cut = []
    for fig in caught:
        canvas = FigureCanvasAgg(fig)
        canvas.draw()
        renderer = canvas.get_renderer()
        width, height = canvas.get_width_height()
        labels = [*fig.texts] + [t for ax in fig.axes for t in (ax.title, ax._left_title, ax._right_title,
                                                                ax.xaxis.label, ax.yaxis.label)]
        labels += [t for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()]
        labels += [t for legend in fig.legends for t in legend.get_texts()]
        for text in labels:
            if not text.get_visible() or not text.get_text().strip():
                continue
            box = text.get_window_extent(renderer)
            if box.x0 < -0.5 or box.y0 < -0.5 or box.x1 > width + 0.5 or box.y1 > height + 0.5:
                cut.append(f"{text.get_text()!r} in a figure of {fig.axes[0].get_title()!r}")
    assert not cut, "\n".join(cut)
