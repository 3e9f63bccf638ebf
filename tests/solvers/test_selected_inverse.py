"""The selected inverse of the block Cholesky factor equals ``H^-1`` on every factor's blocks."""

import numpy as np
import pytest

from fgopt.errors import FgoptError
from fgopt.io import add_gauge_prior, read
from fgopt.problem import Problem
from fgopt.solvers.linear.block_cholesky import BlockCholeskySolver


def _factored(path):
    graph, values = read(path)
    add_gauge_prior(graph, values)
    problem = Problem(graph, values, linear_solver="block")
    problem.linearize(problem.initial_state())
    solver = BlockCholeskySolver()
    solver.analyze(problem.pattern)
    solver.factorize(problem.H_data.copy())
    H = problem.pattern.matrix(problem.H_data).toarray()  # lower triangle
    H = np.tril(H) + np.tril(H, -1).T
    return problem, solver, H


@pytest.mark.parametrize("rel", ["small/pose3example-grid.txt", "small/w100.graph",
                                 "small/tinyGrid3D.g2o"])
def test_factor_blocks_equal_the_dense_inverse(data_file, rel):
    """For every factor (2D and 3D graphs, several supernodes deep), the block of H^-1 over its
    variables, in argument order, equals the dense inverse's (solved through the dense
    Cholesky factor: H is ill-conditioned by the tight gauge prior)."""
    problem, solver, H = _factored(data_file(rel))
    assert solver.symbolic.sn.shape[0] > 3  # more than one supernode below the root
    Linv = np.linalg.inv(np.linalg.cholesky(H))
    Sigma = Linv.T @ Linv
    off = problem.pattern.var_offset
    for b in problem.batches:
        blocks = solver.covariance_blocks(b.var_idx, b.arg_dims, b.arg_local_off)
        for e in range(len(b.source)):
            idx = np.concatenate([off[v] + np.arange(d)
                                  for v, d in zip(b.var_idx[e], b.arg_dims)])
            ref = Sigma[np.ix_(idx, idx)]
            assert np.allclose(blocks[e], ref, rtol=1e-7, atol=1e-9 * np.abs(ref).max())


def test_uncoupled_variables_are_refused(data_file):
    """Two variables no factor couples (not on L's pattern) raise FgoptError, not garbage."""
    problem, solver, H = _factored(data_file("pose2d/intel.g2o"))
    dims = problem.var_dim[:2]
    far = np.array([[0, problem.var_dim.shape[0] - 1]])
    coupled = np.abs(H[np.ix_(problem.pattern.var_offset[far[0]], problem.pattern.var_offset[far[0]])])
    if coupled[0, 1] != 0:
        pytest.skip("the first and last poses are coupled in this graph")
    with pytest.raises(FgoptError, match="not coupled"):
        solver.covariance_blocks(far, dims)
