"""Regenerate the benchmark tables (README.md's headline, docs/benchmarks.md's) at HEAD with one
command.

    python -m benchmarks.run --all [--skip scale,...]   # run every registered benchmark
    python -m benchmarks.run --only startup,navigation  # some tables (their benchmarks run)
    python -m benchmarks.run --render-only [--only ...] # re-render from the saved results
    python -m benchmarks.run --list                     # tables, benchmarks, typical minutes
    make bench                                          # = --all

Benchmarks run one at a time (the machine is shared), each as
``python -m benchmarks.<name> <the registered arguments>``. Its JSON is saved as
``benchmarks/results/tables/<bench>.json`` = ``{"meta": {commit, dirty, date, loadavg,
command, duration_s, protocol}, "results": <the benchmark's own JSON>}``, and the pages'
blocks between ``<!-- table:NAME -->`` markers are rewritten; text outside them is untouched.
"+dirty" after the commit means files other than those pages and ``benchmarks/results`` differed
from HEAD while measuring. A table whose benchmark ``--skip`` left out keeps its saved results
and commit, and says it was not rerun (so does one whose benchmark failed;
``benchmarks/results/tables/index.json`` remembers which).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from . import markers
from .render_util import commit_line, protocol_caption
from .tables import BENCHES, RESULTS, TABLES, benches_of, tables_of

REPO = Path(__file__).resolve().parent.parent
README = REPO / "README.md"
#: The pages whose table markers ``--all`` / ``--only`` / ``--render-only`` rewrite: the README
#: holds the headline table, the docs site's benchmarks page every table.
PAGES = (README, REPO / "docs" / "benchmarks.md")


def git_state(repo: Path = REPO) -> tuple[str, bool]:
    """(short HEAD, dirty?) ignoring the pipeline's own outputs."""
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True, cwd=repo, check=False).stdout.strip()
    status = subprocess.run(["git", "status", "--porcelain", "--", ".", ":(exclude)README.md",
                             ":(exclude)docs/benchmarks.md", ":(exclude)benchmarks/results"], capture_output=True, text=True,
                            cwd=repo, check=False).stdout.strip()
    return head, bool(status)


def _run_group(argv: list[str], **kwargs) -> int:
    """Run ``argv`` in its own process group and wait; if this process is interrupted or
    terminated meanwhile, kill the whole group first (a benchmark's workers would otherwise go
    on using the cores the next timing needs)."""
    def interrupted(signum, frame):
        raise KeyboardInterrupt(f"signal {signum}")

    previous = signal.signal(signal.SIGTERM, interrupted)
    proc = subprocess.Popen(argv, start_new_session=True, **kwargs)
    try:
        return proc.wait()
    except BaseException:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        raise
    finally:
        signal.signal(signal.SIGTERM, previous)


def run_bench(name: str, results_dir: Path = RESULTS) -> dict:
    """Run one registered benchmark at HEAD and save its document; returns the document."""
    bench = BENCHES[name]
    commit, dirty = git_state()
    env = dict(os.environ)
    if "FGOPT_DATA" not in env:  # the Makefile's default: ../shared/data beside the checkout
        env["FGOPT_DATA"] = str((REPO.parent / "shared" / "data").resolve())
    if not Path(env["FGOPT_DATA"]).is_dir():
        raise RuntimeError(f"benchmark {name!r}: no data directory {env['FGOPT_DATA']} "
                           "(set FGOPT_DATA)")
    with tempfile.TemporaryDirectory(prefix=f"fgopt-table-{name}-") as tmp:
        out = [a.replace("{dir}", tmp) for a in bench.out]
        argv = [sys.executable, "-m", bench.module, *bench.args, *out]
        load0, t0, started = os.getloadavg()[0], time.perf_counter(), dt.datetime.now()
        print(f"[{started:%H:%M:%S}] {name}: {bench.command()}", file=sys.stderr, flush=True)
        returncode = _run_group(argv, cwd=REPO, env=env)
        duration, load1 = time.perf_counter() - t0, os.getloadavg()[0]
        if returncode != 0:
            raise RuntimeError(f"benchmark {name!r} failed (exit {returncode}): "
                               f"{bench.command()}")
        found = sorted(Path(tmp).glob(bench.result))
        if not found:
            raise RuntimeError(f"benchmark {name!r} wrote no {bench.result} in its output dir")
        results = json.loads(found[-1].read_text())
    doc = {"meta": {"bench": name, "commit": commit + ("+dirty" if dirty else ""),
                    "date": started.strftime("%Y-%m-%d %H:%M"), "loadavg": [load0, load1],
                    "cores": os.cpu_count(), "command": bench.command(),
                    "duration_s": duration, "protocol": bench.protocol()},
           "results": results}
    save_doc(name, doc, results_dir)
    return doc


def save_doc(name: str, doc: dict, results_dir: Path = RESULTS) -> Path:
    results_dir.mkdir(parents=True, exist_ok=True)
    path = results_dir / f"{name}.json"
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(doc, indent=1, default=float) + "\n")
    os.replace(tmp, path)
    return path


