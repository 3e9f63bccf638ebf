"""The dense side of the small-problem driver (:mod:`fgopt.solvers.small`), as source:
:data:`LM_TEMPLATE` is pasted into each generated driver module around its kernel calls, with
:func:`fgopt.solvers._lm_loop.lm_loop` (the loop the general path runs) and the dense numba
operations it runs on, and compiled with numba there: no Python between iterations.
"""

from __future__ import annotations


#: The dense LM of a generated module, around its ``_lin(x, aux, H, g) -> cost``,
#: ``_retract(x, delta, out, tmp, aux)`` and ``_envelope(aux, n)`` (per row of H the first
#: column that can be nonzero: the Cholesky skips what lies before it); ``{n}`` is the tangent
#: dimension's expression, ``{loop}`` :func:`~fgopt.solvers._lm_loop.lm_loop`'s source and
#: ``{core_flags}`` the extra numba options of it, its operations and ``_lm_core`` (see
#: :func:`lm_source`). :mod:`fgopt.solvers.small` generates one driver per set of kernels
#: around it.
LM_TEMPLATE = '''
# reassociation lets LLVM vectorize the dot products (33 unknowns: 4.1 -> 2.9 us, 72: 34 -> 14
# us); the order of a sum's terms is all it changes, the same on every call
@numba.njit(cache=True, fastmath={"reassoc", "contract"}, error_model="numpy", nogil=True,
            _nrt=False)
def _cholesky_solve(A, b, L, y, first):
    """Solve A y = b for symmetric A by Cholesky (lower L); False if A is not positive definite.

    first[i]: the first column of row i's envelope (A[i, k] = 0 for every k < first[i], so
    first[i] <= i). L has A's envelope, so only entries inside it are computed and read: a
    chain-like pose graph's rows reach a few variables back (pose2example's 33 unknowns: a
    quarter of the dense work)."""
    n = A.shape[0]
    for j in range(n):
        fj = first[j]
        s = A[j, j]
        for k in range(fj, j):
            s -= L[j, k] * L[j, k]
        if not (s > 0.0) or not math.isfinite(s):
            return False
        d = math.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, n):
            fi = first[i]
            if fi > j:
                continue  # outside the envelope: L[i, j] = 0, never read
            s = A[i, j]
            for k in range(max(fi, fj), j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / d
    for i in range(n):
        s = b[i]
        for k in range(first[i], i):
            s -= L[i, k] * y[k]
        y[i] = s / L[i, i]
    for i in range(n - 1, -1, -1):  # L^T y = y by columns of L^T: row i of L, its envelope
        y[i] = y[i] / L[i, i]
        for k in range(first[i], i):
            y[k] -= L[i, k] * y[i]
    return True


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, _nrt=False)
def _absmax(g):
    m = 0.0
    for i in range(g.shape[0]):
        a = abs(g[i])
        if a > m:
            m = a
    return m


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, _nrt=False)
def _all_finite(a):
    for i in range(a.shape[0]):
        if not math.isfinite(a[i]):
            return False
    return True


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, _nrt=False)
def _all_finite_env(a, env):
    """Whether symmetric a's lower envelope (all it can hold) is finite."""
    ok = True
    for i in range(a.shape[0]):
        for j in range(env[i], i + 1):
            ok = ok and math.isfinite(a[i, j])
    return ok


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, _nrt=False)
def _copy(src, dst):
    for i in range(src.shape[0]):
        dst[i] = src[i]


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, _nrt=False)
def _copy_env(src, dst, env):
    """dst = src on symmetric src's envelope, both triangles (outside it both stay zero)."""
    for i in range(src.shape[0]):
        for j in range(env[i], i + 1):
            dst[i, j] = src[i, j]
            dst[j, i] = src[j, i]


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, _nrt=False)
def _record(hist, row, cost, cand, rel, lam, step, grad, acc, pred):
    hist[row, 7] = pred
    hist[row, 0] = cost
    hist[row, 1] = cand
    hist[row, 2] = rel
    hist[row, 3] = lam
    hist[row, 4] = step
    hist[row, 5] = grad
    hist[row, 6] = acc


from fgopt.solvers._lm_loop import CONVERGED, FAILED, MAX_ITERATIONS, STOPPED


# The seven operations of fgopt.solvers._lm_loop.lm_loop on the dense driver's ctx: (x, xc, aux,
# H, g, Hc, gc, Hd, L, Dg, rhs, delta, tmp, env, hist) - the iterate's storage, the trial
# point's, the kernels' aux, H (both triangles, its envelope) and g at the iterate and at the
# trial point, the damped copy and its Cholesky factor, the damping diagonal, -g, the step, the
# retraction's scratch, H's envelope and the history.
@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, inline="always"{core_flags})
def _lm_trial(ctx, first):
    if not first:
        _retract(ctx[0], ctx[11], ctx[1], ctx[12], ctx[2])
    cost = _lin(ctx[1], ctx[2], ctx[5], ctx[6])  # (the one call site of the linearization)
    if not (math.isfinite(cost) and _all_finite(ctx[6]) and _all_finite_env(ctx[5], ctx[13])):
        return np.nan
    return cost


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, inline="always"{core_flags})
def _lm_accept(ctx, cost):
    _copy(ctx[1], ctx[0])
    _copy_env(ctx[5], ctx[3], ctx[13])
    _copy(ctx[6], ctx[4])


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, inline="always"{core_flags})
def _lm_reject(ctx):
    pass  # (the next trial point overwrites xc)


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, inline="always"{core_flags})
def _lm_gradient(ctx):
    return _absmax(ctx[4])


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, inline="always"{core_flags})
def _lm_state_norm(ctx):
    x = ctx[0]
    s = 0.0
    for i in range(x.shape[0]):
        s += x[i] * x[i]
    return math.sqrt(s)


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True{core_flags})
def _record_row(hist, g, it, cost, cand, lam, step, accepted, old, predicted):
    rel = (old - cand) / old if old > 0 else 0.0
    if not math.isfinite(rel):
        rel = np.nan
    _record(hist, it - 1, cost, cand, rel, lam, step, _absmax(g), 1.0 if accepted else 0.0,
            predicted)
    return False


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, inline="always"{core_flags})
def _lm_record(ctx, it, cost, cand, lam, step, accepted, old, predicted):
    # (run-time types: lm_loop's call sites pass literal iterations and flags, one compile of
    # _record_row each)
    return _record_row(ctx[14], ctx[4], np.int64(it), cost, cand, lam, step, np.bool_(accepted),
                       old, predicted)


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, inline="always"{core_flags})
def _lm_step(ctx, lam, identity, min_diag, max_diag):
    H, g, Hd, L, Dg, rhs, delta, env = (ctx[3], ctx[4], ctx[7], ctx[8], ctx[9], ctx[10], ctx[11],
                                        ctx[13])
    n = H.shape[0]
    for i in range(n):
        Dg[i] = 1.0 if identity else min(max(H[i, i], min_diag), max_diag)
        for j in range(env[i], i + 1):  # the lower envelope: all the Cholesky reads
            Hd[i, j] = H[i, j]
        Hd[i, i] += lam * Dg[i]
        rhs[i] = -g[i]
    if not (_cholesky_solve(Hd, rhs, L, delta, env) and _all_finite(delta)):
        return False, np.nan, np.nan
    sn = 0.0
    pred = 0.0
    gd = 0.0
    for i in range(n):
        sn += delta[i] * delta[i]
        pred += delta[i] * (lam * Dg[i] * delta[i])
        gd += g[i] * delta[i]
    return True, math.sqrt(sn), 0.5 * (pred - gd)


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, inline="always"{core_flags})
{loop}

@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True{core_flags})
def _lm_core(x0, aux, prm, hist, H, g, zw, ew):
    """fgopt.solvers._lm_loop.lm_loop on this module's dense operations.

    H, g (out): the linearization at the returned x (H zero on entry: only its envelope is
    written). zw: 2 n^2 + n scratch for Hc, L and gc (zeros, unless _lin clears H and g on
    the envelope before it adds to them, as the small drivers' does: the Cholesky reads L
    only where it has written it), ew: 2 len(x0) + n^2 + 3 n + 8 scratch (one arena each, not
    ten arrays); the final x is ew[:len(x0)]. hist (max_iterations, 8): cost, candidate cost,
    relative decrease, lambda, |step|, |grad|, accepted, predicted decrease. Returns lm_loop's
    (status, message, value, iterations, cost, initial cost).
    """
    n = {n}
    env = _envelope(aux, n)  # per row of H its first column that can be nonzero
    nx = x0.shape[0]
    Hc = zw[:n * n].reshape((n, n))
    L = zw[n * n:2 * n * n].reshape((n, n))
    gc = zw[2 * n * n:2 * n * n + n]
    x = ew[:nx]
    xc = ew[nx:2 * nx]
    for i in range(nx):
        x[i] = x0[i]
        xc[i] = x0[i]
    Hd = ew[2 * nx:2 * nx + n * n].reshape((n, n))
    o = 2 * nx + n * n
    ctx = (x, xc, aux, H, g, Hc, gc, Hd, L, ew[o:o + n], ew[o + n:o + 2 * n],
           ew[o + 2 * n:o + 3 * n], ew[o + 3 * n:o + 3 * n + 8], env, hist)
    return lm_loop(ctx, prm)


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, _nrt=True)
def _lm(x0, aux, prm, hist, H, g):
    """_lm_core with its scratch: (x, status, message, value, iterations, cost, initial cost)."""
    n = {n}
    nx = x0.shape[0]
    ew = np.empty(2 * nx + n * n + 3 * n + 8)
    status, msg, val, its, cost, init = _lm_core(x0, aux, prm, hist, H, g,
                                                 np.zeros(2 * n * n + n), ew)
    return ew[:nx], status, msg, val, its, cost, init
'''


def lm_source(n: str, counted: bool = True) -> str:
    """:data:`LM_TEMPLATE` with ``n`` the tangent dimension's expression; ``counted=False``
    compiles ``_lm_core`` without numba's reference counting (``_nrt=False``: no atomic
    increment and decrement of every array it passes or slices, ~7 ns each here, hundreds per
    solve). Only for modules whose ``_envelope`` is inlined and whose ``_lin`` and
    ``_retract`` return no new array: a core without counting would never release one."""
    # (explicit both ways: numba compiles a function without its own _nrt with its caller's)
    from .._lm_loop import loop_source

    return (LM_TEMPLATE.replace("{n}", n).replace("{loop}", loop_source())
            .replace("{core_flags}", ", _nrt=True" if counted else ", _nrt=False"))
