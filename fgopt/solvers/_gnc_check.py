"""GNC's classification steps (:mod:`fgopt.solvers.gnc`): binary classification, the
scale-aware consistency check, and the leave-one-out check of what was accepted.

Split from :mod:`fgopt.solvers.gnc` so the rounds and the checks each stay readable. The
checks use the leave-one-out algebra of :mod:`fgopt.solvers.influence` on the restricted
problem of the accepted factors (:mod:`fgopt.solvers._subproblem`).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..problem import Problem


#: Below this noise scale ``s^2`` (sigmas 2x too large or more) the first-order prediction
#: covariance, computed with the nominal models, is too wide to be trusted alone: a factor is
#: then an inlier only if it also lies inside its family-wise ellipse (:meth:`_Verifier._clear`).
LOOSE_SCALE = 0.25


def _thresholds(problem: Problem, probability: float) -> list[np.ndarray]:
    from scipy.stats import chi2

    out = [np.full(len(b.source), chi2.ppf(probability, b.kernel.residual_dim))
           for b in problem.batches]
    out.append(np.array([chi2.ppf(probability, s.factor.dim) for s in problem._slow]))
    return out



def _chi2_median(dim: np.ndarray) -> np.ndarray:
    """Median of chi-square(dim) (Wilson-Hilferty; 1 dof: 0.455)."""
    k = np.asarray(dim, dtype=float)
    return np.where(k == 1, 0.454936, k * (1.0 - 2.0 / (9.0 * k)) ** 3)


def noise_scale(problem: Problem, state: Any, weights: list[np.ndarray],
                c2: list[np.ndarray]) -> float:
    """Robust variance factor ``s^2`` of the accepted factors (weight > 0.5): how much their
    whitened residuals are smaller (< 1) or larger than the noise models say.

    At a least-squares optimum ``E sum r_i^2 = m - n`` (m residual, n tangent dimensions: the
    fit absorbs n of them), so the classic estimate is ``sum r^2 / (m - n)``; made robust to
    the outliers still accepted, it is the median of ``r_i^2 / median(chi2(dim_i))`` times
    ``m / (m - n)``. 1 where the noise models are right (``manhattan_2d``); 0.020 on M3500
    (exact ``2 cost / (m - n)``: 0.0235) and ~0.1 on sphere2500.
    """
    r2 = problem.squared_residuals(state)
    dims = [np.full(len(b.source), b.kernel.residual_dim) for b in problem.batches]
    dims.append(np.array([s.factor.dim for s in problem._slow], dtype=float))
    vals, m = [], 0.0
    for x, d, w in zip(r2, dims, weights):
        keep = np.asarray(w) > 0.5
        if x.size and np.any(keep):
            vals.append(x[keep] / _chi2_median(d[keep]))
            m += float(np.sum(d[keep]))
    n = float(problem.var_dim.sum())
    if not vals or m - n < 10:
        return 1.0
    vals = np.concatenate(vals)
    return float(np.median(vals)) * m / (m - n)


def standardized_scale(w2: list[np.ndarray], dims: list[int]) -> float:
    """Robust variance factor ``s^2`` from standardized residuals ``w^2 = r^T (I - h)^-1 r``
    (one array per batch of residual dimension ``dims[i]``): each is ``s^2 chi2(dim)`` under
    the noise models times ``s^2``, whatever its leverage, so the median of
    ``w^2 / median(chi2(dim))`` estimates ``s^2`` without :func:`noise_scale`'s average
    correction (which is biased low where many factors have high leverage: odometry chains
    with few loops). 1 if there are too few."""
    vals = [x / _chi2_median(np.full(x.shape, d)) for x, d in zip(w2, dims) if x.size]
    if not vals or sum(v.size for v in vals) < 10:
        return 1.0
    return float(np.median(np.concatenate(vals)))


class _Verifier:
    """GNC's last steps: binary classification, the scale-aware re-classification, and a
    leave-one-out check of what was accepted.

    GNC is only as global as its inner solver: on real pose graphs it can end in a local
    minimum where a few outliers are accepted and the estimate is bent to fit them (measured on
    M3500 with 10 % random loop closures: 2-5 accepted, 40-90 m error). Such a factor has a small
    residual but a large leave-one-out residual (:mod:`fgopt.solvers.influence`): the rest of the
    graph contradicts it. The check ranks accepted factors by how much the optimal cost would drop
    without them (``0.5 r . r_loo``, first order); for the largest drop above ``c^2 / 2`` (where
    rejecting pays off in the truncated-least-squares objective ``0.5 sum min(r_i^2, c_i^2)``,
    known inliers ``r_i^2``) it rejects the factor, re-solves, re-classifies every factor
    (rejected inliers that fit again come back) and keeps the change only if that objective
    really decreased; it stops when no candidate is left or no rejection helps.
    """

    def __init__(self, full, solver: Any, inliers, c2, alpha: float = 0.05,
                 probability: float = 0.9):
        """``solver``: GNC's weighted solves (``fgopt.solvers.gnc._Solves``)."""
        self.full, self.solver, self.inliers, self.c2 = full, solver, inliers, c2
        m = max(1, sum(len(x) for x in c2))
        self.c2_snoop = _thresholds(full, 1.0 - alpha / m)
        self.c2_low = _thresholds(full, probability)
        self.c2_back = _thresholds(full, 0.5 * (probability + 0.999))
        self.c2_ellipse = c2

    def scaled(self, state) -> list[np.ndarray]:
        return [r / c for r, c in zip(self.full.squared_residuals(state), self.c2)]

    def objective(self, state) -> float:
        s = self.scaled(state)
        return float(sum(np.sum(0.5 * c * np.where(m, x, np.minimum(x, 1.0)))
                         for x, m, c in zip(s, self.inliers, self.c2)))

    def classify(self, state, forced=None, passes: int = 5):
        """Binary weights (inlier iff ``r^2 <= c^2``, ``forced`` rows rejected), re-solved
        from ``state`` until the classification is stable."""
        weights = None
        for _ in range(passes):
            s = self.scaled(state)
            new = [np.where(m | (x <= 1.0), 1.0, 0.0) for x, m in zip(s, self.inliers)]
            if forced is not None:
                for w, f in zip(new, forced):
                    w[f] = 0.0
            if weights is not None and all(np.array_equal(a, b) for a, b in zip(new, weights)):
                break
            weights = new
            state, _ = self.solver.solve(state, weights, chordal=False)
        return state, weights

    def consistency(self, state, weights, verbose: bool = False,
                    deadline: float = float("inf"), fraction: float = 0.5,
                    max_passes: int = 40):
        """Classify every factor by how the rest of the graph predicts it, re-solving until
        stable: an outlier iff its leave-one-out residual is outside its own ellipse *and*
        significant at the inliers' real scale,

            |r_loo|^2 > c^2   and   w^2 > s^2 c_p^2,

        with ``w^2 = r^T (I - h)^-1 r`` for a factor in the solve (Baarda's data snooping) and
        ``r^T (I + h')^-1 r`` for one left out (its residual is then its leave-one-out residual,
        :func:`~fgopt.solvers.influence.prediction_sq_norms`), ``s^2 <= 1`` the robust
        variance factor of the accepted factors (:func:`noise_scale`), ``c^2`` GNC's inlier
        threshold and ``c_p^2`` the chi-square quantile at
        ``GNCParams.consistency_probability``. A rejected factor comes back when it is inside
        the ellipse and ``w^2 <= s^2 c_b^2``, ``c_b^2`` a little above ``c_p^2`` (midway to the
        0.999 quantile: early passes, at a scale inflated by the outliers still accepted,
        reject some true factors, which must come back; letting rejected factors back on
        either test alone cycled on M3500 until the pass limit, 8 outliers accepted; a cycle
        stops the passes at the last solved classification). The ellipse test ignores the prediction's own uncertainty,
        so on a clean graph it flags a few high-leverage true factors; :meth:`_clear` brings
        them back.

        Why: with noise models that overstate the errors (M3500: s^2 = 0.02), bending the
        graph to fit an outlier costs less than the truncated cost of rejecting it, so even the
        global truncated-least-squares optimum accepts outliers (M3500 with 10 % wrong closures
        of sigma 0.1: GNC accepted 132 of 545, clean cost 488 vs 69); against the inliers' real
        spread they are gross. Accepted factors flagged by the rule are rejected a ``fraction``
        at a time, largest ``|r_loo|^2 / c^2`` first (an outlier bends its neighbours'
        statistics too; measured there: ``|r_loo|^2`` of the accepted outliers >= 39 for 90 %,
        of the true loop closures <= 11 for 99 %); once none is flagged, rejected factors the
        rule clears come back at once (a true loop closure rejected earlier, e.g. by GNC's
        nominal threshold).

        Once the rule above flags nothing, accepted factors are tested family-wise at the
        tested factors' own scale, whatever the nominal ellipse says: rejected (largest
        ``w^2 / c_a^2`` first) when ``w^2 > s_t^2 c_a^2``, ``c_a^2`` the Bonferroni quantile
        (``GNCParams.snooping_alpha``) and ``s_t^2`` the robust scale of the standardized
        residuals of the accepted factors under test (:func:`standardized_scale`; not the
        known inliers: on M3500 the loop closures' real spread is ~1.5x the odometry's). The
        ellipse guard is there because a per-factor test at one scale rejects true factors
        where the scales differ; the family-wise level at the tested factors' scale does not
        (clean M3500 / sphere2500: largest ``w^2 / (s_t^2 c_a^2)`` 0.58 / 0.93), while a copy
        of a true loop closure with a gross error can lie inside the nominal ellipse at the
        optimum itself (sphere2500, s^2 = 0.088: 21.97 < 22.46 nominal, ``w^2 / (s_t^2 c_a^2)``
        4.5). Where the noise models overstate the errors by far (``s^2 <`` :data:`LOOSE_SCALE`),
        an accepted factor is also rejected when its leave-one-out residual lies outside its
        family-wise ellipse, ``|r_loo|^2 > c_a^2``: the rule that keeps a rejected factor out in
        :meth:`_clear`, so the final class of a factor does not depend on the path (M3500
        without a prior, 30 % random wrong closures: one accepted at ``|r_loo|^2 = 434``,
        ``w^2 = 6 s^2``, bending the map by 1.8e-3 of the optimal cost; the true loop closures'
        largest ``|r_loo|^2`` there is 23.6, ``c_a^2`` 26.6). Run only after the first rule
        is done: while outliers still bend the estimate the family-wise test also flags true
        factors next to them (M3500 with 10 % random wrong closures, both rules at once: one
        outlier ended accepted). Returns ``(state, weights, s^2)``.
        """
        from .influence import leave_one_out_sq_norms, prediction_sq_norms

        seen: set = set()
        s2 = 1.0
        for _ in range(max_passes):
            if time.perf_counter() > deadline:
                break
            s2 = min(1.0, noise_scale(self.full, state, weights, self.c2))
            sub, sub_state = self.solver.restricted.prepare(state, weights)
            keep, order = self.solver.restricted.keep, self.solver.restricted.order
            masks = [(~self.inliers[i] & (weights[i] > 0.5))[keep[i]] for i in order]
            loo_sub, drop_sub = leave_one_out_sq_norms(sub, sub_state, masks, both=True)
            plain = self.full.squared_residuals(state)
            have = set(sub.var_keys.tolist())
            s2_tested = min(1.0, standardized_scale(
                [2.0 * d[m] for d, m in zip(drop_sub, masks)],
                [b.kernel.residual_dim for b in sub.batches]))
            ranked, snooped, back = [], [], []
            for j, i in enumerate(order):  # accepted factors, in the solve
                c = self.c2_ellipse[i][keep[i]]
                low = self.c2_low[i][keep[i]]
                bad = (loo_sub[j] > c) & (2.0 * drop_sub[j] > s2 * low) & masks[j]
                rows = np.nonzero(keep[i])[0][bad]
                ranked += [(float(v), i, int(r)) for v, r in zip(loo_sub[j][bad] / c[bad], rows)]
                snoop = self.c2_snoop[i][keep[i]]
                score = 2.0 * drop_sub[j] / (s2_tested * snoop)
                if s2 < LOOSE_SCALE:  # the rule that keeps a rejected factor out (_clear)
                    score = np.maximum(score, loo_sub[j] / snoop)
                gross = (score > 1.0) & masks[j]
                rows = np.nonzero(keep[i])[0][gross]
                snooped += [(float(v), i, int(r)) for v, r in zip(score[gross], rows)]
            if not ranked:  # family-wise test at the tested factors' scale, once the
                ranked = snooped  # outliers that bend the estimate are out (see docstring)
            for i, b in enumerate(self.full.batches):  # rejected factors, left out
                if ranked:  # clear rejected ones only once nothing accepted is contradicted:
                    break   # while outliers bend the estimate, some others look consistent
                rows = np.nonzero((weights[i] < 0.5) & ~self.inliers[i])[0]
                rows = rows[[all(int(k) in have for k in b.source.keys[r]) for r in rows]]
                if rows.size == 0:
                    continue
                c = self.c2_ellipse[i][rows]
                inside = plain[i][rows] <= c  # only these can come back: predict only them
                pred = np.full(rows.size, np.inf)
                pred[inside] = prediction_sq_norms(sub, sub_state, b.source, rows[inside],
                                                   bound=s2 * self.c2_back[i][rows[inside]])
                ok = inside & (pred <= s2 * self.c2_back[i][rows])
                back += [(i, int(r)) for r in rows[ok]]
            ranked.sort(reverse=True)
            n_rej = int(np.ceil(fraction * len(ranked)))
            if verbose:
                print(f"GNC consistency: s^2 {s2:.3g}, {len(ranked)} accepted contradicted "
                      f"(rejecting {n_rej}), {len(back)} rejected cleared")
            if not ranked and not back:
                break
            new = [w.copy() for w in weights]
            for _, i, r in ranked[:n_rej]:
                new[i][r] = 0.0
            for i, r in back:
                new[i][r] = 1.0
            key = tuple(np.nonzero(np.concatenate(new) < 0.5)[0].tolist())
            if key in seen:  # a cycle: keep the current (solved) classification
                break
            weights = new
            seen.add(key)
            state, _ = self.solver.solve(state, weights, chordal=False)
        state, weights, s2 = self._clear(state, weights, s2, verbose)
        return state, weights, s2

    def _clear(self, state, weights, s2, verbose: bool = False):
        """Last pass: bring back rejected factors that the final estimate predicts at the
        family-wise level (Bonferroni, ``c_a^2``) and the scale of the standardized residuals of
        the accepted factors (:func:`standardized_scale`: unbiased once the outliers are out,
        where :func:`noise_scale` runs low on graphs with many high-leverage factors and so
        rejects a few true factors of a clean graph by chance). Gross outliers stay out.

        Where the noise models overstate the errors by far (``s^2 < 0.25``, sigmas 2x too
        large), the first-order prediction covariance (computed with the nominal models) was
        measured to be far too wide (M3500, s^2 0.02: 33 wrong closures of 0.5 rad / 5 m came
        back on the prediction alone, clean cost 641 vs 69), so a factor must then also lie
        inside its own family-wise ellipse ``r^2 <= c_a^2`` (M3500 with 30 % of the file-noise
        wrong closures: one true closure at 0.8 ``c_a^2``, outside ``c^2``, comes back here).
        Where the models are about right the prediction test alone decides (Baarda's test; on
        a clean 300-pose graph it brings back two high-leverage true factors the passes
        rejected by chance, 2-4x outside ``c_a^2``, predictions inside the family-wise bound).
        """
        from .influence import leave_one_out_sq_norms, prediction_sq_norms

        sub, sub_state = self.solver.restricted.prepare(state, weights)
        keep, order = self.solver.restricted.keep, self.solver.restricted.order
        masks = [(~self.inliers[i] & (weights[i] > 0.5))[keep[i]] for i in order]
        _, drop_sub = leave_one_out_sq_norms(sub, sub_state, masks, both=True)
        s2b = min(1.0, max(s2, standardized_scale(
            [2.0 * d[m] for d, m in zip(drop_sub, masks)],
            [b.kernel.residual_dim for b in sub.batches])))
        have = set(sub.var_keys.tolist())
        plain = self.full.squared_residuals(state)
        back = []
        for i, b in enumerate(self.full.batches):
            rows = np.nonzero((weights[i] < 0.5) & ~self.inliers[i])[0]
            rows = rows[[all(int(k) in have for k in b.source.keys[r]) for r in rows]]
            if rows.size == 0:
                continue
            c = self.c2_snoop[i][rows]
            pred = prediction_sq_norms(sub, sub_state, b.source, rows, bound=s2b * c)
            ok = pred <= s2b * c
            if s2b < LOOSE_SCALE:  # see the docstring: the prediction alone is not to be trusted
                ok &= plain[i][rows] <= c
            if verbose:
                print(f"GNC clear: s^2 {s2b:.3g}, rejected r^2/c_a^2 "
                      f"{np.round(plain[i][rows] / c, 2).tolist()[:10]}, prediction "
                      f"w^2/(s^2 c_a^2) {np.round(pred / (s2b * c), 2).tolist()[:10]}")
            back += [(i, int(r)) for r in rows[ok]]
        if not back:
            return state, weights, s2
        weights = [w.copy() for w in weights]
        for i, r in back:
            weights[i][r] = 1.0
        state, _ = self.solver.solve(state, weights, chordal=False)
        return state, weights, s2b

    def _loo_scores(self, state, weights):
        from .influence import leave_one_out_sq_norms

        sub, sub_state = self.solver.restricted.prepare(state, weights)
        keep, order = self.solver.restricted.keep, self.solver.restricted.order
        masks = [~self.inliers[i][keep[i]] for i in order]
        drop_sub = leave_one_out_sq_norms(sub, sub_state, masks, cost_decrease=True)
        out = [np.zeros(len(w)) for w in weights[:-1]]
        for j, i in enumerate(order):
            out[i][keep[i]] = drop_sub[j]
        # > 1: rejecting the factor lowers the TLS objective (to first order)
        return [2.0 * x / c for x, c in zip(out, self.c2[:-1])]

    def verify(self, state, weights, max_removals: int, verbose: bool = False,
               deadline: float = float("inf")):
        forced = [np.zeros(len(w), dtype=bool) for w in weights]
        objective = self.objective(state)
        removed = 0
        tried: set = set()
        while removed < max_removals and time.perf_counter() < deadline:
            loo = self._loo_scores(state, weights)
            cands = sorted(((float(x[i]), bi, int(i)) for bi, x in enumerate(loo)
                            for i in np.nonzero((x > 1.0) & (weights[bi] > 0.5))[0]
                            if (bi, int(i)) not in tried), reverse=True)
            improved = False
            for score, bi, i in cands[:3]:  # a few tries per factorization
                tried.add((bi, i))
                trial = [f.copy() for f in forced]
                trial[bi][i] = True
                st, w = self.classify(state, trial)
                obj = self.objective(st)
                if verbose:
                    print(f"GNC check: cost drop without it / (c^2/2) {score:.3g}, factor {i} of "
                          f"batch {bi}: objective {objective:.6g} -> {obj:.6g}")
                if obj < objective * (1.0 - 1e-9):
                    state, weights, forced, objective = st, w, trial, obj
                    removed += 1
                    improved = True
                    break
            if not improved:
                break
        return state, weights, removed
