"""IQM, probability of improvement and profiles (trl_dgpq/analysis/stats.py), by hand and against
rliable's own calls, bit for bit."""
import warnings

import numpy as np
import pytest

from trl_dgpq.analysis import Threshold, stats
from trl_dgpq.analysis.stats import iqm, iqm_point, normalised, oriented, probability_of_improvement, profiles


def test_iqm_is_the_mean_of_the_middle_half_and_its_interval_holds_it():
    point, lo, hi = iqm([8.0, 1.0, 7.0, 2.0, 6.0, 3.0, 5.0, 4.0, np.nan])  # NaN dropped
    assert point == pytest.approx((3 + 4 + 5 + 6) / 4)
    assert 1.0 <= lo <= point <= hi <= 8.0 and lo < hi
    before = np.random.get_state()[1].copy()
    for _ in range(3):   # drawn from a generator of its own, the same every call; numpy's global one untouched
        assert iqm([8.0, 1.0, 7.0, 2.0, 6.0, 3.0, 5.0, 4.0]) == (point, lo, hi)
    assert np.array_equal(np.random.get_state()[1], before)
    assert np.isnan(iqm([np.nan])[0])
    assert iqm_point([8.0, 1.0, 7.0, 2.0, 6.0, 3.0, 5.0, 4.0, np.nan]) == 4.5
    assert iqm_point([2.0, None, 4.0]) == 3.0          # None is missing too (a column read as objects)
    assert iqm([2.0, None, 4.0], reps=50) == iqm([2.0, 4.0], reps=50)
    assert probability_of_improvement([2.0, None], [1.0, None], reps=50) == probability_of_improvement([2.0], [1.0],
                                                                                                       reps=50)
    with warnings.catch_warnings():
        warnings.simplefilter("error")                 # NaN when nothing is left, without numpy's empty-mean warning
        assert np.isnan(iqm_point([np.nan]))


def test_probability_of_improvement_counts_pairs_and_ties():
    assert probability_of_improvement([5.0, 6.0], [1.0, 2.0, 3.0])[0] == 1.0
    assert probability_of_improvement([1.0, 2.0], [5.0, 6.0])[0] == 0.0
    # x = (1, 3) against y = (2, 2): pairs 1>2 no, 1>2 no, 3>2 yes, 3>2 yes -> 2 of 4
    assert probability_of_improvement([1.0, 3.0], [2.0, 2.0])[0] == pytest.approx(0.5)
    # a tie counts one half: x = (2,), y = (2, 1): 0.5 + 1 over 2 pairs
    assert probability_of_improvement([2.0], [2.0, 1.0])[0] == pytest.approx(0.75)
    p, lo, hi = probability_of_improvement([3.0, 4.0, 5.0, 1.0], [2.0, 2.5, 0.0, 3.5])
    assert lo <= p <= hi


def test_fewer_is_better_is_negated():
    assert list(oriented([3.0, -1.0], True)) == [-3.0, 1.0] and list(oriented([3.0], False)) == [3.0]


def test_tasks_are_scaled_by_the_lowest_and_highest_run_and_profiles_count_runs_above_tau():
    scores = normalised({"a": {"t1": np.array([0.0, 10.0]), "t2": np.array([5.0, 7.0])},
                         "b": {"t1": np.array([5.0, 5.0, 5.0]), "t2": np.array([9.0, 5.0])},
                         "c": {"t1": np.array([1.0, 1.0])}})                     # not on t2: left out
    assert set(scores) == {"a", "b"}
    np.testing.assert_allclose(scores["a"], [[0.0, 0.0], [1.0, 0.5]])          # t1 on [0, 10], t2 on [5, 9]
    np.testing.assert_allclose(scores["b"], [[0.5, 1.0], [0.5, 0.0]])          # b's third t1 run cut
    curves, cis = profiles(scores, np.array([0.25, 0.75]), reps=200)
    np.testing.assert_allclose(curves["a"], [2 / 4, 1 / 4])   # a: 0, 0, 1, 0.5 -> above 0.25: 2; above 0.75: 1
    np.testing.assert_allclose(curves["b"], [3 / 4, 1 / 4])
    assert cis["a"].shape == (2, 2)


