"""The online collector on the corridor worked by hand.

The corridor of 4 cells without slip (``CorridorEnv(length=4, slip=0, max_steps=5)``) and a scripted
agent that always moves seed row 0 right and seed row 1 left: row 0's episodes take 3 steps (rewards
-1, -1, 0: return -2, terminated at the goal), row 1's 5 (the step cap: return -5, truncated). With 2
episodes per seed, row 0 finishes at batched step 6, row 1 at step 10.
"""
import types

import pandas as pd
import pytest
import torch

from trl_dgpq.collectors import online
from trl_dgpq.collectors.online import COLUMNS, NonFiniteError, OnlineCollector, frame
from trl_dgpq.envs.corridor.env import CorridorEnv

TIMING = ["wall_s", "cpu_s", "us_per_step"]


class Scripted:
    """Row 0 right, row 1 left (or ``actions``); records what ``observe`` is given."""

    def __init__(self, actions=(1, 0), stats=None):
        self.actions = torch.tensor(actions)
        self.stats = stats or {}
        self.seen = []      # (reward of the step, active mask) per observe

    def act(self, td):
        return self.actions.clone()

    def observe(self, td, active):
        self.seen.append((td["next", "reward"].reshape(-1).clone(), active.clone()))

    def episode_stats(self):
        return dict(self.stats)


def corridor(seeds=(3, 8), **kw):
    return CorridorEnv(list(seeds), length=4, slip=0.0, max_steps=5, **kw)


def collector(episodes=2, seeds=(3, 8), agent=None, **kw):
    return OnlineCollector(corridor(seeds), agent or Scripted(), episodes, progress=False, **kw)


# seed, episode, steps, return, terminated -- and the batched step each ends at
BY_HAND = [(3, 1, 3, -2.0, True), (3, 2, 3, -2.0, True), (8, 1, 5, -5.0, False), (8, 2, 5, -5.0, False)]
ENDS = {(3, 1): 3, (8, 1): 5, (3, 2): 6, (8, 2): 10}


def plain(df):
    return [tuple(r) for r in df[["seed", "episode", "steps", "return", "terminated"]].itertuples(index=False)]


class Clock:
    """perf_counter +1 s and process_time +0.5 s a call (or ``wall`` and ``cpu``): every batched step
    takes 1 s wall, 0.5 s CPU."""

    def __init__(self, wall=1.0, cpu=0.5):
        self.wall = self.cpu = 0.0
        self.wall_step, self.cpu_step = wall, cpu

    def perf_counter(self):
        self.wall += self.wall_step
        return self.wall

    def process_time(self):
        self.cpu += self.cpu_step
        return self.cpu


def test_rows_steps_and_returns_are_the_corridors_by_hand():
    c = collector()
    df = c.run()
    assert list(df.columns) == COLUMNS
    assert plain(df) == BY_HAND
    assert c.finished and c.episodes_done == 4 and c.total == 10
    assert c.stopped_at.tolist() == [6, 10] and c.env_steps_done.tolist() == [6, 10]
    assert c.episode.tolist() == [2, 2] and not c.active.any()
    assert c.steps.tolist() == [0, 0] and c.ret.tolist() == [0.0, 0.0]       # reset at each episode's end
    assert len(c.step_seconds) == 10
    assert c.run().empty and c.total == 10                                     # finished: nothing more


def test_wall_and_cpu_time_are_shared_among_the_active_seeds(monkeypatch):
    """Each step 1 s wall, 0.5 s CPU, split equally between the seeds active in it: both for steps
    1-6, seed 8 alone for 7-10."""
    monkeypatch.setattr(online, "time", Clock())
    c = collector()
    df = c.run()
    assert c.step_seconds == [1.0] * 10
    assert df.wall_s.tolist() == [1.5, 1.5, 2.5, 0.5 + 4.0]
    assert df.cpu_s.tolist() == [0.75, 0.75, 1.25, 0.25 + 2.0]
    assert df.us_per_step.tolist() == [0.5e6, 0.5e6, 0.5e6, 0.9e6]
    assert c.wall.tolist() == [0.0, 0.0] and c.cpu.tolist() == [0.0, 0.0]
    quiet = collector(time_steps=False)
    quiet.run()
    assert quiet.step_seconds == []


def test_times_are_summed_in_float64(monkeypatch):
    """0.1 s a step, split between two seeds: 0.05 is not a float32 number, so a sum made in float32
    (a bool mask times a float) is off by ~1e-9; seed 3's first episode is its first 3 steps."""
    monkeypatch.setattr(online, "time", Clock(wall=0.1, cpu=0.1))
    df = collector().run()
    assert abs(df.wall_s[0] - 0.15) < 1e-15 and abs(df.cpu_s[0] - 0.15) < 1e-15


