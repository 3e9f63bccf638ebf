"""fgopt's approximate minimum degree kernel: a permutation of every node on any graph, the fill
of CHOLMOD's AMD, dense nodes last, and what ``fill_reducing_order("amd")`` returns once numba
is in use."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fgopt._amd import amd_order
from fgopt.structure import fill_reducing_order


def factor_nnz(n: int, pairs_i: np.ndarray, pairs_j: np.ndarray, perm: np.ndarray) -> int:
    """nnz of the Cholesky factor (diagonal included) when eliminating in ``perm``'s order:
    each eliminated node joins its not yet eliminated neighbours into a clique."""
    adj = [set() for _ in range(n)]
    for a, b in zip(pairs_i.tolist(), pairs_j.tolist()):
        if a != b:
            adj[a].add(b)
            adj[b].add(a)
    done = np.zeros(n, dtype=bool)
    total = 0
    for v in perm.tolist():
        later = [u for u in adj[v] if not done[u]]
        total += 1 + len(later)
        for u in later:
            adj[u].update(x for x in later if x != u)
            adj[u].discard(v)
        done[v] = True
    return total


def grid(m: int) -> tuple[int, np.ndarray, np.ndarray]:
    idx = np.arange(m * m).reshape(m, m)
    return (m * m, np.concatenate([idx[:, :-1].ravel(), idx[:-1, :].ravel()]),
            np.concatenate([idx[:, 1:].ravel(), idx[1:, :].ravel()]))


@settings(max_examples=150, deadline=None)
@given(n=st.integers(0, 70), hubs=st.integers(0, 2), data=st.data())
def test_every_node_exactly_once(n, hubs, data):
    """Any pair list (duplicates, self pairs, isolated nodes, hubs coupled to every node, which
    are ordered last as dense above 16 nodes) gives a permutation."""
    m = data.draw(st.integers(0, 4 * n + 1)) if n else 0
    pi = np.array(data.draw(st.lists(st.integers(0, max(n - 1, 0)), min_size=m, max_size=m)),
                  dtype=np.int64)
    pj = np.array(data.draw(st.lists(st.integers(0, max(n - 1, 0)), min_size=m, max_size=m)),
                  dtype=np.int64)
    for h in range(min(hubs, n)):
        pi = np.concatenate([pi, np.full(n, h, dtype=np.int64)])
        pj = np.concatenate([pj, np.arange(n, dtype=np.int64)])
    perm = amd_order(n, pi, pj)
    assert np.array_equal(np.sort(perm), np.arange(n))


def test_complete_graph_and_chain():
    """A clique has no fill to save (nnz is n(n+1)/2 in any order); a path ordered by AMD has
    no fill at all (2n - 1 entries)."""
    n = 30
    i, j = np.triu_indices(n, 1)
    perm = amd_order(n, i.astype(np.int64), j.astype(np.int64))
    assert factor_nnz(n, i, j, perm) == n * (n + 1) // 2
    rng = np.random.default_rng(1)
    labels = rng.permutation(200)
    a, b = labels[:-1].astype(np.int64), labels[1:].astype(np.int64)
    assert factor_nnz(200, a, b, amd_order(200, a, b)) == 2 * 200 - 1


def test_dense_hub_is_ordered_last():
    """A node coupled to everything (a calibration shared by all poses) is eliminated last:
    eliminating it early would fill the whole matrix."""
    n = 400
    hub = np.zeros(n - 1, dtype=np.int64)
    spokes = np.arange(1, n, dtype=np.int64)
    pi = np.concatenate([hub, spokes[:-1]])
    pj = np.concatenate([spokes, spokes[1:]])
    perm = amd_order(n, pi, pj)
    assert perm[-1] == 0
    assert factor_nnz(n, pi, pj, perm) <= 3 * n


@pytest.mark.parametrize("m", [6, 20])
def test_grid_fill_far_below_natural_order(m):
    """On a 2D grid AMD's fill is well below the banded natural order's."""
    n, pi, pj = grid(m)
    natural = factor_nnz(n, pi, pj, np.arange(n))
    assert factor_nnz(n, pi, pj, amd_order(n, pi, pj)) < (0.8 if m == 20 else 1.0) * natural


def _cholmod_perm(n, pi, pj):
    from fgopt.structure import _block_graph_csc
    from sksparse.cholmod import analyze

    return np.asarray(analyze(_block_graph_csc(n, pi, pj), mode="simplicial",
                              ordering_method="amd").P())


@pytest.mark.parametrize("case", ["grid20", "grid35", "random300", "random120dense"])
def test_fill_of_cholmods_amd(case):
    """The same fill as CHOLMOD's AMD, within 3 % (ties broken differently), on grids and
    random graphs."""
    pytest.importorskip("sksparse")
    rng = np.random.default_rng(7)
    if case.startswith("grid"):
        n, pi, pj = grid(int(case[4:]))
    else:
        n = int(case[6:9])
        m = (8 if case.endswith("dense") else 3) * n
        pi, pj = rng.integers(0, n, m), rng.integers(0, n, m)
    ours = factor_nnz(n, pi, pj, amd_order(n, pi, pj))
    theirs = factor_nnz(n, pi, pj, _cholmod_perm(n, pi, pj))
    assert ours <= 1.03 * theirs, (ours, theirs)


@pytest.mark.parametrize("relpath", ["pose2d/intel.g2o", "pose3d/sphere2500.g2o"])
def test_pose_graph_fill_of_cholmods_amd(relpath, data_file):
    """On real pose graphs' variable graphs: nnz(L) within 2 % of CHOLMOD's AMD."""
    pytest.importorskip("sksparse")
    import fgopt

    graph, _ = fgopt.io.read(str(data_file(relpath)))
    keys = np.concatenate([b.keys for b in graph.batches if b.keys.shape[1] == 2])
    _, inv = np.unique(keys, return_inverse=True)
    inv = inv.reshape(keys.shape)
    n = int(inv.max()) + 1
    pi, pj = inv[:, 0].copy(), inv[:, 1].copy()
    from fgopt.structure import _block_graph_csc
    from sksparse.cholmod import cholesky

    A = _block_graph_csc(n, pi, pj)

    def nnz(perm):
        return cholesky(A[perm][:, perm].tocsc(), ordering_method="natural").L().nnz

    assert nnz(amd_order(n, pi, pj)) <= 1.02 * nnz(_cholmod_perm(n, pi, pj))


def test_fill_reducing_order_uses_the_kernel_on_the_numba_backend():
    """``"amd"`` is the kernel's order outside NumPy mode, CHOLMOD's inside it;
    ``"cholmod_amd"`` is CHOLMOD's in both."""
    from fgopt import _jit

    n, pi, pj = grid(12)
    assert np.array_equal(fill_reducing_order(n, pi, pj, "amd"), amd_order(n, pi, pj))
    pytest.importorskip("sksparse")
    theirs = _cholmod_perm(n, pi, pj)
    assert not np.array_equal(theirs, amd_order(n, pi, pj))  # (else this test shows nothing)
    assert np.array_equal(fill_reducing_order(n, pi, pj, "cholmod_amd"), theirs)
    with _jit.numpy_mode():
        assert np.array_equal(fill_reducing_order(n, pi, pj, "amd"), theirs)


