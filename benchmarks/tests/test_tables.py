"""README table pipeline: marker rewriting, renderers, the --render-only / --skip paths."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from benchmarks import markers, pipeline, tables
from benchmarks.render_peers import converged

REPO = Path(__file__).resolve().parents[2]

TEXT = ("# Title  \n\nprose with trailing spaces   \n"
        "<!-- table:a -->\nold a\n<!-- /table:a -->\n"
        "between ünïcode\r\n\n"
        "- item\n  <!-- table:b -->\n  old b\n  <!-- /table:b -->\nend without newline")


def test_rewrite_keeps_outside_text_byte_identical():
    """Replacing both blocks changes only the text between the markers: everything before,
    between and after them (unicode, CR, trailing spaces, no final newline) is kept exactly, and
    an indented block gets its marker's indentation."""
    new = markers.replace_blocks(TEXT, {"a": "| x |\n|---|", "b": "line 1\n\nline 2"})
    assert new == TEXT.replace("old a\n", "| x |\n|---|\n").replace(
        "  old b\n", "  line 1\n\n  line 2\n")
    # only one block: the other keeps its old body
    assert markers.replace_blocks(TEXT, {"a": "new"}) == TEXT.replace("old a\n", "new\n")
    assert markers.block_text(TEXT, "b") == "  old b\n"


@pytest.mark.parametrize("text, name, what", [
    ("<!-- table:x -->\n<!-- table:x -->\n<!-- /table:x -->\n", "x", "not closed"),
    ("<!-- table:x -->\n<!-- /table:x -->\n<!-- table:x -->\n<!-- /table:x -->\n", "x",
     "opened twice"),
    ("<!-- /table:y -->\n", "y", "without an opening"),
    ("<!-- table:z -->\nbody\n", "z", "never closed"),
])
def test_malformed_markers_are_errors_naming_the_table(text, name, what):
    """A duplicated, unopened or unclosed marker raises MarkerError naming the table."""
    with pytest.raises(markers.MarkerError, match=f"'{name}'.*{what}|{what}"):
        markers.find_blocks(text)
    with pytest.raises(markers.MarkerError, match=name):
        markers.find_blocks(text)


def test_missing_block_is_an_error_naming_the_table():
    """Rendering a table whose markers are absent from the README names that table."""
    with pytest.raises(markers.MarkerError, match="gnc"):
        markers.replace_blocks(TEXT, {"gnc": "x"})


def _gnc_doc() -> dict:
    recs = [{"graph": "m3500", "generator": "random", "fraction": f, "method": "GNC-tls",
             "optimum": 68.9574, "relative": rel, "cpu": cpu}
            for f, rel, cpu in ((0.1, -1e-10, 9.7), (0.3, 2e-3, 31.0))]
    recs.append({"graph": "m3500", "method": "LM (clean graph)", "cpu": 0.5})
    meta = {"bench": "gnc", "commit": "abc1234+dirty", "date": "2026-11-25 01:02",
            "loadavg": [0.5, 1.25], "cores": 2, "command": "python -m benchmarks.gnc --no-plain",
            "duration_s": 90.0, "protocol": {"includes": "CPU time.", "stopping": "GNC's own."}}
    return {"meta": meta, "results": {"records": recs}}


def test_render_fixture_gives_the_expected_block():
    """A small GNC results document renders to exactly this block: caption from the declared
    protocol, the table (GNC's time as a multiple of plain LM on the clean graph), the
    generated misses line (cost and the 10x time target), and the commit line."""
    expected = [
        "Timing: CPU time. Stopping: GNC's own.",
        "",
        "| graph (optimum) | LM, clean graph | random 10% / 30% |",
        "|---|---|---|",
        "| m3500 (68.9574) | 0.50 s | exact, 9.7 s (19x) / **+2.0e-03**, 31.0 s (62x) |",
        "",
        ("CPU seconds (multiple of plain LM on the clean graph). Targets: cost over the file's "
         "own edges within 1e-3 of the outlier-free optimum, at most 10x plain LM's time on the "
         "clean graph. Generated summary: cost missed on: m3500 random 30% (cost +2.0e-03). "
         "Time over 10x in 2 of 2 cases (19-62x)."),
        "",
        ("_Measured at commit `abc1234+dirty` on 2026-11-25 01:02, 1-min load average 0.5 at the "
        "start, 1.2 at the end (2 cores), 1.5 min: `python -m benchmarks.gnc --no-plain`. "
        "Regenerate: `python -m benchmarks.run --only gnc`._")]
    assert pipeline.render_table("gnc", _gnc_doc()).split("\n") == expected


