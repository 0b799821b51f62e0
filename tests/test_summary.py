"""The per-seed summaries (trl_dgpq/analysis/summary.py) on small tables by hand."""
import math

import numpy as np
import pandas as pd
import pytest

from trl_dgpq.analysis import (count, curve, kernel_fits_per_seed, last_episodes, median_steps, ms_per_seed_step,
                               paired_ratios, rolling, seed_means)


def table(rows):
    return pd.DataFrame(rows, columns=["seed", "episode", "env_steps", "steps", "return", "wall_s"])


def test_curve_is_each_seeds_windowed_mean_as_it_stood_at_each_grid_step():
    """Seed 0's episodes end at env steps 10, 25, 40 with returns 1, 3, 5 (window 2: 1, 2, 4);
    seed 1's at 5 and 50 with returns 2, 4 (2, 3). NaN before a seed's first episode ended and
    past its last."""
    df = table([(0, 1, 10, 10, 1.0, 0.0), (0, 2, 25, 15, 3.0, 0.0), (0, 3, 40, 15, 5.0, 0.0),
                (1, 1, 5, 5, 2.0, 0.0), (1, 2, 50, 45, 4.0, 0.0)])
    grid = np.array([0, 9, 10, 24, 25, 39, 40, 41, 50, 51])
    nan = math.nan
    expect = [[nan, nan, 1, 1, 2, 2, 4, nan, nan, nan],
              [nan, 2, 2, 2, 2, 2, 2, 2, 3, nan]]
    np.testing.assert_array_equal(curve(df, "return", 2, grid), np.array(expect))


def test_rolling_means_over_what_there_is_unless_full():
    df = table([(0, 1, 1, 1, 1.0, 0.0), (0, 2, 2, 1, 3.0, 0.0), (0, 3, 3, 1, 8.0, 0.0)])
    assert rolling(df, "return", 3).tolist() == [1.0, 2.0, 4.0]
    full = rolling(df, "return", 3, full=True).tolist()
    assert np.isnan(full[0]) and np.isnan(full[1]) and full[2] == 4.0


def test_seed_means_include_both_ends_and_give_nan_to_a_seed_with_no_episode_there():
    df = table([(0, 1, 1, 1, 1.0, 0.0), (0, 2, 2, 1, 3.0, 0.0), (0, 3, 3, 1, 8.0, 0.0), (1, 5, 9, 9, 4.0, 0.0)])
    got = seed_means(df, "return", 1, 2)
    assert got.index.tolist() == [0, 1] and got[0] == 2.0 and np.isnan(got[1])
    assert seed_means(df, "return", 2).tolist() == [5.5, 4.0]


def test_last_episodes_within_a_budget():
    df = table([(0, 1, 10, 10, 1.0, 0.0), (0, 2, 20, 10, 2.0, 0.0), (0, 3, 30, 10, 3.0, 0.0),
                (1, 1, 15, 15, 4.0, 0.0)])
    assert last_episodes(df, 2, budget=25)[["seed", "episode"]].values.tolist() == [[0, 1], [0, 2], [1, 1]]
    assert last_episodes(df, 1)[["seed", "episode"]].values.tolist() == [[0, 3], [1, 1]]


def test_ms_per_seed_step_median_steps_and_kernel_fits():
    """1.5 + 0.5 s over 100 + 300 steps: 5 ms a step. Episodes 1-2 of two seeds with steps 10, 30
    and 20, 60: medians 20 and 40, their median 30."""
    df = table([(0, 1, 10, 10, 0.0, 1.5), (1, 1, 30, 30, 0.0, 0.0), (0, 2, 30, 20, 0.0, 0.5), (1, 2, 90, 60, 0.0, 0.0),
                (0, 3, 300, 210, 0.0, 0.0), (1, 3, 130, 70, 0.0, 0.0)])
    assert ms_per_seed_step(df.iloc[[0, 2]].assign(steps=[100, 300])) == pytest.approx(5.0)
    assert median_steps(df, [1, 2]) == 30.0
    assert kernel_fits_per_seed(df) == 0.0
    assert kernel_fits_per_seed(df.assign(kernel_fits=[1, 2, 3, 6, 5, 4])) == 5.5   # each seed's counter at most: 5, 6


def test_paired_ratios_over_shared_pairs_and_none_without():
    df = table([(0, 1, 1, 1, 2.0, 0.0), (0, 2, 2, 1, 6.0, 0.0)])
    ref = table([(0, 2, 2, 1, 3.0, 0.0), (0, 3, 3, 1, 9.0, 0.0)])
    assert paired_ratios(df, ref, ["return"]) == [2.0]
    assert paired_ratios(df, ref.assign(seed=1), ["return"]) is None


def test_count_says_one_or_many():
    assert [count(1, "seed"), count(2, "seed"), count(1000, "episode"), count(0, "job")] == [
        "1 seed", "2 seeds", "1,000 episodes", "0 jobs"]


def test_a_threshold_is_met_at_its_value():
    from trl_dgpq.analysis import Threshold
    at = pd.Series([25.0, 25.5, 24.5])
    assert Threshold("steps", "<=", 25.0, 10, "").met(at).tolist() == [True, False, True]
    assert Threshold("return", ">=", 25.0, 10, "").met(at).tolist() == [True, True, False]