def test_a_task_every_run_tied_on_is_one_half_and_runs_are_cut_to_the_fewest_over_tasks():
    scores = normalised({"a": {"t1": np.array([1.0, 1.0, 1.0]), "t2": np.array([0.0, 4.0])},
                         "b": {"t1": np.array([1.0, 1.0, 1.0]), "t2": np.array([2.0, 2.0, 2.0])}})
    np.testing.assert_array_equal(scores["a"], [[0.5, 0.0], [0.5, 1.0]])   # t1: 3 runs each, all tied
    np.testing.assert_array_equal(scores["b"], [[0.5, 0.5], [0.5, 0.5]])   # t2 has 2 of a's: 2 rows


def test_intervals_are_the_same_in_another_process():
    """numpy's global generator starts a new process from fresh entropy: the intervals must not
    depend on it, so a second process computes the same numbers, not only a second call here."""
    import subprocess
    import sys
    x, y = [8.0, 1.0, 7.0, 2.0, 6.0, 3.0, 5.0, 4.0], [3.0, 4.0, 5.0, 1.0, 2.5]
    code = ("from trl_dgpq.analysis.stats import iqm, probability_of_improvement\n"
            f"print(repr((iqm({x}, reps=300), probability_of_improvement({x}, {y}, reps=300))))")
    there = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    here = (iqm(x, reps=300), probability_of_improvement(x, y, reps=300))
    assert there.stdout.strip() == repr(here)


def rliables(estimate, reps, *scores):
    """rliable's own ``get_interval_estimates`` as this module's callers used it: its indices drawn
    from numpy's global generator, seeded at stats.SEED for the call (and restored after), arch's
    RandomState warning hidden: ({key: point}, {key: (2, k) interval})."""
    import warnings as w
    from rliable import library
    saved = np.random.get_state()
    np.random.seed(stats.SEED)
    try:
        with w.catch_warnings():
            w.simplefilter("ignore", FutureWarning)
            return library.get_interval_estimates(*scores, estimate, reps=reps,
                                                  random_state=np.random.RandomState(stats.SEED))
    finally:
        np.random.set_state(saved)


def test_intervals_are_rliables_own_bit_for_bit():
    """Every point and interval equals rliable's ``get_interval_estimates`` on the same scores, to
    the last bit: the IQM over 1-30 runs (the cut's rounding, ties), P(X > Y) on runs of equal and
    of unequal length (their draws interleave), and the profiles of three algorithms over two tasks
    (drawn in turn from one stream). rliable is given the per-replication statistics of this module
    (bitwise its own, the test above; scipy's cost ~1 ms a replication)."""
    from rliable import library

    from trl_dgpq.analysis.stats import aggregate_iqm, probability_of_improvement_1task
    rng = np.random.default_rng(3)
    for trial in range(24):
        n, m = (int(k) for k in rng.integers(1, 31, size=2))
        if trial % 4 == 0:
            m = n
        draw = (lambda k: rng.integers(0, 4, size=k).astype(float)) if trial % 3 == 0 else \
            (lambda k: rng.normal(size=k) * 10 ** rng.uniform(-3, 6))
        x, y, reps = draw(n), draw(m), int(rng.integers(20, 400))
        point, ci = rliables(lambda a: np.array([aggregate_iqm(a)]), reps, {"x": x[:, None]})
        assert iqm(x, reps=reps) == (point["x"][0], ci["x"][0, 0], ci["x"][1, 0])
        point, ci = rliables(lambda a, b: np.array([probability_of_improvement_1task(a, b)]), reps,
                             {"p": [x[:, None], y[:, None]]})
        assert probability_of_improvement(x, y, reps=reps) == (point["p"][0], ci["p"][0, 0], ci["p"][1, 0])
    # scores of one decimal against taus 0, 0.1, ..., 1: scores equal to a tau are not above it
    scores = {k: rng.integers(0, 11, size=(int(rng.integers(2, 9)), 2)) / 10 for k in ("a", "b", "c")}
    taus = np.linspace(0.0, 1.0, 11)
    points, cis = rliables(lambda s: library.score_distributions(s, taus), 200, scores)
    mine = profiles(scores, taus, reps=200)
    for k in scores:
        assert np.array_equal(mine[0][k], points[k]) and np.array_equal(mine[1][k], cis[k])
        assert mine[1][k].shape == (2, len(taus))


