"""Parameters and per-update results of the incremental smoother (iSAM2's names where they exist).

Defaults follow GTSAM's ``ISAM2Params`` (relinearize threshold 0.1, skip 10, wildfire 0.001,
batch step when 65 % of the variables are re-eliminated), so results compare with ISAM2's
directly. ``benchmarks/incremental_params.py`` measures them, one field changed at a time
(results/incremental-params-2026-11-24.md, a loaded 2-core machine, CPU seconds):

* ``relinearize_skip`` 1 or 3 instead of 10: no better final cost (M3500 -0.008 %, Victoria
  Park +0.007 %) for 0.9-1.7x the time and a higher 99th-percentile update;
* ``wildfire_threshold`` 0 (exact back-substitution at every read): 1.5-2.3x the time; the
  final estimate is already exact (``estimate()`` back-substitutes fully);
* ``batch_threshold`` 0.5 / 0.8 / never: within the run-to-run noise of 0.65 on M3500 and
  Victoria Park (0.5 is 1.4x slower on Victoria Park);
* ``fill_refresh`` inf / 1.5: no difference where batch steps happen anyway; it is the
  safeguard that reorders when they do not (one reorder on Victoria Park without batch steps);
* ``extra_steps=1``: 1.1-2x the time for a final cost 0.01 % lower (M3500) or 0.008 % higher.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import FgoptError


@dataclass(frozen=True)
class IncrementalParams:
    """Settings of :class:`~fgopt.incremental.IncrementalSmoother`.

    Example:

    >>> params = fgopt.IncrementalParams(relinearize_threshold=0.05, relinearize_skip=1)
    >>> params.relinearize_threshold, params.relinearize_skip
    (0.05, 1)
    """

    #: A variable is relinearized when some ``|delta_i| >= threshold_i`` (tangent coordinates,
    #: rotation first). A float for every component of every variable, or a dict keyed by key
    #: character (``'x'``), manifold kind name (``'SE2'``, ``'R2'``) or ``'default'``, whose
    #: values are a float or one threshold per tangent component (GTSAM's per-symbol vectors).
    relinearize_threshold: Any = 0.1
    #: Check for relinearization every ``relinearize_skip`` updates (iSAM2's relinearizeSkip).
    relinearize_skip: int = 10
    #: False: never relinearize (every factor stays at the point where it was added).
    enable_relinearization: bool = True
    #: Back-substitution stops descending into unchanged subtrees where no separator variable
    #: moved by more than this (iSAM2's wildfire threshold); 0 solves exactly.
    wildfire_threshold: float = 0.001
    #: Extra Gauss-Newton passes per update: relinearize every variable above the threshold
    #: and re-eliminate, until none is or this many passes ran.
    extra_steps: int = 0
    #: When an update's top holds at least this fraction of all variables, every variable is
    #: reordered (fill-reducing order of the whole graph) and re-eliminated (iSAM2: 0.65).
    batch_threshold: float = 0.65
    #: Reorder everything when the factor's stored entries per variable exceed this multiple
    #: of their value after the last full ordering (the frozen orders of untouched subtrees
    #: age as the graph grows); ``inf`` disables.
    fill_refresh: float = 2.0
    #: A pivot below ``pivot_tolerance`` x its assembled diagonal means the variable is not
    #: constrained (the update is refused).
    pivot_tolerance: float = 1e-12

    def __post_init__(self):
        if int(self.relinearize_skip) < 1:
            raise FgoptError("relinearize_skip must be >= 1")
        if self.wildfire_threshold < 0 or self.extra_steps < 0:
            raise FgoptError("wildfire_threshold and extra_steps must be >= 0")
        if not 0.0 < self.batch_threshold:
            raise FgoptError("batch_threshold must be positive (> 1 disables batch steps)")
        thr = self.relinearize_threshold
        values = thr.values() if isinstance(thr, dict) else [thr]
        for v in values:
            if np.any(np.asarray(v, dtype=float) < 0):
                raise FgoptError(f"relinearize_threshold must be >= 0, got {v!r}")


@dataclass
class UpdateResult:
    """What one :meth:`~fgopt.incremental.IncrementalSmoother.update` did.

    >>> from fgopt import SE2, BetweenFactor, PriorFactor
    >>> from fgopt.incremental import IncrementalSmoother
    >>> from fgopt.noise import Isotropic
    >>> noise, step = Isotropic.sigma(3, 0.1), SE2.from_xytheta(1.0, 0.0, 0.0)
    >>> isam = IncrementalSmoother()
    >>> r = isam.update([PriorFactor(key('x', 0), SE2(), noise)], {key('x', 0): SE2()})
    >>> r = isam.update([BetweenFactor(key('x', 0), key('x', 1), step, noise)], {key('x', 1): step})
    >>> r.new_factor_indices, r.variables_reeliminated     # the second factor; both poses
    ([1], 2)
    """

    #: Handles of the new factors (pass them to ``remove=`` to delete a factor later).
    new_factor_indices: list[int] = field(default_factory=list)
    #: Variables whose linearization point moved (``theta <- theta (+) delta``).
    variables_relinearized: int = 0
    #: Variables re-eliminated (the top of the Bayes tree, new ones included).
    variables_reeliminated: int = 0
    #: Factors linearized in this update (new ones and those of relinearized variables).
    factors_relinearized: int = 0
    #: Cliques created by re-elimination, and cliques in the tree afterwards.
    cliques_reeliminated: int = 0
    cliques: int = 0
    #: True when everything was reordered and re-eliminated (a batch step).
    batch: bool = False
    #: Keys removed because removing factors left them without any.
    removed_keys: list = field(default_factory=list)
    #: Keys a :class:`~fgopt.incremental.FixedLagSmoother` marginalized out after the update.
    marginalized_keys: list = field(default_factory=list)
    #: Keys relinearized (int64 array).
    relinearized_keys: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    #: Seconds: ``check`` (adding), ``linearize``, ``tree`` (re-elimination and
    #: back-substitution; ``order`` for large tops ordered by CHOLMOD), ``total``.
    timing: dict = field(default_factory=dict)

    @classmethod
    def _of(cls, fields: dict) -> "UpdateResult":
        """An UpdateResult from a dict of every one of its fields, without the generated
        ``__init__`` (~2 us of an update's ~100; a dict display costs less than keywords)."""
        out = object.__new__(cls)
        out.__dict__ = fields
        return out

    def __repr__(self) -> str:
        return (f"UpdateResult({len(self.new_factor_indices)} new factors, "
                f"{self.variables_relinearized} relinearized, {self.variables_reeliminated} "
                f"re-eliminated in {self.cliques_reeliminated} cliques"
                f"{' (batch)' if self.batch else ''}, {self.cliques} cliques, "
                f"{1e3 * self.timing.get('total', 0.0):.3f} ms)")
