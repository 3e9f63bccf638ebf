"""``fgopt.optimize(initialization=...)``: the given start, the chordal start, and the default
"auto" policy (given first; chordal too when a chi-square test says the result is implausible)."""

import numpy as np
import pytest

import fgopt
from fgopt import SE2, PriorFactor, key
from fgopt.datasets import manhattan_2d
from fgopt.errors import FgoptError
from fgopt.noise import Huber, Isotropic
from fgopt.solvers import LevenbergMarquardt, LMParams
from fgopt.solvers.initialization import chi2_upper, cost_bound


def _scrambled(values, seed):
    """Rotations uniformly random, positions off by ~3 m: LM from here ends in a poor minimum."""
    rng = np.random.default_rng(seed)
    out = fgopt.Variables()
    for k in values.keys():
        t = values.at(k).translation()
        out.add(k, SE2.from_xytheta(t[0] + 3 * rng.normal(), t[1] + 3 * rng.normal(),
                                    rng.uniform(-np.pi, np.pi)))
    return out


def test_chi2_quantile_matches_scipy():
    """The Wilson-Hilferty quantile is within 1 % of scipy's at 10 dof, 1e-4 from 1000 dof."""
    from scipy.stats import chi2

    from fgopt.solvers.initialization import CHI2_TAIL

    for dof in (10, 37, 108, 1000, 5862, 24288, 100000):
        exact = chi2.isf(CHI2_TAIL, dof)
        assert exact <= chi2_upper(dof) <= exact * (1 + (1e-2 if dof < 1000 else 1e-4))


def test_auto_falls_back_to_chordal_when_the_given_start_ends_implausibly():
    """From a scrambled guess LM ends far above the chi-square bound; "auto" then also solves
    from the chordal relaxation and returns the optimum reached from the generator's guess."""
    d = manhattan_2d(200, seed=0)
    bad = _scrambled(d.initial, 0)
    given = fgopt.optimize(d.graph, bad, initialization="given")
    bound, dof = cost_bound(given.problem)
    assert given.final_cost > bound
    ref = fgopt.optimize(d.graph, d.initial, initialization="given")
    r = fgopt.optimize(d.graph, bad)
    assert r.info["initialization"] == "chordal"
    assert "chi-square" in r.info["initialization_reason"]
    assert r.info["initialization_costs"]["given"] == pytest.approx(given.final_cost)
    assert r.final_cost == pytest.approx(ref.final_cost, rel=1e-8)
    assert r.info["iterations_all_starts"] > r.iterations
    # the caller's values are untouched
    assert bad.at(bad.keys()[3]).local(_scrambled(d.initial, 0).at(bad.keys()[3])) == \
        pytest.approx(np.zeros(3))


def test_auto_keeps_a_plausible_given_result_without_a_second_run():
    """From a good guess "auto" is exactly "given": same iterations and cost, no chordal run."""
    d = manhattan_2d(200, seed=1)
    r = fgopt.optimize(d.graph, d.initial)
    g = LevenbergMarquardt(LMParams()).optimize(d.graph, d.initial)
    assert r.info["initialization"] == "given"
    assert "iterations_all_starts" not in r.info
    assert r.iterations == g.iterations
    assert r.final_cost == g.final_cost


def test_chordal_start_and_given_start():
    """``"chordal"`` solves from the relaxation only; ``"given"`` from the values only."""
    d = manhattan_2d(200, seed=0)
    bad = _scrambled(d.initial, 0)
    c = fgopt.optimize(d.graph, bad, initialization="chordal")
    g = fgopt.optimize(d.graph, bad, initialization="given")
    assert c.info["initialization"] == "chordal" and g.info["initialization"] == "given"
    assert c.final_cost < 1e-3 * g.final_cost


def test_no_test_with_robust_losses_or_without_redundancy():
    """The chi-square test needs Gaussian noise and more residuals than unknowns."""
    d = manhattan_2d(100, seed=0)
    robust = fgopt.FactorGraph()
    for f in d.graph:
        robust.add(f if len(f.keys) == 1 else
                   fgopt.BetweenFactor(f.keys[0], f.keys[1], f.measured,
                                       Huber(1.0, Isotropic.sigma(3, 0.1))))
    r = fgopt.optimize(robust, d.initial, initialization="given")
    assert cost_bound(r.problem) is None
    tiny = fgopt.FactorGraph([PriorFactor(key("x", 0), SE2.from_xytheta(1, 2, 0.3))])
    values = fgopt.Variables().add(key("x", 0), SE2())
    r = fgopt.optimize(tiny, values)
    assert cost_bound(r.problem) is None and r.info["initialization"] == "given"


