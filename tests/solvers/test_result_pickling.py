"""Pickling a ``Result``: its values leave the worker as storage rows taken straight from the
final state (same keys, order and bits as ``Result.values``), its iteration records as one array;
a result whose values cannot be rows (unused keys, slow-path values) still pickles exactly."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest

import fgopt
from fgopt import SE2, BetweenFactor, PriorFactor
from fgopt.noise import Diagonal


def _chain(n: int = 30, extra=None):
    rng = np.random.default_rng(0)
    noise = Diagonal.sigmas([0.1, 0.1, 0.05])
    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    graph.add(PriorFactor(0, SE2.identity(), noise))
    for i in range(n):
        initial.add(i, SE2.from_xytheta(i + rng.normal(0, 0.2), rng.normal(0, 0.2),
                                        rng.normal(0, 0.1)))
        if i:
            graph.add(BetweenFactor(i - 1, i, SE2.from_xytheta(1.0, 0.0, 0.02), noise))
    for k, value in (extra or {}).items():
        initial.add(k, value)
    return graph, initial


def _bits(v: fgopt.Variables) -> list:
    return [(int(k), type(v.at(k)), np.asarray(v.at(k).to_storage()).tobytes()
             if hasattr(v.at(k), "to_storage") else repr(v.at(k))) for k in v]


def test_result_values_travel_as_rows_with_the_same_bits():
    """A fresh result (values not built yet) pickles its values as bulk rows; they load with
    exactly the bits and order of ``result.values``; records and costs are equal."""
    result = fgopt.optimize(*_chain())
    blob = pickle.dumps(dataclasses.replace(result, _values=None))
    back = pickle.loads(blob)
    assert back.values._pending and not back.values._dict
    assert _bits(back.values) == _bits(result.values)
    assert back.iteration_records == result.iteration_records
    assert back.cost_history == result.cost_history and back.final_cost == result.final_cost
    assert back.table() == result.table()


def test_result_with_unused_keys_pickles_exactly():
    """Unused initial keys (returned unchanged) make the values go the per-key way; still exact."""
    with pytest.warns(fgopt.FgoptWarning, match="used by no factor"):
        result = fgopt.optimize(*_chain(extra={1000: SE2.from_xytheta(5.0, 5.0, 1.0)}))
    assert result.unused_keys
    back = pickle.loads(pickle.dumps(
        dataclasses.replace(result, _values=None)))
    assert _bits(back.values) == _bits(result.values)
