"""The dense Levenberg-Marquardt loop of the small-problem driver (:mod:`fgopt.solvers.small`),
as source: :data:`LM_TEMPLATE` is pasted into each generated driver module around its kernel
calls and compiled with numba there (the loop runs with no Python between iterations).
"""

from __future__ import annotations


#: The dense LM of a generated module, around its ``_lin(x, aux, H, g) -> cost``,
#: ``_retract(x, delta, out, tmp, aux)`` and ``_envelope(aux, n)`` (per row of H the first
#: column that can be nonzero: the Cholesky skips what lies before it); ``{n}`` is the tangent
#: dimension's expression and ``{core_flags}`` ``_lm_core``'s extra numba options (see
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


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True{core_flags})
def _lm_core(x0, aux, prm, hist, H, g, zw, ew):
    """Dense LM as fgopt.solvers.lm (same damping, gain ratio, lambda policy and stopping tests).

    The whole-problem linearization has ONE call site (the generated program is inlined once):
    each pass of the outer loop linearizes a point, then decides, then proposes the next step.
    prm: max_iterations, relative_tolerance, absolute_tolerance, gradient_tolerance,
    step_tolerance, initial_lambda, min_lambda, max_lambda, min_diagonal, max_diagonal,
    min_relative_decrease, identity damping (1/0), lambda by factor (1/0), lambda_factor.
    hist (max_iterations, 8): cost, candidate cost, relative decrease,
    lambda, |step|, |grad|, accepted, predicted decrease. H, g (out): the linearization at the
    returned x (H zero on entry: only its envelope is written). zw: 2 n^2 + n scratch for
    Hc, L and gc (zeros, unless _lin clears H and g on the envelope before it adds to them, as
    the small drivers' does: the Cholesky reads L only where it has written it), ew:
    2 len(x0) + n^2 + 3 n + 8 scratch (one arena each, not ten arrays); the final x is
    ew[:len(x0)].
    Returns (status, message, value, iterations, cost, initial cost); status 0 converged,
    1 max iterations, 2 failed, -1 non-finite at the initial values.
    """
    max_it = int(prm[0])
    rtol, atol, gtol, stol = prm[1], prm[2], prm[3], prm[4]
    lam, min_lam, max_lam = prm[5], prm[6], prm[7]
    min_diag, max_diag, min_dec = prm[8], prm[9], prm[10]
    identity, by_factor, lam_factor = prm[11] > 0.5, prm[12] > 0.5, prm[13]
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
    Dg = ew[o:o + n]
    rhs = ew[o + n:o + 2 * n]
    delta = ew[o + 2 * n:o + 3 * n]
    tmp = ew[o + 3 * n:o + 3 * n + 8]
    nu = 2.0
    cost = 0.0
    init = 0.0
    it = 0
    first = True
    step_norm = 0.0
    predicted = 0.0
    while True:
        new_cost = _lin(xc, aux, Hc, gc)
        if first:
            first = False
            if not (math.isfinite(new_cost) and _all_finite(gc) and _all_finite_env(Hc, env)):
                return -1, 0, 0.0, 0, new_cost, new_cost
            _copy_env(Hc, H, env)
            _copy(gc, g)
            cost = new_cost
            init = new_cost
            gn = _absmax(g)
            if gn <= gtol:
                return 0, 1, gn, 0, cost, init
        else:
            row = it - 1
            old = cost
            if not (math.isfinite(new_cost) and _all_finite(gc) and _all_finite_env(Hc, env)):
                new_cost = np.nan
            rho = (old - new_cost) / predicted if predicted > 0 else -np.inf
            accepted = math.isfinite(new_cost) and rho > min_dec
            rel = (old - new_cost) / old if old > 0 else 0.0
            if not math.isfinite(rel):
                rel = np.nan
            if accepted:
                _copy(xc, x)
                _copy_env(Hc, H, env)
                _copy(gc, g)
                cost = new_cost
                if by_factor:
                    lam = max(min_lam, lam / lam_factor)
                else:
                    lam = max(min_lam, lam * max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3))
                nu = 2.0
                gn = _absmax(g)
                _record(hist, row, cost, new_cost, rel, lam, step_norm, gn, 1.0, predicted)
                dec = old - new_cost
                if dec < atol:
                    return 0, 2, dec, it, cost, init
                if old > 0 and dec / old < rtol:
                    return 0, 3, dec / old, it, cost, init
                if gn <= gtol:
                    return 0, 1, gn, it, cost, init
            else:
                _record(hist, row, cost, new_cost, rel, lam, step_norm, _absmax(g), 0.0, predicted)
                if by_factor:
                    lam = lam * lam_factor
                else:
                    lam = lam * nu
                    nu = nu * 2.0
                if lam > max_lam:
                    return 0 if step_norm < 1e-8 else 2, 6, step_norm, it, cost, init
            xn = 0.0
            for i in range(x.shape[0]):
                xn += x[i] * x[i]
            if step_norm <= stol * (math.sqrt(xn) + stol):
                return 0, 4, step_norm, it, cost, init
        # propose the next step (failed factorizations retry with more damping, no linearization)
        while True:
            it += 1
            if it > max_it:
                return 1, 7, 0.0, max_it, cost, init
            for i in range(n):
                Dg[i] = 1.0 if identity else min(max(H[i, i], min_diag), max_diag)
                for j in range(env[i], i + 1):  # the lower envelope: all the Cholesky reads
                    Hd[i, j] = H[i, j]
                Hd[i, i] += lam * Dg[i]
                rhs[i] = -g[i]
            ok = _cholesky_solve(Hd, rhs, L, delta, env)
            if ok:
                ok = _all_finite(delta)
            if ok:
                break
            _record(hist, it - 1, cost, np.nan, np.nan, lam, np.nan, _absmax(g), 0.0, np.inf)
            lam = lam * nu
            nu = nu * 2.0
            if lam > max_lam:
                return 2, 5, 0.0, it, cost, init
        sn = 0.0
        pred = 0.0
        gd = 0.0
        for i in range(n):
            sn += delta[i] * delta[i]
            pred += delta[i] * (lam * Dg[i] * delta[i])
            gd += g[i] * delta[i]
        step_norm = math.sqrt(sn)
        predicted = 0.5 * (pred - gd)
        _retract(x, delta, xc, tmp, aux)


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
    return LM_TEMPLATE.replace("{n}", n).replace("{core_flags}",
                                                 ", _nrt=True" if counted else ", _nrt=False")
