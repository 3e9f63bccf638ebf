"""One keyword for the noise model everywhere (``loss=``; ``noise=`` a deprecated alias), an
unknown ``noise=`` pointing to ``loss=``, and a NaN constant named by its argument."""

from __future__ import annotations

import numpy as np
import pytest

from fgopt import key
from fgopt.cameras import Cal3_S2, Cal3_S2Stereo, ProjectionFactor, StereoFactor
from fgopt.cameras.smart import SmartProjectionFactor
from fgopt.errors import FgoptError, NonFiniteError
from fgopt.navigation import GpsFactor
from fgopt.noise import Isotropic

from .test_decorator import pose_prior_xy, range_bearing

N2, N3 = Isotropic.sigma(2, 0.5), Isotropic.sigma(3, 0.5)
K = Cal3_S2(500.0, 500.0, 0.0, 320.0, 240.0)


def _camera_factors(kw: str):
    x, p = key("x", 0), key("l", 0)
    return [ProjectionFactor(x, p, [1.0, 2.0], calibration=K, **{kw: N2}),
            StereoFactor(x, p, [1.0, 0.5, 2.0],
                         calibration=Cal3_S2Stereo(500.0, 500.0, 0.0, 320.0, 240.0, 0.1),
                         **{kw: N3}),
            SmartProjectionFactor([x, key("x", 1)], [[1.0, 2.0], [3.0, 4.0]], K, **{kw: N2}),
            GpsFactor(x, [1.0, 2.0, 3.0], **{kw: N3})]


def test_loss_keyword_on_camera_and_gps_factors():
    """``loss=`` is the keyword of the camera, smart and GPS factors, as of Prior/Between and
    ``@fgopt.factor``; the same noise model is used (same whitening)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        new = _camera_factors("loss")
    with pytest.warns(DeprecationWarning, match="noise= is deprecated.*loss="):
        old = _camera_factors("noise")
    for a, b in zip(new, old):
        assert a.loss is b.loss or a.loss == b.loss or getattr(a, "pixel_noise", 1) is \
            getattr(b, "pixel_noise", 1)
    with pytest.raises(FgoptError, match="both loss= and noise="):
        GpsFactor(key("x", 0), [1.0, 2.0, 3.0], loss=N3, noise=N3)


def test_unknown_noise_keyword_names_loss():
    """``my_factor(..., noise=...)`` says the noise model goes in ``loss=``."""
    with pytest.raises(FgoptError, match=r"unknown argument 'noise'.*loss="):
        range_bearing(key("x", 0), key("l", 0), np.array([1.0, 0.2]), noise=N2)


def test_nan_constant_names_its_argument():
    """A NaN in a constant of an ``@fgopt.factor`` names the argument; a NaN GPS fix names the
    position (or the lever arm)."""
    with pytest.raises(NonFiniteError, match=r"argument 'y' has a NaN"):
        pose_prior_xy(key("x", 0), 1.0, float("nan"), loss=N2)
    with pytest.raises(NonFiniteError, match=r"argument 'measured' has a NaN"):
        range_bearing(key("x", 0), key("l", 0), np.array([np.nan, 0.2]), loss=N2)
    with pytest.raises(NonFiniteError, match=r"GpsFactor: position has a NaN"):
        GpsFactor(key("x", 0), [1.0, np.nan, 3.0], N3)
    with pytest.raises(NonFiniteError, match=r"GpsFactor: lever_arm has a NaN"):
        GpsFactor(key("x", 0), [1.0, 2.0, 3.0], N3, lever_arm=[0.0, np.inf, 0.0])