def test_the_agent_observes_every_step_with_the_seeds_active_in_it():
    agent = Scripted()
    collector(agent=agent).run()
    assert len(agent.seen) == 10
    assert [a.tolist() for _, a in agent.seen] == [[True, True]] * 6 + [[False, True]] * 4
    rewards = torch.stack([r for r, _ in agent.seen])
    assert rewards[:3, 0].tolist() == [-1.0, -1.0, 0.0] and rewards[:5, 1].tolist() == [-1.0] * 5


def test_a_seed_without_seeds_is_its_row():
    env = corridor()
    del env.seeds  # an env that does not name its seeds: rows 0, 1
    c = OnlineCollector(env, Scripted(), 1, progress=False)
    assert c.seeds == [0, 1]


def test_max_total_steps_stops_each_run_call_and_run_continues():
    c = collector(max_total_steps=4)
    parts = [c.run()]
    assert c.total == 4 and plain(parts[0]) == [BY_HAND[0]]
    parts.append(c.run())
    assert c.total == 8 and plain(parts[1]) == [BY_HAND[1], BY_HAND[2]]
    parts.append(c.run())
    assert c.total == 10 and c.finished and plain(parts[2]) == [BY_HAND[3]]


def test_on_rows_gets_each_steps_rows_and_after_step_may_stop():
    got, steps = [], []
    c = collector()
    df = c.run(on_rows=lambda rows: got.append((c.total, [(r["seed"], r["episode"]) for r in rows])),
               keep=False)
    assert got == [(3, [(3, 1)]), (5, [(8, 1)]), (6, [(3, 2)]), (10, [(8, 2)])]
    assert df.empty and list(df.columns) == COLUMNS                          # keep=False: no row held

    c = collector()
    first = c.run(after_step=lambda col: steps.append(col.total) or col.total == 5)
    assert steps == [1, 2, 3, 4, 5] and c.total == 5 and plain(first) == [BY_HAND[0], BY_HAND[2]]
    rest = c.run()
    assert plain(rest) == [BY_HAND[1], BY_HAND[3]]


def test_before_step_runs_before_each_step_and_may_stop_it_before_anything_changes():
    calls = []
    c = collector(before_step=lambda: calls.append(1))
    c.run()
    assert len(calls) == 10

    def guard():
        if c.total == 2:
            raise MemoryError("full")
    c = collector(before_step=guard)
    with pytest.raises(MemoryError):
        c.run()
    assert c.total == 2 and c.steps.tolist() == [2, 2]


@pytest.mark.parametrize("budget, episodes, stopped_at", [
    (6, [2, 2], [6, 10]),    # seed 3 reaches 6 steps at the end of its 2nd episode: it stops there
    (7, [3, 2], [9, 10]),    # ... 7 only in its 3rd; seed 8 reaches both in its 2nd (10 steps)
    (11, [4, 3], [12, 15])])
def test_an_env_steps_budget_stops_each_seed_at_the_end_of_the_episode_that_reaches_it(budget, episodes,
                                                                                         stopped_at):
    c = collector(episodes=10, env_steps=budget)
    df = c.run()
    assert df.groupby("seed").size().tolist() == episodes
    assert c.stopped_at.tolist() == stopped_at and c.total == max(stopped_at)
    assert c.env_steps_done.tolist() == [3 * episodes[0], 5 * episodes[1]]
    assert (df.steps == df.seed.map({3: 3, 8: 5})).all()            # no episode cut short by the budget


def test_the_episode_cap_still_holds_under_a_budget():
    c = collector(episodes=1, env_steps=100)
    assert plain(c.run()) == [BY_HAND[0], BY_HAND[2]]


def test_rows_carry_the_envs_episode_info_and_the_agents_episode_stats():
    env = corridor()
    env.episode_info = ("observation",)        # at the episode's end, before the reset: goal 1, wall 0
    agent = Scripted(stats={"epsilon": torch.tensor([0.25, 0.5])})
    df = OnlineCollector(env, agent, 1, progress=False).run()
    assert list(df.columns) == COLUMNS + ["observation", "epsilon"]
    assert df.observation.tolist() == [1.0, 0.0] and df.epsilon.tolist() == [0.25, 0.5]


@pytest.mark.parametrize("what", ["reward", "observation"])
def test_a_non_finite_reward_or_observation_stops_the_run_naming_the_seed_episode_and_step(monkeypatch, what):
    env = corridor()
    transition, calls = env._transition, []

    def poisoned(action):
        obs, reward, terminated = transition(action)
        calls.append(1)
        if len(calls) == 5:                                   # step 5: seed 8's 5th of its 1st episode
            (reward if what == "reward" else obs["observation"])[1] = float("nan")
        return obs, reward, terminated
    monkeypatch.setattr(env, "_transition", poisoned)
    with pytest.raises(NonFiniteError, match=f"non-finite {what} for seed 8, episode 1, step 5$"):
        OnlineCollector(env, Scripted(), 2, progress=False).run()


