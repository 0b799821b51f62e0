"""What a study is asked (trl_dgpq/study/config.py): its defaults, the stages of a trial's budget
and how settings are shown, each by hand."""
import pytest

from trl_dgpq.study.config import (DEFAULT_SEEDS, DEFAULT_VALIDATION_SEEDS, KEEP, UNMARKED_S, TuneConfig, plain,
                                   shown, stage_lengths)


def test_the_defaults_are_the_documented_ones():
    c = TuneConfig()
    assert (c.trials, c.workers, c.sampler_seed, c.stages, c.prune_after) == (20, 1, 0, (0.25, 0.5, 0.75, 1.0), 5)
    assert (c.objective, c.window, c.measure, c.first, c.search) == ("report", 10, "", "preset", ())
    assert set(TuneConfig.FIXED) == {"sampler_seed", "stages", "prune_after", "objective", "search", "window",
                                     "first", "measure"}
    assert (DEFAULT_SEEDS, DEFAULT_VALIDATION_SEEDS) == ("1000-1004", "1005-1014")
    assert KEEP == ("config.json", "status.json", "episodes.csv") and UNMARKED_S == 60


@pytest.mark.parametrize("run, fractions, want", [
    # an episode budget: ceil of each fraction, 0.7 * 10 = 7.000000000000001 read as 7
    (dict(episodes=10, env_steps=0), (0.25, 0.5, 0.7, 1.0), [3, 5, 7, 10]),
    # stages that round to one length are one stage; never below 1 episode
    (dict(episodes=10, env_steps=0), (0.01, 0.02, 1.0), [1, 10]),
    (dict(episodes=10, env_steps=0), (1e-12, 1.0), [1, 10]),
])
def test_an_episode_budget_is_cut_into_stages_by_hand(run, fractions, want):
    assert stage_lengths(run, fractions) == [dict(episodes=e, env_steps=0) for e in want]


def test_an_env_step_budget_keeps_its_episode_cap_unless_the_cap_followed_it():
    """18,000 steps under a cap of 100,000 episodes: each stage a share of the steps, the cap kept;
    a cap equal to the budget (train's default: the cap follows the steps) follows each stage."""
    assert stage_lengths(dict(episodes=100_000, env_steps=18_000), (0.25, 1.0)) == [
        dict(episodes=100_000, env_steps=4_500), dict(episodes=100_000, env_steps=18_000)]
    assert stage_lengths(dict(episodes=7, env_steps=7), (0.5, 1.0)) == [
        dict(episodes=4, env_steps=4), dict(episodes=7, env_steps=7)]
    assert stage_lengths(dict(episodes=5, env_steps=3), (0.1, 1.0)) == [dict(episodes=5, env_steps=1),
                                                                       dict(episodes=5, env_steps=3)]
    # a quarter of 10 steps is 2.5: the stage ends after 3 (rounded up, never to the even 2)
    assert stage_lengths(dict(episodes=100, env_steps=10), (0.25, 1.0))[0] == dict(episodes=100, env_steps=3)


def test_settings_are_shown_to_four_digits_and_lists_joined():
    assert shown({"lr": 0.000123456, "hidden": [64, 64], "state_scale": (0.123456, 2.0), "name": "x", "n": 3}) \
        == "lr=0.0001235, hidden=64,64, state_scale=0.1235,2, name=x, n=3"
    assert shown({}) == ""
    assert plain({"a": (1, (2.5, "b")), "c": None}) == {"a": [1, [2.5, "b"]], "c": None}


@pytest.mark.parametrize("kw, match", [
    (dict(stages=(0.5, 0.25, 1.0)), r"^stages must increase and end at 1, got \[0.5, 0.25, 1.0\]$"),
    (dict(stages=(0.5, 0.5, 1.0)), r"^stages must increase and end at 1, got \[0.5, 0.5, 1.0\]$"),
    (dict(stages=(0.25, 0.5)), r"^stages must increase and end at 1, got \[0.25, 0.5\]$"),
    (dict(objective="worst", stages=(1.0,)),
     r"^objective 'worst' scores the stages after the first: give at least two stages$"),
    (dict(search=("lengthscale=1:30", "eps1=3")), r"^a search range is NAME=LOW:HIGH, e.g. lengthscale=1:30, got 'eps1=3'$"),
])
def test_a_study_that_cannot_be_run_is_refused_in_one_line(kw, match):
    with pytest.raises(ValueError, match=match):
        TuneConfig(**kw).cross_check()


def test_the_smallest_studies_that_can_be_run_are_accepted():
    TuneConfig(stages=(1.0,)).cross_check()
    TuneConfig(objective="worst", stages=(0.5, 1.0), search=("lengthscale=1:30",)).cross_check()
