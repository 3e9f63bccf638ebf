"""``Result`` made by the compiled loops' fast constructor, and its deferred problem."""

import math

import numpy as np

from fgopt.solvers.result import (Deferred, IterationRecord, Result, Status, compiled_history,
                                  compiled_result)


def _hist():
    # (cost, candidate, relative decrease, lambda, |step|, |grad|, accepted, predicted)
    return np.array([[8.0, 8.0, 0.2, 1e-5, 1.0, 3.0, 1.0, 2.5],
                     [8.0, 9.0, -0.1, 1e-4, 0.5, 1.0, 0.0, 0.5],
                     [6.0, 6.0, 0.25, 1e-5, 0.2, 0.5, 1.0, 2.1]])


def test_compiled_result_is_the_dataclass_result():
    """Same fields and values as ``Result(...)`` from :func:`compiled_history` (a field added to
    ``Result`` without the fast constructor fails here)."""
    hist = _hist()
    fast = compiled_result(hist, 3, 1, "reached max_iterations=3", 6.0, 10.0,
                           {"setup": 0.0, "lm": 0.0}, "lm", "dense")
    records, st, message = compiled_history(hist, 3, 1, "reached max_iterations=3", 6.0)
    slow = Result(None, status=st, message=message, iterations=len(records), initial_cost=10.0,
                  final_cost=6.0, cost_history=[10.0] + records.accepted_costs(),
                  iteration_records=records, timing={"setup": 0.0, "lm": 0.0}, method="lm",
                  linear_solver="dense")
    assert fast.__dict__.keys() == slow.__dict__.keys()
    assert fast.cost_history == [10.0, 8.0, 6.0] == slow.cost_history
    assert (fast.status, fast.message, fast.iterations) == (Status.MAX_ITERATIONS,
                                                            message, 3)
    fr, sr = fast.iteration_records, slow.iteration_records
    assert all(type(r) is IterationRecord for r in fr)
    assert [(r.iteration, r.cost, r.accepted) for r in fr] == [
        (r.iteration, r.cost, r.accepted) for r in sr] == [(1, 8.0, True), (2, 8.0, False),
                                                           (3, 6.0, True)]
    assert all(math.isnan(r.time) for r in fr)


def test_a_deferred_problem_is_made_once_when_first_read():
    """``Result.problem`` given as :class:`Deferred` is made on the first read only; the
    dataclass default (no problem) reads as None."""
    made = []
    r = compiled_result(_hist(), 3, 1, "m", 6.0, 10.0, {}, "lm", "dense")
    assert r.problem is None
    r.problem = Deferred(lambda: made.append(1) or "the problem", (9, 3))
    assert made == []
    assert r.problem == "the problem" and r.problem == "the problem"
    assert made == [1]
    assert Result(None, Status.CONVERGED, "m", 0, 1.0, 1.0, [1.0]).problem is None


def test_a_compiled_history_becomes_lists_only_when_read():
    """The compiled loop's history stays its array until ``cost_history`` or
    ``iteration_records`` is read; either reads the same as when made eagerly, pickling
    carries them as lists, and a result pickled with ``cost_history`` as a plain field (before
    it was made on read) still loads."""
    import pickle

    from fgopt import Variables

    r = compiled_result(_hist(), 3, 1, "m", 6.0, 10.0, {}, "lm", "dense")
    r.__dict__["_values"] = Variables()
    lazy = r.__dict__["_cost_history"]
    assert lazy is r.__dict__["_records"] and lazy._rows is None  # no lists made yet
    back = pickle.loads(pickle.dumps(r))
    assert back.cost_history == [10.0, 8.0, 6.0] == r.cost_history
    assert [x.cost for x in back.iteration_records] == [8.0, 8.0, 6.0]
    state = r.__getstate__()
    state["cost_history"] = state.pop("_cost_history")  # the older form
    old = object.__new__(Result)
    old.__setstate__(state)
    assert old.cost_history == [10.0, 8.0, 6.0] and len(old.iteration_records) == 3
