"""Registry of the generated tables (README's headline, docs/benchmarks.md's others): which benchmark produces each table, with which
arguments, and which renderer turns the benchmark's saved results into markdown.

A README table lives between ``<!-- table:NAME -->`` and ``<!-- /table:NAME -->``
(:mod:`benchmarks.markers`); ``python -m benchmarks.run --all`` (:mod:`benchmarks.pipeline`)
runs every benchmark below at HEAD, saves ``benchmarks/results/tables/<bench>.json`` (the
benchmark's own JSON plus the commit, date, load average and command) and rewrites the tables.
Each benchmark module declares ``TABLE_PROTOCOL = {"includes": ..., "stopping": ...}``: what its
timings include for every library and how each run stops; the caption is taken from there.
"""

from __future__ import annotations

import ast
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from . import constraints as constraints_bench
from . import render_misc, render_peers

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results" / "tables"


@dataclass(frozen=True)
class Bench:
    """One benchmark run: ``python -m <module> <args> <out args>``; ``out`` gets ``{dir}``
    replaced by a scratch directory and ``result`` (a glob in it) finds the JSON it wrote."""

    module: str
    args: tuple[str, ...]
    out: tuple[str, ...]
    result: str
    minutes: float  # typical wall time on the shared 2-core machine (for --list / estimates)

    def command(self) -> str:
        """The command as a person types it (the scratch output arguments left out)."""
        return " ".join(["python -m", self.module, *self.args])

    def protocol(self) -> dict:
        """The module's ``TABLE_PROTOCOL``, read without importing the benchmark."""
        path = HERE / (self.module.split(".", 1)[1].replace(".", "/") + ".py")
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.Assign) and any(
                    getattr(t, "id", None) == "TABLE_PROTOCOL" for t in node.targets):
                return ast.literal_eval(node.value)
        raise LookupError(f"{path}: no TABLE_PROTOCOL")


@dataclass(frozen=True)
class Table:
    """A README table: the benchmark whose saved document it renders, and the renderer."""

    bench: str
    render: Callable[[dict], str]


BENCHES: dict[str, Bench] = {
    "peers": Bench("benchmarks.run", (
        "--datasets", "m3500,intel,sphere2500,garage,torus3d,cubicle,ladybug,robot_localization",
        "--peers", "gtsam,ceres_cpp", "--repeats", "3"), ("--out", "{dir}/peers.json"),
        "peers.json", 15),
    "startup": Bench("benchmarks.startup", (
        "--repeats", "5", "--ba-repeats", "1", "--overhead-repeats", "1", "--cold-repeats", "1"),
        ("--out", "{dir}"), "startup-*.json", 47),
    "navigation": Bench("benchmarks.navigation", (), ("--out", "{dir}/navigation"),
                        "navigation.json", 1.5),
    "numpy-backend": Bench("benchmarks.numpy_backend", ("--repeats", "3"), ("--out", "{dir}"),
                           "numpy-backend-*.json", 6),
    "incremental": Bench("benchmarks.incremental", ("--fixed-lag", "100"),
                         ("--out", "{dir}/incremental"), "incremental.json", 15),
    "scale": Bench("benchmarks.scale", (), ("--out", "{dir}/scale.md", "--json", "{dir}/scale.json"),
                   "scale.json", 20),
    "gnc": Bench("benchmarks.gnc", ("--no-plain",),
                 ("--out", "{dir}/gnc.md", "--json", "{dir}/gnc.json"), "gnc.json", 15),
    "small-graphs": Bench("benchmarks.small_graphs", (),
                          ("--out", "{dir}/small-graphs.md", "--json",
                           "{dir}/small-graphs.json"), "small-graphs.json", 5),
    "constraints": Bench("benchmarks.constraints", (),
                         ("--out", "{dir}/constraints.md", "--json", "{dir}/constraints.json"),
                         "constraints.json", 5),
    "constants": Bench("benchmarks.constants", ("--repeats", "3"),
                       ("--out", "{dir}/constants.md", "--json", "{dir}/constants.json"),
                       "constants.json", 4),
}

TABLES: dict[str, Table] = {
    "peers": Table("peers", render_peers.render),
    "headline": Table("peers", render_peers.headline),
    "startup": Table("startup", render_misc.startup),
    "startup-overheads": Table("startup", render_misc.startup_overheads),
    "startup-first-use": Table("startup", render_misc.startup_first_use),
    "navigation": Table("navigation", render_misc.navigation),
    "numpy-backend": Table("numpy-backend", render_misc.numpy_backend),
    "incremental": Table("incremental", render_misc.incremental),
    "scale": Table("scale", render_misc.scale),
    "gnc": Table("gnc", render_misc.gnc),
    "small-graphs": Table("small-graphs", render_misc.small_graphs),
    "constraints": Table("constraints", constraints_bench.render),
    "constants": Table("constants", render_misc.constants),
}


def benches_of(names: list[str]) -> list[str]:
    """Benchmarks behind table or benchmark names (unknown names: ``KeyError`` naming them)."""
    bad = [n for n in names if n not in TABLES and n not in BENCHES]
    if bad:
        raise KeyError(f"unknown table(s) {', '.join(bad)}; known: {', '.join(TABLES)}")
    out = [TABLES[n].bench if n in TABLES else n for n in names]
    return list(dict.fromkeys(out))


def tables_of(benches: list[str]) -> list[str]:
    """Tables rendered from the given benchmarks, in registry order."""
    return [t for t, spec in TABLES.items() if spec.bench in benches]
