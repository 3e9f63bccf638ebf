"""One keyword for a factor's noise model or robust loss: ``loss=`` (``@fgopt.factor``,
``PriorFactor``, ``BetweenFactor``, the camera and GPS factors). ``noise=`` is an old alias."""

from __future__ import annotations

import warnings
from typing import Any

from ..errors import FgoptError

#: ``noise=`` was not given.
UNSET: Any = object()

#: Keywords a GTSAM user may try for the noise model; error messages point them to ``loss=``.
NOISE_KEYWORDS = ("noise", "noise_model", "noiseModel", "model", "sigma", "sigmas")


def loss_argument(loss: Any, noise: Any, where: str) -> Any:
    """``loss``, or the value of the deprecated ``noise=`` (with a DeprecationWarning)."""
    if noise is UNSET:
        return loss
    if loss is not None:
        raise FgoptError(f"{where}: got both loss= and noise=; pass the noise model once, as "
                         "loss=")
    warnings.warn(f"{where}: noise= is deprecated, pass the noise model or robust loss as loss=",
                  DeprecationWarning, stacklevel=3)
    return noise


def unknown_keyword_hint(name: str) -> str:
    """What to say about an unknown keyword ``name`` of a factor (empty if nothing)."""
    if name in NOISE_KEYWORDS:
        return "; a noise model or robust loss goes in loss="
    return ""
