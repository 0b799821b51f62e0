"""Statistics over seeds that hold up (Agarwal et al., NeurIPS 2021), as their ``rliable``
library computes them: the interquartile mean (IQM) with a 95 % stratified bootstrap
confidence interval, the probability of improvement, and performance profiles.

The numbers are rliable's to the last bit (tests/test_stats.py compares every one with
rliable's own call): the same per-replication indices, drawn from the same generator in the
same order, the same per-replication formulas (scipy's ``trim_mean`` and Mann-Whitney U,
written without scipy's per-call checks) and arch's percentile interval. What differs is that
every replication is computed at once, as arrays with a leading replication axis: rliable
resamples and calls the statistic once per replication in Python (arch's iterator, its index
update), which took two thirds of a quick-scale report's time (87 of 137 s under cProfile,
2026-11-29) for ~0.1 ms of arithmetic per interval.

Bootstraps draw from their own ``RandomState(SEED)`` per call (rliable draws from numpy's
global generator, which a caller would have to seed; this one is never touched), so a report
is the same every time it is drawn. Scores are "higher is better" where a comparison needs a
direction: a domain where less is better (fewer steps, lower cost) is negated first
(``oriented``).
"""
from __future__ import annotations

from typing import Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np

REPS = 2000  # bootstrap replications (rliable's default for profiles; CIs move < 1 % from 2,000 to 50,000);
            # read at each call (reps=None), so the tests that check what a report says, not its
            # intervals' precision, can draw fewer (tests/conftest.py)
SEED = 0
ALPHA = (1.0 - 0.95) / 2   # arch's two-sided 95 % percentile interval: its tails, the same float


def oriented(values: np.ndarray, lower_is_better: bool) -> np.ndarray:
    """``values`` as higher-is-better scores: negated where less is better (fewer steps, lower cost)."""
    values = np.asarray(values, dtype=float)
    return -values if lower_is_better else values


# ------------------------------------------------------------------ per replication, all at once
# Each statistic takes arrays with a leading replication axis, (reps, runs, tasks), and returns
# (reps, k): row r is what rliable's ``metrics`` compute on replication r (tested bitwise equal).
def iqm_rows(scores: np.ndarray) -> np.ndarray:
    """rliable's ``aggregate_iqm`` of each replication: scipy's ``trim_mean`` over all its entries,
    25 % cut from each end (the same partition and slice, so the same float)."""
    flat = scores.reshape(len(scores), -1)
    n = flat.shape[1]
    cut = int(0.25 * n)
    return np.mean(np.partition(flat, (cut, n - cut - 1), axis=1)[:, cut:n - cut], axis=1)[:, None]


