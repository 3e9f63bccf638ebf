"""Plots of pose graphs, bundle-adjustment scenes and cost histories (matplotlib, lazily).

matplotlib is imported only when a function here runs. Figures are built with
``matplotlib.figure.Figure`` (no pyplot, so no display is needed and no backend is switched);
pass ``ax`` to draw into your own axes instead, e.g. in a notebook.

- :func:`plot_pose_graph`: 2D or 3D trajectory (poses in key order: SE2, SE3, or a declared
  manifold whose declaration has a ``position`` accessor, e.g. ``SE23``), loop closures (between
  factors whose keys are not consecutive) and landmarks; with ``initial`` the starting guess is
  drawn faintly underneath ("before / after").
- :func:`plot_bundle`: BAL cameras (centres ``-R^T t``) and points.
- :func:`plot_cost_history`: cost per iteration on a log scale.
- :func:`plot_result` / :func:`save_result_plot`: the two panels ``fgopt solve --plot`` writes.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from .errors import FgoptError
from .key import key_index
from .manifolds.base import ops_for
from .manifolds.declared import DeclaredValue


def _figure(figsize=(6, 5)):
    from matplotlib.figure import Figure

    return Figure(figsize=figsize, layout="constrained")


def _kind_name(v: Any) -> str:
    kind = ops_for(v).batch_kind(v)
    return kind.name if kind is not None else ""


def _position_dim(v: Any) -> int:
    """2 or 3 for values with a position: SE2 / SE3, declared manifolds whose declaration has a
    ``position`` accessor (e.g. ``SE23``); else 0."""
    name = _kind_name(v)
    if name in ("SE2", "SE3"):
        return 2 if name == "SE2" else 3
    return int(v.position_dim()) if isinstance(v, DeclaredValue) else 0


def _poses(values: Any) -> tuple[list[int], np.ndarray, int]:
    """Pose keys in key order, their positions ``(n, d)`` and ``d`` (2 or 3; 0 if no poses).

    Poses are the values of the most common positioned kind (SE2, SE3 or a declared manifold
    with a ``position`` accessor)."""
    found = [(int(k), _kind_name(values.at(k))) for k in values.keys()
             if _position_dim(values.at(k)) > 0]
    if not found:
        return [], np.zeros((0, 2)), 0
    names = [n for _, n in found]
    kind = max(set(names), key=names.count)
    keys = sorted(k for k, n in found if n == kind)
    if kind in ("SE2", "SE3"):
        st = np.array([values.at(k).to_storage() for k in keys])
        if st.shape[1] == 4:
            return keys, st[:, 2:4], 2
        return keys, st[:, 4:7], 3
    xyz = np.array([values.at(k).plot_position() for k in keys])
    return keys, xyz, xyz.shape[1]


def _points(values: Any, dim: int) -> np.ndarray:
    pts = [np.asarray(values.at(k)) for k in values.keys()
           if _kind_name(values.at(k)) == f"R{dim}"]
    return np.array(pts).reshape(-1, dim)


def _loop_closures(graph: Any, pose_keys: list[int]) -> np.ndarray:
    """``(m, 2)`` row indices into ``pose_keys`` of between factors on non-consecutive poses."""
    if graph is None or not pose_keys:
        return np.zeros((0, 2), dtype=np.int64)
    keys = np.array(pose_keys, dtype=np.int64)
    pairs = [b.keys for b in graph.batches
             if b.kernel.name.startswith("between_") and b.keys.shape[1] == 2]
    pairs += [np.array([[int(k) for k in f.keys]]) for f in graph.factors
              if f.kernel is not None and f.kernel.name.startswith("between_")]
    if not pairs:
        return np.zeros((0, 2), dtype=np.int64)
    pk = np.concatenate(pairs)
    pos = np.searchsorted(keys, pk)
    pos = np.clip(pos, 0, keys.shape[0] - 1)
    ok = (keys[pos] == pk).all(axis=1)
    pos = pos[ok]
    return pos[np.abs(pos[:, 0] - pos[:, 1]) > 1]


def _segments(xyz: np.ndarray, pairs: np.ndarray, dim: int, ax: Any, **style) -> None:
    if pairs.shape[0] == 0:
        return
    segs = np.stack([xyz[pairs[:, 0]], xyz[pairs[:, 1]]], axis=1)
    if dim == 2:
        from matplotlib.collections import LineCollection

        ax.add_collection(LineCollection(segs, **style))
    else:
        from mpl_toolkits.mplot3d.art3d import Line3DCollection

        ax.add_collection3d(Line3DCollection(segs, **style))


def _axes(ax: Any, dim: int):
    if ax is not None:
        return ax
    fig = _figure()
    return fig.add_subplot(projection="3d" if dim == 3 else None)


def plot_pose_graph(graph: Any, values: Any, ax: Any = None, initial: Any = None,
                    loop_closures: bool = True, title: str | None = None) -> Any:
    """Draw the trajectory of ``values`` (and ``initial`` faintly); returns the axes.

    >>> s = fgopt.datasets.manhattan_2d(num_poses=50, seed=0)
    >>> ax = fgopt.plot.plot_pose_graph(s.graph, s.initial)
    >>> ax.get_title(), ax.lines[0].get_xydata().shape          # one (x, y) per pose
    ('50 poses', (50, 2))
    >>> [t.get_text() for t in ax.get_legend().get_texts()]
    ['trajectory', 'loop closures (4)', 'first pose (x0)']
    """
    keys, xyz, dim = _poses(values)
    if dim == 0:
        raise FgoptError("plot_pose_graph: the values hold no poses (SE2, SE3 or a declared "
                         "manifold with a position accessor)")
    ax = _axes(ax, dim)
    cols = [xyz[:, i] for i in range(dim)]
    if initial is not None:
        _, xyz0, dim0 = _poses(initial)
        if dim0 == dim and xyz0.shape == xyz.shape:
            ax.plot(*[xyz0[:, i] for i in range(dim)], color="0.6", lw=0.6, ls="--",
                    label="initial")
    ax.plot(*cols, color="tab:blue", lw=0.9, label="trajectory" if initial is None else "optimized")
    if loop_closures:
        pairs = _loop_closures(graph, keys)
        _segments(xyz, pairs, dim, ax, colors="tab:red", linewidths=0.4, alpha=0.35,
                  label=f"loop closures ({pairs.shape[0]})")
    pts = _points(values, dim)
    if pts.shape[0] > 0:
        ax.scatter(*[pts[:, i] for i in range(dim)], s=4, color="tab:green", label="landmarks")
    ax.scatter(*[xyz[:1, i] for i in range(dim)], s=25, color="k", marker="o", zorder=5,
               label=f"first pose ({_key_label(keys[0])})")
    if dim == 2:
        ax.set_aspect("equal", adjustable="datalim")
        ax.autoscale_view()
    else:
        _equal_3d(ax, xyz)
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.legend(loc="best", fontsize="small")
    ax.set_title(title or f"{len(keys)} poses")
    return ax


def _key_label(k: int) -> str:
    from .key import key_str

    return key_str(k) if key_index(k) != k else str(k)


def _box(xyz: np.ndarray, q: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Axis limits from the ``q`` .. ``100 - q`` percentiles plus a margin (crops outliers)."""
    lo, hi = np.percentile(xyz, q, axis=0), np.percentile(xyz, 100 - q, axis=0)
    pad = 0.05 * float((hi - lo).max()) + 1e-9
    return lo - pad, hi + pad