def load_doc(name: str, results_dir: Path = RESULTS) -> dict | None:
    path = results_dir / f"{name}.json"
    return json.loads(path.read_text()) if path.is_file() else None


def render_table(table: str, doc: dict, not_rerun: dict | None = None) -> str:
    """One table's block: caption (the benchmark's declared protocol), the rendered table and
    summary, then the commit line."""
    caption = protocol_caption(doc["meta"])
    body = TABLES[table].render(doc)
    parts = ([caption, ""] if caption else []) + [body, "", commit_line(doc["meta"], table,
                                                                          not_rerun)]
    return "\n".join(parts)


def render_readme(text: str, tables: list[str], results_dir: Path = RESULTS) -> tuple[str, list]:
    """``text`` with the given tables re-rendered from saved results; tables without saved
    results are left as they are (returned in the second value)."""
    index = json.loads((results_dir / "index.json").read_text()) \
        if (results_dir / "index.json").is_file() else {}
    stale = index.get("not_rerun", {})
    bodies, missing = {}, []
    for t in tables:
        doc = load_doc(TABLES[t].bench, results_dir)
        if doc is None:
            missing.append(t)
            continue
        bodies[t] = render_table(t, doc, stale.get(TABLES[t].bench))
    return markers.replace_blocks(text, bodies), missing


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.run",
                                 description="Regenerate the README's tables at HEAD.")
    ap.add_argument("--all", action="store_true", help="run every registered benchmark")
    ap.add_argument("--only", default="", help="comma list of tables (or benchmarks)")
    ap.add_argument("--skip", default="", help="with --all: benchmarks (or tables) not to rerun")
    ap.add_argument("--render-only", action="store_true",
                    help="re-render from the saved results without running anything")
    ap.add_argument("--list", action="store_true", help="list tables and benchmarks")
    ap.add_argument("--readme", action="append", default=None,
                    help="a page to rewrite (repeatable; default: README.md and "
                         "docs/benchmarks.md)")
    ap.add_argument("--results", default=str(RESULTS), help="saved results directory")
    args = ap.parse_args(argv)
    results_dir = Path(args.results)
    if args.list:
        total = 0.0
        for name, b in BENCHES.items():
            total += b.minutes
            print(f"{name:14s} ~{b.minutes:4.1f} min  tables: {', '.join(tables_of([name]))}\n"
                  f"{'':14s} {b.command()}")
        print(f"full --all: ~{total:.0f} min on the shared 2-core machine (load 1-4)")
        return 0
    try:
        only = benches_of([n for n in args.only.split(",") if n])
        skip = benches_of([n for n in args.skip.split(",") if n])
    except KeyError as e:
        ap.error(str(e.args[0]))
    if not (args.all or only or args.render_only):
        ap.error("give --all, --only NAME[,NAME], --render-only or --list")
    selected = only or list(BENCHES)
    run = [] if args.render_only else [b for b in selected if b not in skip]
    pages = [Path(p) for p in args.readme] if args.readme else list(PAGES)
    texts = {p: p.read_text() for p in pages}
    present = set()
    for text in texts.values():  # malformed markers fail before hours of benchmarks
        present |= set(markers.find_blocks(text))
    absent = [t for t in tables_of(selected) if t not in present]
    if absent and not args.readme:
        ap.error(f"table(s) {', '.join(absent)}: no markers in {', '.join(map(str, pages))}")
    failed = []
    if not args.render_only:
        head, dirty = git_state()
        for name in run:
            try:
                run_bench(name, results_dir)
            except RuntimeError as e:  # keep going: the others' tables still get regenerated
                print(f"FAILED: {e}; its table keeps its saved results", file=sys.stderr)
                failed.append(name)
        index_path = results_dir / "index.json"
        index = json.loads(index_path.read_text()) if index_path.is_file() else {}
        stale = index.get("not_rerun", {})
        at = head + ("+dirty" if dirty else "")
        for b in run:  # measured now: no longer "not rerun"
            stale.pop(b, None)
        for b in [b for b in skip if b in selected] + failed:
            stale[b] = {"at": at, "why": "failed" if b in failed else "skipped"}
        index["not_rerun"] = stale
        results_dir.mkdir(parents=True, exist_ok=True)
        index_path.write_text(json.dumps(index, indent=1, sort_keys=True) + "\n")
    for page, text in texts.items():
        here = [t for t in tables_of(selected) if t in markers.find_blocks(text)]
        new, missing = render_readme(text, here, results_dir)
        if new != text:
            page.write_text(new)
        for t in missing:
            print(f"table {t}: no saved results in {results_dir}; left as it was",
                  file=sys.stderr)
        print(f"rendered {len(here) - len(missing)} table(s) into {page}", file=sys.stderr)
    for t in absent:
        print(f"table {t}: no markers in {', '.join(map(str, pages))}; not rendered",
              file=sys.stderr)
    if failed:
        print(f"benchmarks that failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0