def test_pairs_outside_the_graph_are_an_error():
    """A pair naming a node outside ``0..n-1`` (or pair arrays of different lengths): an
    FgoptError, not a read past the arrays."""
    from fgopt.errors import FgoptError

    n, pi, pj = grid(5)
    for bad in (n, -1):
        pj2 = pj.copy()
        pj2[3] = bad
        assert amd_order(n, pi, pj2).shape[0] == 0
        with pytest.raises(FgoptError, match="outside 0..24"):
            fill_reducing_order(n, pi, pj2, "amd")
    with pytest.raises(FgoptError, match="1-D arrays of one length"):
        fill_reducing_order(n, pi, pj[:-1], "amd")


@pytest.mark.parametrize("case", ["grid30", "random400"])
def test_no_free_room_gives_the_same_order(case):
    """With no room after the graph's lists the kernel compacts them (and grows its array)
    over and over; the order is the same as with room to spare."""
    rng = np.random.default_rng(3)
    if case == "grid30":
        n, pi, pj = grid(30)
    else:
        n = 400
        pi, pj = rng.integers(0, n, 5 * n), rng.integers(0, n, 5 * n)
    reference = amd_order(n, pi, pj)
    for elbow in (0, 1, 7):
        assert np.array_equal(amd_order(n, pi, pj, 10.0, elbow), reference)
