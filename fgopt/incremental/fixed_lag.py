"""``FixedLagSmoother``: incremental smoothing over a sliding time window.

Every key carries a timestamp (the latest one given for it). After each update, the variables
older than ``lag`` before the newest timestamp are marginalized out: the Schur complement of
the linearized system onto their Markov blanket, with its linearization point, replaces every
factor that touched them (a :class:`~fgopt.incremental.LinearContainerFactor`). As in GTSAM's
``IncrementalFixedLagSmoother``, the old variables are cut from the Bayes tree as whole
subtrees (the smoother orders new variables last, so old ones are normally already at the
leaves; otherwise their cliques are re-eliminated with them first). The window's size is
bounded, so are the work per update and the memory (slots and pool blocks are reused).
"""

from __future__ import annotations

import heapq
import math
from typing import Any, Iterable

from ..errors import FgoptError
from ..factors.base import Factor
from ..graph import FactorGraph
from ..key import Key, as_key, key_str
from ..variables import Variables
from .params import IncrementalParams, UpdateResult
from .smoother import IncrementalSmoother


class FixedLagSmoother:
    """``FixedLagSmoother(lag, params)``; ``update(new_factors, new_values, timestamps)``.

    Variables older than ``lag`` seconds (behind the newest timestamp) are marginalized:

    >>> from fgopt import SE2, BetweenFactor, PriorFactor
    >>> from fgopt.incremental import FixedLagSmoother
    >>> from fgopt.noise import Isotropic
    >>> noise, step = Isotropic.sigma(3, 0.1), SE2.from_xytheta(1.0, 0.0, 0.0)
    >>> smoother = FixedLagSmoother(1.0)
    >>> r = smoother.update([PriorFactor(key('x', 0), SE2(), noise)], {key('x', 0): SE2()},
    ...                     {key('x', 0): 0.0})
    >>> for i in range(1, 4):                 # a pose a second
    ...     r = smoother.update([BetweenFactor(key('x', i - 1), key('x', i), step, noise)],
    ...                         {key('x', i): SE2.from_xytheta(i, 0.0, 0.0)}, {key('x', i): i})
    >>> smoother.keys(), r.marginalized_keys
    ([x2, x3], [x1])
    >>> smoother.estimate(key('x', 3)).equals(SE2.from_xytheta(3.0, 0.0, 0.0), 1e-9)
    True
    """

    def __init__(self, lag: float, params: IncrementalParams | None = None):
        lag = float(lag)
        if not lag >= 0 or math.isinf(lag):
            raise FgoptError(f"FixedLagSmoother: lag must be a finite number >= 0, got {lag}")
        self.lag = lag
        self.smoother = IncrementalSmoother(params)
        self._time: dict[Key, float] = {}
        self._heap: list[tuple[float, int]] = []
        self._now = -math.inf

    @property
    def params(self) -> IncrementalParams:
        return self.smoother.params

    def update(self, new_factors: "FactorGraph | Iterable[Factor]" = (),
               new_values: "Variables | dict | None" = None,
               timestamps: "dict | None" = None, remove: Iterable[int] = ()) -> UpdateResult:
        """Add factors and variables (every new key needs a timestamp; a known key's timestamp
        may move forward), then marginalize the keys older than ``lag``.

        Returns the incremental update's :class:`UpdateResult`; ``result.marginalized_keys``
        lists the keys marginalized out.
        """
        stamps = {}
        for k, t in (timestamps or {}).items():
            t = float(t)
            if not math.isfinite(t):
                raise FgoptError(f"FixedLagSmoother: timestamp of {key_str(as_key(k))} is {t}")
            stamps[as_key(k)] = t
        new_keys = list(new_values.keys()) if new_values is not None else []
        for k in new_keys:
            if as_key(k) not in stamps:
                raise FgoptError(f"FixedLagSmoother: new variable {key_str(as_key(k))} has no "
                                 "timestamp")
        for k in stamps:
            if k not in self._time and k not in set(map(as_key, new_keys)):
                raise FgoptError(f"FixedLagSmoother: timestamp given for {key_str(k)}, which "
                                 "is neither a variable of the smoother nor in new_values")
        result = self.smoother.update(new_factors, new_values, remove)
        for k, t in stamps.items():
            if t > self._time.get(k, -math.inf):
                self._time[k] = t
                heapq.heappush(self._heap, (t, int(k)))
            self._now = max(self._now, t)
        for k in result.removed_keys:
            self._time.pop(k, None)
        old = []
        horizon = self._now - self.lag
        while self._heap and self._heap[0][0] < horizon:
            t, k = heapq.heappop(self._heap)
            k = Key(k)
            if self._time.get(k) == t:          # not a stale entry of a re-stamped key
                old.append(k)
                del self._time[k]
        result.marginalized_keys = old
        if old:
            self.smoother.marginalize(old)
        return result

    # ------------------------------------------------------------------ reading
    def estimate(self, key: Any = None) -> Any:
        """The window's estimates (or one key's), see :meth:`IncrementalSmoother.estimate`."""
        return self.smoother.estimate(key)

    def marginal(self, key: Any) -> Any:
        return self.smoother.marginal(key)

    def cost(self) -> float:
        """Cost of the window's factors (marginal priors included) at the estimate."""
        return self.smoother.cost()

    def timestamps(self) -> dict[Key, float]:
        return dict(self._time)

    def keys(self) -> list[Key]:
        return self.smoother.keys()

    def factors(self) -> FactorGraph:
        return self.smoother.factors()

    def __len__(self) -> int:
        return len(self.smoother)

    def __contains__(self, k: object) -> bool:
        return k in self.smoother

    def __repr__(self) -> str:
        return (f"FixedLagSmoother(lag={self.lag:g}, {len(self.smoother)} variables in the "
                f"window, {len(self.smoother._facs)} factors)")
