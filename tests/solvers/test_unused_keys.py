"""Keys in the initial values that no factor uses: a warning, and ``result.unused_keys``."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import fgopt
from fgopt import SE2, BetweenFactor, FactorGraph, PriorFactor, Variables, key
from fgopt.manifolds.base import ops_for
from fgopt.noise import Diagonal


def graph_and_values():
    g = FactorGraph()
    noise = Diagonal.sigmas([0.1, 0.5, 0.5])
    g.add(PriorFactor(key("x", 1), SE2.from_xytheta(0, 0, 0), noise))
    g.add(BetweenFactor(key("x", 1), key("x", 2), SE2.from_xytheta(5, 0, 0), noise))
    v = Variables()
    v.add(key("x", 1), SE2.from_xytheta(0.2, -0.3, 0.2))
    v.add(key("x", 2), SE2.from_xytheta(5.1, 0.3, -0.1))
    return g, v


@pytest.mark.parametrize("method", ["lm", "gn", "dogleg", "gnc"])
def test_unused_initial_keys_warn_and_are_reported(method):
    """An initial key no factor uses (a typo'd x3 instead of a factor on it) is warned about,
    listed in ``result.unused_keys`` and the repr, and returned unchanged."""
    g, v = graph_and_values()
    v.add(key("x", 3), SE2.from_xytheta(9, 9, 0))
    v.add(key("l", 0), np.array([1.0, 2.0]))
    with pytest.warns(fgopt.FgoptWarning, match=r"2 key\(s\) .* used by no factor \(x3, l0\)"):
        r = fgopt.optimize(g, v, method=method)
    assert r.success, r
    assert r.unused_keys == (key("x", 3), key("l", 0))
    assert "unused: 2 initial key(s) no factor uses (x3, l0)" in repr(r)
    assert r.values.at(key("x", 3)).equals(SE2.from_xytheta(9, 9, 0), 0.0)


def test_no_warning_when_every_key_is_used():
    """A graph that uses every initial key warns nothing and reports no unused keys."""
    g, v = graph_and_values()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = fgopt.optimize(g, v)
    assert r.unused_keys == () and "unused" not in repr(r)


def test_values_from_bulk_rows_keep_the_initial_order_and_unused_rows():
    """Initial values added in bulk (``add_rows``, what file readers do) with an unused key in
    the middle: the result has every key in the initial order, the unused one unchanged, the
    others optimized, and the caller's Variables still holds its bulk rows untouched."""
    g, _ = graph_and_values()
    x1, x2, x3 = key("x", 1), key("x", 2), key("x", 3)
    v = Variables()
    v.add(key("l", 0), np.array([1.0, 2.0]))
    first = SE2.from_xytheta(0.2, -0.3, 0.2)
    kind = ops_for(first).batch_kind(first)
    rows = np.array([first.to_storage(), SE2.from_xytheta(9, 9, 0).to_storage(),
                     SE2.from_xytheta(5.1, 0.3, -0.1).to_storage()])
    v.add_rows(np.array([x1, x3, x2]), kind, rows)
    with pytest.warns(fgopt.FgoptWarning):
        r = fgopt.optimize(g, v)
    assert r.success
    assert list(r.values.keys()) == [key("l", 0), x1, x3, x2]
    assert r.values.at(x3).equals(SE2.from_xytheta(9, 9, 0), 0.0)
    assert r.values.at(x2).equals(SE2.from_xytheta(5, 0, 0), 1e-6)
    assert len(v._pending) == 1 and v._pending[0].rows is not None
    assert np.array_equal(v._pending[0].rows, rows)


def test_values_from_one_bulk_block_keep_its_order_and_match_the_general_path():
    """Initial values that are one bulk block of one kind, every key used, keys not in graph
    order (a file's poses): the result is one block of storage rows (objects made when read)
    with the block's key order, Key keys, read-only values equal to the per-kind path's
    (``values_as_rows``), and does not share rows with the problem's state."""
    g, _ = graph_and_values()
    x1, x2 = key("x", 1), key("x", 2)
    first, second = SE2.from_xytheta(0.2, -0.3, 0.2), SE2.from_xytheta(5.1, 0.3, -0.1)
    v = Variables()
    v.add_rows(np.array([x2, x1]), ops_for(first).batch_kind(first),
               np.array([second.to_storage(), first.to_storage()]))
    r = fgopt.optimize(g, v)
    assert r.success
    out = r.values
    assert len(out._pending) == 1 and not out._dict
    assert not any(np.shares_memory(out._pending[0].rows, s) for s in r.state.storages)
    assert list(out.keys()) == [x2, x1] and all(type(k) is fgopt.Key for k in out.keys())
    rows = r.problem.values_as_rows(r.state)
    for k in (x1, x2):
        assert type(out.at(k)) is SE2 and not out.at(k)._data.flags.writeable
        assert np.array_equal(out.at(k).to_storage(), rows.at(k).to_storage())
        assert not any(np.shares_memory(out.at(k)._data, s) for s in r.state.storages)
    assert out.at(x2).equals(SE2.from_xytheta(5, 0, 0), 1e-6)