def improvement_rows(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """rliable's ``probability_of_improvement`` on one task of each replication (``x`` (reps, n, 1),
    ``y`` (reps, m, 1)): Mann-Whitney's U of x over y -- the pairs where x is greater, ties counted
    half (exact in floats, as scipy's rank sums are) -- divided by n m. (rliable returns 0.5 for
    identical runs without scipy; U is n^2 / 2 there, so this gives the same.)"""
    if x.shape[2] != 1 or y.shape[2] != 1:
        raise ValueError(f"P(X > Y) is of one task's runs, got {x.shape[2]} and {y.shape[2]} tasks")
    a, b = x[:, :, None, 0], y[:, None, :, 0]
    u = np.count_nonzero(a > b, axis=(1, 2)) + 0.5 * np.count_nonzero(a == b, axis=(1, 2))
    return (u / (x.shape[1] * y.shape[1]))[:, None]


def above_rows(scores: np.ndarray, taus: np.ndarray) -> np.ndarray:
    """rliable's ``score_distributions`` of each replication: per tau, the fraction of its
    (run, task) entries above tau (a count over a count: exact, in any order)."""
    return np.mean(scores[:, None] > taus[None, :, None, None], axis=(2, 3))


def aggregate_iqm(scores: np.ndarray) -> float:
    """rliable's ``aggregate_iqm`` of one array: the IQM of all its entries."""
    return iqm_rows(np.asarray(scores, dtype=float)[None])[0, 0]


def probability_of_improvement_1task(x: np.ndarray, y: np.ndarray) -> float:
    """rliable's ``probability_of_improvement`` of ``x`` (n, 1) over ``y`` (m, 1) on one task."""
    return improvement_rows(np.asarray(x, dtype=float)[None], np.asarray(y, dtype=float)[None])[0, 0]


# ------------------------------------------------------------------ rliable's stratified bootstrap
def _indices(rs: np.random.RandomState, shapes: Sequence[tuple], reps: int) -> List[np.ndarray]:
    """rliable's indices for ``reps`` replications of arrays of ``shapes`` (runs, tasks), each
    (reps, runs, tasks): per replication, per array in turn, ``choice(runs, shape)`` (which is
    ``randint(0, runs, shape)``) -- for each task a draw of its runs with replacement. Draws of one
    bound are one call (a stream drawn at once is the same numbers as drawn in turn); arrays of
    different shapes interleave their draws replication by replication, as rliable's."""
    if all(shape == shapes[0] for shape in shapes):
        drawn = rs.randint(0, shapes[0][0], size=(reps, len(shapes), *shapes[0]))
        return [drawn[:, k] for k in range(len(shapes))]
    per = [[rs.randint(0, shape[0], size=shape) for shape in shapes] for _ in range(reps)]
    return [np.stack([drawn[k] for drawn in per]) for k in range(len(shapes))]


def _resampled(scores: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """(reps, runs, tasks): replication r's run i of task t is run ``indices[r, i, t]`` of task t."""
    return scores[indices, np.arange(scores.shape[1])]


def _interval(arrays: Sequence[np.ndarray], statistic: Callable, reps: Optional[int],
              rs: np.random.RandomState) -> Tuple[np.ndarray, np.ndarray]:
    """rliable's ``get_interval_estimates`` of one key: the point estimate (k,) of ``statistic`` on
    ``arrays`` (each (runs, tasks)) and arch's 95 % percentile interval (2, k) over ``reps``
    (None: REPS, read now) stratified replications drawn from ``rs``."""
    arrays = [np.asarray(a, dtype=float) for a in arrays]
    if any(a.ndim != 2 for a in arrays):
        raise ValueError(f"scores must be (runs, tasks) arrays, got shapes {[a.shape for a in arrays]}")
    reps = REPS if reps is None else reps
    point = statistic(*(a[None] for a in arrays))[0]
    drawn = _indices(rs, [a.shape for a in arrays], reps)
    results = np.asarray(statistic(*(_resampled(a, i) for a, i in zip(arrays, drawn))), dtype=float)
    ci = np.stack([np.percentile(results[:, k], [100 * ALPHA, 100 * (1.0 - ALPHA)]) for k in range(results.shape[1])],
                  axis=1)
    return point, ci


def iqm_point(values) -> float:
    """The IQM alone, no interval, over the non-NaN values (NaN if none)."""
    v = np.asarray(values, dtype=float)
    v = v[~np.isnan(v)]
    return float(aggregate_iqm(v)) if len(v) else np.nan


def iqm(values, reps: Optional[int] = None) -> Tuple[float, float, float]:
    """(IQM, CI low, CI high) over the runs in ``values`` (NaN dropped); all NaN if none."""
    v = np.asarray(values, dtype=float)
    v = v[~np.isnan(v)]
    if len(v) == 0:
        return (np.nan, np.nan, np.nan)
    point, ci = _interval([v[:, None]], iqm_rows, reps, np.random.RandomState(SEED))
    return float(point[0]), float(ci[0, 0]), float(ci[1, 0])


def probability_of_improvement(x, y, reps: Optional[int] = None) -> Tuple[float, float, float]:
    """P(X > Y) of a run of X against a run of Y on one task (higher-is-better scores),
    with its 95 % CI: (point, low, high); all NaN where either has no run (NaN dropped)."""
    x, y = (np.asarray(a, dtype=float) for a in (x, y))
    x, y = x[~np.isnan(x)], y[~np.isnan(y)]
    if len(x) == 0 or len(y) == 0:
        return (np.nan, np.nan, np.nan)
    point, ci = _interval([x[:, None], y[:, None]], improvement_rows, reps, np.random.RandomState(SEED))
    return float(point[0]), float(ci[0, 0]), float(ci[1, 0])


def normalised(task_scores: Dict[str, Dict[str, np.ndarray]]) -> Dict[str, np.ndarray]:
    """{algorithm: (runs, tasks)} of higher-is-better scores, each task's scaled to [0, 1] by the
    lowest and highest score any algorithm's run had on it; only algorithms on every task,
    each task cut to the fewest runs any of them had there."""
    tasks = sorted({t for per in task_scores.values() for t in per})
    algos = [a for a, per in task_scores.items() if set(per) == set(tasks)]
    if not algos:
        return {}
    columns = {a: [] for a in algos}
    for t in tasks:
        n = min(len(task_scores[a][t]) for a in algos)
        everything = np.concatenate([task_scores[a][t] for a in algos])
        lo, hi = np.nanmin(everything), np.nanmax(everything)
        for a in algos:
            s = np.asarray(task_scores[a][t][:n], dtype=float)
            columns[a].append((s - lo) / (hi - lo) if hi > lo else np.full(n, 0.5))
    n = min((len(c) for cols in columns.values() for c in cols), default=0)
    return {a: np.stack([c[:n] for c in cols], axis=1) for a, cols in columns.items()}


def profiles(scores: Dict[str, np.ndarray], taus: np.ndarray, reps: Optional[int] = None):
    """rliable's performance profiles (``create_performance_profile`` with its default, score
    distributions: the fraction of runs scoring above each tau) with 95 % CIs, the algorithms
    drawn in turn from one generator as rliable's are: ({algorithm: (len(taus),)},
    {algorithm: (2, len(taus))})."""
    taus = np.asarray(taus, dtype=float)
    rs = np.random.RandomState(SEED)
    out = {name: _interval([s], lambda a: above_rows(a, taus), reps, rs) for name, s in scores.items()}
    return {n: point for n, (point, _) in out.items()}, {n: ci for n, (_, ci) in out.items()}
