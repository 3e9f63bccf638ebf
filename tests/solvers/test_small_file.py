"""The small-problem driver's file lane (``fgopt.solvers.small.optimize_file``): a file's graph
solved without compiling a Problem first.

It must give exactly what the driver gives on the compiled problem (same driver, same inputs:
bit for bit), make ``result.problem`` on first read as the graph and values were at the solve,
and decline (None) everything else, which then takes the usual path unchanged.
"""

import pickle
import warnings

import numpy as np
import pytest

import fgopt
from fgopt import SE2, PriorFactor, key
from fgopt.errors import KeyNotFoundError
from fgopt.solvers import LevenbergMarquardt, LMParams, small
from fgopt.solvers._run import compile_problem
from fgopt.solvers.result import Deferred

DRIVER = "dense cholesky (small-problem driver)"
FILES = ["small/pose2example.txt", "small/noisyToyGraph.txt", "small/Klaus3.g2o",
         "small/pose3example-offdiagonal.txt", "small/toyExample.g2o"]


@pytest.fixture(autouse=True)
def compile_drivers(monkeypatch):
    """Drivers compile in the test process (by default a cold one goes to a background process)."""
    monkeypatch.setattr(small, "COMPILE_IN_FOREGROUND", True)


def params(**options):
    return LMParams(backend="numba", **options)


def solve(graph, init, lane=True, **options):
    """LM from ``init``; ``lane=False``: with the file lane switched off (the compiled problem)."""
    if lane:
        return LevenbergMarquardt(params(**options)).optimize(graph, init)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(small, "optimize_file", lambda *a: None)
        return LevenbergMarquardt(params(**options)).optimize(graph, init)


def rows_of(values):
    return {int(k): np.asarray(values.at(k).to_storage()) for k in values.keys()}


def assert_identical(a, b):
    """``a`` (file lane) and ``b`` (compiled problem): the same driver run, bit for bit."""
    assert a.linear_solver == b.linear_solver == DRIVER
    assert (a.status, a.message, a.iterations) == (b.status, b.message, b.iterations)
    assert (a.initial_cost, a.final_cost, a.cost_history) == (
        b.initial_cost, b.final_cost, b.cost_history)
    fields = ("iteration", "cost", "candidate_cost", "relative_decrease", "lam", "step_norm",
              "gradient_norm", "accepted")
    np.testing.assert_array_equal(  # (NaN where nothing was tried: equal to NaN here)
        [[getattr(r, f) for f in fields] for r in a.iteration_records],
        [[getattr(r, f) for f in fields] for r in b.iteration_records])
    assert (a.unused_keys, a.clamps, a.num_clamped) == (b.unused_keys, b.clamps, b.num_clamped)
    assert list(a.values.keys()) == list(b.values.keys())
    ra, rb = rows_of(a.values), rows_of(b.values)
    assert all(np.array_equal(ra[k], rb[k]) for k in rb)
    assert all(np.array_equal(x, y) for x, y in zip(a.state.storages, b.state.storages))


@pytest.mark.parametrize("name", FILES)
def test_a_file_takes_the_lane_and_matches_the_compiled_problem(data_file, name):
    """Each tiny file: the lane runs (no Problem compiled until ``result.problem`` is read) and
    its result equals the driver's on the compiled problem, 5 iterations and to convergence."""
    graph, init = fgopt.io.read(str(data_file(name)), add_prior=True)
    for options in (dict(max_iterations=5, relative_tolerance=0.0, absolute_tolerance=0.0,
                         gradient_tolerance=0.0, step_tolerance=0.0), {}):
        before = small.STATS["solves"]
        a = solve(graph, init, **options)
        assert small.STATS["solves"] == before + 1
        assert type(a.__dict__["_problem"]) is Deferred  # solved without a Problem
        b = solve(graph, init, lane=False, **options)
        assert type(b.__dict__["_problem"]) is not Deferred
        assert_identical(a, b)
        p, q = a.problem, b.problem  # the deferred one, made now
        assert type(a.__dict__["_problem"]) is not Deferred
        assert (p.size, p.var_keys.tolist(), [x.kernel.name for x in p.batches]) == (
            q.size, q.var_keys.tolist(), [x.kernel.name for x in q.batches])


