"""README tables of ``benchmarks.run`` (fgopt vs GTSAM / Ceres / ... per problem): exactly 5 LM
iterations, to convergence (with each library's own convergence verdict), final costs.

Ratios are fgopt / peer (> 1: fgopt slower); the summary line under each table is generated.
"""

from __future__ import annotations

from .render_util import Losses, fmt_ratio, fmt_s

_LABEL = {"fgopt": "fgopt", "gtsam": "GTSAM", "ceres": "pyceres", "ceres_cpp": "Ceres C++",
          "symforce": "SymForce", "scipy": "scipy"}
# Iteration caps of each library's "converge" mode (benchmarks/README.md), used only to read
# records saved before the GTSAM runner recorded its own status.
_GTSAM_CAP = 100


def _label(problem: str) -> str:
    from .problems import PROBLEMS

    spec = PROBLEMS.get(problem)
    return spec.label if spec is not None else problem


def converged(r: dict) -> tuple[bool | None, str]:
    """Did the library's OWN convergence test stop this run? (verdict, what the record says)"""
    s = (r.get("lib_status") or "").strip()
    if r["peer"] in ("ceres", "ceres_cpp"):
        return s == "CONVERGENCE", s.lower().replace("_", " ") or "not recorded"
    if s:
        return s == "converged", s
    if r["peer"] == "gtsam" and r.get("iterations") is not None:
        if r["iterations"] >= _GTSAM_CAP:
            return False, f"{_GTSAM_CAP}-iteration limit"
        return None, "not recorded (run before the GTSAM runner kept its status)"
    return None, "not recorded"


def _by(records: list[dict]) -> dict:
    return {(r["problem"], r["peer"], r["mode"]): r for r in records}


def _peers(records: list[dict]) -> list[str]:
    seen = list(dict.fromkeys(r["peer"] for r in records))
    return ["fgopt"] + [p for p in seen if p != "fgopt"]


def _time(r: dict | None) -> float | None:
    return r["solve_s"] if r and r.get("status") == "ok" else None


def _status_cell(r: dict | None) -> str:
    if r is None:
        return "—"
    return {"unsupported": "n/a", "timeout": "timeout", "skipped": "skipped"}.get(
        r.get("status"), "error")


def table_5it(doc: dict) -> str:
    """Exactly 5 LM iterations: seconds per library, fgopt / peer ratios."""
    records, peers = doc["results"]["runs"], _peers(doc["results"]["runs"])
    by, others = _by(records), peers[1:]
    problems = list(dict.fromkeys(r["problem"] for r in records))
    head = ["problem"] + [_LABEL.get(p, p) + " s" for p in peers] + [
        f"fgopt / {_LABEL.get(p, p)}" for p in others]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    losses, unchanged = Losses(), []
    for pb in problems:
        fg = _time(by.get((pb, "fgopt", "5it")))
        row = [_label(pb)]
        for p in peers:
            r = by.get((pb, p, "5it"))
            row.append(fmt_s(_time(r)) if _time(r) is not None else _status_cell(r))
            if r and r.get("status") == "ok" and r.get("final_cost") is not None and \
                    r.get("initial_cost") and r["final_cost"] >= r["initial_cost"] * (1 - 1e-12):
                unchanged.append(f"{_LABEL.get(p, p)} on {_label(pb)}")
        for p in others:
            q = fg / _time(by.get((pb, p, "5it"))) if fg and _time(by.get((pb, p, "5it"))) \
                else None
            row.append(fmt_ratio(q))
            losses.check(_LABEL.get(p, p), _label(pb), q)
        lines.append("| " + " | ".join(row) + " |")
    lines += ["", losses.line()]
    if unchanged:
        lines.append("Five iterations that changed nothing (final cost = initial cost: every step "
                     f"rejected, so this row times rejected trials only): {', '.join(unchanged)}.")
    return "\n".join(lines)


