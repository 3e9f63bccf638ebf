"""fgopt symbolic factors used by the benchmark (no ``from __future__ import annotations`` here:
``@fgopt.factor`` reads the annotations at definition time)."""

from fgopt.symbolic import V2, Pose2, atan2, cos, factor, sin


@factor(name="bench_bearing_range_known")
def bearing_range_known(pose: Pose2, landmark: V2, measured: V2) -> V2:
    """Bearing (wrapped to (-pi, pi]) and range from ``pose`` to a known landmark."""
    d = pose.inverse() * landmark
    cz, sz = cos(measured[0]), sin(measured[0])
    return V2(atan2(cz * d[1] - sz * d[0], cz * d[0] + sz * d[1]), d.norm() - measured[1])
