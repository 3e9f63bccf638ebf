"""Key shorthands as GTSAM's ``gtsam.symbol_shorthand``: ``X(1)`` is ``key('x', 1)``, for every
letter ``A``-``Z`` (by custom ``B`` bias, ``L`` landmark, ``V`` velocity, ``X`` pose).

>>> from fgopt.symbol_shorthand import B, L, V, X
>>> X(1), L(42)
(x1, l42)
"""

from __future__ import annotations

from functools import partial

from .key import key

__all__ = [chr(c) for c in range(ord("A"), ord("Z") + 1)]

for _name in __all__:
    globals()[_name] = partial(key, _name.lower())
del _name
