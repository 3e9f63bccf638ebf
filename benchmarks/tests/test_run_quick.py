"""End to end: the orchestrator on small problems with the cheap peers."""

import json

import pytest

pytest.importorskip("gtsam")


def test_quick_run(tmp_path, capsys):
    from benchmarks import run

    out = tmp_path / "r.json"
    rc = run.main(["--datasets", "pose2example,robot_localization", "--peers", "gtsam",
                   "--quick", "--out", str(out)])
    assert rc == 0
    data = json.loads(out.read_text())
    runs = {(r["peer"], r["problem"], r["mode"]): r for r in data["runs"]}
    g = runs[("gtsam", "pose2example", "converge")]
    assert g["status"] == "ok" and g["final_cost"] == pytest.approx(0.5494864, rel=1e-5)
    md = capsys.readouterr().out
    assert "quoted, not measured" in md and "| pose2example |" in md