def test_a_non_finite_value_of_a_stopped_seed_is_ignored(monkeypatch):
    env = corridor()
    transition, calls = env._transition, []

    def poisoned(action):
        obs, reward, terminated = transition(action)
        calls.append(1)
        if len(calls) > 3:                                    # seed 3 stopped after step 3
            reward[0] = float("inf")
            obs["observation"][0] = float("nan")
        return obs, reward, terminated
    monkeypatch.setattr(env, "_transition", poisoned)
    df = OnlineCollector(env, Scripted(), 1, progress=False).run()
    assert plain(df) == [BY_HAND[0], BY_HAND[2]]


def test_integer_observations_are_not_checked():
    c = collector()
    obs = torch.tensor([[1], [2]])
    c._check_finite(torch.tensor([0.0, 1.0], dtype=torch.float64), obs, torch.tensor([True, True]))
    with pytest.raises(NonFiniteError, match="reward for seed 3, episode 1, step 1"):
        c._check_finite(torch.tensor([float("-inf"), 1.0], dtype=torch.float64), obs, torch.tensor([True, True]))


@pytest.mark.parametrize("bad", [0, -1, 1.5])
def test_episodes_must_be_a_positive_integer(bad):
    with pytest.raises(ValueError, match="episodes must be a positive integer"):
        collector(episodes=bad)


@pytest.mark.parametrize("bad", [-1, 2.5])
def test_env_steps_must_be_a_non_negative_integer(bad):
    with pytest.raises(ValueError, match="env_steps must be a non-negative integer"):
        collector(env_steps=bad)


def test_first_stop_is_only_the_step_where_seeds_stopped_and_none_before():
    seen = []
    c = collector(episodes=1)
    c.run(after_step=lambda col: seen.append((col.total, col.stopped_now, col.first_stop)) and False)
    assert [s for s in seen if s[1]] == [(3, True, True), (5, True, False)]
    assert [t for t, _, first in seen if first] == [3]
    # both seeds stopping in the same step: a first stop
    c = collector(episodes=1, agent=Scripted((1, 1)))
    c.run(after_step=lambda col: seen.append((col.total, col.first_stop)) and False)
    assert seen[-1] == (3, True)


def test_a_state_kept_at_the_first_stop_continues_exactly_when_the_run_is_lengthened():
    """Stopped at step 3 (seed 3's only episode), lengthened to 2 episodes: seed 3 goes on from where it
    stopped and the rows are those of a run of 2 episodes from the start."""
    c = collector(episodes=1)
    first = c.run(after_step=lambda col: col.first_stop)
    assert c.total == 3 and c.active.tolist() == [False, True] and c.stopped_at.tolist() == [3, -1]
    assert c.to_continue().tolist() == [False, False]
    c.episodes = 2
    assert c.to_continue().tolist() == [True, False]
    c.reactivate()
    assert c.active.tolist() == [True, True] and c.stopped_at.tolist() == [-1, -1]
    rest = c.run()
    assert plain(pd.concat([first, rest]).sort_values(["seed", "episode"])) == BY_HAND


def test_reactivate_refuses_a_seed_stepped_since_it_stopped():
    c = collector(episodes=1)
    c.run()                                                     # seed 3 stopped at 3, the state is at 5
    c.episodes = 2
    with pytest.raises(ValueError, match=r"seeds \[3\] stopped at an earlier step than this state's 5"):
        c.reactivate()
    assert not c.active.any()
    c.episodes = 1
    c.reactivate()                                              # nothing to continue: nothing changes
    assert not c.active.any() and c.stopped_at.tolist() == [3, 5]


def test_to_continue_with_a_budget_wants_steps_left():
    c = collector(episodes=10, env_steps=6)
    c.run()
    assert c.to_continue().tolist() == [False, False]            # both past 6 steps
    c.env_steps = 8
    assert c.to_continue().tolist() == [True, False]             # seed 3 ran 6, seed 8 10
    c.episodes = 2
    assert c.to_continue().tolist() == [False, False]            # and its episodes are done


def test_state_dict_round_trip_continues_exactly():
    a = collector(max_total_steps=4)
    a.run()
    state = a.state_dict()
    assert state["total"] == 4 and state["steps"].tolist() == [1, 4] and state["ret"].tolist() == [-1.0, -4.0]
    b = collector()
    b.env.load_state_dict(a.env.state_dict())
    b.load_state_dict(state)
    state["steps"][0] = 99                                       # the state is a copy, not a view
    assert b.total == 4 and b.steps.tolist() == [1, 4] and a.steps.tolist() == [1, 4]
    assert torch.equal(b.td["observation"], a.td["observation"])
    a.max_total_steps = None
    rest_a, rest_b = a.run(), b.run()
    assert plain(rest_a) == plain(rest_b) == BY_HAND[1:]
    pd.testing.assert_frame_equal(rest_a.drop(columns=TIMING), rest_b.drop(columns=TIMING))


