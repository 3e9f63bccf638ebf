"""Plots: pose graphs (2D / 3D, before / after), BA scenes, cost history; lazy matplotlib."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from fgopt import FactorGraph, Variables, key  # noqa: E402
from fgopt.factors.library.prior_between import BetweenFactor  # noqa: E402
from fgopt.manifolds import SE2, SE3  # noqa: E402
from fgopt.plot import (camera_centers, plot_bundle, plot_cost_history,  # noqa: E402
                        plot_pose_graph, plot_result, save_result_plot)


def _square(group):
    values, graph = Variables(), FactorGraph()
    rng = np.random.default_rng(0)
    for i in range(8):
        if group is SE2:
            values.add(key("x", i), SE2.from_xytheta(np.cos(i), np.sin(i), 0.1 * i))
        else:
            values.add(key("x", i), SE3(None, [np.cos(i), np.sin(i), 0.1 * i]))
    for i, j in [(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 6), (6, 7), (7, 0), (2, 6)]:
        graph.add(BetweenFactor(key("x", i), key("x", j), group.random(rng)))
    values.add(key("l", 0), np.zeros(2 if group is SE2 else 3))
    return graph, values


@pytest.mark.parametrize("group", [SE2, SE3])
def test_pose_graph_plot_draws_trajectory_loop_closures_and_initial(group):
    graph, values = _square(group)
    ax = plot_pose_graph(graph, values, initial=values, title="square")
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "optimized" in labels and "initial" in labels
    assert "loop closures (2)" in labels  # 7-0 and 2-6 are not consecutive
    assert "landmarks" in labels
    assert ax.get_title() == "square"


def test_bundle_plot_and_camera_centres():
    rng = np.random.default_rng(1)
    cams = np.column_stack([rng.normal(size=(4, 3)) * 0.3, rng.normal(size=(4, 3)),
                            np.full((4, 1), 500.0), np.zeros((4, 2))])
    values = Variables()
    for i, c in enumerate(cams):
        values.add(key("c", i), c)
    for j, p in enumerate(rng.normal(size=(50, 3))):
        values.add(key("p", j), p)
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(cams[:, :3]).as_matrix()
    expected = -np.einsum("nji,nj->ni", R, cams[:, 3:6])
    assert np.allclose(camera_centers(cams), expected)
    ax = plot_bundle(values)
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any(t.startswith("points (50") for t in labels) and "cameras (4)" in labels


def test_cost_history_accepts_lists_and_results():
    ax = plot_cost_history([100.0, 10.0, 1.0, 0.0])
    assert ax.get_yscale() == "log"
    assert ax.get_title() == "cost 100 -> 0"


def test_save_result_plot_writes_a_png(tmp_path):
    import fgopt

    graph, values = _square(SE2)
    graph.add(fgopt.PriorFactor(key("x", 0), values.at(key("x", 0))))
    with pytest.warns(fgopt.FgoptWarning, match="l0"):  # the landmark only shows in plots
        result = fgopt.optimize(graph, values, linear_solver="dense", max_iterations=5)
    fig = plot_result(graph, values, result, title="t")
    assert len(fig.axes) == 2
    out = tmp_path / "r.png"
    save_result_plot(out, graph, values, result)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # a folder that does not exist, or an extension matplotlib cannot write: an FgoptError
    for bad in (tmp_path / "no" / "r.png", tmp_path / "r.unknownformat"):
        with pytest.raises(fgopt.FgoptError, match="cannot write"):
            save_result_plot(bad, graph, values, result)


def test_matplotlib_is_imported_lazily():
    code = "import fgopt.plot, fgopt.cli, sys; print('matplotlib' in sys.modules)"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.stdout.strip() == "False", proc.stderr