def _equal_3d(ax: Any, xyz: np.ndarray, q: float = 1.0) -> None:
    """Limits from :func:`_box`, true aspect ratio (thin axes kept readable)."""
    from matplotlib.ticker import MaxNLocator

    lo, hi = _box(xyz, q)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(tuple(np.maximum(hi - lo, 0.2 * float((hi - lo).max()))))
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.set_major_locator(MaxNLocator(5))


def camera_centers(cameras: np.ndarray) -> np.ndarray:
    """Centres ``-R(r)^T t`` of BAL cameras ``(n, 9)`` (angle-axis ``r``, translation ``t``).

    >>> cameras = np.zeros((2, 9))
    >>> cameras[1, :6] = [0.0, 0.0, np.pi / 2, 1.0, 0.0, 0.0]    # 90 deg about z, t = (1, 0, 0)
    >>> np.round(fgopt.plot.camera_centers(cameras), 6) + 0.0
    array([[0., 0., 0.],
           [0., 1., 0.]])
    """
    r, t = cameras[:, :3], cameras[:, 3:6]
    th = np.linalg.norm(r, axis=1, keepdims=True)
    k = np.where(th > 1e-12, r / np.where(th > 1e-12, th, 1.0), 0.0)
    # R^T t = rotation by -r: t cos - (k x t) sin + k (k.t)(1 - cos)
    c, s = np.cos(th), np.sin(th)
    Rt_t = t * c - np.cross(k, t) * s + k * np.sum(k * t, axis=1, keepdims=True) * (1 - c)
    return -Rt_t


