"""``FactorGraph``: a list of factors, with cost evaluation and an informative summary."""

from __future__ import annotations

from collections import Counter
from typing import Any, Iterable, Iterator

import numpy as np

from .errors import FgoptError, FgoptIndexError
from .factors.base import Factor
from .key import Key, key_str


def factor_type_name(f: Factor) -> str:
    return f.kernel.name if f.kernel is not None else type(f).__name__


class FactorGraph:
    """Factors over keyed variables: the nonlinear least-squares problem.

    ``error(values)`` is ``0.5 * sum |R_i e_i|^2`` (robust factors contribute ``rho``), the cost
    GTSAM's ``NonlinearFactorGraph.error`` and Ceres report.

    Constraints (:func:`fgopt.constraint` instances) added with ``add`` are kept apart, in
    ``constraints``: they are not part of the cost; :func:`fgopt.optimize` enforces them.

    Example:

    >>> from fgopt import SE2, PriorFactor, BetweenFactor
    >>> from fgopt.noise import Isotropic
    >>> graph = fgopt.FactorGraph()
    >>> noise = Isotropic.sigma(3, 0.1)
    >>> graph.add(PriorFactor(key('x', 0), SE2(), noise)).add(BetweenFactor(key('x', 0), key('x', 1), SE2.from_xytheta(1, 0, 0), noise))
    FactorGraph(2 factors on 2 keys)
             1 x prior_pose2
             1 x between_pose2
    >>> len(graph), graph.keys()
    (2, [x0, x1])
    >>> values = fgopt.Variables().add(key('x', 0), SE2()).add(key('x', 1), SE2.from_xytheta(1.1, 0, 0))
    >>> round(graph.error(values), 6)
    0.5
    """

    def __init__(self, factors: Iterable[Factor] = ()):
        self._factors: list[Factor] = []
        self._batches: list = []  # FactorBatch: vectorized factors (see fgopt.batch)
        self._constraints: list = []  # fgopt.factors.constraint.Constraint
        for f in factors:
            self.add(f)

    def add(self, factor: Factor) -> "FactorGraph":
        if not isinstance(factor, Factor):
            raise FgoptError(
                f"FactorGraph.add expects a Factor, got {type(factor).__name__}: derive your "
                "factor from fgopt.factors.Factor (or NumericalFactor)")
        if not hasattr(factor, "loss") or not hasattr(factor, "keys"):
            raise FgoptError(
                f"{type(factor).__name__} was not initialized: call "
                "super().__init__(keys, dim, loss) in its __init__")
        if getattr(factor, "is_constraint", False):
            self._constraints.append(factor)
            return self
        self._factors.append(factor)
        return self

    def add_batch(self, kernel, keys, constants, sqrt_information=None, loss_code: int = 0,
                  loss_param: float = 0.0, origin=None,
                  loss_shape: float = 0.0) -> "FactorGraph":
        """Add ``n`` factors of one kernel from arrays (see :class:`fgopt.batch.FactorBatch`).

        The vectorized way to build large graphs (file readers use it): no Python object per
        factor. Iterating the graph materializes them on demand.
        """
        from .batch import FactorBatch

        b = FactorBatch(kernel, keys, constants, sqrt_information, loss_code, loss_param,
                        loss_shape, origin)
        if len(b) > 0:
            self._batches.append(b)
        return self

    @property
    def batches(self) -> list:
        return self._batches

    @property
    def constraints(self) -> list:
        """The constraints (``g(x) = 0`` / ``h(x) <= 0``), in the order they were added."""
        return self._constraints

    def copy(self) -> "FactorGraph":
        """A new graph with the same factors and batches (adding to it leaves this one alone)."""
        out = FactorGraph(self._factors)
        out._batches = list(self._batches)
        out._constraints = list(self._constraints)
        return out

    def extend(self, factors: Iterable[Factor]) -> "FactorGraph":
        for f in factors:
            self.add(f)
        return self

    def __iadd__(self, other: "FactorGraph | Iterable[Factor]") -> "FactorGraph":
        return self.extend(other)

    @property
    def factors(self) -> list[Factor]:
        """The individually added factors (batches are in ``batches``)."""
        return self._factors

    def __len__(self) -> int:
        return len(self._factors) + sum(len(b) for b in self._batches)

    def __iter__(self) -> Iterator[Factor]:
        yield from self._factors
        for b in self._batches:
            for i in range(len(b)):
                yield b.factor(i)

    def __getitem__(self, i: int) -> Factor:
        if isinstance(i, bool) or not isinstance(i, (int, np.integer)):
            raise FgoptError(f"FactorGraph index must be an int, got {i!r}")
        i = int(i)
        if i < 0:
            i += len(self)
        if 0 <= i < len(self._factors):
            return self._factors[i]
        j = i - len(self._factors)
        for b in self._batches:
            if j < len(b):
                return b.factor(j)
            j -= len(b)
        raise FgoptIndexError(f"factor index {i} out of range ({len(self)} factors)")

    def keys(self) -> list[Key]:
        """All keys any factor touches, in first-use order."""
        seen: dict[Key, None] = {}
        for f in self._factors:
            for k in f.keys:
                seen.setdefault(k, None)
        for b in self._batches:
            for k in dict.fromkeys(b.keys.reshape(-1).tolist()):
                seen.setdefault(Key(k), None)
        return list(seen)

    def error(self, values: Any) -> float:
        """``0.5 * sum`` of squared whitened residuals (robust: sum of rho)."""
        from .problem import Problem

        if len(self) == 0:
            return 0.0
        problem = Problem(self, values, ordering=None, build_structure=False)
        return problem.cost(problem.initial_state())

    def compile(self, values: Any, ordering: str = "amd"):
        """Compile against ``values`` once: batches, storage arrays, H's pattern, scatter map.

        Returns a :class:`fgopt.problem.Problem`; ``optimize`` does this itself.
        """
        from .problem import Problem

        return Problem(self, values, ordering=ordering)

    def errors(self, values: Any) -> list[float]:
        """Per-factor cost, in the order the factors were added (slow; for inspection)."""
        return [f.cost(values) for f in self]

    def type_counts(self) -> Counter:
        counts = Counter(factor_type_name(f) for f in self._factors)
        for b in self._batches:
            counts[b.kernel.name] += len(b)
        return counts

    def __repr__(self) -> str:
        if len(self) == 0:
            return "FactorGraph(empty)"
        counts = self.type_counts()
        lines = [f"FactorGraph({len(self)} factors on {len(self.keys())} keys)"]
        for name, n in counts.most_common():
            lines.append(f"  {n:>8} x {name}")
        if len(self._constraints) > 0:
            lines.append(f"  constraints: {len(self._constraints)}")
        return "\n".join(lines)

    def _repr_html_(self) -> str:
        if len(self) == 0:
            return "<b>FactorGraph</b> (empty)"
        rows = "".join(f"<tr><td>{name}</td><td style='text-align:right'>{n}</td></tr>"
                       for name, n in self.type_counts().most_common())
        return (f"<b>FactorGraph</b>: {len(self)} factors on {len(self.keys())} keys"
                f"<table><tr><th>factor type</th><th>count</th></tr>{rows}</table>")


def describe_keys(keys: Iterable[Key]) -> str:
    return ", ".join(key_str(k) for k in keys)
