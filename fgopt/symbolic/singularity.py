"""Checking epsilon-handled removable singularities (SymForce paper, Sec. VI-B).

For ``f_safe(x, epsilon)`` meant to remove a singularity of ``f`` at ``x = x0``:

1. ``f_safe(x0, 0)`` should be an indeterminate form (SymPy ``nan``); ``+-oo`` / ``zoo`` means
   the singularity is not removable and epsilon cannot fix it;
2. ``L_x = lim_{x -> x0} f_safe(x, 0)`` (from both sides) is the correct value;
3. ``L_eps = lim_{eps -> 0+} f_safe(x0, eps)`` must be finite and equal ``L_x``.

The same test is run on the first derivative ``d f_safe / dx``. One-sided limits substitute
``x = x0 +- u`` with ``u -> 0+`` (so ``|x - x0|`` and ``sqrt((x - x0)^2)`` simplify);
``sign_no_zero`` terms are resolved per side (``+1`` right of ``x0``, ``-1`` left of it).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


def _s():
    from . import _sym

    return _sym


@dataclass
class SingularityReport:
    """Result of :func:`check_removable_singularity` (``ok`` and the limits per order)."""

    ok: bool
    messages: list = field(default_factory=list)
    values: dict = field(default_factory=dict)  # order -> (at_x0, lim_x, lim_eps)

    def __bool__(self) -> bool:
        return self.ok


def _resolve_snz(expr: Any, x: Any, side: int):
    sp = _s().sp

    def value(e):
        return sp.S.One if side > 0 else sp.S.NegativeOne

    return expr.replace(lambda e: isinstance(e, _s().SignNoZero) and e.has(x), value)


def _finite(v: Any) -> bool:
    sp = _s().sp
    return v.is_finite is True or (v.is_number and v not in (sp.nan, sp.zoo, sp.oo, -sp.oo))


def check_removable_singularity(f: Any, x: Any, x0: Any = 0, epsilon: Any = None,
                                orders: int = 1) -> SingularityReport:
    """Check value (and derivatives up to ``orders``) of ``f(x, epsilon)`` at ``x0``.

    Args:
        f: SymPy expression in the symbol ``x`` and ``epsilon``.
        x: the variable.
        x0: the singular point.
        epsilon: the epsilon symbol (default :data:`fgopt.symbolic.epsilon`).
        orders: also check derivatives up to this order.

    Example: ``sin(x) / x`` at 0. Shifting only the denominator gives ``0`` for ``epsilon > 0``
    where the limit is 1; shifting ``x`` in both places is right:

    >>> from fgopt.symbolic import check_removable_singularity, epsilon, safe_div, sin, snz, symbols
    >>> x = symbols("x")
    >>> check_removable_singularity(safe_div(sin(x), x), x).messages[0]
    'value: limit in epsilon 0 != limit in x 1'
    >>> xs = x + snz(x) * epsilon
    >>> bool(check_removable_singularity(sin(xs) / xs, x))
    True
    """
    sp = _s().sp
    eps = _s().epsilon if epsilon is None else epsilon
    x0 = sp.sympify(x0)
    report = SingularityReport(ok=True)
    expr = sp.sympify(f)
    for order in range(orders + 1):
        g = expr if order == 0 else sp.diff(expr, x, order)
        g = _s().remove_distributions(g)
        tag = "value" if order == 0 else f"derivative {order}"
        at = sp.simplify(_resolve_snz(g.subs(eps, 0), x, 1).subs(x, x0))
        lims = []
        u = sp.Dummy("u", positive=True)  # x = x0 + side * u, u -> 0+ (so |u| = u)
        for side in (1, -1):
            g_side = _resolve_snz(g.subs(eps, 0), x, side).subs(x, x0 + side * u)
            lims.append(sp.limit(g_side, u, 0, dir="+"))
        lim_eps = sp.limit(_resolve_snz(g, x, 1).subs(x, x0), eps, 0, dir="+")
        report.values[order] = (at, lims, lim_eps)
        if at in (sp.zoo, sp.oo, -sp.oo):
            report.ok = False
            report.messages.append(f"{tag}: f(x0, 0) = {at}: not a removable singularity")
            continue
        if at is not sp.nan and _finite(at):
            report.messages.append(f"{tag}: f(x0, 0) = {at} is not singular")
        if not all(_finite(v) for v in lims) or sp.simplify(lims[0] - lims[1]) != 0:
            report.ok = False
            report.messages.append(f"{tag}: one-sided limits {lims} differ or are infinite")
            continue
        if not _finite(lim_eps):
            report.ok = False
            report.messages.append(f"{tag}: limit as epsilon -> 0 is {lim_eps}")
            continue
        if sp.simplify(lim_eps - lims[0]) != 0:
            report.ok = False
            report.messages.append(f"{tag}: limit in epsilon {lim_eps} != limit in x {lims[0]}")
    return report
