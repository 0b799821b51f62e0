"""Section 5 of GWH14: epsilon_1 and sigma_tol^2 from (epsilon, delta).

    eps1      = eps (1 - gamma) / 3
    N_S       = N_S(eps (1 - gamma) / (3 L_Q))          covering number of the state space
    kappa     = |A| N_S (3 R_max / ((1 - gamma)^2 eps) + 1)
    sigma_tol2 = 2 w_n^2 eps^2 (1 - gamma)^4 / (9 R_max^2 ln(6 |A| N_S (1 + kappa) / delta))

N_S comes from the env's state box and the metric (``box_covering``); the seed
report's formula for the unit square (``unit_square_covering``) stays available
to reproduce its numbers.
"""
from __future__ import annotations

import math
from typing import Callable, Sequence, Tuple

# Side of the largest axis-aligned cube inside a ball of radius r in d dimensions.
_CUBE_IN_BALL = {"l1": lambda r, d: 2 * r / d, "l2": lambda r, d: 2 * r / math.sqrt(d), "linf": lambda r, d: 2 * r}


def unit_square_covering(r: float) -> int:
    """N_S(r) for the unit square, as the seed report used: ceil(1 / (pi r^2))."""
    return math.ceil(1.0 / (math.pi * r * r))


def box_covering(low: Sequence[float], high: Sequence[float], metric: str) -> Callable[[float], int]:
    """N_S(r) for the box [low, high] under ``metric``: a grid of cubes, each inside one
    ball of radius r (side 2r/d for L1, 2r/sqrt(d) for L2, 2r for Linf), covers the box
    with prod_i ceil(width_i / side) balls."""
    if metric not in _CUBE_IN_BALL:
        raise ValueError(f"metric must be one of {sorted(_CUBE_IN_BALL)}, got {metric!r}")
    widths = [float(h) - float(lo) for lo, h in zip(low, high)]
    if not widths or not all(math.isfinite(w) and w >= 0 for w in widths):
        raise ValueError(f"the state box must be finite, got low={list(low)}, high={list(high)}")

    def covering(r: float) -> int:
        side = _CUBE_IN_BALL[metric](r, len(widths))
        return math.prod(max(1, math.ceil(w / side)) for w in widths)
    return covering


def section5(eps: float, delta: float, gamma: float, r_max: float, lipschitz: float,
             num_actions: int, noise_var: float,
             covering: Callable[[float], int] = unit_square_covering) -> Tuple[float, float]:
    """Return (eps1, sigma_tol2). Raises ValueError where the formulas are undefined."""
    if not eps > 0:
        raise ValueError(f"eps must be > 0, got {eps}")
    if not 0 < delta < 1:
        raise ValueError(f"delta must be in (0, 1), got {delta}")
    if not 0 <= gamma < 1:
        raise ValueError(f"Section 5 needs 0 <= gamma < 1 (got {gamma}); set sigma_tol2 and eps1 directly")
    if not (r_max > 0 and lipschitz > 0 and noise_var > 0 and num_actions >= 1):
        raise ValueError("Section 5 needs r_max > 0, lipschitz > 0, noise_var > 0 and >= 1 action")
    eps1 = eps * (1 - gamma) / 3
    n_s = covering(eps * (1 - gamma) / (3 * lipschitz))
    kappa = num_actions * n_s * (3 * r_max / ((1 - gamma) ** 2 * eps) + 1)
    sigma_tol2 = (2 * noise_var * eps ** 2 * (1 - gamma) ** 4
                  / (9 * r_max ** 2 * math.log(6 * num_actions * n_s * (1 + kappa) / delta)))
    return eps1, sigma_tol2
