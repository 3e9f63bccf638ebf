"""The fixed formulation (fgopt.solvers.fixed) against the dynamic, batched problem.

Robot localization as in the SymForce paper, Sec. VIII-C (2D here): SE2 poses, odometry
BetweenFactors, bearing/range to known landmarks (an @fgopt.factor). Small (3 poses, 6 landmarks)
to keep the cold SymPy derivation + numba compilation short.
"""

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import fgopt
from fgopt import SE2, BetweenFactor, FactorGraph, Variables, key
from fgopt.errors import FgoptError
from fgopt.factors import Factor
from fgopt.solvers import LevenbergMarquardt, LMParams
from fgopt.symbolic import V2, Pose2, atan2, cos, factor, sin
from fgopt.solvers import fixed as fx


@factor(name="test_fixed_bearing_range")
def bearing_range(pose: Pose2, landmark: V2, measured: V2) -> V2:
    d = pose.inverse() * landmark
    cz, sz = cos(measured[0]), sin(measured[0])
    return V2(atan2(cz * d[1] - sz * d[0], cz * d[0] + sz * d[1]), d.norm() - measured[1])


def robot_graph(num_poses=3, num_landmarks=6, seed=0):
    """Same construction as benchmarks/problems.py: robot_localization (smaller)."""
    rng = np.random.default_rng(seed)
    k = np.arange(num_poses)
    th = 0.35 * k
    truth = np.stack([3.0 * np.sin(th), 3.0 * (1 - np.cos(th)), th], axis=1)
    lms = rng.uniform(-10.0, 10.0, size=(num_landmarks, 2))
    br_s, odo_s = np.array([0.05, 0.1]), np.array([0.02, 0.05, 0.05])  # odo: theta, x, y
    graph, init = FactorGraph(), Variables()
    for i in range(num_poses):
        init.add(key("x", i), SE2.from_xytheta(0.0, 0.0, 0.0))
    br = fgopt.noise.Diagonal.sigmas(br_s)
    for i in range(num_poses):
        for j in range(num_landmarks):
            d = lms[j] - truth[i, :2]
            c, s = np.cos(th[i]), np.sin(th[i])
            loc = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])
            z = np.array([np.arctan2(loc[1], loc[0]), np.linalg.norm(loc)])
            z += rng.normal(size=2) * br_s
            graph.add(bearing_range(pose=key("x", i), landmark=lms[j].copy(), measured=z,
                                    loss=br))
    odo = fgopt.noise.Diagonal.sigmas(odo_s)
    for i in range(num_poses - 1):
        rel = SE2.from_xytheta(*truth[i]).inverse() * SE2.from_xytheta(*truth[i + 1])
        noise = rng.normal(size=3) * odo_s
        graph.add(BetweenFactor(key("x", i), key("x", i + 1),
                                rel * SE2.from_xytheta(noise[1], noise[2], noise[0]), odo))
    return graph, init


_PLAIN: list = []


def plain_module():
    """This file imported without pytest's assertion rewriting, as the subprocess test imports
    it: rewriting changes the factor function's code fingerprint and so its cache key."""
    if not _PLAIN:
        import importlib.util

        spec = importlib.util.spec_from_file_location("fgopt_test_fixed_plain", __file__)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        _PLAIN.append(mod)
    return _PLAIN[0]


@pytest.fixture(scope="module")
def compiled():
    graph, init = plain_module().robot_graph()
    return graph, init, fx.compile_fixed(graph, init)


def _xyt(values, keys):
    return np.array([[*values.at(k).translation(), values.at(k).theta()] for k in keys])


