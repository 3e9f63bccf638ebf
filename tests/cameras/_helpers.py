"""Shared helpers of the camera tests: random calibrations, GTSAM twins, poses near pi, central
differences. Load with :func:`load` (by file path, under a unique module name)."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np

from fgopt.cameras import (Cal3_S2, Cal3_S2Stereo, Cal3Bundler, Cal3DS2, Cal3Fisheye,
                           Cal3Unified, DoubleSphere)
from fgopt.manifolds import SE3, SO3

MODELS = (Cal3_S2, Cal3DS2, Cal3Bundler, Cal3Fisheye, Cal3Unified, DoubleSphere, Cal3_S2Stereo)
GTSAM_MODELS = tuple(m for m in MODELS if m is not DoubleSphere)

#: Rotation angles of camera poses: identity, tiny, generic, near pi and pi.
ANGLES = (0.0, 1e-9, 0.7, 2.5, math.pi - 1e-4, math.pi)


def random_params(cls, rng: np.random.Generator) -> np.ndarray:
    """Plausible random parameters of ``cls`` (focal 300-900 px, mild distortion)."""
    f = rng.uniform(300.0, 900.0, size=2)
    s = rng.uniform(-2.0, 2.0)
    c = rng.uniform(200.0, 500.0, size=2)
    if cls is Cal3_S2:
        return np.array([f[0], f[1], s, c[0], c[1]])
    if cls is Cal3DS2:
        return np.array([f[0], f[1], s, c[0], c[1], *rng.uniform(-0.2, 0.2, 2),
                         *rng.uniform(-0.01, 0.01, 2)])
    if cls is Cal3Bundler:
        return np.array([f[0], rng.uniform(-0.2, 0.2), rng.uniform(-0.05, 0.05), c[0], c[1]])
    if cls is Cal3Fisheye:
        return np.array([f[0], f[1], s, c[0], c[1], *rng.uniform(-0.05, 0.05, 4)])
    if cls is Cal3Unified:
        return np.array([f[0], f[1], s, c[0], c[1], *rng.uniform(-0.1, 0.1, 2),
                         *rng.uniform(-0.01, 0.01, 2), rng.uniform(0.3, 1.2)])
    if cls is DoubleSphere:
        return np.array([f[0], f[1], c[0], c[1], rng.uniform(-0.3, 0.6), rng.uniform(0.3, 0.7)])
    return np.array([f[0], f[1], s, c[0], c[1], rng.uniform(0.1, 1.0)])


def random_pose(rng: np.random.Generator, angle: float | None = None) -> SE3:
    """A random camera pose; with ``angle`` its rotation has exactly that angle."""
    if angle is None:
        return SE3.random(rng)
    axis = rng.normal(size=3)
    return SE3(SO3.exp(axis / np.linalg.norm(axis) * angle), rng.normal(size=3))


def point_in_front(rng: np.random.Generator, pose: SE3, spread: float = 0.4) -> np.ndarray:
    """A world point 2-6 units in front of the camera, within ``spread`` of the optical axis."""
    z = rng.uniform(2.0, 6.0)
    return pose * np.array([*(rng.uniform(-spread, spread, 2) * z), z])


def gtsam_calibration(K):
    import gtsam

    return getattr(gtsam, type(K).__name__)(*K.to_storage())


def gtsam_pose(pose: SE3):
    import gtsam

    return gtsam.Pose3(pose.matrix())


def gtsam_camera(pose: SE3, K):
    import gtsam

    cls = getattr(gtsam, f"PinholeCamera{type(K).__name__}")
    return cls(gtsam_pose(pose), gtsam_calibration(K))


def zeros_f(r: int, c: int) -> np.ndarray:
    """An output Jacobian buffer for GTSAM's Python wrapper (column-major)."""
    return np.zeros((r, c), order="F")


def central_diff(fn, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """``d fn / d x`` by central differences on a plain vector ``x``."""
    cols = []
    for i in range(x.shape[0]):
        e = np.zeros_like(x)
        e[i] = h
        cols.append((np.asarray(fn(x + e)) - np.asarray(fn(x - e))).reshape(-1) / (2 * h))
    return np.stack(cols, axis=1)


def kernel_fd(kernel, args, consts, h=1e-6):
    """Central-difference Jacobian ``(r, D)`` of ``kernel.residual`` for one instance, each
    argument perturbed through its kind's own retract (the tangent space the optimizer uses)."""
    cols = []
    for i, kind in enumerate(kernel.arg_kinds):
        for j in range(kind.dim):
            d = np.zeros((1, kind.dim))
            d[0, j] = h
            plus, minus = list(args), list(args)
            plus[i] = kind.retract(args[i], d)
            minus[i] = kind.retract(args[i], -d)
            rp = kernel.residual(tuple(plus), consts)[0]
            rm = kernel.residual(tuple(minus), consts)[0]
            cols.append((rp - rm) / (2 * h))
    return np.stack(cols, axis=1)


def load(name: str = "fgopt_tests_camera_helpers"):
    if name not in sys.modules:
        path = Path(__file__).resolve()
        spec = importlib.util.spec_from_file_location(name, path)
        sys.modules[name] = module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    return sys.modules[name]
