"""The NumPy backend (a solve without numba) gives the numba backend's results.

Each piece is compared with its numba counterpart - the reader's scan, the structure (pattern
and scatter map), the NumPy assembly, the vectorized retracts - and whole solves on real pose
graphs (M3500, sphere2500) and small synthetic ones must take the same iterations to the same
final cost (1e-9 relative). A new process solving M3500 from the command line must not import
numba at all, and the switch to numba of a long solve must keep the iterate going.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import fgopt
from fgopt import _jit
from fgopt.errors import FgoptError
from fgopt.io import _scan
from fgopt.manifolds import SE2, SE3, SO2, SO3
from fgopt.manifolds._kernels import dispatch
from fgopt.manifolds._kernels.vectorized import RETRACT_NUMPY
from fgopt.problem import Problem

REPO = Path(__file__).resolve().parents[2]


def _numba_scan(buf: np.ndarray, has_tag: bool):
    """The numba scan's outputs in :func:`fgopt.io._scan._scan_np`'s layout."""
    values, bad, start, line, first, count, th, ts, te = _scan._scan_numba(buf, has_tag,
                                                                            ord("#"))
    end = _scan._token_ends(buf, start, ord("#"))
    if not has_tag:  # the NumPy scan gives zeros per record
        th = np.zeros(line.shape[0], np.uint64)
        ts = te = np.zeros(line.shape[0], np.int64)
    return values, bad, start, end, line, first, count, th, ts, te


ODD_TEXT = [(b"VERTEX_SE2 0 1 2 3\n# a comment line\n  EDGE 1 2 1_0 x\xc3\xa9 nan inf -1e400 1e-400 "
            b"0.1000000000000000055511151231257827 # tail\nTAG\nX 1\r\n\n\n"
            b"12345678901234567890123 .5 +.5e3 -0 1e22 1e23 4.9e-324"), b"", b"\n\n", b"A",
            b"A 1 2#x\nB 3", b"\t  \t\nV 1.5\tW\x0b2\x0c3"]


@pytest.mark.parametrize("text", ODD_TEXT)
@pytest.mark.parametrize("has_tag", [True, False])
def test_numpy_scan_equals_numba_scan_on_odd_text(text, has_tag):
    """Every output array (values with NaN for bad tokens, bad flags, token spans, records,
    tag hashes) is the same, on comments, CR/LF, tabs, garbage, 17+ digit and extreme numbers."""
    buf = np.frombuffer(text, dtype=np.uint8)
    got = _scan._scan_np(buf, has_tag, ord("#"))
    want = _numba_scan(buf, has_tag)
    for i, (a, b) in enumerate(zip(got, want)):
        assert a.shape == b.shape, i
        if a.dtype.kind == "f":
            assert np.array_equal(a, b, equal_nan=True), i
        else:
            assert np.array_equal(a, b), i


@pytest.mark.parametrize("rel", ["pose2d/input_M3500_g2o.g2o", "pose3d/sphere2500.g2o",
                                 "small/pose3example-offdiagonal.txt"])
def test_numpy_scan_equals_numba_scan_on_files(data_file, rel):
    buf = np.frombuffer(_scan.read_bytes(data_file(rel)), dtype=np.uint8)
    for a, b in zip(_scan._scan_np(buf, True, ord("#")), _numba_scan(buf, True)):
        assert np.array_equal(a, b)


def test_vectorized_retracts_equal_the_kernels():
    """x * Exp(d) for SO2, SE2, SO3, SE3 over tangent sizes from 1e-9 (series branches) to 2."""
    rng = np.random.default_rng(1)
    for gid, cls in enumerate([SO2, SE2, SO3, SE3]):
        n = 250
        x = np.array([cls.random(rng)._data for _ in range(n)])
        scale = np.repeat([1e-9, 1e-6, 1e-3, 0.3, 2.0], n // 5)[:, None]
        d = rng.normal(size=(n, cls._DIM)) * scale
        want = dispatch.batch_retract(gid, x, d)
        assert np.allclose(RETRACT_NUMPY[gid](x, d), want, rtol=0, atol=1e-14)


def _pose_graph(n: int, dim: int, seed: int = 0):
    data = (fgopt.datasets.manhattan_2d(n, seed=seed) if dim == 2
            else fgopt.datasets.grid_3d(n, seed=seed))
    return data.graph, data.initial


@pytest.mark.parametrize("dim", [2, 3])
def test_structure_and_assembly_equal(dim):
    """Pattern, scatter map and the assembled H, g and cost of the two backends agree (batches
    above 1000 factors, so the numba backend really runs numba), in one ordering both compute
    (``"amd"`` is fgopt's own kernel on numba, CHOLMOD's or MMD on NumPy)."""
    graph, initial = _pose_graph(1500, dim)
    a = Problem(graph, initial, backend="numpy", ordering="mmd")
    b = Problem(graph, initial, backend="numba", ordering="mmd")
    assert a.backend == "numpy" and b.backend == "numba"
    assert max(len(x.source) for x in b.batches) > 1000
    assert np.array_equal(a.pattern.indptr, b.pattern.indptr)
    assert np.array_equal(a.pattern.indices, b.pattern.indices)
    for x, y in zip(a.batches, b.batches):
        assert np.array_equal(x.pos, y.pos)
    ca, cb = a.linearize(a.initial_state()), b.linearize(b.initial_state())
    assert ca == pytest.approx(cb, rel=1e-12)
    assert np.allclose(a.H_data, b.H_data, rtol=1e-12, atol=1e-9 * np.abs(b.H_data).max())
    assert np.allclose(a.g, b.g, rtol=1e-12, atol=1e-12 * np.abs(b.g).max())


def _same_solve(graph, initial, **kw):
    ra = fgopt.optimize(graph, initial, backend="numpy", **kw)
    rb = fgopt.optimize(graph, initial, backend="numba", **kw)
    assert ra.info["backend"] == "numpy" and rb.info["backend"] == "numba"
    assert ra.iterations == rb.iterations
    assert ra.final_cost == pytest.approx(rb.final_cost, rel=1e-9)
    assert [r.accepted for r in ra.iteration_records] == [r.accepted for r in rb.iteration_records]
    return ra, rb


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("solver", ["auto", "ldlt"])
def test_synthetic_solves_match(dim, solver):
    """LM on both backends: same iterations, same acceptances, final cost to 1e-9 (auto:
    CHOLMOD on NumPy; ldlt: qdldl, the default without the CHOLMOD extra)."""
    graph, initial = _pose_graph(1500, dim)
    ra, rb = _same_solve(graph, initial, linear_solver=solver)
    assert ra.linear_solver in ("cholmod", "ldlt") and rb.linear_solver in ("block", "ldlt")


@pytest.mark.parametrize("rel", ["pose2d/input_M3500_g2o.g2o", "pose3d/sphere2500.g2o"])
def test_real_pose_graphs_match(data_file, rel):
    from fgopt.io import add_gauge_prior, read

    graph, initial = read(data_file(rel), format="g2o")
    add_gauge_prior(graph, initial)
    ra, rb = _same_solve(graph, initial)
    assert ra.status.value == "converged" and rb.status.value == "converged"


def test_auto_backend_rule(monkeypatch):
    """auto: NumPy only while numba is not loaded, for problems up to the size limit, serial."""
    graph, initial = _pose_graph(200, 2)
    monkeypatch.setattr(_jit, "is_numba_loaded", lambda: False)
    assert Problem(graph, initial).backend == "numpy"
    assert Problem(graph, initial, threads=2).backend == "numba"
    monkeypatch.setattr("fgopt.problem.NUMPY_BACKEND_MAX_SIZE", 10)
    assert Problem(graph, initial).backend == "numba"
    monkeypatch.setattr("fgopt.problem.NUMPY_BACKEND_MAX_SIZE", 10 ** 9)
    monkeypatch.setattr(_jit, "is_numba_loaded", lambda: True)
    assert Problem(graph, initial).backend == "numba"
    with pytest.raises(FgoptError, match="unknown backend"):
        Problem(graph, initial, backend="gpu")


def test_numpy_backend_refuses_kernels_without_twins():
    """A hand-written numba kernel has no NumPy form: backend='numpy' says so, auto uses numba."""
    from fgopt.navigation import GpsFactor

    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    initial.add(fgopt.key("x", 0), SE3())
    graph.add(GpsFactor(fgopt.key("x", 0), np.array([1.0, 2.0, 3.0]),
                        fgopt.noise.Isotropic.sigma(3, 1.0)))
    with pytest.raises(FgoptError, match="NumPy form"):
        Problem(graph, initial, backend="numpy")
    assert Problem(graph, initial).backend == "numba"


def test_long_solve_switches_to_numba_when_warm(monkeypatch):
    """With numba's cache marked warm, a NumPy solve moves to numba after SWITCH_AFTER_SECONDS
    (0 here: before its first linear solve, after the initial linearization on NumPy): the
    iterations go on to the numba backend's result."""
    from fgopt.solvers import _run, _warmup

    graph, initial = _pose_graph(1500, 3)
    monkeypatch.setattr(_run, "SWITCH_AFTER_SECONDS", 0.0)
    monkeypatch.setattr(_warmup, "is_warm", lambda problem: True)
    monkeypatch.setattr(_jit, "is_numba_loaded", lambda: False)
    switched = fgopt.optimize(graph, initial)
    assert switched.info["backend"].startswith("numpy for 0 iterations, then numba")
    assert switched.linear_solver == "block"
    plain = fgopt.optimize(graph, initial, backend="numba")
    assert switched.iterations == plain.iterations
    assert switched.final_cost == pytest.approx(plain.final_cost, rel=1e-9)


