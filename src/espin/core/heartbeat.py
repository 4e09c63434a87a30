"""A line every so often while a long phase runs, so that no phase is silent for long off a terminal
(a log file, a batch job): :class:`Heartbeat`."""

from __future__ import annotations

import threading
from collections.abc import Callable

__all__ = ["Heartbeat", "HEARTBEAT_S"]

HEARTBEAT_S = 25.0
"""Longest silence of a reporting phase [s] (under the 30 s a user waits before wondering)."""


class Heartbeat:
    """Call ``report(status())`` whenever ``interval`` seconds pass without a :meth:`beat`, until
    the phase ends (use as a context manager).

    Parameters
    ----------
    report
        Where the lines go (a console's print); None: nothing is reported and no thread starts.
    status
        The current state in words (e.g. ``"3 of 80 paths done, 2:10 elapsed"``).
    interval
        Longest silence [s].
    """

    def __init__(self, report: Callable[[str], None] | None, status: Callable[[], str],
                 interval: float = HEARTBEAT_S) -> None:
        self.report, self.status, self.interval = report, status, interval
        self._beat = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def say(self, line: str) -> None:
        """Report ``line`` now (and restart the silence count)."""
        if self.report is not None:
            self.report(line)
            self._beat.set()

    def beat(self) -> None:
        """Something was reported elsewhere: restart the silence count."""
        self._beat.set()

    def _run(self, report: Callable[[str], None]) -> None:
        while not self._stop.is_set():
            if not self._beat.wait(self.interval) and not self._stop.is_set():
                report(self.status())
            self._beat.clear()

    def __enter__(self) -> Heartbeat:
        if self.report is not None:
            self._thread = threading.Thread(target=self._run, args=(self.report,), name="espin-heartbeat",
                                            daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *_: object) -> None:
        self._stop.set()
        self._beat.set()
        if self._thread is not None:
            self._thread.join()