def test_auto_on_a_graph_that_is_not_a_pose_graph():
    """Implausible result, but no chordal relaxation exists: the given result, with the reason."""
    graph = fgopt.FactorGraph()
    values = fgopt.Variables()
    rng = np.random.default_rng(0)
    for i in range(30):  # contradictory priors on a vector: cost far above its chi-square
        graph.add(PriorFactor(key("p", 0), rng.normal(size=2) * 100, Isotropic.sigma(2, 0.01)))
    values.add(key("p", 0), np.zeros(2))
    r = fgopt.optimize(graph, values)
    assert r.info["initialization"] == "given"
    assert "not a pose graph" in r.info["initialization_reason"]


def test_unknown_initialization_is_an_error():
    d = manhattan_2d(20, seed=0)
    with pytest.raises(FgoptError, match="initialization"):
        fgopt.optimize(d.graph, d.initial, initialization="spanning")


@pytest.mark.parametrize("name", ["pose2d/input_M3500_g2o.g2o", "pose2d/manhattan.g2o"])
def test_m3500_and_manhattan_keep_the_given_start(data_file, name):
    """Both files' given-guess minima are plausible, so "auto" costs nothing extra there.
    manhattan.g2o is M3500's measurements with other information matrices: its optimum 1774.52
    is not M3500's 68.96 (LM from M3500's optimum ends there too)."""
    graph, values = fgopt.io.read(data_file(name), add_prior=True)
    r = fgopt.optimize(graph, values)
    assert r.info["initialization"] == "given"
    expected = 68.957439 if "M3500" in name else 1774.52
    assert r.final_cost == pytest.approx(expected, rel=1e-5)


def test_manhattan_is_not_m3500(data_file):
    """manhattan.g2o has M3500's measurements but other information matrices (full, rotation
    information ~9745 vs M3500's 44.7): LM on manhattan from M3500's optimum ends at manhattan's
    1774.52, the minimum its odometry guess and its chordal start reach too."""
    m_graph, m_values = fgopt.io.read(data_file("pose2d/input_M3500_g2o.g2o"), add_prior=True)
    m_opt = fgopt.optimize(m_graph, m_values).values
    graph, values = fgopt.io.read(data_file("pose2d/manhattan.g2o"), add_prior=True)
    start = values.copy()
    for k in values.keys():
        start.update(k, m_opt.at(k))
    r = fgopt.optimize(graph, start, initialization="given")
    c = fgopt.optimize(graph, values, initialization="chordal")
    assert r.final_cost == pytest.approx(1774.52, rel=1e-5)
    assert c.final_cost == pytest.approx(r.final_cost, rel=1e-6)


def test_auto_keeps_a_run_cut_short_by_its_iteration_limit():
    """initialization="auto" judges optima only: a first run that stopped at max_iterations is
    returned as it is (no chordal relaxation, no second run), with the reason stated."""
    from fgopt import key
    from fgopt.manifolds import SE2

    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    noise = fgopt.noise.Isotropic.sigma(3, 0.01)
    graph.add(fgopt.PriorFactor(key("x", 0), SE2(), noise))
    rng = np.random.default_rng(4)
    n = 40
    for i in range(n):  # a ring: a loop closure makes the odometry guess implausible
        j = (i + 1) % n
        graph.add(fgopt.BetweenFactor(key("x", i), key("x", j),
                                      SE2.from_xytheta(1.0, 0.0, 2 * np.pi / n), noise))
    pose = SE2()
    for i in range(n):
        initial.add(key("x", i), pose)
        pose = pose * SE2.from_xytheta(1.0, 0.0, 2 * np.pi / n + rng.normal(0, 0.2))
    capped = fgopt.optimize(graph, initial, max_iterations=2)
    assert capped.status is fgopt.Status.MAX_ITERATIONS
    assert capped.info["initialization"] == "given"
    assert "no second start" in capped.info["initialization_reason"]
    assert "iterations_all_starts" not in capped.info
    full = fgopt.optimize(graph, initial)  # converges: the test applies (and may restart)
    assert full.status is fgopt.Status.CONVERGED
    assert "no second start" not in full.info["initialization_reason"]


def test_repr_of_a_restarted_result_shows_the_given_start_and_why():
    """``print(result)`` after "auto" restarted from the chordal relaxation shows the cost of the
    caller's values (not only the chordal start's), that it restarted, and why."""
    d = manhattan_2d(200, seed=0)
    bad = _scrambled(d.initial, 0)
    given = fgopt.optimize(d.graph, bad, initialization="given")
    r = fgopt.optimize(d.graph, bad)
    assert r.info["initialization"] == "chordal"
    text = repr(r)
    assert f"{given.initial_cost:.6g} at the given values" in text
    assert "restarted from the chordal relaxation" in text and "chi-square" in text
    assert f"{r.initial_cost:.6g} -> {r.final_cost:.6g} (kept)" in text
