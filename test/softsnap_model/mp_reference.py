"""High-precision (mpmath) reference for forward solves; shared by tests and benchmarks.

Refines a candidate (angles, tension) by Newton on the full KKT system
``2 k_i a_i + lam L_i'(a_i) = 0``, ``sum L_i = L_target`` in mpmath, with derivatives
from mpmath's own differentiation of the FACTS.md formula (not our code).
"""
import mpmath as mp


def _length(a, d1, d2, s):
    c = mp.mpf(1) if a == 0 else 2 * mp.sin(a / 2) / a
    return mp.sqrt((d1 - d2) ** 2 + c * c * (s + d1 * a) * (s + d2 * a))


def kkt_reference(d, k, s, length_mm, angles, tension, free=None, dps=40, iters=30):
    """Return (angles, tension) as mpf lists; segments not in ``free`` stay fixed."""
    mp.mp.dps = dps
    n = len(d) - 1
    free = list(range(n)) if free is None else list(free)
    a = [mp.mpf(float(x)) for x in angles]
    lam = mp.mpf(float(tension))
    s = mp.mpf(s)
    dd = [mp.mpf(float(x)) for x in d]
    for _ in range(iters):
        lp = [mp.diff(lambda x, i=i: _length(x, dd[i], dd[i + 1], s), a[i]) for i in range(n)]
        lpp = [mp.diff(lambda x, i=i: _length(x, dd[i], dd[i + 1], s), a[i], 2)
               for i in range(n)]
        g = sum(_length(a[i], dd[i], dd[i + 1], s) for i in range(n)) - length_mm
        f = {i: 2 * k[i] * a[i] + lam * lp[i] for i in free}
        h = {i: 2 * k[i] + lam * lpp[i] for i in free}
        num = g - sum(lp[i] * f[i] / h[i] for i in free)
        den = sum(lp[i] ** 2 / h[i] for i in free)
        dlam = num / den
        for i in free:
            a[i] -= (f[i] + lp[i] * dlam) / h[i]
        lam += dlam
        if abs(dlam) < mp.mpf(10) ** (-dps + 5):
            break
    return a, lam


def rib_centers_mp(angles, s):
    """Rib centres in mpmath (FACTS.md recursion)."""
    x, y, t = mp.mpf(0), mp.mpf(0), mp.mpf(0)
    out = [(x, y)]
    for a in angles:
        chord = s if a == 0 else s * mp.sin(a / 2) / (a / 2)
        x += chord * mp.cos(t + a / 2)
        y += chord * mp.sin(t + a / 2)
        t += a
        out.append((x, y))
    return out
