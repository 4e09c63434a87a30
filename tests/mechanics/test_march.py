"""The march on a fake problem: cuts, growth, rejection, the budget and the smallest step,
rollback, and a bug that is not taken for a hard step."""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from espin.core.errors import InadmissibleState, StepNotConverged
from espin.mechanics.march import MarchFailed, StepPolicy, march


@dataclass(frozen=True)
class _Step:
    start: float
    end: float
    iterations: int
    factorizations: int = 1


class _Fake:
    """Fails steps longer than ``longest`` [s] or ending after ``wall`` [s]; converges in ``iterations``; its local time
    error is ``error_per_s2`` times the step squared (as backward Euler's is)."""

    def __init__(self, longest: float = float("inf"), iterations: int = 1, error_per_s2: float = 0.0,
                 limit: int | None = 10, bug_at: float | None = None, wall: float = float("inf")) -> None:
        self.longest, self.iterations, self.error_per_s2, self.wall = longest, iterations, error_per_s2, wall
        self.iteration_limit = limit
        self.bug_at = bug_at
        self.time = 0.0  # committed
        self.attempts: list[tuple[float, float]] = []
        self.commits: list[float] = []
        self.rollbacks = 0

    def attempt(self, start: float, end: float) -> _Step:
        assert start == self.time  # always from the committed state
        self.attempts.append((start, end))
        if self.bug_at is not None and end > self.bug_at:
            raise ValueError("operands could not be broadcast together")
        if end - start > self.longest or end > self.wall:
            raise InadmissibleState("step too long", history=[1.0, 2.0])
        return _Step(start, end, self.iterations)

    def error(self, trial: _Step) -> float:
        return self.error_per_s2 * (trial.end - trial.start) ** 2

    def commit(self, trial: _Step) -> None:
        self.time = trial.end
        self.commits.append(trial.end)

    def rollback(self) -> None:
        self.rollbacks += 1


def _run(problem: _Fake, reports, **policy):
    tallies = []
    march(problem, reports, StepPolicy(**policy), on_report=tallies.append)
    return tallies


def test_every_report_is_hit_exactly_and_easy_steps_grow():
    problem = _Fake(iterations=1)  # easy: 1 < 0.2 x 10
    tallies = _run(problem, [1.0, 2.0, 6.0])
    assert [t.time for t in tallies] == [1.0, 2.0, 6.0]
    assert problem.commits == [1.0, 2.0, 4.0, 6.0]  # step 1, 1, then 2 (doubled), 2
    assert [t.substeps for t in tallies] == [1, 1, 2]
    assert [t.trial.end for t in tallies] == [1.0, 2.0, 6.0]


def test_hard_steps_do_not_grow():
    problem = _Fake(iterations=5)  # not easy: 5 >= 0.2 x 10
    _run(problem, [1.0, 4.0])
    assert problem.commits == [1.0, 2.0, 3.0, 4.0]


def test_a_failed_step_is_rolled_back_and_halved_and_does_not_grow_right_after():
    problem = _Fake(longest=0.3, iterations=1)
    tallies = _run(problem, [1.0])
    # 1 and 0.5 fail, 0.25 converges; the next is 0.25 again (not 0.5: right after a cut), then it
    # doubles to 0.5, fails, and is cut again
    assert problem.attempts == [(0.0, 1.0), (0.0, 0.5), (0.0, 0.25), (0.25, 0.5), (0.5, 1.0), (0.5, 0.75),
                                (0.75, 1.0)]
    assert tallies[0].cuts == 3 and problem.rollbacks == 3 and tallies[0].substeps == 4
    assert tallies[0].iterations == 7  # the failed attempts' iterations count too
    assert problem.commits == [0.25, 0.5, 0.75, 1.0]


def test_too_many_cuts_in_a_row_stop_with_the_failure_and_keep_the_committed_state():
    problem = _Fake(wall=0.2)
    with pytest.raises(MarchFailed) as stopped:
        _run(problem, [0.2, 1.0], max_cuts=1)  # 0.2-0.6 fails, 0.2-0.4 fails: one halving allowed
    assert stopped.value.failure.kind == "inadmissible" and stopped.value.failure.history == [1.0, 2.0]
    assert stopped.value.tally.index == 2 and stopped.value.tally.cuts == 1
    assert stopped.value.time == pytest.approx(0.4)
    assert problem.time == 0.2 and problem.commits == [0.2] and problem.rollbacks == 2