def test_a_fresh_state_has_no_td_and_an_older_state_lacks_the_budget_and_stops():
    c = collector()
    state = c.state_dict()
    assert state["td"] is None and state["stopped_at"].tolist() == [-1, -1]
    old = collector(max_total_steps=6)
    old.run()                                                   # seed 3 stopped at 6
    state = {k: v for k, v in old.state_dict().items() if k not in ("env_steps_done", "stopped_at")}
    c.load_state_dict(state)
    assert c.env_steps_done.tolist() == [0, 0] and c.stopped_at.tolist() == [-2, -1]   # where: unknown
    assert c.td is not None and c.td.batch_size == torch.Size([2])
    c.load_state_dict(collector().state_dict())
    assert c.td is None and c.total == 0


def test_a_state_for_other_seeds_is_refused():
    with pytest.raises(ValueError, match="collector state is for 3 seeds, not 2"):
        collector().load_state_dict(collector(seeds=(0, 1, 2)).state_dict())


def test_frame_puts_the_fixed_columns_first_and_sorts_by_seed_then_episode():
    row = dict(zip(COLUMNS, [0] * len(COLUMNS)))
    rows = [{**row, "extra": 1, "seed": 2, "episode": 1}, {**row, "extra": 2, "seed": 1, "episode": 2},
            {**row, "extra": 3, "seed": 1, "episode": 1}]
    df = frame(rows)
    assert list(df.columns) == COLUMNS + ["extra"] and df.extra.tolist() == [3, 2, 1]
    assert list(df.index) == [0, 1, 2]
    assert frame([]).empty and list(frame([]).columns) == COLUMNS


class Bar:
    """A stand-in for tqdm: keeps its settings and count."""
    made = []

    def __init__(self, **kw):
        self.kw, self.n, self.closed, self.updates = kw, kw["initial"], False, []
        Bar.made.append(self)

    def update(self, k):
        self.n += k
        self.updates.append(k)

    def close(self):
        self.closed = True


def test_progress_counts_seed_episodes_or_with_a_budget_seed_steps(monkeypatch):
    monkeypatch.setattr(online, "tqdm", Bar)
    Bar.made = []
    c = OnlineCollector(corridor(), Scripted(), 2, progress=True, desc="train", max_total_steps=4)
    c.run()
    c.max_total_steps = None
    c.run()
    first, second = Bar.made
    assert first.kw["total"] == 2 * 2 and first.kw["initial"] == 0 and second.kw["initial"] == 1
    assert first.kw["desc"] == "train" and first.kw["unit"] == "seed-episodes" and not first.kw["unit_scale"]
    assert not first.kw["disable"] and first.closed and second.n == 4
    Bar.made = []
    c = OnlineCollector(corridor(), Scripted(), 10 ** 6, progress=True, env_steps=60)
    c.run()
    bar, = Bar.made
    assert bar.kw["total"] == 2 * 60 and bar.kw["unit"] == "seed-steps" and bar.kw["unit_scale"]
    # seed 3 stops at 60 steps, seed 8 at 60: updated every 50 batched steps, then at the end
    assert bar.updates == [100, 20] and bar.n == 120 and bar.closed
    Bar.made = []
    OnlineCollector(corridor(), Scripted(), 1, progress=False).run()
    assert Bar.made[0].kw["disable"] and Bar.made[0].updates == [1, 1]


def test_counters_are_integer_tensors_before_and_after_a_run():
    # float32 counters would silently lose counts past 2**24 env steps (a long budget), and a
    # checkpoint's integers would be copied into floats
    c = collector()
    for _ in range(2):
        for name in ("episode", "steps", "env_steps_done", "stopped_at"):
            assert getattr(c, name).dtype == torch.long, name
            assert c.state_dict()[name].dtype == torch.long, name
        c.run()


def test_a_fresh_collector_has_stopped_nothing():
    c = collector()
    assert c.first_stop is False and c.stopped_now is False


class WithoutEpisodeInfo:
    """Any TorchRL env: the corridor seen through a wrapper that has no ``episode_info``."""

    def __init__(self, env):
        self._env = env

    def __getattr__(self, name):
        if name == "episode_info":
            raise AttributeError(name)
        return getattr(self._env, name)


def test_an_env_without_episode_info_gives_the_fixed_columns():
    env = WithoutEpisodeInfo(corridor())
    assert not hasattr(env, "episode_info")
    df = OnlineCollector(env, Scripted(), 2, progress=False).run()
    assert list(df.columns) == COLUMNS and plain(df) == BY_HAND
