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
