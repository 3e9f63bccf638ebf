"""Shared pieces of the README table renderers: number formats, the fgopt / peer ratio, the
generated "where fgopt loses" line, the protocol caption and the commit line."""

from __future__ import annotations


def fmt_s(x: float | None) -> str:
    """Seconds with three significant digits (whole seconds from 100 s)."""
    if x is None:
        return "—"
    return f"{x:.3g}" if x < 100 else f"{x:.0f}"


def ratio(fg: float | None, peer: float | None) -> float | None:
    """fgopt / peer: > 1 means fgopt is slower (or uses more)."""
    if fg is None or peer is None or peer <= 0:
        return None
    return fg / peer


def fmt_ratio(r: float | None, mark: str = "") -> str:
    """A ratio cell; bold when fgopt loses (> 1)."""
    if r is None:
        return "—"
    s = f"{r:.2f}{mark}"
    return f"**{s}**" if r > 1 else s


class Losses:
    """Collects the rows where fgopt is slower (or misses a target) for the summary line."""

    def __init__(self) -> None:
        self.items: dict[str, list[str]] = {}

    def add(self, against: str, what: str, r: float | None = None) -> None:
        self.items.setdefault(against, []).append(what + (f" (×{r:.2f})" if r else ""))

    def check(self, against: str, what: str, r: float | None) -> None:
        if r is not None and r > 1:
            self.add(against, what, r)

    def line(self, subject: str = "fgopt is slower than") -> str:
        if not self.items:
            return "Generated summary: fgopt loses nowhere in this table."
        parts = [f"{subject} {k} on: {', '.join(v)}" for k, v in self.items.items()]
        return "Generated summary: " + "; ".join(parts) + "."


def protocol_caption(meta: dict) -> str:
    """'Timing: ... Stopping: ...' from the protocol the benchmark itself declares."""
    p = meta.get("protocol") or {}
    parts = []
    if p.get("includes"):
        parts.append(f"Timing: {p['includes']}")
    if p.get("stopping"):
        parts.append(f"Stopping: {p['stopping']}")
    return " ".join(parts)


def commit_line(meta: dict, table: str, not_rerun: dict | None = None) -> str:
    """The line under every generated table: commit, date, load, the exact command."""
    commit = meta.get("commit") or "not recorded"
    where = f"commit `{commit}`" if meta.get("commit") else "a commit that was not recorded"
    load = meta.get("loadavg") or []
    cores = meta.get("cores", "?")
    if meta.get("loadavg_range"):
        lo, hi = meta["loadavg_range"]
        load_s = f"1-min load average {lo:.1f}–{hi:.1f} while measuring ({cores} cores)"
    elif len(load) == 2:
        load_s = f"1-min load average {load[0]:.1f} at the start, {load[1]:.1f} at the end " \
                 f"({cores} cores)"
    elif len(load) == 1:
        load_s = f"1-min load average {load[0]:.1f} at the start ({cores} cores)"
    else:
        load_s = "load average not recorded"
    took = f", {meta['duration_s'] / 60:.1f} min" if meta.get("duration_s") else ""
    line = (f"_Measured at {where} on {meta.get('date', '?')}, {load_s}{took}: "
            f"`{meta.get('command', '?')}`")
    if meta.get("imported_from"):
        line += (f" (imported from `{meta['imported_from']}`, measured before the tables "
                 f"pipeline: {meta.get('import_note', 'figures as saved then')})")
    line += f". Regenerate: `python -m benchmarks.run --only {table}`._"
    if not_rerun:
        line += (f" **Not rerun** by the last run at `{not_rerun['at']}` ({not_rerun['why']}): "
                 "these figures are from the commit above.")
    return line
