"""Leave-one-out residuals from one factorization equal removing the factor and re-solving."""

import numpy as np

import fgopt
from fgopt import BetweenFactor, PriorFactor, key
from fgopt.problem import Problem
from fgopt.solvers.influence import leave_one_out_sq_norms


def linear_graph(seed=0, n=12, loops=10):
    """Points in the plane with noisy differences (between factors on R^2 are linear)."""
    rng = np.random.default_rng(seed)
    truth = np.cumsum(rng.normal(size=(n, 2)), axis=0)
    graph, values = fgopt.FactorGraph(), fgopt.Variables()
    for i in range(n):
        values.add(key("p", i), truth[i] + rng.normal(size=2))
    graph.add(PriorFactor(key("p", 0), truth[0], fgopt.noise.Isotropic.sigma(2, 0.1)))
    pairs = [(i, i + 1) for i in range(n - 1)]
    pairs += [tuple(rng.choice(n, 2, replace=False)) for _ in range(loops)]
    for k, (i, j) in enumerate(pairs):
        sigma = 0.1 + 0.2 * rng.random()
        d = truth[j] - truth[i] + rng.normal(size=2) * sigma
        if k == len(pairs) - 1:
            d += 5.0  # one gross outlier
        graph.add(BetweenFactor(key("p", int(i)), key("p", int(j)), d,
                                fgopt.noise.Isotropic.sigma(2, sigma)))
    return graph, values


def test_equals_remove_and_resolve_on_a_linear_problem():
    """For a linear least-squares problem the deleted residual formula is exact: it matches the
    factor's whitened residual at the solution of the graph without it, and the cost decrease
    matches the difference of the two optimal costs, for every factor."""
    graph, values = linear_graph()
    sol = fgopt.optimize(graph, values, method="gn", max_iterations=3).values
    problem = Problem(graph, sol)
    state = problem.initial_state()
    masks = [np.ones(len(b.source), dtype=bool) for b in problem.batches]
    loo = leave_one_out_sq_norms(problem, state, masks)
    drop = leave_one_out_sq_norms(problem, state, masks, cost_decrease=True)
    full_cost = graph.error(sol)
    factors = list(graph)
    checked = 0
    for b, sq in zip(problem.batches, loo):
        for row in range(len(b.source)):
            f = b.source.factor(row)
            idx = next(i for i, g in enumerate(factors)
                       if list(g.keys) == list(f.keys) and np.allclose(g.constants, f.constants))
            rest = fgopt.FactorGraph([g for i, g in enumerate(factors) if i != idx])
            if len(f.keys) == 1:  # the prior fixes the gauge: without it H is singular
                continue
            sub = fgopt.optimize(rest, sol, method="gn", max_iterations=3).values
            r = factors[idx].whitened_error(sub)
            assert np.isclose(sq[row], r @ r, rtol=1e-6, atol=1e-9), (row, sq[row], r @ r)
            d = next(x for bb, x in zip(problem.batches, drop) if bb is b)[row]
            assert np.isclose(d, full_cost - rest.error(sub), rtol=1e-6, atol=1e-9)
            checked += 1
    assert checked == 21
    # and the outlier stands out
    between = next(sq for b, sq in zip(problem.batches, loo) if len(b.source) > 1)
    assert np.argmax(between) == len(between) - 1


def test_mask_selects_factors_and_others_are_zero():
    graph, values = linear_graph(seed=1)
    problem = Problem(graph, values)
    masks = [np.zeros(len(b.source), dtype=bool) for b in problem.batches]
    between = next(i for i, b in enumerate(problem.batches) if len(b.source) > 2)
    masks[between][:2] = True
    loo = leave_one_out_sq_norms(problem, problem.initial_state(), masks)
    assert np.all(loo[between][2:] == 0) and np.all(loo[between][:2] > 0)
    assert all(np.all(x == 0) for i, x in enumerate(loo) if i != between)


