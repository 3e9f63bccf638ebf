"""Problem's plain-Python collection of small graphs (``Problem._collect_small``) against the
vectorized one: the same variables, kinds, storages and batches, and the same errors."""

import numpy as np
import pytest

import fgopt
from fgopt import SE2, SE3, SO3, BetweenFactor, FactorGraph, PriorFactor, Variables, key
from fgopt import problem as P
from fgopt.errors import FgoptError, KeyNotFoundError, ManifoldError


def both(graph, values, monkeypatch):
    """The problem collected by the small path (it does: the general one would fail), and by
    the general path."""
    with monkeypatch.context() as m:
        m.setattr(P.Problem, "_collect_variables", None)
        lean = P.Problem(graph, values, build_structure=False)
    with monkeypatch.context() as m:
        general_only(m)
        general = P.Problem(graph, values, build_structure=False)
    return lean, general


def general_only(m) -> None:
    """Turn off both lean collections (the file path runs at any size) in context ``m``."""
    m.setattr(P, "SMALL_COLLECT_MAX", -1)
    m.setattr(P.Problem, "_collect_file", lambda self, *a: False)


def assert_same_problem(a, b):
    assert [id(k) for k in a.kinds] == [id(k) for k in b.kinds]
    # (_key_start / _key_var: the individually added factors' keys, made by the lean
    # collection only when there are such factors)
    for name in ("var_keys", "var_kind", "var_row", "var_dim", "_slow_vars", "_sorted",
                 "_key_start", "_key_var")[:6 + 2 * hasattr(a, "_key_start")]:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
        assert getattr(a, name).dtype == getattr(b, name).dtype, name
    assert len(a._initial_storages) == len(b._initial_storages)
    for x, y in zip(a._initial_storages, b._initial_storages):
        np.testing.assert_array_equal(x, y)
    for x, y in zip(a._kind_vars, b._kind_vars):
        np.testing.assert_array_equal(x, y)
    assert a.unused_keys == b.unused_keys
    assert a.backend == b.backend
    assert len(a.batches) == len(b.batches)
    for x, y in zip(a.batches, b.batches):
        assert x.kernel is y.kernel and x.kind_ids == y.kind_ids and x.unit == y.unit
        for name in ("var_idx", "sqrt_info", "arg_dims", "arg_local_off", "weights"):
            np.testing.assert_array_equal(getattr(x, name), getattr(y, name), err_msg=name)
        for r, s in zip(x.rows, y.rows):
            np.testing.assert_array_equal(r, s)
            assert r.flags.c_contiguous
        np.testing.assert_array_equal(x.source.keys, y.source.keys)
        np.testing.assert_array_equal(x.source.constants, y.source.constants)
        assert (x.source.loss_code, x.source.loss_param) == (y.source.loss_code,
                                                            y.source.loss_param)


def mixed(seed=0):
    """Interleaved kernels, SE3 / SO3 / R^3 / SE2 values, shared and per-factor noise, a robust
    loss on some factors of one kernel, and two values no factor uses."""
    rng = np.random.default_rng(seed)
    graph, init = FactorGraph(), Variables()
    init.add(key("u", 0), np.ones(2))  # unused, first in the values
    for i in range(4):
        init.add(key("v", i), rng.normal(size=3))
        init.add(key("x", i), SE3.exp(rng.normal(size=6)))
        init.add(key("r", i), SO3.exp(rng.normal(size=3)))
        init.add(key("p", i), SE2.from_xytheta(*rng.normal(size=3)))
    init.add(key("u", 1), SO3())
    graph.add(PriorFactor(key("x", 2), SE3()))
    for i in range(3):
        graph.add(BetweenFactor(key("v", i + 1), key("v", i), rng.normal(size=3)))
        loss = fgopt.noise.Huber(1.0, fgopt.noise.Unit(6)) if i == 1 else None
        graph.add(BetweenFactor(key("x", i), key("x", i + 1), SE3.exp(rng.normal(size=6)),
                                loss))
        graph.add(BetweenFactor(key("r", i), key("r", i + 1), SO3.exp(rng.normal(size=3)),
                                fgopt.noise.Isotropic.sigma(3, 0.1 + i)))
        graph.add(BetweenFactor(key("p", i), key("p", i + 1), SE2.from_xytheta(1, 0, 0.1)))
    graph.add(PriorFactor(key("v", 0), np.zeros(3), fgopt.noise.Diagonal.sigmas([1, 2, 3.0])))
    return graph, init


