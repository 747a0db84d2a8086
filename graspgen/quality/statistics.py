"""Statistics of the robustness labels: the Wilson score interval of a success rate.

A robustness label is a binomial proportion (copies with outcome 5 out of the copies rolled out), so its
uncertainty is a binomial confidence interval; the Wilson score interval stays inside [0, 1] at the small counts
(tens of copies) a dataset can afford.
"""

from __future__ import annotations

import math

from graspgen.validation import check, check_int, check_number

__all__ = ["wilson_interval"]


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion.

    Parameters
    ----------
    successes : int
        Successes, ``0 <= successes <= n``.
    n : int
        Trials, ``>= 0``.
    z : float
        Standard normal quantile (1.96: 95% two-sided).

    Returns
    -------
    (lo, hi) : floats in [0, 1]; ``(nan, nan)`` when ``n = 0`` (no trials: no information).

    Notes
    -----
    ``(p + z^2 / 2n -+ z sqrt(p (1 - p) / n + z^2 / 4n^2)) / (1 + z^2 / n)`` with ``p = successes / n``. Unlike the
    normal (Wald) interval it stays inside [0, 1] and does not collapse to a point at 0/n or n/n: for 0/n it is
    ``[0, z^2 / (n + z^2)]``.
    """
    successes, n = check_int("successes", successes, low=0), check_int("n", n, low=0)
    check("successes", successes <= n, f"be <= n ({n})", successes)
    check_number("z", z, low=0.0, low_open=True)
    if n == 0:
        return math.nan, math.nan
    p = successes / n
    z2 = z * z
    denom = 1.0 + z2 / n
    centre = (p + z2 / (2 * n)) / denom
    half = z * math.sqrt(p * (1.0 - p) / n + z2 / (4.0 * n * n)) / denom
    # Clamp: at 0/n and n/n the bound is 0 or 1 up to round-off.
    lo = 0.0 if successes == 0 else max(0.0, centre - half)
    hi = 1.0 if successes == n else min(1.0, centre + half)
    return lo, hi
