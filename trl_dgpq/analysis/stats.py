"""Statistics over seeds that hold up (Agarwal et al., NeurIPS 2021), computed by their
``rliable`` library: the interquartile mean (IQM) with a 95 % stratified bootstrap
confidence interval, the probability of improvement, and performance profiles. The bootstrap
is rliable's; the IQM and P(X > Y) that it computes per replication are rliable's formulas,
written here without scipy's per-call overhead (tested bitwise equal to rliable's).

Bootstraps use fixed random numbers (``_quiet``), so a report is the same every time it
is drawn. Scores are "higher is better" where a comparison needs a direction: a domain
where less is better (fewer steps, lower cost) is negated first (``oriented``).
"""
from __future__ import annotations

import warnings
from typing import Dict, Optional, Tuple

import numpy as np

REPS = 2000  # bootstrap replications (rliable's default for profiles; CIs move < 1 % from 2,000 to 50,000);
            # read at each call (reps=None), so the tests that check what a report says, not its
            # intervals' precision, can draw fewer (tests/conftest.py)
SEED = 0


def _rly():
    from rliable import library  # imported when used: it brings scipy and arch
    return library


def _quiet(estimate):
    """Reproducible and quiet. rliable's stratified resampling draws its indices from numpy's
    global generator, not the RandomState it is given (measured: the same call gave three
    different intervals), so that generator is seeded for the call and then put back as it
    was. rliable passes ``random_state`` on to arch, which warns that it prefers a Generator;
    the warning only clutters a report."""
    def quiet(*args, **kwargs):
        saved = np.random.get_state()
        np.random.seed(SEED)
        try:
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", "random_state is deprecated", FutureWarning)
                return estimate(*args, **kwargs)
        finally:
            np.random.set_state(saved)
    return quiet


def _intervals(scores: dict, estimate, reps: Optional[int]):
    """rliable's point estimates and stratified-bootstrap 95 % CIs of ``estimate`` over ``scores``,
    ``reps`` replications (None: REPS, read now) from the fixed RandomState."""
    return _rly().get_interval_estimates(scores, estimate, reps=REPS if reps is None else reps,
                                         random_state=np.random.RandomState(SEED))


def oriented(values: np.ndarray, lower_is_better: bool) -> np.ndarray:
    """``values`` as higher-is-better scores: negated where less is better (fewer steps, lower cost)."""
    values = np.asarray(values, dtype=float)
    return -values if lower_is_better else values


# The statistics each bootstrap replication computes, as rliable's ``metrics`` compute them
# (tested bitwise equal), without scipy's per-call input checks: ``trim_mean`` and
# ``mannwhitneyu`` cost ~1.5 ms a call through scipy's NaN-policy wrapper (and the latter an
# exact p-value nobody reads), 2,000 times per interval -- most of a report's time.
def aggregate_iqm(scores: np.ndarray) -> float:
    """rliable's ``aggregate_iqm``: scipy's ``trim_mean`` over all entries, 25 % cut from each end
    (the same partition and slice, so the same float)."""
    a = np.ravel(scores)
    cut = int(0.25 * a.size)
    return np.mean(np.partition(a, (cut, a.size - cut - 1))[cut:a.size - cut])


def probability_of_improvement_1task(x: np.ndarray, y: np.ndarray) -> float:
    """rliable's ``probability_of_improvement`` on one task (``x`` (n, 1), ``y`` (m, 1)):
    Mann-Whitney's U of x over y -- the pairs where x is greater, ties counted half (exact in
    floats, as scipy's rank sums are) -- divided by n m. (rliable returns 0.5 for identical
    runs without scipy; U is n^2 / 2 there, so this gives the same.)"""
    x, y = np.ravel(x), np.ravel(y)
    u = np.count_nonzero(x[:, None] > y[None, :]) + 0.5 * np.count_nonzero(x[:, None] == y[None, :])
    return u / (len(x) * len(y))


def iqm_point(values) -> float:
    """The IQM alone, no interval, over the non-NaN values (NaN if none), without importing
    rliable (and arch: seconds) for it."""
    v = np.asarray(values, dtype=float)
    v = v[~np.isnan(v)]
    return float(aggregate_iqm(v)) if len(v) else np.nan


@_quiet
def iqm(values, reps: Optional[int] = None) -> Tuple[float, float, float]:
    """(IQM, CI low, CI high) over the runs in ``values`` (NaN dropped); all NaN if none."""
    v = np.asarray(values, dtype=float)
    v = v[~np.isnan(v)]
    if len(v) == 0:
        return (np.nan, np.nan, np.nan)
    point, ci = _intervals({"x": v[:, None]}, lambda x: np.array([aggregate_iqm(x)]), reps)
    return float(point["x"][0]), float(ci["x"][0, 0]), float(ci["x"][1, 0])


@_quiet
def probability_of_improvement(x, y, reps: Optional[int] = None) -> Tuple[float, float, float]:
    """P(X > Y) of a run of X against a run of Y on one task (higher-is-better scores),
    with its 95 % CI: (point, low, high)."""
    x, y = (np.asarray(a, dtype=float) for a in (x, y))
    x, y = x[~np.isnan(x)], y[~np.isnan(y)]
    point, ci = _intervals({"p": [x[:, None], y[:, None]]},
                           lambda a, b: np.array([probability_of_improvement_1task(a, b)]), reps)
    return float(point["p"][0]), float(ci["p"][0, 0]), float(ci["p"][1, 0])


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


@_quiet
def profiles(scores: Dict[str, np.ndarray], taus: np.ndarray, reps: Optional[int] = None):
    """rliable's performance profiles (the fraction of runs scoring above each tau) with
    95 % CIs: ({algorithm: (len(taus),)}, {algorithm: (2, len(taus))})."""
    library = _rly()
    # create_performance_profile with its default (score distributions), but with our RandomState:
    # it takes none and would draw from numpy's global one
    return _intervals(scores, lambda s: library.score_distributions(s, taus), reps)
