"""Keys print like x1; Variables store private copies, refuse bad input with FgoptErrors."""

import numpy as np
import pytest

import fgopt
from fgopt import Variables, key
from fgopt.errors import (DimensionMismatchError, DuplicateKeyError, FgoptError,
                          KeyNotFoundError, ManifoldError, NonFiniteError)


def test_key_prints_char_and_index():
    k = key("x", 1)
    assert repr(k) == "x1" and str(key("l", 42)) == "l42"
    assert k.char == "x" and k.index == 1
    assert key("x", 1) == key("x", 1) and key("x", 1) != key("y", 1)
    assert hash(k) == hash(int(k))


@pytest.mark.parametrize("bad", [("xy", 1), ("x", -1), (1, 1)])
def test_bad_keys_raise(bad):
    with pytest.raises(FgoptError):
        key(*bad)


def test_variables_add_at_update_copy():
    v = Variables()
    a = np.array([1.0, 2.0])
    v.add(key("p", 0), a).add(key("s", 0), 3)
    a[0] = 100.0  # caller's array must not alias ours
    assert v.at(key("p", 0))[0] == 1.0
    assert isinstance(v.at(key("s", 0)), float)
    w = v.copy()
    w.update(key("p", 0), np.array([5.0, 6.0]))
    assert v.at(key("p", 0))[0] == 1.0 and w.at(key("p", 0))[0] == 5.0
    assert key("p", 0) in v and key("q", 0) not in v and len(v) == 2
    assert v.keys() == [key("p", 0), key("s", 0)]
    assert "p0" in repr(v) and "2 keys" in repr(v)
    assert "<table>" in v._repr_html_()


def test_variables_errors_name_the_key():
    v = Variables().add(key("x", 1), np.zeros(3))
    with pytest.raises(KeyNotFoundError, match="x2"):
        v.at(key("x", 2))
    with pytest.raises(DuplicateKeyError, match="x1"):
        v.add(key("x", 1), np.zeros(3))
    with pytest.raises(DimensionMismatchError, match="x1"):
        v.update(key("x", 1), np.zeros(4))
    with pytest.raises(NonFiniteError, match="x3"):
        v.add(key("x", 3), np.array([np.nan]))
    with pytest.raises(ManifoldError):
        v.add(key("x", 4), "not a manifold")
    with pytest.raises(ManifoldError):
        v.add(key("x", 5), np.zeros((2, 2)))
    assert isinstance(KeyNotFoundError("x"), FgoptError)
    assert fgopt.FgoptError is FgoptError


def _bulk(n=5):
    rows = np.arange(3.0 * n).reshape(n, 3)
    keys = np.array([int(key("p", j)) for j in range(n)])
    return keys, rows


def test_bulk_rows_behave_like_added_values():
    """Vector rows added in bulk (kept as an array until needed): at, in, len, the key order,
    duplicates, copies, updates and pickling behave as if each value had been added."""
    import pickle

    from fgopt.manifolds.base import vector_kind

    keys, rows = _bulk()
    v = Variables().add(key("x", 0), 1.0)
    v.add_rows(keys, vector_kind(3), rows)
    assert len(v) == 6 and key("p", 4) in v and int(key("p", 4)) in v and key("p", 5) not in v
    assert np.array_equal(v.at(key("p", 2)), rows[2]) and len(v._pending) == 1
    with pytest.raises(DuplicateKeyError, match="p3"):
        v.add_rows(keys[3:4], vector_kind(3), rows[:1])
    with pytest.raises(DuplicateKeyError, match="x0"):
        v.add_rows([int(key("x", 0))], vector_kind(3), rows[:1])
    with pytest.raises(KeyNotFoundError, match="p9"):
        v.at(key("p", 9))
    w = v.copy()
    w.update(key("p", 1), np.array([7.0, 8.0, 9.0]))
    assert np.array_equal(v.at(key("p", 1)), rows[1]) and w.at(key("p", 1))[0] == 7.0
    assert v.keys() == [key("x", 0)] + [key("p", j) for j in range(5)]
    u = pickle.loads(pickle.dumps(v))
    assert u.keys() == v.keys() and np.array_equal(u.at(key("p", 4)), rows[4])
    with pytest.raises(DuplicateKeyError):
        Variables().add_rows(np.array([3, 3]), vector_kind(3), rows[:2])