def plot_bundle(values: Any, ax: Any = None, max_points: int = 20000,
                title: str | None = None) -> Any:
    """BAL scene: camera centres (R^9 values) and points (R^3 values); returns the axes.

    >>> graph, initial = fgopt.datasets.bal_synthetic(cameras=3, points=10, observations_per_point=2).read()
    >>> ax = fgopt.plot.plot_bundle(initial)
    >>> [t.get_text() for t in ax.get_legend().get_texts()]
    ['points (10; 0 outside the view)', 'cameras (3)']
    """
    cams = np.array([values.at(k) for k in values.keys() if _kind_name(values.at(k)) == "R9"])
    pts = _points(values, 3)
    ax = _axes(ax, 3)
    cc = camera_centers(cams.reshape(-1, 9)) if cams.shape[0] > 0 else np.zeros((0, 3))
    everything = np.concatenate([pts, cc])
    if everything.shape[0] == 0:
        raise FgoptError("plot_bundle: the values hold no R^9 cameras and no R^3 points")
    lo, hi = _box(everything, q=3.0)  # BAL scenes have far outliers: crop them
    if pts.shape[0] > 0:
        inside = np.all((pts >= lo) & (pts <= hi), axis=1)
        p = pts[inside][::max(1, int(inside.sum()) // max_points)]
        ax.scatter(p[:, 0], p[:, 1], p[:, 2], s=0.3, color="tab:blue", alpha=0.5,
                   label=f"points ({pts.shape[0]}; {int((~inside).sum())} outside the view)")
    if cc.shape[0] > 0:
        ax.scatter(cc[:, 0], cc[:, 1], cc[:, 2], s=18, color="tab:red", marker="^",
                   label=f"cameras ({cams.shape[0]})")
    _equal_3d(ax, everything, q=3.0)
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_zlabel("z")
    ax.legend(loc="upper right", fontsize="small")
    ax.set_title(title or "bundle adjustment")
    return ax


def plot_cost_history(history: Any, ax: Any = None, title: str | None = None) -> Any:
    """Cost per iteration (a list, or a Result's ``cost_history``), log scale.

    >>> ax = fgopt.plot.plot_cost_history([100.0, 10.0, 1.0, 0.5])
    >>> ax.get_yscale(), ax.get_title(), ax.lines[0].get_ydata().tolist()
    ('log', 'cost 100 -> 0.5', [100.0, 10.0, 1.0, 0.5])
    """
    costs = np.asarray(getattr(history, "cost_history", history), dtype=float)
    if ax is None:
        ax = _figure((5, 4)).add_subplot()
    it = np.arange(costs.shape[0])
    positive = costs > 0
    from matplotlib.ticker import MaxNLocator

    ax.semilogy(it[positive], costs[positive], marker="o", ms=3, color="tab:blue")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("accepted step")
    ax.set_ylabel("cost")
    ax.grid(True, which="both", alpha=0.3)
    if costs.shape[0] > 0:
        ax.set_title(title or f"cost {costs[0]:.4g} -> {costs[-1]:.4g}")
    return ax


def plot_result(graph: Any, initial: Any, result: Any, title: str | None = None) -> Any:
    """Two panels: the problem after optimization (over the initial guess) and the cost.

    Example:

    >>> import matplotlib
    >>> matplotlib.use('Agg')
    >>> s = fgopt.datasets.manhattan_2d(num_poses=50, seed=0)
    >>> fig = fgopt.plot.plot_result(s.graph, s.initial, fgopt.optimize(s.graph, s.initial))
    >>> len(fig.axes)
    2
    """
    values = result.values
    _, _, dim = _poses(values)
    fig = _figure((12, 5.5))
    if dim == 0:
        ax = fig.add_subplot(1, 2, 1, projection="3d")
        plot_bundle(values, ax=ax, title=title)
    else:
        ax = fig.add_subplot(1, 2, 1, projection="3d" if dim == 3 else None)
        plot_pose_graph(graph, values, ax=ax, initial=initial, title=title)
    plot_cost_history(result, ax=fig.add_subplot(1, 2, 2))
    return fig


def save_result_plot(path: str | os.PathLike, graph: Any, initial: Any, result: Any,
                     title: str | None = None, dpi: int = 110) -> None:
    """Write :func:`plot_result` to ``path`` (format from the extension, e.g. ``.png``).

    >>> import pathlib, tempfile
    >>> path = pathlib.Path(tempfile.mkdtemp()) / 'result.png'
    >>> s = fgopt.datasets.manhattan_2d(num_poses=20, seed=0)
    >>> fgopt.plot.save_result_plot(path, s.graph, s.initial, fgopt.optimize(s.graph, s.initial))
    >>> path.read_bytes()[:4]                                    # a PNG file
    b'\\x89PNG'
    """
    fig = plot_result(graph, initial, result, title=title)
    try:
        fig.savefig(os.fspath(path), dpi=dpi)
    except (OSError, ValueError) as exc:  # ValueError: an extension matplotlib cannot write
        raise FgoptError(f"save_result_plot: cannot write {os.fspath(path)}: "
                         f"{getattr(exc, 'strerror', None) or exc}") from None

#: The public names (each has an entry in the API reference: tests/test_docs_reference.py).
__all__ = ["plot_pose_graph", "camera_centers", "plot_bundle", "plot_cost_history", "plot_result",
           "save_result_plot"]
