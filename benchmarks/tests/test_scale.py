"""benchmarks.scale's choice among repeated runs."""

from __future__ import annotations

import os


def _scale():
    saved = dict(os.environ)
    try:
        from benchmarks import scale  # pins the thread variables on import
    finally:
        os.environ.clear()
        os.environ.update(saved)
    return scale


def test_least_cpu_keeps_one_whole_run_and_skips_failures():
    """The run kept is the one with the least total CPU over its library's figures, unmixed
    (its other fields come with it); failed runs are counted, and only when every run failed is
    an error returned."""
    scale = _scale()
    runs = [{"read_cpu_s": 1.0, "setup_cpu_s": 0.3, "iterations_cpu_s": 5.0, "peak_rss_mb": 700},
            {"error": "killed"},
            {"read_cpu_s": 1.2, "setup_cpu_s": 0.2, "iterations_cpu_s": 4.7, "peak_rss_mb": 760}]
    best = scale.least_cpu(runs, "fgopt")
    assert best["read_cpu_s"] == 1.2 and best["peak_rss_mb"] == 760
    assert best["runs_failed"] == 1 and len(best["runs_cpu_s"]) == 2
    ceres = [{"load_cpu_s": 1.4, "solve_cpu_s": 14.0}, {"load_cpu_s": 1.3, "solve_cpu_s": 14.2}]
    assert scale.least_cpu(ceres, "ceres")["load_cpu_s"] == 1.4
    assert scale.least_cpu([{"error": "a"}, {"error": "b"}], "ceres") == {"error": "a"}
