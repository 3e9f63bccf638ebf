"""Parameter objects reject values that are not numbers of the right kind with an
``FgoptError`` naming the field (a negative iteration limit used to run 0 iterations and report
"max iterations"; a string limit was silently converted; ``int("abc")`` escaped as a ValueError)."""

from __future__ import annotations

import numpy as np
import pytest

import fgopt
from fgopt.errors import FgoptError
from fgopt.solvers import DoglegParams, GaussNewtonParams, GNCParams, LMParams


@pytest.mark.parametrize("cls", [LMParams, GaussNewtonParams, DoglegParams])
@pytest.mark.parametrize("field, value", [
    ("max_iterations", -1), ("max_iterations", "3"), ("max_iterations", 2.5),
    ("max_iterations", True), ("relative_tolerance", float("nan")),
    ("absolute_tolerance", -1e-5), ("gradient_tolerance", float("inf")), ("threads", 0)])
def test_bad_termination_numbers_name_the_field(cls, field, value):
    """Every method's params refuse a bad iteration limit, tolerance or thread count."""
    with pytest.raises(FgoptError, match=f"{cls.__name__}.{field}"):
        cls(**{field: value})


@pytest.mark.parametrize("field, value", [("min_lambda", 0.0), ("initial_lambda", -1.0),
                                          ("lambda_factor", float("nan"))])
def test_bad_damping_numbers_name_the_field(field, value):
    """LM's damping settings must be positive numbers."""
    with pytest.raises(FgoptError, match=f"LMParams.{field}"):
        LMParams(**{field: value})


@pytest.mark.parametrize("field, value", [("mu_step", 1.0), ("inlier_probability", 1.0),
                                          ("snooping_alpha", 0.0), ("max_rounds", -1),
                                          ("time_limit", 0.0)])
def test_bad_gnc_numbers_name_the_field(field, value):
    """GNC's schedule, probabilities and limits are checked when the params are built."""
    with pytest.raises(FgoptError, match=f"GNCParams.{field}"):
        GNCParams(**{field: value})


def test_good_values_still_accepted():
    """Defaults, NumPy integers and whole floats (stored as ``int``, as the kernels take), ``None``
    where the default is ``None`` and 0 tolerances pass."""
    p = LMParams(max_iterations=np.int64(7), relative_tolerance=None, absolute_tolerance=0.0)
    assert p.max_iterations == 7 and type(p.max_iterations) is int
    assert type(LMParams(max_iterations=20.0).max_iterations) is int  # a whole float: stored int
    assert GNCParams(time_limit=None, max_rounds=0).max_rounds == 0
    assert DoglegParams(initial_radius=0.5).initial_radius == 0.5


def test_optimize_keyword_is_checked_too():
    """``fgopt.optimize(max_iterations=...)`` goes through the same check (no int() of a
    string, no silent truncation of 2.7)."""
    sample = fgopt.datasets.manhattan_2d(num_poses=5, seed=0)
    for bad in ("abc", 2.7, -3):
        with pytest.raises(FgoptError, match="max_iterations"):
            fgopt.optimize(sample.graph, sample.initial, max_iterations=bad)