def test_same_optimum_as_dynamic(compiled):
    graph, init, fp = compiled
    rf = fp.optimize(init)
    rd = fgopt.optimize(graph, init, method="lm")
    assert rf.status == rd.status and rf.iterations == rd.iterations
    assert abs(rf.final_cost - rd.final_cost) <= 1e-9 * max(1.0, rd.final_cost)
    assert abs(rf.initial_cost - rd.initial_cost) <= 1e-9 * rd.initial_cost
    np.testing.assert_allclose(rf.cost_history, rd.cost_history, rtol=1e-9)
    np.testing.assert_allclose(_xyt(rf.values, fp.keys), _xyt(rd.values, fp.keys), atol=1e-9)
    assert rf.values.at(key("x", 0)).__class__ is SE2
    assert init.at(key("x", 1)).translation()[0] == 0.0  # caller's values untouched


def test_fixed_five_iterations_match_dynamic_records(compiled):
    graph, init, fp = compiled
    p = LMParams(max_iterations=5, relative_tolerance=0.0, absolute_tolerance=0.0,
                 gradient_tolerance=0.0, step_tolerance=0.0)
    rf = fp.optimize(init, params=p)
    rd = LevenbergMarquardt(p).optimize(graph, init)
    assert rf.iterations == rd.iterations == 5
    assert rf.status is rd.status is fgopt.solvers.result.Status.MAX_ITERATIONS
    for a, b in zip(rf.iteration_records, rd.iteration_records):
        assert a.accepted == b.accepted
        np.testing.assert_allclose([a.cost, a.lam, a.step_norm, a.gradient_norm],
                                   [b.cost, b.lam, b.step_norm, b.gradient_norm], rtol=1e-7)


def test_H_g_cost_equal_dynamic_at_initial(compiled):
    graph, init, fp = compiled
    cost, H, g = fp.linearize(init)
    prob = fgopt.Problem(graph, init)
    cost_d = prob.linearize(prob.initial_state())
    Hd = prob.pattern.full(prob.H_data).toarray()
    perm = np.concatenate([prob.pattern.var_offset[prob._var_of_key[k]] + np.arange(kind.dim)
                           for k, kind in zip(fp.keys, fp.kinds)])
    scale = np.abs(Hd).max()
    np.testing.assert_allclose(H, Hd[np.ix_(perm, perm)], rtol=1e-9, atol=1e-9 * scale)
    np.testing.assert_allclose(g, prob.g[perm], rtol=1e-9, atol=1e-9 * np.abs(g).max())
    assert abs(cost - cost_d) <= 1e-9 * cost_d
    assert np.array_equal(H, H.T)
    # the readable Python twin in the generated module computes the same thing
    H2, g2 = np.zeros_like(H), np.zeros_like(g)
    cost2 = fp.module.linearize_py(fp.flatten(init), fp._aux, H2, g2)
    np.testing.assert_allclose(H2, H, rtol=1e-12, atol=1e-12 * scale)
    assert abs(cost2 - cost) <= 1e-12 * cost


def test_new_measurements_reuse_generated_code(compiled):
    graph, init, fp = compiled
    graph2, init2 = plain_module().robot_graph(seed=7)
    derived = fx.STATS["derived"]
    fp2 = fx.compile_fixed(graph2, init2)
    assert fx.STATS["derived"] == derived and fp2.module is fp.module
    assert fp2.structure_key == fp.structure_key
    rf = fp2.optimize()
    rd = fgopt.optimize(graph2, init2, method="lm")
    assert abs(rf.final_cost - rd.final_cost) <= 1e-9 * max(1.0, rd.final_cost)
    # update() swaps the numeric inputs of an existing FixedProblem
    fp3 = fx.compile_fixed(graph, init).update(graph2)
    assert abs(fp3.optimize().final_cost - rd.final_cost) <= 1e-9 * max(1.0, rd.final_cost)
    r = fx.optimize_fixed(graph2, init2, max_iterations=50)
    assert abs(r.final_cost - rd.final_cost) <= 1e-9 * max(1.0, rd.final_cost)


def test_op_counts_and_source(compiled):
    _, _, fp = compiled
    ops = fp.ops
    assert ops["linearize"] > 0 and ops["instructions"]["arith"] > 0
    assert "_LIN_CODE" in fp.source and "def linearize_py" in fp.source
    assert "FixedProblem(3 variables" in repr(fp)