def test_a_bridge_has_no_leave_one_out_residual():
    """The only prior (the gauge: without it nothing predicts the pose) is a bridge, h = I:
    its leave-one-out residual is 0, not a division by ~0."""
    graph, values = linear_graph(seed=1)
    problem = Problem(graph, values)
    masks = [np.ones(len(b.source), dtype=bool) for b in problem.batches]
    loo = leave_one_out_sq_norms(problem, problem.initial_state(), masks)
    prior = next(i for i, b in enumerate(problem.batches) if len(b.source) == 1)
    assert loo[prior][0] < 1e-12 and all(np.all(np.isfinite(x)) for x in loo)


def test_prediction_of_a_left_out_factor_matches_dense_algebra():
    """For factors not in the problem: ``r^T (I + J H^-1 J^T)^-1 r`` (whitened) from the sparse
    factorization equals the dense computation, and at a left-out factor's own residual
    ``r`` is its leave-one-out residual (the solution without it)."""
    from fgopt.solvers.influence import prediction_sq_norms

    graph, values = linear_graph(seed=3)
    factors = list(graph)
    left_out = [len(factors) - 1, len(factors) - 3]  # the gross outlier and one loop
    kept = fgopt.FactorGraph([f for i, f in enumerate(factors) if i not in left_out])
    sol = fgopt.optimize(kept, values, method="gn", max_iterations=3).values
    problem = Problem(kept, sol)
    state = problem.initial_state()
    extra = fgopt.FactorGraph([factors[i] for i in left_out])
    ep = Problem(extra, sol, build_structure=False)
    b = ep.batches[0]
    got = prediction_sq_norms(problem, state, b.source, np.arange(len(b.source)))
    problem.linearize(state)
    Hinv = np.linalg.inv(problem.pattern.full(problem.H_data).toarray())
    for row in range(len(b.source)):
        f = b.source.factor(row)
        r = f.whitened_error(sol)
        J = np.zeros((2, problem.size))
        Js = f.jacobians(sol)
        for k, Jk in zip(f.keys, Js):
            off = problem.pattern.var_offset[problem._vars_of(np.array([int(k)]))[0]]
            J[:, off:off + 2] = f.noise.whiten(Jk)
        expected = r @ np.linalg.solve(np.eye(2) + J @ Hinv @ J.T, r)
        assert np.isclose(got[row], expected, rtol=1e-8)
    assert got.max() > 100 * got.min()  # the outlier stands out, the loop does not


def test_prediction_with_a_bound_is_exact_below_it_and_above_it_otherwise():
    """With ``bound``: rows whose exact statistic is at most their bound get it exactly; rows
    above get a value above their bound (the cheap lower bound from the diagonal blocks of
    ``H^-1``), never below the exact value: the caller's test ``value <= bound`` decides as on
    the exact values."""
    from fgopt.solvers.influence import prediction_sq_norms

    graph, values = linear_graph(seed=5, n=30, loops=25)
    factors = list(graph)
    left_out = list(range(len(factors) - 12, len(factors)))  # loops, the gross outlier last
    kept = fgopt.FactorGraph([f for i, f in enumerate(factors) if i not in left_out])
    sol = fgopt.optimize(kept, values, method="gn", max_iterations=3).values
    problem = Problem(kept, sol)
    state = problem.initial_state()
    extra = Problem(fgopt.FactorGraph([factors[i] for i in left_out]), sol,
                    build_structure=False).batches[0].source
    rows = np.arange(len(extra))
    exact = prediction_sq_norms(problem, state, extra, rows)
    for bound in (np.full(rows.size, np.median(exact)), exact * 1.5, exact / 1.5,
                  np.zeros(rows.size)):
        got = prediction_sq_norms(problem, state, extra, rows, bound=bound)
        below = exact <= bound
        assert np.allclose(got[below], exact[below], rtol=1e-10)
        assert np.all(got[~below] > bound[~below])
        assert np.all(got <= exact * (1 + 1e-9))
    # with a bound of 0 every row gets its lower bound: positive, and the outlier's stays large
    low = prediction_sq_norms(problem, state, extra, rows, bound=np.zeros(rows.size))
    assert np.all(low > 0) and low[-1] > 10 * np.median(low)
