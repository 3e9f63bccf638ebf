"""Pickling ``Variables``: one storage array per kind, exact, and small.

A pickled Variables keeps every key, its order, each value's type and each value's storage bit
for bit (built-in groups, vectors, floats, declared manifolds, duck-typed and other per-value
values), loads values of batched kinds as bulk rows (no object per value), and solves after a
round trip exactly as before.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys

import numpy as np
import pytest

import fgopt
from fgopt import SE2, SE3, SO2, SO3, Sim3, key
from fgopt.manifolds import SE2 as _SE2  # noqa: F401  (registers the groups' kinds)


class Duck:
    """A miniSAM-style value (no storage layout): it travels as itself."""

    def __init__(self, x):
        self.x = np.asarray(x, dtype=float)

    def dim(self):
        return self.x.shape[0]

    def local(self, other):
        return other.x - self.x

    def retract(self, d):
        return Duck(self.x + d)


def _bits(value) -> tuple:
    """Type and exact bytes of a value's storage (duck values: their array)."""
    if isinstance(value, Duck):
        return Duck, value.x.tobytes()
    if isinstance(value, np.ndarray):
        return np.ndarray, value.dtype.str, value.tobytes()
    if isinstance(value, (float, np.floating)):
        return type(value), np.float64(value).tobytes()
    return type(value), value.to_storage().tobytes()


def _same(a: fgopt.Variables, b: fgopt.Variables) -> bool:
    return a.keys() == b.keys() and all(_bits(a.at(k)) == _bits(b.at(k)) for k in a)


def _mixed(seed: int = 0) -> fgopt.Variables:
    rng = np.random.default_rng(seed)
    v = fgopt.Variables()
    # interleaved kinds (more runs than are kept as bulk blocks), awkward bits (retracted values)
    for i in range(20):
        v.add(key("x", i), SE3.identity().retract(rng.normal(0, 1, 6)))
        v.add(key("l", i), rng.normal(0, 1, 3))
    v.add(key("a", 0), SE2.from_xytheta(1.0, 2.0, 3.0).retract(rng.normal(0, 1, 3)))
    v.add(key("a", 1), SO2.identity().retract(rng.normal(0, 1, 1)))
    v.add(key("a", 2), SO3.identity().retract(rng.normal(0, 1, 3)))
    v.add(key("a", 3), Sim3.identity().retract(rng.normal(0, 1, 7)))
    v.add(key("a", 4), 0.1 + 0.2)
    v.add(key("a", 5), np.float64(1 / 3))  # a NumPy scalar keeps its type (per-value path)
    v.add(key("a", 6), Duck([1.0, 2.0]))
    v.add(key("a", 7), fgopt.Unit3(rng.normal(0, 1, 3)))
    v.add(key("a", 8), np.array([np.pi]))
    v.add_rows(np.arange(100, 110), SE2.batch_kind(), np.c_[rng.normal(0, 1, (10, 2)),
                                                            np.cos(np.arange(10)),
                                                            np.sin(np.arange(10))])
    return v


def test_round_trip_keeps_keys_order_types_and_bits():
    """Every kind of value (groups, vectors, float, NumPy scalar, declared Unit3, duck-typed,
    bulk rows) comes back with the same key order, type and storage bits."""
    v = _mixed()
    back = pickle.loads(pickle.dumps(v))
    assert _same(v, back)
    assert back == v and len(back) == len(v)


def test_round_trip_of_bulk_rows_and_empty():
    """Bulk rows (a file reader's) and an empty Variables round-trip; the loaded rows stay rows."""
    rows = np.random.default_rng(1).normal(0, 1, (50, 3))
    v = fgopt.Variables().add_rows(np.arange(7, 57), fgopt.manifolds.vector_kind(3), rows)
    back = pickle.loads(pickle.dumps(v))
    assert back._pending and not back._dict and _same(v, back)
    empty = pickle.loads(pickle.dumps(fgopt.Variables()))
    assert len(empty) == 0 and empty.keys() == []


