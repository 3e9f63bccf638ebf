"""A new manifold declared with ``@fgopt.manifold``, from its definition to the first optimized
result (prints JSON): headings as unit 2-vectors (the circle S^1, storage 2, tangent 1), a
ring of 12 headings linked by relative-heading measurements (fgopt's generated BetweenFactor,
since the declaration has ``compose`` and ``inverse``) and a prior on the first one."""

import json
import sys
import time

t_start = time.perf_counter()
import numpy as np  # noqa: E402

import fgopt  # noqa: E402
from fgopt import BetweenFactor, PriorFactor, key  # noqa: E402
from fgopt.noise import Isotropic  # noqa: E402
from fgopt.symbolic import V1, V2, atan2, cos, sin  # noqa: E402

t_import = time.perf_counter() - t_start


def declare():
    @fgopt.manifold
    class Heading:
        """A planar direction ``(cos a, sin a)``; tangent: the angle (rad, counter-clockwise).
        ``retract(x, d)`` rotates ``x`` by ``d``; ``local(x, y)`` is the angle from x to y."""

        storage_dim = 2
        dim = 1

        def identity():
            return V2(1, 0)

        def retract(x, d):
            c, s = cos(d[0]), sin(d[0])
            return V2(c * x[0] - s * x[1], s * x[0] + c * x[1])

        def local(x, y):
            return V1(atan2(x[0] * y[1] - x[1] * y[0], x[0] * y[0] + x[1] * y[1]))

        def compose(x, y):  # group operations: a value of the manifold, type(x)
            return type(x)([x[0] * y[0] - x[1] * y[1], x[0] * y[1] + x[1] * y[0]])

        def inverse(x):
            return type(x)([x[0], -x[1]])

        def normalize(x):
            return x.storage / x.storage.norm(0)

    return Heading


def main() -> None:
    t0 = time.perf_counter()
    Heading = declare()

    def heading(angle):
        return Heading.Value([np.cos(angle), np.sin(angle)])

    rng = np.random.default_rng(3)
    n = 12
    truth = 2 * np.pi * np.arange(n) / n + 0.3
    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    graph.add(PriorFactor(key("h", 0), heading(truth[0]), Isotropic.sigma(1, 0.01)))
    for i in range(n):
        j = (i + 1) % n
        measured = heading(truth[j] - truth[i] + 0.02 * rng.standard_normal())
        graph.add(BetweenFactor(key("h", i), key("h", j), measured, Isotropic.sigma(1, 0.05)))
        initial.add(key("h", i), heading(truth[i] + 0.3 * rng.standard_normal()))
    result = fgopt.optimize(graph, initial)
    seconds = time.perf_counter() - t0
    angles = [float(np.arctan2(*result.values.at(key("h", i)).to_storage()[::-1]))
              for i in range(n)]
    from fgopt.symbolic.declare import decorator

    print(json.dumps({"definition to result": seconds, "import": t_import,
                      "final cost": result.final_cost, "converged": result.success,
                      "max heading error": float(np.max(np.abs(np.angle(
                          np.exp(1j * (np.array(angles) - truth)))))),
                      "derived": decorator.STATS["derived"], "loaded": decorator.STATS["loaded"],
                      "sympy imported": "sympy" in sys.modules}))


if __name__ == "__main__":
    main()