def test_unsupported_factor_is_named():
    class Custom(Factor):
        def __init__(self, k):
            super().__init__([k], 1)

        def error(self, values):
            return np.zeros(1)

        def jacobians(self, values):
            return [np.zeros((1, 3))]

    graph, init = robot_graph(2, 1)
    graph.add(Custom(key("x", 1)))
    with pytest.raises(FgoptError, match="Custom"):
        fx.compile_fixed(graph, init)
    graph, init = robot_graph(2, 1)
    robust = fgopt.noise.Huber(1.0, fgopt.noise.Isotropic.sigma(2, 1.0)) \
        if hasattr(fgopt.noise, "Huber") else None
    if robust is not None:
        graph.add(bearing_range(pose=key("x", 0), landmark=np.ones(2), measured=np.ones(2),
                                loss=robust))
        with pytest.raises(FgoptError, match="robust"):
            fx.compile_fixed(graph, init)


def test_second_process_loads_from_cache(compiled):
    """A new process imports the generated module (no SymPy) and numba's cached machine code."""
    code = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {os.path.dirname(__file__)!r})
        import importlib.util
        spec = importlib.util.spec_from_file_location("fgopt_test_fixed_plain", {__file__!r})
        tf = importlib.util.module_from_spec(spec); spec.loader.exec_module(tf)
        graph, init = tf.robot_graph()
        fp = tf.fx.compile_fixed(graph, init)
        print(fp.generation["source"], "sympy" in sys.modules, fp.optimize().final_cost)
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=dict(os.environ), timeout=300, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    src, sympy_loaded, cost = out.stdout.split()
    assert src == "disk" and sympy_loaded == "False"
    _, init, fp = compiled
    assert abs(float(cost) - fp.optimize(init).final_cost) <= 1e-9 * float(cost)


def test_tampered_cached_module_is_regenerated(compiled, tmp_path):
    """A statement planted in the fixed formulation's cached module never runs: the next
    compile discards the entry (one CacheWarning naming it), regenerates a verified entry and
    reaches the same optimum. (The regenerated text may order instructions differently: the
    derivation's order depends on the process's string hash seed.)"""
    from pathlib import Path

    from fgopt.solvers.fixed import formulation
    from fgopt.symbolic import cache
    from fgopt.symbolic.cache import CacheWarning

    graph, init, fp = compiled
    path = Path(fp.module.__file__)
    original = path.read_bytes()
    marker = tmp_path / "planted-ran"
    path.write_bytes(original + f"\nopen({str(marker)!r}, 'w').close()\n".encode())
    formulation._MODULES.pop(fp.structure_key)
    sys.modules.pop(path.stem)
    with pytest.warns(CacheWarning, match=path.stem):
        again = fx.compile_fixed(graph, init)
    assert again.generation["source"] == "derived"
    assert not marker.exists()
    assert cache.verify(path) is None and b"planted-ran" not in path.read_bytes()
    assert again.source == path.read_text()
    assert abs(again.optimize(init).final_cost - fp.optimize(init).final_cost) <= 1e-12


def test_bal_reader_batches_run_in_the_fixed_formulation(data_file):
    """A BAL file's reprojection batch (graph.add_batch rows, not factor instances) is traced back
    to the generated bal_reprojection factor type: the fixed formulation reaches the same
    iterates as the dynamic one."""
    graph, values = fgopt.io.read_bal(data_file("bal/dubrovnik-1-1-pre.txt"))
    kw = {"max_iterations": 3, "relative_tolerance": 0.0, "absolute_tolerance": 0.0,
          "gradient_tolerance": 0.0, "step_tolerance": 0.0}
    dyn = fgopt.optimize(graph, values, **kw)
    fix = fgopt.optimize(graph, values, formulation="fixed", **kw)
    assert np.isclose(fix.final_cost, dyn.final_cost, rtol=1e-6, atol=1e-12)
    for k in values.keys():
        assert np.allclose(fix.values.at(k), dyn.values.at(k), rtol=1e-6, atol=1e-9)
