"""Pose noise by component: ``Diagonal.pose2(x=, y=, theta=)``, ``pose3``, ``sim3`` put sigmas in
fgopt's tangent order (rotation first) and say the order in their repr; the resulting prior
costs equal GTSAM's for the same sigmas given in GTSAM's own order."""

from __future__ import annotations

import numpy as np
import pytest

import fgopt
from fgopt import SE2, SE3, PriorFactor, Variables, key
from fgopt.errors import DimensionMismatchError, FgoptError
from fgopt.noise import Diagonal, Isotropic


def test_pose2_by_component_is_rotation_first_and_says_so():
    """Sigmas land as [theta, x, y]; the repr names each component and the tangent order."""
    m = Diagonal.pose2(x=0.5, y=0.6, theta=0.1)
    assert np.allclose(m.sigma_values, [0.1, 0.5, 0.6])
    assert repr(m) == "Diagonal.pose2(sigmas theta=0.1, x=0.5, y=0.6; tangent order [theta, x, y])"


def test_pose3_and_sim3_by_component():
    """pose3 takes one or three sigmas per part, order [w, v]; sim3 adds log-scale last."""
    m = Diagonal.pose3(rotation=0.1, translation=[0.3, 0.4, 0.5])
    assert np.allclose(m.sigma_values, [0.1, 0.1, 0.1, 0.3, 0.4, 0.5])
    assert "tangent order [wx, wy, wz, x, y, z]" in repr(m)
    s = Diagonal.sim3(rotation=[0.1, 0.2, 0.3], translation=1.0, scale=0.05)
    assert np.allclose(s.sigma_values, [0.1, 0.2, 0.3, 1, 1, 1, 0.05])
    assert "log_s=0.05" in repr(s)
    with pytest.raises(DimensionMismatchError, match="rotation"):
        Diagonal.pose3(rotation=[0.1, 0.2], translation=1.0)
    with pytest.raises(FgoptError):
        Diagonal.pose2(x=-1.0, y=1.0, theta=1.0)
    with pytest.raises(FgoptError):
        Diagonal.sigmas("abc")


def test_plain_models_show_their_sigmas():
    """Plain diagonal and isotropic models print their sigmas (not only their dimension)."""
    assert repr(Diagonal.sigmas([0.1, 0.5])) == "Diagonal(sigmas=[0.1, 0.5])"
    assert repr(Isotropic.sigma(3, 0.2)) == "Isotropic(dim=3, sigma=0.2)"


def test_pose2_prior_cost_matches_gtsam_with_gtsam_order_sigmas():
    """A Pose2 prior with GTSAM sigmas [x, y, theta] = [0.5, 0.6, 0.1] costs the same in GTSAM
    as fgopt's prior with Diagonal.pose2(x=0.5, y=0.6, theta=0.1); passing GTSAM's vector to
    Diagonal.sigmas (the porting mistake) does not."""
    gtsam = pytest.importorskip("gtsam")
    prior, x = (0.3, -0.2, 0.4), (1.0, 0.5, -0.3)
    gm = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.5, 0.6, 0.1]))
    gf = gtsam.PriorFactorPose2(1, gtsam.Pose2(*prior), gm)
    gv = gtsam.Values()
    gv.insert(1, gtsam.Pose2(*x))
    expected = gf.error(gv)
    v = Variables().add(key("x", 1), SE2.from_xytheta(*x))
    named = PriorFactor(key("x", 1), SE2.from_xytheta(*prior), Diagonal.pose2(x=0.5, y=0.6,
                                                                              theta=0.1))
    naive = PriorFactor(key("x", 1), SE2.from_xytheta(*prior), Diagonal.sigmas([0.5, 0.6, 0.1]))
    assert np.isclose(named.cost(v), expected, rtol=1e-9)
    assert not np.isclose(naive.cost(v), expected, rtol=1e-3)


def test_pose3_prior_cost_matches_gtsam():
    """GTSAM's Pose3 noise is [rotation, translation] as fgopt's: pose3() matches it."""
    gtsam = pytest.importorskip("gtsam")
    rot, trans = np.array([0.1, 0.2, 0.05]), np.array([0.3, 0.4, 0.5])
    prior = SE3.exp(np.array([0.1, -0.2, 0.3, 1.0, 2.0, -1.0]))
    x = SE3.exp(np.array([0.3, 0.1, -0.2, 0.5, 1.5, -0.5]))
    gm = gtsam.noiseModel.Diagonal.Sigmas(np.concatenate([rot, trans]))
    gf = gtsam.PriorFactorPose3(1, gtsam.Pose3(prior.matrix()), gm)
    gv = gtsam.Values()
    gv.insert(1, gtsam.Pose3(x.matrix()))
    v = Variables().add(key("x", 1), x)
    f = PriorFactor(key("x", 1), prior, Diagonal.pose3(rotation=rot, translation=trans))
    assert np.isclose(f.cost(v), gf.error(gv), rtol=1e-9)
    assert fgopt.FgoptError is FgoptError
