"""Progress of long runs: the notebook bar's text, and espin.simulate's progress option."""

from __future__ import annotations

import espin
from espin.core.parallel import TaskPlace
from espin.core.progress import NotebookProgress, in_notebook


def test_not_a_notebook_here():
    assert not in_notebook()  # pytest: scripts and tests stay silent by default


class _Handle:
    def update(self, shown):
        self.shown = shown


def test_bar_shows_done_total_and_time_left():
    bar = NotebookProgress(4, "step")
    bar._handle, bar._html = _Handle(), str  # what the notebook would display
    text = bar._render(1, "strain 0.01")
    assert 'value="1" max="4"' in text and "step 1/4  strain 0.01" in text and "left" in text
    assert "left" not in bar._render(4, "")  # finished: no time left to show
    bar.update(9)  # more than planned (split steps) is shown as the total, not beyond
    assert "step 4/4" in bar._handle.shown
    unknown = NotebookProgress(None, "evaluation")
    assert "<progress" not in unknown._render(7, "SSE 0.5") and "evaluation 7  SSE 0.5" in unknown._render(7, "SSE 0.5")


def test_simulate_progress_lines_off_a_notebook(capfd):
    espin.simulate("plla", rve__size_ratio=30, rve__layers=2, loading__max_strain=0.02, loading__steps=2,
                   progress=True)
    lines = [line for line in capfd.readouterr().err.splitlines() if line.startswith("step ")]
    assert lines == ["step 0/2: strain 0.0000", "step 1/2: strain 0.0100", "step 2/2: strain 0.0200"]
    espin.simulate("plla", rve__size_ratio=30, rve__layers=2, loading__max_strain=0.02, loading__steps=2)
    assert "step " not in capfd.readouterr().err  # default: silent outside a notebook


def test_ensemble_shows_one_bar_of_tests_in_a_notebook(monkeypatch):
    import espin.core.progress as progress
    from espin.core.config import load_config
    from espin.studies.ensemble import plan_tasks, run_ensemble

    bars = []

    class Recorder:
        def __init__(self, total, what):
            self.total, self.what, self.shown = total, what, []
            bars.append(self)

        def update(self, done, info=""):
            self.shown.append(done)

    monkeypatch.setattr(progress, "in_notebook", lambda: True)
    monkeypatch.setattr(progress, "NotebookProgress", Recorder)
    base = load_config("plla", {"rve.size_ratio": 30, "rve.layers": 2, "loading.max_strain": 0.04,
                                "loading.steps": 4})
    ensemble = run_ensemble(plan_tasks(base, [{}], [1, 2]), place=TaskPlace(1))
    assert len(ensemble.records) == 2
    # One bar for the two tests, none for each test's simulation (they run with progress=False).
    assert [(b.total, b.what, b.shown) for b in bars] == [(2, "test", [1, 2])]
