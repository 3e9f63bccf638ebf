"""``Result``, ``Status`` and per-iteration records of an optimization."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field, fields

import numpy as np

from ..key import key_str
from ..variables import Variables


class Status(enum.Enum):
    CONVERGED = "converged"
    STALLED = "stalled"
    """No progress: every step since some iteration was rejected although the model predicted
    a decrease the cost could resolve (a wrong Jacobian, or NaN beyond the current point); the
    stopping test that fired (damping or radius limit, step size) says nothing about
    convergence. The values are the last accepted ones."""
    MAX_ITERATIONS = "max iterations"
    FAILED = "failed"
    STOPPED = "stopped by callback"
    INFEASIBLE = "infeasible"
    """The constraints could not be met to their tolerance (contradictory constraints, or the
    augmented-Lagrangian loop ran out of outer iterations or penalty); the values are the last
    iterate, ``Result.constraint_violation`` says by how much it misses."""

    def __repr__(self) -> str:
        return f"Status.{self.name}"


@dataclass(frozen=True)
class IterationRecord:
    """One iteration of a solve (``Result.iteration_records``): costs, damping, step and
    gradient norms, whether the step was accepted, seconds since the start.

    >>> sample = fgopt.datasets.manhattan_2d(num_poses=30, seed=0)
    >>> result = fgopt.optimize(sample.graph, sample.initial)
    >>> record = result.iteration_records[0]
    >>> record.iteration, record.accepted, record.cost < result.initial_cost
    (1, True, True)
    """

    iteration: int
    cost: float
    """Cost after this iteration (the accepted iterate's)."""
    candidate_cost: float
    """Cost of the step tried this iteration (NaN if not evaluated)."""
    relative_decrease: float
    lam: float
    """Damping (LM) or trust-region radius (dogleg) used for this step."""
    step_norm: float
    gradient_norm: float
    accepted: bool
    time: float
    """Seconds since the optimization started."""

    HEADER = (" iter        cost      rel.decr     lambda   |step|     |grad|   time(s)")

    def row(self) -> str:
        mark = "" if self.accepted else "  (rejected)"
        return (f"{self.iteration:5d} {self.cost:12.6e} {self.relative_decrease:10.3e} "
                f"{self.lam:9.2e} {self.step_norm:9.2e} {self.gradient_norm:9.2e} "
                f"{self.time:8.3f}{mark}")


class _RecordTable:
    """Iteration records pickled as one float64 array (a column per field; the integer and
    boolean fields are exact in float64)."""

    __slots__ = ("table",)
    FIELDS = tuple(f.name for f in fields(IterationRecord))

    def __init__(self, records: list[IterationRecord]):
        self.table = np.array([[getattr(r, f) for f in self.FIELDS] for r in records],
                              dtype=np.float64)

    def __getstate__(self):
        return self.table

    def __setstate__(self, table) -> None:
        self.table = table

    def records(self) -> list[IterationRecord]:
        out = []
        for row in self.table.tolist():
            d = dict(zip(self.FIELDS, row))
            d["iteration"], d["accepted"] = int(d["iteration"]), bool(d["accepted"])
            out.append(IterationRecord(**d))
        return out


class _HistoryRows:
    """A compiled LM loop's history (its first ``its`` rows, see :func:`compiled_history`), made
    into lists when first read and into :class:`IterationRecord` s when those are: building the
    records costs ~6 us for 5 iterations and even the lists ~0.7 us, against a tiny problem's
    ~30 us solve, and most callers read neither (``Result.iteration_records`` and
    ``Result.cost_history`` make them)."""

    __slots__ = ("hist", "its", "_rows")

    def __init__(self, hist: np.ndarray, its: int):
        self.hist, self.its, self._rows = hist, its, None

    @property
    def rows(self) -> list[list[float]]:
        if self._rows is None:
            self._rows = self.hist[:self.its].tolist()
        return self._rows

    def __len__(self) -> int:
        return self.its

    def accepted_costs(self) -> list[float]:
        return [h[0] for h in self.rows if h[6] > 0.5]

    def records(self) -> list[IterationRecord]:
        new, names, nan = object.__new__, _RecordTable.FIELDS, math.nan
        out = []
        for i, h in enumerate(self.rows, 1):  # frozen dataclass: __init__ costs ~1.5 us a record
            r = new(IterationRecord)
            r.__dict__.update(zip(names, (i, h[0], h[1], h[2], h[3], h[4], h[5], h[6] > 0.5, nan)))
            out.append(r)
        return out


_COMPILED_STATUS = {0: Status.CONVERGED, 1: Status.MAX_ITERATIONS, 2: Status.FAILED}


def compiled_history(hist: np.ndarray, its: int, status: int, message: str,
                     cost: float) -> tuple[_HistoryRows, Status, str]:
    """Iteration records, status and message of a compiled LM loop (the dense template of
    :mod:`fgopt.solvers.small._lm_template`): ``hist[:its]`` rows are (cost, candidate cost,
    relative decrease, lambda, step norm, gradient norm, accepted, predicted decrease), a
    ``status`` of 0 / 1 / 2 is converged / max iterations / failed, and a converged run whose
    trailing steps were all rejected becomes :func:`stall_status`'s STALLED. The records (pass
    them to :class:`Result` as ``iteration_records``) are made when first read and carry no
    time (NaN: the loop runs compiled)."""
    records = _HistoryRows(hist, its)
    st = _COMPILED_STATUS[int(status)]
    if st is not Status.CONVERGED:  # (stall_status changes only a converged run)
        return records, st, message
    rows = records.rows
    since, gain = None, 0.0  # the trailing run of rejected steps, as Run tracks it
    for i in range(its - 1, -1, -1):
        h = rows[i]
        if h[6] > 0.5:
            break
        since = i + 1
        g = h[7] if math.isfinite(h[1]) else math.inf
        gain = max(gain, g if g == g else math.inf)
    st, message = stall_status(st, message, float(cost), since, gain)
    return records, st, message


def compiled_result(hist: np.ndarray, its: int, status: int, message: str, cost: float,
                    init: float, timing: dict, method: str, linear_solver: str,
                    info: dict | None = None, values: Variables | None = None,
                    state: object = None, problem: object = None) -> "Result":
    """The :class:`Result` of a compiled LM loop (:func:`compiled_history`'s records, status
    and message; ``values``, ``state`` and ``problem`` as given, no unused keys or clamps),
    made without the dataclass' ``__init__`` (~1 us of a small problem's ~40 us solve). Same
    fields as ``Result(...)``."""
    records = _HistoryRows(hist, its)
    st = _COMPILED_STATUS[status]
    if st is Status.CONVERGED:  # (stall_status changes only a converged run)
        _, st, message = compiled_history(hist, its, status, message, cost)
    r = object.__new__(Result)
    r.__dict__ = {  # (a literal: ~0.5 us less than update(**fields))
        "_values": values, "status": st, "message": message, "iterations": its,
        "initial_cost": float(init), "final_cost": float(cost), "_cost_history": records,
        "_records": records, "timing": timing, "method": method,
        "linear_solver": linear_solver, "_problem": problem, "state": state,
        "info": {} if info is None else info, "unused_keys": (), "clamps": (), "num_clamped": 0,
        "constraint_violation": 0.0, "multipliers": ()}
    return r


#: A rejected step whose model predicted a decrease above this fraction of the cost was one the
#: cost could resolve in floating point: when every step since then was rejected, the run
#: stalled (the rounding of a sum of squares is ~1e-16 relative per term, far below).
RESOLVABLE_DECREASE = 1e-10


def stall_status(status: Status, message: str, cost: float, rejected_since: int | None,
                 rejected_gain: float) -> tuple[Status, str]:
    """``(Status.STALLED, why)`` for a "converged" run whose last steps were all rejected while
    the model predicted a resolvable decrease (``rejected_gain``, infinite for non-finite
    trials); otherwise ``(status, message)`` unchanged."""
    if (status is Status.CONVERGED and rejected_since is not None and cost > 0
            and rejected_gain > RESOLVABLE_DECREASE * cost):
        return Status.STALLED, (f"no progress: every step since iteration {rejected_since} was "
                                "rejected or fell far short of the model's predicted decrease "
                                f"({message}); check the Jacobians with "
                                "fgopt.check_jacobians(graph, values)")
    return status, message


class _Records:
    """``Result.iteration_records``: a list, or :class:`_HistoryRows` turned into one when first
    read (a data descriptor, so the dataclass' ``__init__`` and ``==`` go through it)."""

    def __get__(self, obj: "Result | None", owner: type | None = None):
        if obj is None:
            return ()  # the dataclass field's default: no records
        v = obj.__dict__["_records"]
        if type(v) is _HistoryRows:
            v = obj.__dict__["_records"] = v.records()
        return v

    def __set__(self, obj: "Result", value) -> None:
        obj.__dict__["_records"] = value if isinstance(value, (list, _HistoryRows)) else list(value)


class _Costs:
    """``Result.cost_history``: a list, or for a compiled loop its :class:`_HistoryRows`, turned
    into the list (the initial cost, then each accepted step's) when first read. A data
    descriptor with no class-level default, so the field stays required in ``__init__``."""

    def __get__(self, obj: "Result | None", owner: type | None = None):
        if obj is None:
            raise AttributeError("cost_history")  # (dataclasses: no default)
        d = obj.__dict__
        v = d["_cost_history"]
        if type(v) is _HistoryRows:
            v = d["_cost_history"] = [d["initial_cost"]] + v.accepted_costs()
        return v

    def __set__(self, obj: "Result", value) -> None:
        obj.__dict__["_cost_history"] = value


class Deferred:
    """A problem made by ``make(*args)`` when first read (see :class:`_MadeOnRead`); ``dims``:
    its ``(residual dimensions, tangent dimensions)`` when known without making it (the
    chi-square test of :mod:`fgopt.solvers.initialization` needs only those)."""

    __slots__ = ("make", "dims", "args")

    def __init__(self, make, dims: tuple[int, int] | None = None, args: tuple = ()):
        self.make, self.dims, self.args = make, dims, args


def deferred_dims(result: "Result") -> tuple[int, int] | None:
    """``(residual dimensions, tangent dimensions)`` of ``result``'s problem when it is still
    :class:`Deferred` with them known (reading ``result.problem`` would make it)."""
    p = result.__dict__.get("_problem")
    return p.dims if type(p) is Deferred else None


class _MadeOnRead:
    """``Result.problem``: the compiled problem, or a :class:`Deferred` one made when first read
    (a fast path that solved without compiling one: most callers never read it). A data
    descriptor, so the dataclass' ``__init__``, ``==`` and ``repr`` go through it."""

    def __get__(self, obj: "Result | None", owner: type | None = None):
        if obj is None:
            return None  # the dataclass field's default
        v = obj.__dict__["_problem"]
        if type(v) is Deferred:
            v = obj.__dict__["_problem"] = v.make(*v.args)
        return v

    def __set__(self, obj: "Result", value) -> None:
        obj.__dict__["_problem"] = value


def _restart_lines(r: dict, final_cost: float) -> list[str]:
    """The cost lines of a result of ``initialization="auto"`` that also ran from the chordal
    relaxation: the caller's start cost first, then why and where it restarted."""
    given = f"{r['given_initial_cost']:.6g} -> {r['given_final_cost']:.6g}"
    chordal = f"{r['chordal_initial_cost']:.6g} -> {r['chordal_final_cost']:.6g}"
    if r["kept"] == "chordal":
        return [f"  cost: {r['given_initial_cost']:.6g} at the given values -> "
                f"{final_cost:.6g}, restarted from the chordal relaxation",
                f"  restart: {r['why']}; from the given values {given}, from the chordal "
                f"relaxation {chordal} (kept)"]
    return [f"  cost: {given} (given values kept)",
            f"  restart: {r['why']}; from the chordal relaxation {chordal} (higher, dropped)"]


@dataclass
class Result:
    """What an optimizer returns. ``values`` are built on first access from the final state.

    Example:

    >>> sample = fgopt.datasets.manhattan_2d(num_poses=20, seed=0)
    >>> result = fgopt.optimize(sample.graph, sample.initial)
    >>> result.success, result.iterations > 0, len(result.values) == len(sample.initial)
    (True, False, True)
    >>> result.unused_keys
    ()
    """

    _values: "Variables | None"
    status: Status
    message: str
    iterations: int
    initial_cost: float
    final_cost: float
    cost_history: list[float] = _Costs()  # type: ignore[assignment]
    iteration_records: list[IterationRecord] = _Records()  # type: ignore[assignment]
    timing: dict[str, float] = field(default_factory=dict)
    method: str = ""
    linear_solver: str = ""
    problem: object = _MadeOnRead()  # type: ignore[assignment]
    """The compiled problem (for marginals)."""
    state: object = field(default=None, repr=False)
    """The final :class:`fgopt.problem.State` (storage arrays)."""
    info: dict = field(default_factory=dict, repr=False)
    """Method-specific details (e.g. GNC weights and outlier count)."""
    unused_keys: tuple = ()
    """Keys of the initial values no factor uses (not optimized, returned unchanged)."""
    clamps: tuple = ()
    """:class:`~fgopt.solvers.diagnostics.ClampHit` of factors whose clamped ``sqrt``/``log``/
    ``acos``/``asin`` argument lies outside its domain at the final values (at most 100 listed)."""
    num_clamped: int = 0
    """How many such (factor, clamped call) pairs there are in all."""
    constraint_violation: float = 0.0
    """Largest constraint violation at the result, ``max(|g|, max(h, 0))`` over every
    constraint of the graph (0 without constraints)."""
    multipliers: tuple = ()
    """Lagrange multipliers, one array per constraint of ``graph.constraints`` (same order), with
    ``grad cost + sum_i J_i^T multipliers_i = 0`` at a solution; inequality multipliers are
    ``>= 0`` and zero where the constraint is inactive. Empty without constraints."""

    @property
    def values(self) -> Variables:
        """The optimized values as a new ``Variables`` (the caller's initial is untouched)."""
        if self._values is None:
            self._values = self.problem.values(self.state)
        return self._values

    def __getstate__(self) -> dict:
        # A pickled result carries its values, not the compiled problem (kernels, H's pattern,
        # factorization): a sphere2500 result is 0.3 MB instead of 10 MB. Marginals then need
        # graph= and values= (see fgopt.marginals).
        # The values travel as one storage array per kind (Variables' pickling), taken from the
        # final state without a Python object per variable; the iteration records as one array.
        state = dict(self.__dict__)
        if self._values is None and hasattr(self.problem, "values_as_rows"):
            state["_values"] = self.problem.values_as_rows(self.state)
        else:
            state["_values"] = self.values
        state.pop("_problem")
        state["problem"] = state["state"] = None
        state["_cost_history"] = self.cost_history
        records = state.pop("_records")
        records = state["iteration_records"] = (
            records.records() if type(records) is _HistoryRows else records)
        if records and all(type(r) is IterationRecord for r in records):
            try:
                state["iteration_records"] = _RecordTable(records)
            except (TypeError, ValueError):  # a non-numeric field: the records as they are
                pass
        return state

    def __setstate__(self, state: dict) -> None:
        state = dict(state)
        if "cost_history" in state:  # (pickled before it was a descriptor)
            state["_cost_history"] = state.pop("cost_history")
        records = state.pop("iteration_records", [])
        problem = state.pop("problem", None)
        self.__dict__.update(state)
        self.problem = problem
        self.iteration_records = (records.records() if isinstance(records, _RecordTable)
                                  else records)

    @property
    def success(self) -> bool:
        return self.status is Status.CONVERGED

    def __repr__(self) -> str:
        t = self.timing
        lines = [
            f"Result({self.method}/{self.linear_solver}: {self.status.value} after "
            f"{self.iterations} iterations — {self.message})",
            f"  cost: {self.initial_cost:.6g} -> {self.final_cost:.6g}",
        ]
        restart = self.info.get("restart")
        if restart is not None:  # initialization="auto" also ran from the chordal relaxation
            lines[1:] = _restart_lines(restart, self.final_cost)
        if self.num_clamped > 0:
            lines.append(f"  clamped: {self.num_clamped} factor(s) end outside a clamped "
                         f"function's domain, e.g. {self.clamps[0]}")
        if len(self.multipliers) > 0:
            lines.append(f"  constraints: {len(self.multipliers)}, largest violation "
                         f"{self.constraint_violation:.3g}")
        if len(self.unused_keys) > 0:
            shown = ", ".join(key_str(k) for k in self.unused_keys[:8])
            more = ", ..." if len(self.unused_keys) > 8 else ""
            lines.append(f"  unused: {len(self.unused_keys)} initial key(s) no factor uses "
                         f"({shown}{more}), returned unchanged")
        if t:
            parts = ", ".join(f"{k} {v:.3f}s" for k, v in t.items())
            lines.append(f"  time: {parts}")
        return "\n".join(lines)

    def table(self) -> str:
        return "\n".join([IterationRecord.HEADER] + [r.row() for r in self.iteration_records])

    def _repr_html_(self) -> str:
        rows = "".join(
            f"<tr><td>{r.iteration}</td><td>{r.cost:.6e}</td><td>{r.relative_decrease:.2e}</td>"
            f"<td>{r.lam:.1e}</td><td>{r.step_norm:.2e}</td><td>{'yes' if r.accepted else 'no'}"
            f"</td><td>{r.time:.3f}</td></tr>" for r in self.iteration_records[:50])
        t = ", ".join(f"{k} {v:.3f}s" for k, v in self.timing.items())
        return (f"<b>Result</b> ({self.method}/{self.linear_solver}): <b>{self.status.value}</b> "
                f"after {self.iterations} iterations — {self.message}<br>"
                f"cost {self.initial_cost:.6g} &rarr; {self.final_cost:.6g}<br><small>{t}</small>"
                "<table><tr><th>iter</th><th>cost</th><th>rel. decrease</th><th>lambda</th>"
                f"<th>|step|</th><th>accepted</th><th>time</th></tr>{rows}</table>")