def test_one_kernel_in_several_batches_takes_the_lane_as_one_slot(data_file):
    """A graph whose between factors are split over two batches (one with unit noise, one
    with its own), in an order that interleaves the kernels, gives the compiled problem's
    result bit for bit (the lane merges each kernel's batches into its one driver slot)."""
    graph, init = fgopt.io.read(str(data_file("small/pose2example.txt")), add_prior=True)
    between, prior = graph.batches
    split = fgopt.FactorGraph()
    half = len(between) // 2
    split.add_batch(between.kernel, between.keys[:half], between.constants[:half])
    split.add_batch(prior.kernel, prior.keys, prior.constants, prior.sqrt_information)
    split.add_batch(between.kernel, between.keys[half:], between.constants[half:],
                    None if between.sqrt_information is None else between.sqrt_information[half:])
    before = small.STATS["solves"]
    a = solve(split, init, max_iterations=5)
    assert small.STATS["solves"] == before + 1
    assert type(a.__dict__["_problem"]) is Deferred
    assert_identical(a, solve(split, init, lane=False, max_iterations=5))


def test_the_deferred_problem_is_the_graph_as_solved(data_file):
    """``result.problem`` made after the caller changed the graph and values is the problem that
    was solved (the graph's batches then, the values then), and serves marginals like the
    compiled problem's."""
    graph, init = fgopt.io.read(str(data_file("small/pose2example.txt")), add_prior=True)
    a = solve(graph, init)
    b = solve(graph, init, lane=False)
    graph.add_batch(graph.batches[0].kernel, graph.batches[0].keys[:1],
                    graph.batches[0].constants[:1])
    init.add(key("z", 1), SE2())
    assert len(a.problem.batches[0].source) == len(b.problem.batches[0].source)
    assert a.problem.var_keys.tolist() == b.problem.var_keys.tolist()
    k = list(b.values.keys())[3]
    np.testing.assert_allclose(fgopt.marginals(a, keys=[k])[k], fgopt.marginals(b, keys=[k])[k],
                               rtol=1e-12)


def test_a_lane_result_pickles_with_its_values(data_file):
    """Pickling carries the values (not the deferred problem), as for any result."""
    graph, init = fgopt.io.read(str(data_file("small/Klaus3.g2o")), add_prior=True)
    a = solve(graph, init)
    back = pickle.loads(pickle.dumps(a))
    assert back.problem is None and back.state is None
    assert rows_of(back.values).keys() == rows_of(a.values).keys()
    assert all(np.array_equal(rows_of(back.values)[k], v) for k, v in rows_of(a.values).items())
    assert (back.final_cost, back.iterations) == (a.final_cost, a.iterations)


def _with_extra_value(graph, init):
    blk = init._pending[0]
    out = fgopt.Variables()
    out.add_rows(np.append(blk.keys, blk.keys.max() + 1), blk.kind,
                 np.vstack([blk.rows, blk.rows[:1]]))
    return graph, out


def _keys_descending(graph, init):
    blk = init._pending[0]
    out = fgopt.Variables()
    out.add_rows(blk.keys[::-1].copy(), blk.kind, blk.rows[::-1])
    return graph, out


def _with_python_factor(graph, init):
    graph = graph.copy()
    graph.add(PriorFactor(int(init._pending[0].keys[1]), SE2()))
    return graph, init


def _robust(graph, init):
    graph = graph.copy()
    b = graph.batches[0]
    graph._batches[0] = type(b)(b.kernel, b.keys, b.constants, b.sqrt_information,
                                loss_code=1, loss_param=1.0)
    return graph, init


def _split_values(graph, init):
    blk = init._pending[0]
    out = fgopt.Variables()
    out.add_rows(blk.keys[:2], blk.kind, blk.rows[:2])
    out.add_rows(blk.keys[2:], blk.kind, blk.rows[2:])
    return graph, out


@pytest.mark.parametrize("change", [_with_extra_value, _keys_descending, _with_python_factor,
                                    _robust, _split_values])