@pytest.mark.parametrize("seed", [0, 1])
def test_individual_factors_collect_as_the_general_path(seed, monkeypatch):
    """Per-key values and individually added factors: every attribute the solvers read."""
    a, b = both(*mixed(seed), monkeypatch)
    assert_same_problem(a, b)
    assert len(a.unused_keys) == 2


def test_reader_batches_bulk_values_and_extra_factors(data_file, monkeypatch):
    """A reader's batches and bulk (``add_rows``) values, plus factors added one by one, some on
    keys the batches use and one on a new per-key value."""
    graph, init = fgopt.io.read(str(data_file("small/pose2example.txt")), add_prior=True)
    keys = sorted(int(k) for k in init.keys())
    graph.add(BetweenFactor(keys[3], keys[0], SE2.from_xytheta(4.0, 0.1, 0.2)))
    init.add(key("z", 0), SE2())
    graph.add(BetweenFactor(key("z", 0), keys[5], SE2()))
    a, b = both(graph, init, monkeypatch)
    assert_same_problem(a, b)


@pytest.mark.parametrize("name", ["small/pose3example-offdiagonal.txt", "small/Klaus3.g2o",
                                  "small/tinyGrid3D.g2o"])
def test_shared_tiny_files(data_file, name, monkeypatch):
    a, b = both(*fgopt.io.read(str(data_file(name)), add_prior=True), monkeypatch)
    assert_same_problem(a, b)


def test_larger_graphs_take_the_general_path(monkeypatch):
    """Above SMALL_COLLECT_MAX factors and values the vectorized collection runs."""
    graph, init = mixed()
    monkeypatch.setattr(P, "SMALL_COLLECT_MAX", len(graph) + len(init) - 1)
    calls = []
    original = P.Problem._collect_variables
    monkeypatch.setattr(P.Problem, "_collect_variables",
                        lambda self, g, v: (calls.append(1), original(self, g, v))[1])
    P.Problem(graph, init, build_structure=False)
    assert calls == [1]


def errors(graph, values, monkeypatch):
    """The (type, message) each collection raises."""
    out = []
    for lean in (True, False):
        with monkeypatch.context() as m:
            if not lean:
                general_only(m)
            with pytest.raises(FgoptError) as e:
                P.Problem(graph, values, build_structure=False)
        out.append((type(e.value), str(e.value)))
    return out


def test_bad_input_raises_the_general_paths_errors(data_file, monkeypatch):
    """A missing key, a value of the wrong manifold and a repeated key in a batch: the same
    error and message whichever collection ran."""
    graph, init = mixed()
    graph.add(BetweenFactor(key("x", 0), key("x", 9), SE3()))
    (t, msg), other = errors(graph, init, monkeypatch)
    assert t is KeyNotFoundError and "x9" in msg and other == (t, msg)

    graph, init = mixed()
    graph.add(BetweenFactor(key("r", 0), key("r", 1), SE3()))  # SE3 factor on SO3 values
    (t, msg), other = errors(graph, init, monkeypatch)
    assert t is ManifoldError and other == (t, msg)

    graph, init = fgopt.io.read(str(data_file("small/pose2example.txt")), add_prior=True)
    b = graph.batches[0]
    b.keys[1, 1] = b.keys[1, 0]
    (t, msg), other = errors(graph, init, monkeypatch)
    assert "same key twice" in msg and other == (t, msg)