def test_one_kind_loads_as_rows_without_objects():
    """Values of one batched kind load as bulk rows (no Python object per value), and reading
    them after loading gives the exact values."""
    rng = np.random.default_rng(2)
    v = fgopt.Variables()
    for i in range(300):
        v.add(i, SE2.from_xytheta(*rng.normal(0, 1, 3)))
    back = pickle.loads(pickle.dumps(v))
    assert not back._dict and len(back._pending) == 1
    assert _same(v, back)


def test_interleaved_kinds_load_as_values():
    """Batched kinds interleaved key by key (more runs than bulk blocks are kept for) load as
    per-key values, in order, exactly."""
    rng = np.random.default_rng(4)
    v = fgopt.Variables()
    for i in range(30):
        v.add(key("x", i), SE3.identity().retract(rng.normal(0, 1, 6)))
        v.add(key("l", i), rng.normal(0, 1, 3))
    back = pickle.loads(pickle.dumps(v))
    assert len(back._dict) == 60 and not back._pending
    assert _same(v, back)


def test_keys_past_int64_round_trip():
    """Keys an int64 cannot hold still round-trip (the per-value form)."""
    v = fgopt.Variables().add(2 ** 64 + 5, SE2.identity())
    back = pickle.loads(pickle.dumps(v))
    assert back.keys() == [2 ** 64 + 5] and _same(v, back)


def test_pickle_is_the_storage_floats(data_file):
    """A 3500-pose Pose2 problem's Variables pickles to at most 1.2x its raw storage floats
    (keys are run-encoded), whether its values are per-key objects or a reader's bulk rows."""
    _, initial = fgopt.io.read(data_file("pose2d/input_M3500_g2o.g2o"))
    raw = 3500 * SE2._STORAGE_DIM * 8
    per_key = fgopt.Variables()
    for k in initial:
        per_key.add(k, initial.at(k))
    for v in (initial, per_key):
        assert len(v) == 3500
        assert len(pickle.dumps(v)) <= 1.2 * raw


def test_round_tripped_values_solve_identically(data_file):
    """A pose graph's initial values solve to the identical result after a round trip."""
    graph, initial = fgopt.io.read(data_file("pose2d/intel.g2o"))
    per_key = fgopt.Variables()  # per-key values, as a solver's result holds them
    for k in initial:
        per_key.add(k, initial.at(k))
    a = fgopt.optimize(graph, per_key, backend="numba")
    b = fgopt.optimize(graph, pickle.loads(pickle.dumps(per_key)), backend="numba")
    assert a.final_cost == b.final_cost and a.iterations == b.iterations
    assert _same(a.values, b.values)


def test_declared_values_load_in_a_new_process(tmp_path):
    """Declared-manifold values travel as their declaration: a process that has not made the
    kind yet loads them with the same bits."""
    v = fgopt.Variables()
    for i in range(5):
        v.add(i, fgopt.Unit3(np.array([1.0, i, 2.0 - i])))
    blob = tmp_path / "v.pkl"
    blob.write_bytes(pickle.dumps(v))
    code = ("import pickle, sys; v = pickle.load(open(sys.argv[1], 'rb')); "
            "print(type(v.at(3)).__name__, ' '.join(v.at(k).to_storage().tobytes().hex() "
            "for k in v))")
    out = subprocess.run([sys.executable, "-c", code, str(blob)], capture_output=True, text=True,
                         env=dict(os.environ), timeout=600, check=False)
    assert out.returncode == 0, out.stderr[-3000:]
    name, hexes = out.stdout.strip().split(" ", 1)
    assert name == "Unit3"
    assert hexes == " ".join(v.at(k).to_storage().tobytes().hex() for k in v)


@pytest.mark.parametrize("protocol", [2, pickle.HIGHEST_PROTOCOL])
def test_old_protocols(protocol):
    """Every pickle protocol the standard library writes round-trips the mixed values."""
    v = _mixed(3)
    assert _same(v, pickle.loads(pickle.dumps(v, protocol=protocol)))