def _peer_rec(peer, mode, t, its, status, cost=1.0):
    return {"peer": peer, "problem": "m3500", "mode": mode, "status": "ok", "solve_s": t,
            "iterations": its, "lib_status": status, "initial_cost": 10.0, "final_cost": cost}


def test_peers_converged_only_from_the_library_test():
    """'converged' comes from each library's own status: GTSAM at its iteration cap is 'no',
    and a ratio against a run that did not converge is marked † and listed; where fgopt is
    slower (ratio > 1) the generated line says so."""
    runs = [_peer_rec("fgopt", "5it", 0.2, 5, "max iterations", cost=10.0),
            _peer_rec("gtsam", "5it", 0.1, 5, "max iterations"),
            _peer_rec("fgopt", "converge", 0.3, 7, "converged"),
            _peer_rec("gtsam", "converge", 0.6, 100, ""),
            _peer_rec("ceres_cpp", "converge", 0.2, 20, "CONVERGENCE")]
    doc = {"meta": {}, "results": {"runs": runs, "meta": {"args": {"repeats": 3, "long": 30},
                                                          "versions": {}}}}
    assert converged(runs[3]) == (False, "100-iteration limit")
    assert converged(runs[4]) == (True, "convergence")
    out = tables.TABLES["peers"].render(doc)
    assert "| M3500 | 0.2 | 0.1 | — | **2.00** | — |" in out
    assert "fgopt is slower than GTSAM on: M3500 (×2.00)" in out
    assert "every step rejected" in out and "fgopt on M3500" in out
    assert "0.6 (100, **no**: 100-iteration limit)" in out
    assert "| 0.50† | **1.50** |" in out
    assert "fgopt is slower than Ceres C++ on: M3500 (×1.50)" in out


def test_render_only_on_the_real_readme_is_idempotent(tmp_path):
    """--render-only with the saved results reproduces the committed README byte for byte, and
    a second pass changes nothing."""
    readme = tmp_path / "README.md"
    shutil.copy(REPO / "README.md", readme)
    assert pipeline.main(["--render-only", "--readme", str(readme)]) == 0
    once = readme.read_bytes()
    assert once == (REPO / "README.md").read_bytes()
    assert pipeline.main(["--render-only", "--readme", str(readme)]) == 0
    assert readme.read_bytes() == once