def test_a_step_over_the_time_error_is_rejected_and_redone_smaller():
    problem = _Fake(error_per_s2=1.0)  # error h^2: h = 1 gives 1 > 0.01
    tallies = _run(problem, [1.0], time_rtol=0.01)
    first_retry = problem.attempts[1][1] - problem.attempts[1][0]
    assert first_retry == pytest.approx(0.2)  # shrunk by at most 5x
    assert tallies[0].rejected >= 1 and problem.rollbacks == tallies[0].rejected
    accepted = [b - a for a, b in problem.attempts if (b - a) ** 2 <= 0.01 + 1e-15]
    assert len(accepted) == tallies[0].substeps and problem.commits[-1] == 1.0


def test_a_step_whose_foreseen_error_is_over_the_tolerance_is_rejected_unsolved_with_the_same_steps():
    solved, foreseeing = _Fake(error_per_s2=1.0, iterations=1), _Fake(error_per_s2=1.0, iterations=1)
    reports = [1.0, 1.5, 3.0]
    plain = _run(solved, reports, time_rtol=0.01)
    tallies = []
    march(foreseeing, reports, StepPolicy(time_rtol=0.01), on_report=tallies.append,
          estimate=lambda start, end: foreseeing.error_per_s2 * (end - start) ** 2)
    assert foreseeing.commits == solved.commits  # the same time steps
    assert foreseeing.attempts == [(a, b) for a, b in solved.attempts if (b - a) ** 2 <= 0.01 + 1e-15]
    assert foreseeing.rollbacks == 0 < solved.rollbacks  # nothing solved was thrown away
    assert [t.rejected for t in tallies] == [t.rejected for t in plain] and sum(t.rejected for t in tallies) > 0
    assert sum(t.iterations for t in tallies) == len(foreseeing.commits) < sum(t.iterations for t in plain)


def test_the_budget_and_the_smallest_step_stop_a_flow_too_fast_to_follow():
    with pytest.raises(MarchFailed, match="more than 20 time steps") as stopped:
        _run(_Fake(error_per_s2=1e4), [1.0], time_rtol=1e-3, budget=20, smallest=0.0)
    assert stopped.value.failure.kind == "stiff"
    with pytest.raises(MarchFailed, match="below the smallest") as stopped:
        _run(_Fake(error_per_s2=1e30), [1.0], time_rtol=1e-3)
    assert stopped.value.failure.kind == "stiff"


def test_steps_halved_below_the_smallest_report_the_failure_that_halved_them():
    """Newton failures (not the plastic flow) made the step tiny: the march says so, with their kind."""
    problem = _Fake(wall=0.2 + 1e-12)  # every step ending beyond it fails; steps shrink towards it
    with pytest.raises(MarchFailed, match="step too long; the time step fell to .* after") as stopped:
        _run(problem, [0.2, 1.0], max_cuts=100)
    assert stopped.value.failure.kind == "inadmissible"


def test_a_problem_without_iterations_keeps_one_step_per_report():
    problem = _Fake(limit=None)
    _run(problem, [1.0, 5.0, 5.0, 6.0])  # a report at the time of the one before: one step of zero length
    assert problem.attempts == [(0.0, 1.0), (1.0, 5.0), (5.0, 5.0), (5.0, 6.0)]


def test_a_bug_in_a_step_stops_the_march_at_once():
    problem = _Fake(bug_at=1.5)
    with pytest.raises(ValueError, match="broadcast"):
        _run(problem, [1.0, 2.0, 3.0])
    assert problem.attempts == [(0.0, 1.0), (1.0, 2.0)] and problem.rollbacks == 0


def test_step_failures_survive_pickling_with_their_fields():
    import pickle

    failure = StepNotConverged("stalled here", "uphill", history=[3.0, 2.0, 2.5], factorizations=4)
    back = pickle.loads(pickle.dumps(failure))
    assert (type(back), back.reason, back.kind, back.history, back.iterations, back.factorizations) == (
        StepNotConverged, "stalled here", "uphill", [3.0, 2.0, 2.5], 2, 4)
