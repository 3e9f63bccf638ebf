"""The ``fgopt`` command line: solve / info, exit codes, table, outputs."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from fgopt.cli import main
from fgopt.io import read_g2o

SMALL = """VERTEX_SE2 0 0 0 0
VERTEX_SE2 1 1.2 0.1 0.1
VERTEX_SE2 2 2.1 -0.2 0.2
VERTEX_SE2 3 2.9 0.4 -0.1
EDGE_SE2 0 1 1 0 0 100 0 0 100 0 400
EDGE_SE2 1 2 1 0 0 100 0 0 100 0 400
EDGE_SE2 2 3 1 0 0 100 0 0 100 0 400
EDGE_SE2 0 3 3 0 0 10 0 0 10 0 40
EDGE_SE2 1 3 2 0 0 10 0 0 10 0 40
"""


@pytest.fixture
def small(tmp_path):
    p = tmp_path / "small.g2o"
    p.write_text(SMALL)
    return p


def test_solve_prints_table_and_summary_and_writes_outputs(small, tmp_path, capsys):
    out, png = tmp_path / "out.g2o", tmp_path / "plot.png"
    rc = main(["solve", str(small), "--out", str(out), "--plot", str(png), "--solver", "dense"])
    text = capsys.readouterr().out
    assert rc == 0
    assert " iter        cost      rel.decr     lambda   |step|" in text
    assert "    1 " in text
    assert "gauge: tight prior on x0" in text
    assert "converged after" in text and "on the file's edges" in text
    assert "initialization: given (given values: the final cost is consistent" in text
    graph, values = read_g2o(out)
    assert graph.error(values) < 1e-12  # consistent measurements: optimum has zero cost
    assert len(graph) == 5  # the gauge prior is not written back
    # the edges come back as the input had them (solving changed only the vertices)
    edges = [ln for ln in out.read_text().splitlines() if ln.startswith("EDGE")]
    assert edges == [ln for ln in SMALL.splitlines() if ln.startswith("EDGE")]
    assert png.stat().st_size > 10_000


@pytest.mark.parametrize("method", ["lm", "gn", "dogleg"])
@pytest.mark.parametrize("solver", ["ldlt", "dense", "pcg"])
def test_methods_and_solvers(small, capsys, method, solver):
    assert main(["solve", str(small), "--method", method, "--solver", solver, "--quiet"]) == 0
    text = capsys.readouterr().out
    assert text.startswith("converged") and "rel.decr" not in text and len(text.splitlines()) == 1


def test_init_chordal_is_reported(small, capsys):
    """``--init chordal`` starts from the chordal relaxation and says so."""
    assert main(["solve", str(small), "--init", "chordal"]) == 0
    text = capsys.readouterr().out
    assert "initialization: chordal" in text and "converged after" in text


def test_not_converged_exits_1_with_reason(small, capsys):
    rc = main(["solve", str(small), "--max-iterations", "1", "--quiet"])
    captured = capsys.readouterr()
    assert rc == 1
    assert captured.err.strip().startswith("fgopt: not converged: max iterations")


def test_robust_loss(small, capsys):
    assert main(["solve", str(small), "--robust", "huber:0.5"]) == 0
    assert "robust loss: huber (k = 0.5)" in capsys.readouterr().out


def test_bad_input_exits_2_with_file_and_line(tmp_path, capsys):
    p = tmp_path / "bad.g2o"
    p.write_text("VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1\n")
    assert main(["solve", str(p)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("fgopt: error: ") and "bad.g2o:2:" in err and len(err.splitlines()) == 1


def test_non_pd_information_hint_uses_the_command_line_flag(tmp_path, capsys):
    p = tmp_path / "npd.g2o"
    p.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 2 0 1 0 1\n")
    assert main(["info", str(p)]) == 2
    assert "--repair-information clip" in capsys.readouterr().err
    assert main(["info", str(p), "--repair-information", "clip"]) == 0


def test_usage_errors_exit_2(small, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["solve", str(small), "--robust", "bogus:1"])
    assert exc.value.code == 2
    with pytest.raises(SystemExit) as exc:
        main(["solve", str(small), "--max-iterations", "0"])
    assert exc.value.code == 2
    assert main(["solve", str(small.parent / "missing.g2o")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_unwritable_outputs_are_refused_before_the_solve(small, tmp_path, capsys):
    """--out into a missing folder or --plot onto a directory exits 2 naming the option before
    any solving (it used to solve, print the summary, then fail to write)."""
    assert main(["solve", str(small), "--out", str(tmp_path / "no" / "out.g2o")]) == 2
    out = capsys.readouterr()
    assert "--out" in out.err and "folder does not exist" in out.err
    assert "initial cost" not in out.out
    assert main(["solve", str(small), "--plot", str(tmp_path)]) == 2
    assert "is a directory" in capsys.readouterr().err


def test_info_counts_cost_components_and_gauge(tmp_path, capsys):
    p = tmp_path / "two.g2o"
    p.write_text(SMALL + "VERTEX_SE2 7 0 0 0\nVERTEX_SE2 8 1 0 0\nVERTEX_SE2 9 5 5 0\n"
                 "EDGE_SE2 7 8 1 0 0 1 0 0 1 0 1\n")
    assert main(["info", str(p)]) == 0
    text = capsys.readouterr().out
    assert "variables:   7 (7 SE2)" in text
    assert "factors:     6 (6 between_pose2)" in text
    assert "initial cost" in text
    assert "components:  2 disconnected parts (sizes 4, 2)" in text
    assert "isolated:    1 variables no factor touches (x9)" in text
    assert "gauge:       free (3-DoF" in text


def test_info_and_solve_on_bal(data_file, capsys, tmp_path):
    path = data_file("bal/dubrovnik-3-7-pre.txt")
    assert main(["info", str(path)]) == 0
    text = capsys.readouterr().out
    assert "10 (7 R3, 3 R9)" in text and "19 bal_reprojection" in text
    assert "7-DoF similarity" in text
    out = tmp_path / "ba.txt"
    rc = main(["solve", str(path), "--out", str(out), "--quiet", "--max-iterations", "50"])
    assert rc in (0, 1)
    assert out.read_text().startswith("3 7 19\n")


def test_console_entry_point_runs_as_module(small):
    proc = subprocess.run([sys.executable, "-m", "fgopt.cli", "info", str(small)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "variables:   4 (4 SE2)" in proc.stdout


def test_m3500_reaches_the_benchmark_cost(data_file, capsys):
    path = data_file("pose2d/input_M3500_g2o.g2o")
    assert main(["solve", str(path), "--quiet"]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    final = float(line.split("->")[1].split()[0])
    assert final == pytest.approx(68.957, abs=0.01)  # BENCHMARKS.md
    assert np.isfinite(final)


def test_gnc_and_barron_from_the_command_line(small, capsys):
    """--method gnc runs graduated non-convexity; --robust barron:K:ALPHA parses both numbers."""
    assert main(["solve", str(small), "--method", "gnc", "--quiet"]) == 0
    assert "gnc-tls" in capsys.readouterr().out
    assert main(["solve", str(small), "--robust", "barron:2:0.5"]) == 0
    assert "robust loss: barron (k = 2, alpha = 0.5)" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exc:  # argparse refuses a second parameter for huber
        main(["solve", str(small), "--robust", "huber:1:2"])
    assert exc.value.code == 2
