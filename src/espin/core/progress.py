"""Progress of a long run in a Jupyter notebook: one HTML bar updated in place.

The command line draws its bars with rich; in a notebook, :func:`espin.simulate`, the studies
and the fit show this bar instead (shown in a notebook only by default, so that scripts stay
silent). A simulation run inside a study or a fit shows none of its own.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from html import escape
from typing import Any, TypeVar

Step = TypeVar("Step")

__all__ = ["in_notebook", "NotebookProgress", "with_progress", "clock"]


def in_notebook() -> bool:
    """True inside a Jupyter kernel (a notebook, JupyterLab, VS Code's notebooks)."""
    shell = sys.modules.get("IPython")
    if shell is None or "ipykernel" not in sys.modules:
        return False
    ipython = shell.get_ipython()
    return ipython is not None and type(ipython).__name__ == "ZMQInteractiveShell"


def clock(seconds: float) -> str:
    """A duration [s] as a clock: ``0:07``, ``12:34``, ``1:02:03``."""
    minutes, secs = divmod(int(round(seconds)), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


class NotebookProgress:
    """An HTML progress bar in the notebook's output, with elapsed time and time left.

    Parameters
    ----------
    total
        Number of units of work (steps, tensile tests); None when not known in advance (the
        evaluations of a fit): then only the count and the elapsed time are shown.
    what
        What a unit is, for the text ("step", "test").
    """

    def __init__(self, total: int | None, what: str) -> None:
        from IPython.display import HTML, display

        self.total = None if total is None else max(int(total), 1)
        self.what = what
        self._html = HTML
        self._start = time.perf_counter()
        self._handle = display(HTML(self._render(0, "")), display_id=True)

    def _render(self, done: int, info: str) -> str:
        elapsed = time.perf_counter() - self._start
        if self.total is None:
            return f"<code>{escape(self.what)} {done}  {escape(info)}  {clock(elapsed)} elapsed</code>"
        left = f", about {clock(elapsed / done * (self.total - done))} left" if 0 < done < self.total else ""
        return (
            f'<progress value="{done}" max="{self.total}" style="width:40%"></progress> '
            f"<code>{escape(self.what)} {done}/{self.total}  {escape(info)}  "
            f"{clock(elapsed)} elapsed{left}</code>"
        )

    def update(self, done: int, info: str = "") -> None:
        """Show ``done`` units finished, with a short text (e.g. the strain reached)."""
        done = int(done) if self.total is None else min(int(done), self.total)
        self._handle.update(self._html(self._render(done, info)))


def with_progress(
    on_step: Callable[[Step], None] | None,
    total: int,
    progress: bool | None,
    describe: Callable[[Step], tuple[int, str]],
) -> Callable[[Step], None] | None:
    """``on_step`` followed by a display of the steps done: in a notebook a bar updated in place,
    elsewhere a line per step on stderr; by default (``progress`` None) in a notebook only.
    ``describe(step)`` gives the step's number and a short text (the strain reached ...)."""
    notebook = in_notebook()
    if not (progress or (progress is None and notebook)):
        return on_step
    bar = NotebookProgress(total, "step") if notebook else None

    def show(step: Any) -> None:
        if on_step is not None:
            on_step(step)
        index, info = describe(step)
        if bar is not None:
            bar.update(index, info)
        else:
            print(f"step {index}/{total}: {info}", file=sys.stderr, flush=True)

    return show