def test_switch_is_decided_only_before_another_step(monkeypatch):
    """The move to numba is considered before each linear solve, never after the last
    iteration: a solve that has just converged does not pay numba's loads."""
    from fgopt.solvers import _run, _warmup

    graph, initial = _pose_graph(1500, 3)
    monkeypatch.setattr(_warmup, "is_warm", lambda problem: False)  # considered, never taken
    monkeypatch.setattr(_jit, "is_numba_loaded", lambda: False)
    done_before = []
    original = _run.Run.maybe_switch
    monkeypatch.setattr(_run.Run, "maybe_switch",
                        lambda self: (done_before.append(len(self.records)), original(self))[1])
    result = fgopt.optimize(graph, initial, max_iterations=3, relative_tolerance=0.0,
                            absolute_tolerance=0.0, gradient_tolerance=0.0, step_tolerance=0.0)
    assert result.iterations == 3 and result.info["backend"] == "numpy"
    assert done_before == [0, 1, 2]


def test_warm_marker_round_trip(tmp_path, monkeypatch):
    """A numba-backend solve marks its kernels warm; a different kernel set is not warm."""
    from fgopt.solvers import _warmup, small

    monkeypatch.setenv("FGOPT_CACHE_DIR", str(tmp_path / "cache"))
    # the general path's marker: keep the solve off the small-problem driver, whose kernel set
    # an earlier test in this process may have made ready (its plan remembers that)
    monkeypatch.setattr(small, "SMALL_MAX_SIZE", -1)
    graph, initial = _pose_graph(60, 2)
    problem = Problem(graph, initial, backend="numba")
    assert not _warmup.is_warm(problem)
    fgopt.optimize(graph, initial, backend="numba", max_iterations=1)
    assert _warmup.is_warm(problem)
    graph3, initial3 = _pose_graph(60, 3)
    assert not _warmup.is_warm(Problem(graph3, initial3, backend="numba"))