def test_reading_bulk_rows_by_key_keeps_the_rows(monkeypatch):
    """``at`` on bulk rows (a file's poses) makes the block's objects once and then reads them
    by key: the values equal the materialized ones, a key reads the same object twice, ints,
    numpy ints and Keys all find it, and the block stays rows (the compiled problem's bulk
    path); a block above the indexed size reads row by row with the same values."""
    import fgopt.variables as V
    from fgopt import SE2
    from fgopt.manifolds import ops_for
    from fgopt.manifolds.base import vector_kind

    poses = [SE2.from_xytheta(0.1 * j, -0.2 * j, 0.3 * j - 1.0) for j in range(6)]
    keys = np.array([int(key("x", j)) for j in (3, 0, 5, 1, 4, 2)])
    kind = ops_for(poses[0]).batch_kind(poses[0])
    v = Variables().add(key("l", 0), 2.0)
    v.add_rows(keys, kind, np.array([p.to_storage() for p in poses]))
    v.add_rows(np.array([int(key("p", 0))]), vector_kind(2), np.array([[1.0, 2.0]]))
    first = v.at(key("x", 5))
    assert v.at(int(key("x", 5))) is first and v.at(np.int64(int(key("x", 5)))) is first
    assert len(v._pending) == 2 and not v._pending[1]._objects  # only the read block
    want = {k: x for k, x in v.copy().items()}  # a copy materializes; v keeps its rows
    assert len(v._pending) == 2
    for k, x in want.items():
        got = v.at(k)
        assert type(got) is type(x)
        if isinstance(x, SE2):
            got, x = got.to_storage(), x.to_storage()
        assert np.array_equal(got, x)
    with pytest.raises(KeyNotFoundError, match="x9"):
        v.at(key("x", 9))
    monkeypatch.setattr(V, "_INDEXED_ROWS", 0)
    w = Variables().add_rows(keys, kind, np.array([p.to_storage() for p in poses]))
    assert w.at(key("x", 5)).equals(first, 0.0) and w._pending[0]._objects is None
    assert list(v.keys())[:3] == [key("l", 0), key("x", 3), key("x", 0)]


def test_type_counts_count_bulk_rows_without_making_their_objects():
    """``type_counts`` of bulk rows (a file's poses) equals that of the same values held one by
    one, and leaves the rows as rows (a message must not cost the bulk path)."""
    from fgopt import SE3
    from fgopt.manifolds import ops_for
    from fgopt.manifolds.base import vector_kind

    poses = [SE3.exp(np.array([0.1 * j, 0.2, 0.3, 1.0, 2.0, 3.0])) for j in range(4)]
    kind = ops_for(poses[0]).batch_kind(poses[0])
    v = Variables().add(key("l", 0), 2.0).add(key("l", 1), np.zeros(3))
    v.add_rows(np.array([int(key("x", j)) for j in range(4)]), kind,
               np.array([p.to_storage() for p in poses]))
    v.add_rows(np.array([int(key("p", 0)), int(key("p", 1))]), vector_kind(3), np.ones((2, 3)))
    counts = v.type_counts()
    assert all(blk._objects is None for blk in v._pending) and len(v._pending) == 2
    assert counts == {"float": 1, "R3": 3, "SE3": 4}
    assert counts == v.copy().type_counts() == Variables(dict(v.items())).type_counts()


def test_problem_takes_bulk_rows_as_arrays():
    """A problem compiled from bulk rows has the same variables, kinds, order and storage as
    one compiled from per-key values, and never turns the rows into per-key objects."""
    from fgopt.datasets import bal_synthetic
    from fgopt.problem import Problem

    graph, bulk = bal_synthetic(6, 40, 3, seed=2).read()
    assert bulk._pending  # the BAL reader adds cameras and points in bulk
    per_key = Variables()
    for k in bulk.keys():
        per_key.add(k, bulk.at(k))
    assert not per_key._pending
    _, bulk = bal_synthetic(6, 40, 3, seed=2).read()
    a, b = Problem(graph, bulk), Problem(graph, per_key)
    assert bulk._pending  # still arrays
    assert np.array_equal(a.var_keys, b.var_keys) and np.array_equal(a.var_kind, b.var_kind)
    assert [k.name for k in a.kinds] == [k.name for k in b.kinds]
    for x, y in zip(a._initial_storages, b._initial_storages):
        assert np.array_equal(x, y)
    assert a.linearize(a.initial_state()) == b.linearize(b.initial_state())
