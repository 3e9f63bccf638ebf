"""Epsilon handling of removable singularities (SymForce paper Sec. VI) and its checker."""

from __future__ import annotations

import sympy as sp

from fgopt.symbolic import (
    V3,
    Pose2,
    Pose3,
    Rot3,
    check_removable_singularity,
    epsilon,
    sign_no_zero,
)

x = sp.Symbol("x", real=True)


def test_checker_accepts_shifted_sinc_and_rejects_poles():
    shifted = x + sign_no_zero(x) * epsilon
    assert check_removable_singularity(sp.sin(shifted) / shifted, x, 0)
    report = check_removable_singularity(1 / shifted, x, 0)  # a pole: epsilon cannot fix it
    assert not report.ok
    # an unshifted function is not rescued: its value at x0 is NaN for any epsilon
    assert not check_removable_singularity(sp.sin(x) / x, x, 0)


def test_sign_no_zero_is_never_zero():
    assert sign_no_zero(0) == 1 and sign_no_zero(-2) == -1 and sign_no_zero(3) == 1
    assert sp.diff(sign_no_zero(x), x) == 0
    assert sign_no_zero(x) ** 2 == 1


def test_builtin_exp_log_are_safe_at_angle_zero():
    """Value and first derivative of the built-in maps along a line through the identity."""
    # SE(2) Exp: translation part (sin t / t, (1 - cos t) / t) along the rotation angle
    t_se2 = Pose2.exp(V3(x, 1, 2)).t[0]
    assert check_removable_singularity(t_se2, x, 0)
    # SE(2) Log: (t/2) cot(t/2), as a function of the angle t = atan2(s, c)
    from fgopt.symbolic import Rot2

    c, s = sp.symbols("c s", real=True)
    log_se2 = Pose2(Rot2(c, s), [1, 2]).log()[1].xreplace({sp.atan2(s, c): x})
    assert check_removable_singularity(log_se2, x, 0)
    # SO(3) Exp along an axis (SymPy's limits cannot do the atan2 of the logs; the generated
    # Jacobians are checked numerically at angle 0 in test_library.py)
    assert check_removable_singularity(Rot3.exp(V3(x, 0, 0)).q[0], x, 0)
    # SE(3) Exp: the V matrix coefficients multiply the translation
    assert check_removable_singularity(Pose3.exp([x, 0, 0, 1, 2, 3]).t[1], x, 0)