def test_what_the_lane_does_not_take_goes_the_usual_way(data_file, change):
    """An unused value, keys out of order, a Python factor, a robust loss, values in two blocks:
    the lane declines and the solve is the usual path's (same result as with the lane off)."""
    graph, init = change(*fgopt.io.read(str(data_file("small/pose2example.txt")),
                                        add_prior=True))
    assert small.optimize_file(graph, init, params(), 0.0) is None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (the unused value's warning)
        a = solve(graph, init)
        b = solve(graph, init, lane=False)
    assert type(a.__dict__["_problem"]) is not Deferred
    assert (a.status, a.iterations, a.final_cost, a.linear_solver) == (
        b.status, b.iterations, b.final_cost, b.linear_solver)
    assert a.unused_keys == b.unused_keys


def test_options_only_the_usual_path_serves_decline(data_file):
    """verbose, a linear solver chosen, threads, the NumPy backend, a callback: not the lane."""
    graph, init = fgopt.io.read(str(data_file("small/pose2example.txt")), add_prior=True)
    assert small.optimize_file(graph, init, params(), 0.0) is not None
    for options in (dict(verbose=True), dict(linear_solver="dense"), dict(threads=2)):
        assert small.optimize_file(graph, init, params(**options), 0.0) is None
    assert small.optimize_file(graph, init, LMParams(backend="numpy"), 0.0) is None
    seen = []
    r = LevenbergMarquardt(params()).optimize(graph, init, callback=seen.append)
    assert seen and r.linear_solver != DRIVER


def test_a_missing_key_keeps_the_usual_error(data_file):
    """A factor's key absent from the values: the lane declines, the usual path names it."""
    graph, init = fgopt.io.read(str(data_file("small/pose2example.txt")), add_prior=True)
    blk = init._pending[0]
    short = fgopt.Variables()
    short.add_rows(blk.keys[:-1], blk.kind, blk.rows[:-1])
    assert small.optimize_file(graph, short, params(), 0.0) is None
    with pytest.raises(KeyNotFoundError):
        solve(graph, short)


@pytest.mark.parametrize("name", FILES)
def test_the_chi_square_test_reads_no_problem(data_file, name):
    """``fgopt.optimize``'s test of the final cost (``initialization="auto"``) decides on a lane
    result as on the compiled problem's, from the deferred problem's dimensions (not made)."""
    from fgopt.solvers.initialization import cost_bound, implausible

    graph, init = fgopt.io.read(str(data_file(name)), add_prior=True)
    a = fgopt.optimize(graph, init, backend="numba")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(small, "optimize_file", lambda *x: None)
        b = fgopt.optimize(graph, init, backend="numba")
    assert a.info == b.info and a.final_cost == b.final_cost
    assert type(a.__dict__["_problem"]) is Deferred  # not made by the test
    assert a.__dict__["_problem"].dims == (sum(len(x.source) * x.kernel.residual_dim
                                               for x in b.problem.batches), b.problem.size)
    assert implausible(a) == implausible(b)
    a.final_cost = b.final_cost = 1e12  # far above any bound: fires wherever one applies
    assert implausible(a) == implausible(b)
    assert (implausible(a) is None) == (cost_bound(b.problem) is None)
    assert type(a.__dict__["_problem"]) is Deferred


def test_read_only_keys_take_the_lane_without_a_new_compilation(data_file):
    """Read-only key arrays (values' and factors') are another argument type for numba: the
    lane copies them, so the driver keeps its one compiled signature."""
    graph, init = fgopt.io.read(str(data_file("small/Klaus3.g2o")), add_prior=True)
    a = solve(graph, init)
    solve_fn = small._plan(graph.batches).module._solve
    before = len(solve_fn.signatures)
    blk = init._pending[0]
    blk.keys = blk.keys.copy()
    blk.keys.flags.writeable = False
    for b in graph.batches:
        b.keys = b.keys.copy()
        b.keys.flags.writeable = False
    c = solve(graph, init)
    assert type(c.__dict__["_problem"]) is Deferred
    assert len(solve_fn.signatures) == before
    assert_identical(c, a)


def test_a_graph_solved_again_reuses_its_inputs_and_sees_every_change(data_file):
    """The second solve of a graph reuses the driver inputs built by the first (same objects);
    whatever changes the graph -- a batch's constants replaced or changed in place, a batch
    added, another values block -- gives the compiled problem's result for the graph as it is
    then, never the earlier one's."""
    from fgopt.solvers.small import _file

    graph, init = fgopt.io.read(str(data_file("small/pose2example.txt")), add_prior=True)
    five = dict(max_iterations=5)
    first = solve(graph, init, **five)
    memo = _file._MEMOS[id(graph)]
    assert_identical(solve(graph, init, **five), first)
    assert _file._MEMOS[id(graph)] is memo  # reused, not rebuilt

    between = graph.batches[0]
    between.constants = between.constants + 0.05  # replaced
    a = solve(graph, init, **five)
    assert a.final_cost != first.final_cost
    assert_identical(a, solve(graph, init, lane=False, **five))
    between.constants[0, 0] += 0.3  # changed in place
    b = solve(graph, init, **five)
    assert b.final_cost != a.final_cost
    assert_identical(b, solve(graph, init, lane=False, **five))
    graph.add_batch(between.kernel, between.keys[:1], between.constants[1:2])  # one more factor
    c = solve(graph, init, **five)
    assert c.final_cost != b.final_cost
    assert_identical(c, solve(graph, init, lane=False, **five))
    other = fgopt.io.read(str(data_file("small/pose2example.txt")))[1]  # another values block
    assert_identical(solve(graph, other, **five), solve(graph, other, lane=False, **five))


def test_a_kept_graph_calls_the_machine_code_directly_on_its_own_views(data_file):
    """After the first solve of a kept graph the lane calls the driver's compiled entry point,
    skipping numba's typing of the arguments. That entry reads each argument as the type it was
    compiled for, so the inputs are the lane's own views of the batches' arrays: data changed
    in place reaches the driver, but a batch array reshaped in place cannot change what the
    driver reads (results stay the compiled problem's; nothing is misread)."""
    from fgopt.solvers.small import _file

    graph, init = fgopt.io.read(str(data_file("small/pose2example.txt")), add_prior=True)
    first = solve(graph, init)
    memo = _file._MEMOS[id(graph)]
    assert memo.entry is not None
    between = graph.batches[0]
    assert memo.inputs[6][0][0] is not between.keys  # a view of them
    assert np.shares_memory(memo.inputs[6][0][0], between.keys)
    assert_identical(solve(graph, init), first)  # the entry point's solve
    assert _file._MEMOS[id(graph)] is memo
    between.keys.shape = (between.keys.size,)  # (abuse: the batch itself is now malformed)
    try:
        assert_identical(solve(graph, init), first)
    finally:
        between.keys.shape = (between.keys.size // 2, 2)
    between.constants[0, 0] += 0.3  # in place: seen
    assert_identical(solve(graph, init), solve(graph, init, lane=False))


def test_threads_solving_one_kept_graph_each_get_its_result(data_file):
    """The kept scratch goes to one solve at a time: two threads solving the same graph at
    once (the driver releases the GIL) each get the compiled problem's result, every time."""
    import threading

    graph, init = fgopt.io.read(str(data_file("small/pose3example.txt")), add_prior=True)
    want = solve(graph, init, lane=False, max_iterations=5)
    solve(graph, init, max_iterations=5)  # (kept, with its entry point)
    bad = []

    def run():
        for _ in range(300):
            r = solve(graph, init, max_iterations=5)
            if r.final_cost != want.final_cost or r.cost_history != want.cost_history:
                bad.append(r.final_cost)

    threads = [threading.Thread(target=run) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not bad


def test_a_collected_graph_leaves_no_inputs_behind(data_file):
    """The reused inputs hold the graph weakly: once it is gone, so is its entry."""
    import gc

    from fgopt.solvers.small import _file

    graph, init = fgopt.io.read(str(data_file("small/noisyToyGraph.txt")), add_prior=True)
    solve(graph, init)
    key_ = id(graph)
    assert key_ in _file._MEMOS
    del graph
    gc.collect()
    assert key_ not in _file._MEMOS


def test_a_graph_the_lane_no_longer_takes_drops_its_kept_inputs(data_file):
    """Once a graph changes so that the lane declines it (a robust loss here), its kept inputs
    are dropped, and the usual path solves it."""
    from fgopt.solvers.small import _file

    graph, init = fgopt.io.read(str(data_file("small/noisyToyGraph.txt")), add_prior=True)
    solve(graph, init)
    assert id(graph) in _file._MEMOS
    graph.batches[0].loss_code, graph.batches[0].loss_param = 1, 1.0  # Huber on the betweens
    r = solve(graph, init)
    assert id(graph) not in _file._MEMOS
    assert type(r.__dict__["_problem"]) is not Deferred
