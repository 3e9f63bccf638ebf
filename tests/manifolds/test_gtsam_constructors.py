"""GTSAM conveniences a porting user looks for: ``SO3.ypr`` / ``rz_ry_rx`` / ``rodrigues`` equal
``gtsam.Rot3.Ypr`` / ``RzRyRx`` / ``Rodrigues`` numerically, and ``fgopt.symbol_shorthand``'s
``X(i)`` keys equal ``key('x', i)`` (and GTSAM's symbol_shorthand integers)."""

import numpy as np
import pytest

import fgopt
from fgopt import SO3, key

gtsam = pytest.importorskip("gtsam")

ANGLES = [(0.1, 0.2, 0.3), (-2.5, 1.2, 0.7), (3.0, -1.5, -3.1), (0.0, np.pi / 2, 0.0),
          (1e-9, 0.0, -1e-9)]


@pytest.mark.parametrize("a", ANGLES)
def test_ypr_and_rz_ry_rx_match_gtsam(a):
    """Same matrix as GTSAM for the same arguments (including gimbal lock, pitch = pi/2)."""
    y, p, r = a
    assert np.allclose(SO3.ypr(y, p, r).matrix(), gtsam.Rot3.Ypr(y, p, r).matrix(), atol=1e-12)
    assert np.allclose(SO3.rz_ry_rx(*a).matrix(), gtsam.Rot3.RzRyRx(*a).matrix(), atol=1e-12)


@pytest.mark.parametrize("w", [[0.1, -0.2, 0.3], [0.0, 0.0, 0.0], [np.pi - 1e-7, 0, 0],
                               [1e-8, 2e-8, -1e-8], [1.0, 2.0, 2.0]])
def test_rodrigues_matches_gtsam(w):
    """``SO3.rodrigues(w)`` equals ``Rot3.Rodrigues(w)`` (rotation vector, radians)."""
    assert np.allclose(SO3.rodrigues(w).matrix(), gtsam.Rot3.Rodrigues(np.array(w, float)).matrix(),
                       atol=1e-12)


def test_symbol_shorthand_keys():
    """``X(1)`` is ``key('x', 1)``, prints ``x1``, and is GTSAM's integer for ``X(1)``."""
    from fgopt.symbol_shorthand import B, L, V, X

    assert X(1) == key("x", 1) and repr(L(42)) == "l42"
    for ours, theirs in ((X, gtsam.symbol_shorthand.X), (L, gtsam.symbol_shorthand.L),
                         (V, gtsam.symbol_shorthand.V), (B, gtsam.symbol_shorthand.B)):
        assert int(ours(7)) == int(theirs(7))
    assert fgopt.symbol_shorthand.X(3) == key("x", 3)