def table_converge(doc: dict) -> str:
    """To convergence: seconds (iterations, converged?) per library, fgopt / peer ratios; a
    ratio where either side did not converge by its own test is marked †."""
    records, peers = doc["results"]["runs"], _peers(doc["results"]["runs"])
    by, others = _by(records), peers[1:]
    problems = list(dict.fromkeys(r["problem"] for r in records))
    head = ["problem"] + [f"{_LABEL.get(p, p)} s (iterations, converged)" for p in peers] + [
        f"fgopt / {_LABEL.get(p, p)}" for p in others]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    losses, not_conv = Losses(), []
    for pb in problems:
        fg_r = by.get((pb, "fgopt", "converge"))
        fg = _time(fg_r)
        row = [_label(pb)]
        verdict = {}
        for p in peers:
            r = by.get((pb, p, "converge"))
            if _time(r) is None:
                row.append(_status_cell(r))
                continue
            ok, why = converged(r)
            verdict[p] = ok
            word = "yes" if ok else ("**no**: " + why if ok is False else "? " + why)
            note = "¹" if r.get("timing_note") else ""
            row.append(f"{fmt_s(r['solve_s'])}{note} ({r.get('iterations')}, {word})")
            if ok is False:
                not_conv.append(f"{_LABEL.get(p, p)} on {_label(pb)} ({why})")
        for p in others:
            pt = _time(by.get((pb, p, "converge")))
            q = fg / pt if fg and pt else None
            mark = "†" if q is not None and (verdict.get("fgopt") is not True
                                             or verdict.get(p) is not True) else ""
            row.append(fmt_ratio(q, mark))
            losses.check(_LABEL.get(p, p), _label(pb) + (" †" if mark else ""), q)
        lines.append("| " + " | ".join(row) + " |")
    lines += ["", losses.line()]
    if not_conv:
        lines.append("Not converged by the library's own test (their time is the time to their "
                     f"iteration limit, not to convergence): {'; '.join(not_conv)}.")
    lines.append("† = not a time-to-convergence comparison: one side did not converge by its own "
                 "test, or its verdict was not recorded. ¹ = one sample (the warm-up took > "
                 f"{doc['results']['meta']['args'].get('long', 30):g} s).")
    return "\n".join(lines)


def table_costs(doc: dict) -> str:
    """Final cost on one yardstick, 5 iterations / converged, per library."""
    records, peers = doc["results"]["runs"], _peers(doc["results"]["runs"])
    by = _by(records)
    problems = list(dict.fromkeys(r["problem"] for r in records))
    head = ["problem", "initial"] + [f"{_LABEL.get(p, p)} 5 it / converge" for p in peers]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    higher = Losses()
    for pb in problems:
        init = next((r.get("initial_cost") for r in records
                     if r["problem"] == pb and r.get("initial_cost") is not None), None)
        row = [_label(pb), _fmt_c(init)]
        for p in peers:
            cells = []
            for mode in ("5it", "converge"):
                r = by.get((pb, p, mode))
                cells.append(_fmt_c(r.get("final_cost")) if r and r.get("status") == "ok"
                             else _status_cell(r))
            row.append(" / ".join(cells))
        fg = by.get((pb, "fgopt", "converge"))
        for p in peers[1:]:
            r = by.get((pb, p, "converge"))
            if fg and r and fg.get("final_cost") is not None and r.get("status") == "ok" and \
                    r.get("final_cost") is not None and \
                    fg["final_cost"] > r["final_cost"] * (1 + 1e-6):
                higher.add(_LABEL.get(p, p), f"{_label(pb)} ({_fmt_c(fg['final_cost'])} vs "
                           f"{_fmt_c(r['final_cost'])})")
        lines.append("| " + " | ".join(row) + " |")
    lines += ["", higher.line("fgopt's converged cost is higher than")
              .replace("fgopt loses nowhere", "fgopt's converged cost is nowhere higher than a "
                       "peer's")]
    return "\n".join(lines)


def _fmt_c(x: float | None) -> str:
    if x is None:
        return "—"
    return f"{x:.4g}" if abs(x) >= 1e5 else f"{x:.6g}"


def render(doc: dict) -> str:
    """The three tables of one ``benchmarks.run`` results file, with their headings."""
    meta = doc["results"]["meta"]
    versions = ", ".join(f"{_LABEL.get(k, k)} {v}" for k, v in meta.get("versions", {}).items())
    return "\n".join([
        "#### Exactly 5 LM iterations (stopping tests off, file's initial guess)", "",
        table_5it(doc), "",
        "#### To convergence (each library's default stopping rules)", "",
        table_converge(doc), "",
        ("#### Final cost, one yardstick (0.5 Σ squared whitened residuals over the problem's own "
        "measurements, GTSAM's residuals, no gauge prior; BAL: every observation)"), "",
        table_costs(doc), "",
        (f"Seconds, median of {meta['args'].get('repeats')} runs after a warm-up, one process per "
        f"library × problem × mode, single thread. Versions: {versions}.")])


def headline(doc: dict) -> str:
    """The README's headline: the to-convergence table alone (the docs' benchmarks page has all
    three)."""
    meta = doc["results"]["meta"]
    versions = ", ".join(f"{_LABEL.get(k, k)} {v}" for k, v in meta.get("versions", {}).items())
    return "\n".join([table_converge(doc), "",
                      (f"Seconds, median of {meta['args'].get('repeats')} runs after a warm-up, "
                       f"one process per library × problem × mode, single thread. Versions: "
                       f"{versions}.")])
