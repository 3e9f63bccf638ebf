"""Keys in the initial values that no factor uses: a warning, and ``result.unused_keys``."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import fgopt
from fgopt import SE2, BetweenFactor, FactorGraph, PriorFactor, Variables, key
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


@pytest.mark.parametrize("method", ["lm", "gn", "dogleg", "gnc", "fixed"])
def test_unused_initial_keys_warn_and_are_reported(method):
    """An initial key no factor uses (a typo'd x3 instead of a factor on it) is warned about,
    listed in ``result.unused_keys`` and the repr, and returned unchanged."""
    g, v = graph_and_values()
    v.add(key("x", 3), SE2.from_xytheta(9, 9, 0))
    v.add(key("l", 0), np.array([1.0, 2.0]))
    kw = {"formulation": "fixed"} if method == "fixed" else {"method": method}
    with pytest.warns(fgopt.FgoptWarning, match=r"2 key\(s\) .* used by no factor \(x3, l0\)"):
        r = fgopt.optimize(g, v, **kw)
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