def test_cli_solve_of_m3500_imports_no_numba(data_file, tmp_path):
    """A new process: `fgopt solve M3500 --out` reads, solves and writes without numba (NumPy
    reader, NumPy kernels, CHOLMOD/qdldl) and reports the NumPy backend."""
    path = data_file("pose2d/input_M3500_g2o.g2o")
    # no move to numba mid-solve: on a loaded machine this solve can pass the 1 s mark
    code = ("import fgopt.solvers._run as run\nrun.SWITCH_AFTER_SECONDS = float('inf')\n"
            "import sys, runpy\nsys.argv = ['fgopt', 'solve', sys.argv[1], '--out', sys.argv[2], "
            "'--quiet']\ntry:\n    runpy.run_module('fgopt.cli', run_name='__main__')\n"
            "except SystemExit:\n    pass\nprint('NUMBA' if 'numba' in sys.modules else 'NO-NUMBA')")
    env = dict(os.environ, PYTHONPATH=str(REPO))
    out = subprocess.run([sys.executable, "-c", code, str(path), str(tmp_path / "o.g2o")],
                         capture_output=True, text=True, cwd=REPO, env=env, check=True).stdout
    assert "NO-NUMBA" in out and "numpy kernels" in out and "6.895744e+01" in out
    assert (tmp_path / "o.g2o").stat().st_size > 100000