def test_batches_made_without_init_hold_every_field(data_file):
    """``Problem._batch`` fills a ``_Batch``'s attributes directly (no dataclass ``__init__``):
    the same attributes and values as the constructor gives, and the fields made on first read
    (argument rows, weights) as the general path makes them."""
    import dataclasses

    graph, init = fgopt.io.read(str(data_file("small/toyExample.g2o")), add_prior=True)
    b = P.Problem(graph, init, build_structure=False).batches[0]
    ref = P._Batch(b.kernel, b.source, b.var_idx, b.kind_ids, b.sqrt_info, b.unit, b.arg_dims,
                   b.arg_local_off, sqrt_info0=b.sqrt_info0, unit0=b.unit0, var_row=b.var_row)
    assert sorted(ref.__dict__) == sorted(b.__dict__)
    for f in dataclasses.fields(P._Batch):
        x, y = getattr(ref, f.name), getattr(b, f.name)
        if isinstance(x, list):
            assert len(x) == len(y) and all(np.array_equal(u, v) for u, v in zip(x, y)), f.name
        elif isinstance(x, np.ndarray):
            np.testing.assert_array_equal(x, y, err_msg=f.name)
        else:
            assert x == y or x is y, f.name
    np.testing.assert_array_equal(b.weights, np.ones(len(b.source)))
    np.testing.assert_array_equal(b.rows[1], b.var_row[b.var_idx[:, 1]])


def test_repeated_key_in_a_large_batch_names_its_row(data_file):
    """A batch above the Python-checked size (vectorized checks) with one factor on the same key
    twice: the error names that factor's file line, as for small batches."""
    graph, init = fgopt.io.read(str(data_file("pose2d/intel.g2o")), add_prior=True)
    b = graph.batches[0]
    assert len(b) > P._PYTHON_CHECK_ROWS
    b.keys[700, 1] = b.keys[700, 0]
    with pytest.raises(FgoptError, match="same key twice") as err:
        P.Problem(graph, init, build_structure=False)
    assert b._where(700) in str(err.value)


@pytest.fixture
def numba_in_use(monkeypatch):
    """The process has loaded numba (the condition of the file path, ``_collect_file``); counts
    the solves that path took."""
    monkeypatch.setattr(P._jit, "is_numba_loaded", lambda: True)
    taken = []
    original = P.Problem._collect_file
    monkeypatch.setattr(P.Problem, "_collect_file",
                        lambda self, *a: (taken.append(original(self, *a)), taken[-1])[1])
    return taken


def block_of(values):
    blk = values._pending[0]
    return blk.keys, blk.kind, blk.rows


@pytest.mark.parametrize("name", ["small/pose2example.txt", "small/pose3example-offdiagonal.txt",
                                  "small/Klaus3.g2o", "small/tinyGrid3D.g2o", "pose2d/intel.g2o"])
def test_a_files_graph_numbered_in_one_compiled_call(data_file, name, numba_in_use, monkeypatch):
    """A reader's batches over one ascending bulk block: the file path collects it (block rows
    as variables, each batch's variables from one compiled call) as the general path does, at
    any size (intel: 1728 poses, above ``SMALL_COLLECT_MAX``)."""
    a, b = both(*fgopt.io.read(str(data_file(name)), add_prior=True), monkeypatch)
    assert numba_in_use == [True]
    assert_same_problem(a, b)
    np.testing.assert_array_equal(a._bulk_order, np.arange(len(a.var_keys)))


def test_file_path_leaves_what_it_cannot_number_to_the_python_pass(data_file, numba_in_use,
                                                                   monkeypatch):
    """Keys not ascending, a value no factor uses, a missing key and a repeated key: the file
    path declines (nothing set), and the Python pass gives the general path's problem or error."""
    graph, init = fgopt.io.read(str(data_file("small/pose2example.txt")), add_prior=True)
    keys, kind, rows = block_of(init)
    descending = Variables().add_rows(keys[::-1], kind, rows[::-1])
    a, b = both(graph, descending, monkeypatch)
    assert_same_problem(a, b)
    extra = Variables().add_rows(np.append(keys, keys[-1] + 7), kind, np.vstack([rows, rows[:1]]))
    a, b = both(graph, extra, monkeypatch)
    assert_same_problem(a, b)
    assert [int(k) for k in a.unused_keys] == [int(keys[-1] + 7)]
    assert numba_in_use == [False, False]

    missing = Variables().add_rows(keys[1:], kind, rows[1:])
    (t, msg), other = errors(graph, missing, monkeypatch)
    assert t is KeyNotFoundError and other == (t, msg)
    graph.batches[0].keys[1, 1] = graph.batches[0].keys[1, 0]
    (t, msg), other = errors(graph, init, monkeypatch)
    assert "same key twice" in msg and other == (t, msg)
    assert numba_in_use[2:] == [False, False]