def test_an_empty_side_has_no_interval_and_scores_must_be_runs_by_tasks():
    with warnings.catch_warnings():
        warnings.simplefilter("error")            # no 0 / 0 on the way
        assert all(np.isnan(probability_of_improvement([np.nan], [1.0, 2.0])))
        assert all(np.isnan(probability_of_improvement([1.0], [])))
    with pytest.raises(ValueError, match=r"\(runs, tasks\)"):
        profiles({"a": np.ones(3)}, np.array([0.5]), reps=10)
    with pytest.raises(ValueError, match="one task's runs, got 2 and 1 tasks"):
        stats.improvement_rows(np.ones((1, 3, 2)), np.ones((1, 3, 1)))


def test_per_replication_statistics_are_rliables_bit_for_bit():
    """The IQM and P(X > Y) each bootstrap replication computes are rliable's own (scipy's
    trim_mean and Mann-Whitney U), to the last bit: over sizes 1-13 (the cut's rounding, odd and
    even), ties (integer scores), NaN-free runs of unequal length and identical runs."""
    from rliable import metrics
    from trl_dgpq.analysis.stats import aggregate_iqm, probability_of_improvement_1task
    rng = np.random.default_rng(0)
    for trial in range(300):
        n, m = rng.integers(1, 14, size=2)
        draw = (lambda k: rng.integers(0, 4, size=(k, 1)).astype(float)) if trial % 2 else \
            (lambda k: rng.normal(size=(k, 1)) * 10 ** rng.uniform(-3, 6))
        x, y = draw(n), draw(m)
        assert aggregate_iqm(x) == metrics.aggregate_iqm(x)
        assert probability_of_improvement_1task(x, y) == metrics.probability_of_improvement(x, y)
        assert probability_of_improvement_1task(x, x.copy()) == 0.5 == metrics.probability_of_improvement(x, x.copy())
    wide = rng.normal(size=(11, 3))           # every entry of a (runs, tasks) matrix, as rliable's
    assert aggregate_iqm(wide) == metrics.aggregate_iqm(wide)


def test_the_default_replications_are_reps_at_the_call(monkeypatch):
    """reps=None reads REPS when called (the suite's 2,000), so a caller, or a test, that sets
    REPS gets that many."""
    v = np.array([3.0, 1.0, 4.0, 1.0, 5.0, 9.0, 2.0, 6.0])
    assert stats.REPS == 2000
    assert stats.iqm(v) == stats.iqm(v, reps=2000) != stats.iqm(v, reps=200)
    assert stats.probability_of_improvement(v, v[::-1] + 0.5) == stats.probability_of_improvement(v, v[::-1] + 0.5,
                                                                                                 reps=2000)
    monkeypatch.setattr(stats, "REPS", 200)
    assert stats.iqm(v) == stats.iqm(v, reps=200)
    taus = np.linspace(0.0, 1.0, 5)
    scores = {"a": np.array([[0.1, 0.9], [0.4, 0.5]]), "b": np.array([[0.3, 0.2], [0.8, 0.6]])}
    for x, y in zip(stats.profiles(scores, taus)[1].values(), stats.profiles(scores, taus, reps=200)[1].values()):
        assert np.array_equal(x, y)


def test_a_bootstrap_leaves_numpys_global_generator_alone_and_warns_nothing():
    """rliable draws from numpy's global generator; these draw from their own: whatever the global
    one's state, the intervals are the same, and it is where it was afterwards."""
    v, w = [3.0, 1.0, 4.0, 1.0, 5.0, 9.0], [2.0, 6.0, 5.0]
    np.random.seed(123)
    first = (iqm(v, reps=100), probability_of_improvement(v, w, reps=100),
             profiles({"a": np.array([[0.1], [0.7]])}, np.array([0.5]), reps=100)[1]["a"].tolist())
    expect_after = np.random.RandomState(123).random_sample(2)
    np.random.seed(7)
    np.random.random_sample(5)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        again = (iqm(v, reps=100), probability_of_improvement(v, w, reps=100),
                 profiles({"a": np.array([[0.1], [0.7]])}, np.array([0.5]), reps=100)[1]["a"].tolist())
    assert again == first
    np.random.seed(123)
    iqm(v, reps=100), probability_of_improvement(v, w, reps=100)
    assert np.array_equal(np.random.random_sample(2), expect_after)


def test_oriented_scores_are_floats_negated_where_less_is_better():
    got = oriented([1, 2], lower_is_better=True)
    assert got.dtype == float and got.tolist() == [-1.0, -2.0]
    assert oriented(np.array([3], dtype=np.uint8), lower_is_better=True).tolist() == [-3.0]