def test_run_and_skip_end_to_end(tmp_path, monkeypatch):
    """A registered benchmark runs as a module, its JSON is saved with the commit, and its table
    is rewritten; a later --all that skips it keeps its saved figures and says it was not
    rerun, also after a --render-only."""
    mod = tmp_path / "fakebench_tables.py"
    mod.write_text("import json, sys\nout = sys.argv[sys.argv.index('--out') + 1]\n"
                   "json.dump({'value': 42}, open(out, 'w'))\n")
    monkeypatch.setenv("PYTHONPATH", str(tmp_path))
    monkeypatch.setenv("FGOPT_DATA", str(tmp_path))
    monkeypatch.setattr(tables.Bench, "protocol", lambda self: {"includes": "all.",
                                                                  "stopping": "none."})
    fake = tables.Bench("fakebench_tables", ("--x",), ("--out", "{dir}/r.json"), "r.json", 0.1)
    benches = {"fake": fake}
    tabs = {"fake": tables.Table("fake", lambda doc: f"| v |\n|---|\n| {doc['results']['value']} |")}
    monkeypatch.setattr(pipeline, "BENCHES", benches)
    monkeypatch.setattr(pipeline, "TABLES", tabs)
    monkeypatch.setattr(tables, "BENCHES", benches)
    monkeypatch.setattr(tables, "TABLES", tabs)
    readme = tmp_path / "README.md"
    readme.write_text("top\n<!-- table:fake -->\n<!-- /table:fake -->\nbottom\n")
    res = tmp_path / "results"
    args = ["--readme", str(readme), "--results", str(res)]
    assert pipeline.main(["--all", *args]) == 0
    text = readme.read_text()
    head, dirty = pipeline.git_state()
    assert "| 42 |" in text and f"commit `{head}{'+dirty' if dirty else ''}`" in text
    assert "`python -m fakebench_tables --x`" in text and "Timing: all." in text
    assert text.startswith("top\n<!-- table:fake -->\n") and text.endswith("<!-- /table:fake -->"
                                                                          "\nbottom\n")
    assert json.loads((res / "fake.json").read_text())["results"] == {"value": 42}
    assert pipeline.main(["--all", "--skip", "fake", *args]) == 0
    skipped = readme.read_text()
    assert "**Not rerun** by the last run at" in skipped and "| 42 |" in skipped
    assert pipeline.main(["--render-only", *args]) == 0
    assert readme.read_text() == skipped


def test_small_graphs_marks_and_lists_every_loss():
    """The small-graphs table gives fgopt / peer ratios (the README's convention), bolds each
    above 1 (the peer faster), and its generated line lists exactly those graphs per peer."""
    def rec(name, f, c, g, path="dense cholesky (small-problem driver)"):
        return {"file": name, "fgopt": {"cpu_s": f, "poses": 5, "path": path, "iterations": 5},
                "ceres_cpp": {"cpu_s": c, "iterations": 5}, "gtsam": {"cpu_s": g}}
    doc = {"meta": {}, "results": {"records": [
        rec("a.g2o", 1e-4, 2e-5, 2e-4), rec("b.g2o", 2e-3, 4e-3, 1e-3, path="cholmod"),
        {**rec("c.g2o", 1e-4, 1e-4, 1e-4), "ceres_cpp": {"error": "cannot read"}}]}}
    out = tables.TABLES["small-graphs"].render(doc)
    assert "| a.g2o | 5 | 0.1 | 0.02 **×5.00** | 0.2 ×0.50 | 5, 5, — | dense driver |" in out
    assert "| b.g2o | 5 | 2 | 4 ×0.50 | 1 **×2.00** | 5, 5, — | sparse |" in out
    assert "| c.g2o | 5 | 0.1 | cannot read | 0.1 ×1.00 | 5, —, — |" in out
    assert "slower than C++ Ceres on 1 of 3 graphs: a.g2o (×5.00)" in out
    assert "slower than GTSAM on 1 of 3 graphs: b.g2o (×2.00)" in out


def test_small_graphs_compares_an_early_ceres_stop_with_as_many_fgopt_iterations():
    """Where Ceres' own test stopped it before fgopt's 5 iterations, the x Ceres ratio is
    fgopt's time for as many iterations (the same work), and the cell says why."""
    doc = {"meta": {}, "results": {"records": [{
        "file": "d.txt", "fgopt": {"cpu_s": 4e-5, "poses": 2, "path": "x", "iterations": 5,
                                   "matched_ceres": {"cpu_s": 2e-5, "iterations": 0}},
        "ceres_cpp": {"cpu_s": 1e-5, "iterations": 0, "termination": "CONVERGENCE"},
        "gtsam": {"cpu_s": 8e-5, "iterations": 0}}]}}
    out = tables.TABLES["small-graphs"].render(doc)
    assert ("| d.txt | 2 | 0.04 | 0.01 **×2.00** (Ceres: convergence after 0; fgopt 0.02 "
            "for 0) | 0.08 ×0.50 | 5, 0, 0 |") in out
    assert "slower than C++ Ceres on 1 of 1 graphs: d.txt (×2.00)" in out
