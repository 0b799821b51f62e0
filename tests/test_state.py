"""Everything with state saves and restores exactly: a restored copy, continued the same
way, gives bitwise the same results as the original. And an interrupted run, resumed,
writes the same episodes.csv as an uninterrupted one."""

import shutil

import pandas as pd
import pytest
import torch
from tensordict import TensorDictBase

from conftest import through_disk
from trl_dgpq.agents import agent_names
from trl_dgpq.collectors import runner
from trl_dgpq.collectors.experiment import TIMING_COLUMNS, build, resolve_config
from trl_dgpq.collectors.online import OnlineCollector
from trl_dgpq.envs import domains
from trl_dgpq.envs.square.env import SquareEnv
from trl_dgpq.gp import ExactGP, ManifoldKernel, RBFKernel, SparseOnlineGP, fit
from trl_dgpq.qhat import LipschitzQ
from trl_dgpq.rng import SeedStreams

D = torch.float64


def test_seed_streams_continue_where_they_were():
    a = SeedStreams([1, 4], stream=2)
    for _ in range(300):  # past a buffer refill
        a.uniform(3)
    b = SeedStreams([1, 4], stream=2)
    b.load_state_dict(through_disk(a.state_dict()))
    for _ in range(300):
        assert torch.equal(a.uniform(3), b.uniform(3))
    with pytest.raises(ValueError, match="other seeds"):
        SeedStreams([1, 5], stream=2).load_state_dict(a.state_dict())


def test_qhat_round_trip_with_grown_storage():
    g = torch.Generator().manual_seed(0)
    q = LipschitzQ(2, 3, 2, lipschitz=1.0, v_max=5.0, capacity=2)
    for _ in range(20):
        q.insert(torch.rand(2, 2, generator=g, dtype=D), torch.randint(3, (2,), generator=g),
                 torch.rand(2, generator=g, dtype=D), torch.tensor([True, True]))
    assert q.capacity > 2
    r = LipschitzQ(2, 3, 2, lipschitz=1.0, v_max=5.0, capacity=2)
    r.load_state_dict(through_disk(q.state_dict()))
    assert (r.width, r.version, r.capacity) == (q.width, q.version, q.capacity)
    x = torch.rand(2, 2, generator=g, dtype=D)
    assert torch.equal(q(x), r(x)) and torch.equal(q.size(), r.size())
    for t in (q, r):
        t.insert(x, torch.tensor([0, 2]), torch.tensor([0.1, 0.2], dtype=D), torch.tensor([True, False]))
    assert torch.equal(q.mu, r.mu) and torch.equal(q.s, r.s)


def gp_pair(kind):
    if kind == "exact":
        make = lambda: ExactGP(RBFKernel(0.3, 1.0), 0.1, 2, batch_shape=(2, 3), capacity=2)  # noqa: E731
    elif kind == "sparse":
        make = lambda: SparseOnlineGP(RBFKernel(0.3, 1.0), 0.1, 2, batch_shape=(2, 3), budget=5)  # noqa: E731
    else:
        make = lambda: ExactGP(ManifoldKernel(6, 2, lengthscale=0.3,  # noqa: E731
                                              uniform=lambda n, c: torch.rand(n, c, generator=torch.Generator().manual_seed(len(kind)), dtype=D)),
                               0.1, 2, batch_shape=(2, 3), capacity=2)
    return make


@pytest.mark.parametrize("kind", ["exact", "sparse", "manifold"])
def test_gp_round_trip_into_a_fresh_instance(kind):
    make = gp_pair(kind)
    g = torch.Generator().manual_seed(1)
    data = lambda: (torch.rand(2, 3, 2, generator=g, dtype=D), torch.rand(2, 3, generator=g, dtype=D))  # noqa: E731
    a = make()
    for _ in range(12):
        a.add(*data(), mask=torch.rand(2, 3, generator=g) < 0.7)
    if kind == "manifold":
        fit(a, steps=5, lr=0.05, min_points=3)
    b = make()
    b.kernel.raw_lengthscale.data += 1.0  # a fresh instance differs: the load must set everything
    b.load_state_dict(through_disk(a.state_dict()))
    xq = torch.rand(2, 3, 4, 2, generator=g, dtype=D)
    for u, v in zip(a.predict(xq), b.predict(xq)):
        assert torch.equal(u, v)
    for _ in range(5):
        x, y = data()
        for gp in (a, b):
            gp.add(x, y)
    for u, v in zip(a.predict(xq), b.predict(xq)):
        assert torch.equal(u, v)


def test_env_round_trip():
    a = SquareEnv(seeds=[0, 3])
    td = a.reset()
    for i in range(7):
        td["action"] = torch.tensor([i % 4, 0])
        td = a.step_and_maybe_reset(td)[1]
    b = SquareEnv(seeds=[0, 3])
    b.reset()
    b.load_state_dict(through_disk(a.state_dict()))
    for i in range(30):
        act = torch.tensor([2, i % 4])
        ta, tb = a.step(td.clone().set("action", act)), b.step(td.clone().set("action", act))
        assert torch.equal(ta["next", "observation"], tb["next", "observation"])
        assert torch.equal(ta["next", "done"], tb["next", "done"])
        td = a.step_mdp(ta)
        b.step_mdp(tb)


def test_dgpq_state_includes_the_tie_stream():
    """Empty Q̂: every action ties, so each choice is a draw of the tie stream; a restored
    agent must go on with the next draws, not start the stream again."""
    from trl_dgpq.dgpq import DGPQ, DGPQConfig
    obs = torch.zeros(3, 2, dtype=D)
    a = DGPQ(DGPQConfig(), seeds=[0, 1, 2], state_dim=2, num_actions=4)
    first = torch.stack([a.select_action(obs) for _ in range(20)])
    b = DGPQ(DGPQConfig(), seeds=[0, 1, 2], state_dim=2, num_actions=4)
    b.load_state_dict(through_disk(a.state_dict()))
    nxt_a = torch.stack([a.select_action(obs) for _ in range(20)])
    assert torch.equal(nxt_a, torch.stack([b.select_action(obs) for _ in range(20)]))
    assert not torch.equal(nxt_a, first)


AGENT_CASES = {
    "dgpq-sparse": dict(agent="dgpq", gp="sparse", budget=8),
    "dgpq-exact": dict(agent="dgpq", gp="exact", capacity=2),
    "dgpq-manifold": dict(agent="dgpq", gp="exact", kernel="manifold", sigma_tol2=0.05, kernel_train_every=5,
                          kernel_min_points=5, kernel_train_steps=5, max_steps=30),
    "random": dict(agent="random", max_steps=30),
    # liquidation: short episodes; level noise puts the env's OU state in play
    "dgpq-liquidation": dict(env="liquidation", agent="dgpq", trades=20, level_noise=0.2),
    "ac-optimal": dict(env="liquidation", agent="ac-optimal", trades=20),
    "twap": dict(env="liquidation", agent="twap", trades=20),
    "ddpg": dict(env="liquidation", agent="ddpg", trades=20, batch_size=8, buffer_size=64),
    "td3": dict(env="liquidation", agent="td3", trades=20, batch_size=8, buffer_size=64, learning_starts=12,
                policy_delay=3, actor_hidden=(16,), critic_hidden=(16, 16)),
    # push: pybullet worlds saved as .bullet bytes
    "dgpq-push": dict(env="push", agent="dgpq", max_steps=12),
    "oracle": dict(env="push", agent="oracle", max_steps=12),
    # DQN: updates from the 8th step, a target copy every 7 (not a divisor of 40, where the round trip
    # cuts); gymnasium envs pickled per seed
    "dqn": dict(agent="dqn", batch_size=8, buffer_size=64, learning_starts=8, hidden=(16,), target_update_interval=7,
                exploration_steps=50, max_steps=30),
    "dqn-cartpole": dict(env="gym:CartPole-v1", agent="dqn", batch_size=8, buffer_size=64, learning_starts=8,
                         train_freq=2, gradient_steps=2, hidden=(16,), max_steps=30),
    "dgpq-acrobot": dict(env="gym:Acrobot-v1", agent="dgpq", max_steps=20),
    # the noisy square: its reward-noise stream saved with the env
    "dgpq-noisy": dict(agent="dgpq", preset="noisy", max_steps=40),
}


def supported_case(agent):
    """An agent without a case above runs on the example of the first domain with presets for it."""
    for d in domains():
        for env, name, _ in d.preset_tables():
            if name == agent:
                return dict(env=env, agent=agent, **d.example)
    return None


AGENT_CASES.update({f"{a}-example": supported_case(a) for a in agent_names()
                    if a not in {c["agent"] for c in AGENT_CASES.values()} and supported_case(a)})


# The runner-level checks below (a stop and resume, a lengthening) go through the same state_dict as the
# mid-run round trip above, which every case runs by default; by default they run on cases that differ
# in what they save (a GP and Q̂, pybullet worlds, TD3's networks, replay and delayed policy), and on every
# case under -m slow (the noisy square's reward stream and gymnasium envs pickled per seed among them).
RUNNER_CASES = {"dgpq-sparse", "dgpq-push", "td3"}


def runner_cases():
    return [c if c in RUNNER_CASES else pytest.param(c, marks=pytest.mark.slow) for c in sorted(AGENT_CASES)]


def test_every_agent_has_a_resume_case():
    assert {c["agent"] for c in AGENT_CASES.values()} == set(agent_names())


@pytest.mark.parametrize("case", sorted(AGENT_CASES))
def test_agent_round_trip_mid_run(case, env_steps=0, **extra):
    """Run 40 steps, save env + agent + collector, load into fresh objects, run on:
    the rows equal those of the original continuing."""
    config = resolve_config(seeds=[0, 2], episodes=8, **{**AGENT_CASES[case], **extra})

    def collector():
        env, agent = build(config)
        return OnlineCollector(env, agent, 8, progress=False, env_steps=env_steps)
    a = collector()
    a.max_total_steps = 40
    a.run()
    state = through_disk(dict(env=a.env.state_dict(), agent=a.agent.state_dict(), collector=a.state_dict()))
    b = collector()
    b.env.load_state_dict(state["env"])
    b.agent.load_state_dict(state["agent"])
    b.load_state_dict(state["collector"])
    a.max_total_steps = b.max_total_steps = None
    rest_a, rest_b = a.run(), b.run()
    assert len(rest_a) > 0
    pd.testing.assert_frame_equal(rest_a.drop(columns=list(TIMING_COLUMNS)), rest_b.drop(columns=list(TIMING_COLUMNS)))
    assert_same_state(a.agent.state_dict(), b.agent.state_dict())  # learners too, not just their actions


def assert_same_state(x, y, where="state"):
    """Nested dicts / lists / TensorDicts of tensors and plain values, equal to the last bit."""
    if isinstance(x, TensorDictBase):
        x, y = x.to_dict(), y.to_dict()
    if torch.is_tensor(x):
        assert torch.equal(x, y), where
    elif isinstance(x, dict):
        assert x.keys() == y.keys(), where
        for k in x:
            assert_same_state(x[k], y[k], f"{where}.{k}")
    elif isinstance(x, (list, tuple)):
        assert len(x) == len(y), where
        for i, (u, v) in enumerate(zip(x, y)):
            assert_same_state(u, v, f"{where}[{i}]")
    else:
        assert x == y, where


def test_round_trip_keeps_the_env_steps_budget():
    """Episodes of 30 steps; seeds stop at the end of the one that reaches 90 steps (the 3rd): a
    restored collector must remember the steps each seed had taken (40)."""
    test_agent_round_trip_mid_run("random", env_steps=90, max_steps=30)


def episodes(folder):
    return runner.read_csv_exact(folder.file("episodes.csv")).drop(columns=list(TIMING_COLUMNS))


@pytest.mark.parametrize("stop", ["signal", "crash"])
@pytest.mark.parametrize("case", runner_cases())
def test_interrupted_run_resumes_to_the_same_csv(tmp_path, stop_run_after, case, stop):
    """"signal": SIGINT after the 3rd batch of rows (checkpoint at the stop); "crash": an
    error after the 3rd batch (the last checkpoint is older, rows past it are on disk and
    must be replaced, not duplicated)."""
    config = resolve_config(seeds=[0, 1, 2], episodes=5, checkpoint_every=1, **AGENT_CASES[case])
    whole = runner.RunFolder.create(str(tmp_path / "whole"), "x")
    runner.start(config, whole, progress=False)

    part = runner.RunFolder.create(str(tmp_path / "part"), "x")
    stop_run_after(3, stop)
    with pytest.raises(runner.Interrupted if stop == "signal" else RuntimeError):
        runner.start(config, part, progress=False)
    status = part.status()
    assert status["status"] == ("interrupted" if stop == "signal" else "failed")
    on_disk = episodes(part)
    assert len(on_disk) == status["episodes_done"]              # every finished episode is on disk
    ckpt = part.load_checkpoint()  # None if no seed had finished an episode yet: resume from scratch
    assert ckpt is None or ckpt["episodes_done"] <= len(on_disk)
    runner.resume(part, runner.resumable_config(part), progress=False)
    assert part.status()["status"] == "finished"
    pd.testing.assert_frame_equal(episodes(whole), episodes(part))


def test_a_damaged_checkpoint_falls_back_to_the_previous_one_and_resumes_to_the_same_csv(tmp_path, stop_run_after,
                                                                                          capsys):
    config = resolve_config(seeds=[0, 1], episodes=6, checkpoint_every=1)
    whole = runner.RunFolder.create(str(tmp_path / "whole"), "x")
    runner.start(config, whole, progress=False)
    part = runner.RunFolder.create(str(tmp_path / "part"), "x")
    stop_run_after(7, "crash")                 # several checkpoints; rows past the last on disk
    with pytest.raises(RuntimeError):
        runner.start(config, part, progress=False)
    latest, previous = part.file("checkpoint.pt"), part.file("checkpoint.prev.pt")
    assert latest.exists() and previous.exists()
    kept = torch.load(previous, weights_only=True)["episodes_done"]
    latest.write_bytes(latest.read_bytes()[: latest.stat().st_size // 2])     # a copy cut short
    lines = []
    state = part.load_checkpoint(log=lines.append)
    assert state["episodes_done"] == kept and len(lines) == 1 and "continuing from checkpoint.prev.pt" in lines[0]
    assert "the file is cut short" in lines[0] and "zip" not in lines[0]                # our words, not torch's
    runner.resume(part, runner.resumable_config(part), progress=False)
    pd.testing.assert_frame_equal(episodes(whole), episodes(part))            # the CSV cut back to it, redone
    extend = part.file("checkpoint.extend.pt")   # the finished run's other earlier state
    assert extend.exists() and not previous.exists()
    for path in (latest, previous, extend):
        path.write_bytes(b"not a checkpoint")
    with pytest.raises(runner.RunError, match="cannot read") as err:
        part.load_checkpoint(log=lambda line: None)
    assert str(err.value).count("it is not a checkpoint") == 3 and "weights_only" not in str(err.value)
    assert str(err.value).endswith("start it again (--overwrite)")


def test_a_row_left_half_written_is_cut_off_on_resume(tmp_path, stop_run_after):
    """A crash or a full disk in the middle of an append leaves part of a row, here "1,1" of seed 1's
    episode 1x: resume keeps the rows its checkpoint covers by (seed, episode), so it must cut that
    part off first rather than read it as a second row of seed 1's episode 1."""
    config = resolve_config(seeds=[0, 1], episodes=4, max_steps=30, checkpoint_every=1)
    whole = runner.RunFolder.create(str(tmp_path / "whole"), "x")
    runner.start(config, whole, progress=False)
    part = runner.RunFolder.create(str(tmp_path / "part"), "x")
    stop_run_after(3, "crash")
    with pytest.raises(RuntimeError):
        runner.start(config, part, progress=False)
    with open(part.file("episodes.csv"), "a") as f:
        f.write("1,1")
    runner.resume(part, runner.resumable_config(part), progress=False)
    pd.testing.assert_frame_equal(episodes(whole), episodes(part))


def test_a_sigint_during_the_last_step_leaves_a_finished_sorted_run(tmp_path, stop_run_after):
    """Liquidation episodes all take 10 steps, so 2 seeds x 3 episodes end in 3 batches of 2 rows;
    SIGINT right after the last batch: nothing is left to do, so the run is finished, its CSV
    sorted by seed (not left "interrupted" in append order)."""
    config = resolve_config(env="liquidation", agent="twap", seeds=[0, 1], episodes=3, trades=10, horizon=10)
    folder = runner.RunFolder.create(str(tmp_path / "run"), "x")
    stop_run_after(3, "signal")
    runner.start(config, folder, progress=False)
    assert folder.status()["status"] == "finished"
    assert list(episodes(folder).seed) == [0, 0, 0, 1, 1, 1]


def stops_apart(folder) -> bool:
    """Whether the run's seeds stopped at different steps (checkpoint.extend.pt is then an earlier state)."""
    total = lambda name: torch.load(folder.file(name), weights_only=True)["collector"]["total"]  # noqa: E731
    return total("checkpoint.extend.pt") < total("checkpoint.pt")


def lengthened(tmp_path, config, name, **lengths):
    """A run of ``config`` started, finished (its seeds stopping at different steps), then
    lengthened to ``lengths`` and resumed."""
    folder = runner.RunFolder.create(str(tmp_path / name), "x")
    runner.start(config, folder, progress=False)
    assert stops_apart(folder)
    longer = runner.lengthen(folder, runner.resumable_config(folder, lengthen=True), **lengths)
    runner.resume(folder, longer, progress=False)
    assert folder.status()["status"] == "finished"
    return folder


@pytest.mark.parametrize("case", runner_cases())
def test_a_finished_run_lengthened_equals_the_longer_run(tmp_path, case):
    """3 episodes per seed, then --episodes 5: the same CSV as 5 from the start. The seeds end
    their 3rd episode at different steps and go on stepping with the batch, so this holds
    only if each goes on from where it stopped (checkpoint.extend.pt)."""
    whole = runner.RunFolder.create(str(tmp_path / "whole"), "x")
    runner.start(resolve_config(seeds=[0, 1, 2], episodes=5, **AGENT_CASES[case]), whole, progress=False)
    part = runner.RunFolder.create(str(tmp_path / "part"), "x")
    runner.start(resolve_config(seeds=[0, 1, 2], episodes=3, **AGENT_CASES[case]), part, progress=False)
    longer = runner.lengthen(part, runner.resumable_config(part, lengthen=True), episodes=5)
    runner.resume(part, longer, progress=False)
    pd.testing.assert_frame_equal(episodes(whole), episodes(part))


# behind slow: three runs lengthened (~4 s); one lengthening per case is
# test_a_finished_run_lengthened_equals_the_longer_run's, a cap raised later
# test_a_seed_the_episode_cap_stopped_goes_on_when_the_cap_is_raised_later's, lengths in units test_runner_units'
@pytest.mark.slow
def test_lengthening_twice_and_by_budget_equals_the_longer_run(tmp_path):
    """Square episodes of random lengths: 2 -> 4 -> 7 episodes, and a budget of 60 -> 150 steps,
    each equal to the longer run from the start; config.json records the new length."""
    base = dict(seeds=[0, 1, 2, 3], max_steps=60, checkpoint_every=1)
    whole = runner.RunFolder.create(str(tmp_path / "whole"), "x")
    runner.start(resolve_config(episodes=7, **base), whole, progress=False)
    part = runner.RunFolder.create(str(tmp_path / "part"), "x")
    runner.start(resolve_config(episodes=2, **base), part, progress=False)
    point = lambda: torch.load(part.file("checkpoint.extend.pt"), weights_only=True)["collector"]["total"]  # noqa
    first = point()
    runner.resume(part, runner.lengthen(part, runner.resumable_config(part, lengthen=True), episodes=4),
                  progress=False)
    assert episodes(part).groupby("seed").size().tolist() == [4] * 4
    assert point() > first      # where the next lengthening goes on from moved on: only the tail is redone
    longer = runner.lengthen(part, runner.resumable_config(part, lengthen=True), episodes=7)
    runner.resume(part, longer, progress=False)
    pd.testing.assert_frame_equal(episodes(whole), episodes(part))
    recorded = part.read_json("config.json")
    assert recorded["run"]["episodes"] == 7 and [e["episodes"]["was"] for e in recorded["lengthened"]] == [2, 4]

    budget = runner.RunFolder.create(str(tmp_path / "budget"), "x")
    runner.start(resolve_config(env_steps=150, **base), budget, progress=False)
    short = lengthened(tmp_path, resolve_config(env_steps=60, **base), "short", env_steps=150)
    pd.testing.assert_frame_equal(episodes(budget), episodes(short))
    assert short.read_json("config.json")["run"]["episodes"] == 150   # the cap a budget alone set follows it


def test_a_kill_between_recording_the_length_and_running_it_is_resumed(tmp_path):
    """``lengthen`` writes the new length; a plain resume afterwards (the process killed before it
    ran) ends as the longer run, from the finished run's final checkpoint."""
    base = dict(seeds=[0, 1, 2], max_steps=60)
    whole = runner.RunFolder.create(str(tmp_path / "whole"), "x")
    runner.start(resolve_config(episodes=4, **base), whole, progress=False)
    part = runner.RunFolder.create(str(tmp_path / "part"), "x")
    runner.start(resolve_config(episodes=2, **base), part, progress=False)
    assert stops_apart(part)
    runner.lengthen(part, runner.resumable_config(part, lengthen=True), episodes=4)
    assert part.status()["status"] == "interrupted"
    runner.resume(part, runner.resumable_config(part), progress=False)
    pd.testing.assert_frame_equal(episodes(whole), episodes(part))


def test_a_finished_run_with_a_damaged_checkpoint_lengthened_from_the_previous_one_equals_the_longer_run(
        tmp_path, capsys, monkeypatch):
    """The user's issue 30: checkpoint.pt cut short, so lengthening falls back to checkpoint.prev.pt,
    taken mid-run (every seed at 3 of 4 episodes, none stopped). Its rows were appended in the
    order episodes ended, but the finished run has since rewritten episodes.csv sorted by seed: the
    rows kept must be each seed's first 3 (the sorted file's first bytes hold seed 0's 4th episode
    and a row cut in two)."""
    base = dict(seeds=[0, 1, 2], max_steps=60)
    whole = runner.RunFolder.create(str(tmp_path / "whole"), "x")
    runner.start(resolve_config(episodes=6, **base), whole, progress=False)
    part = runner.RunFolder.create(str(tmp_path / "part"), "x")
    with monkeypatch.context() as m:  # finished by a version that kept checkpoint.prev.pt
        m.setattr(runner.RunFolder, "drop_previous", lambda self: None)
        runner.start(resolve_config(episodes=4, checkpoint_every=3, **base), part, progress=False)
    previous = torch.load(part.file("checkpoint.prev.pt"), weights_only=True)["collector"]
    assert previous["episode"].tolist() == [3, 3, 3] and previous["active"].all()
    latest = part.file("checkpoint.pt")
    latest.write_bytes(latest.read_bytes()[: latest.stat().st_size // 2])
    capsys.readouterr()
    longer = runner.lengthen(part, runner.resumable_config(part, lengthen=True), episodes=6)
    runner.resume(part, longer, progress=False)
    assert "continuing from checkpoint.prev.pt (9 episodes done)" in capsys.readouterr().err
    assert part.status()["status"] == "finished"
    pd.testing.assert_frame_equal(episodes(whole), episodes(part))


def test_lengthening_refuses_what_it_cannot_do_exactly(tmp_path):
    base = dict(seeds=[0, 1, 2], max_steps=60)
    folder = runner.RunFolder.create(str(tmp_path / "r"), "x")
    runner.start(resolve_config(episodes=3, **base), folder, progress=False)
    assert stops_apart(folder)
    config = runner.resumable_config(folder, lengthen=True)
    for lengths, words in [(dict(episodes=2), "fewer"), (dict(env_steps=100), "smaller budget"),
                           (dict(gamma=0.5), "only be lengthened in")]:
        with pytest.raises(runner.RunError, match=words):
            runner.lengthen(folder, config, **lengths)
    assert folder.status()["status"] == "finished"                    # refused before anything changed
    folder.file("checkpoint.extend.pt").unlink()    # as a run finished by an older version
    longer = runner.lengthen(folder, config, episodes=4)
    with pytest.raises(runner.RunError, match="cannot be lengthened exactly"):
        runner.resume(folder, longer, progress=False)


def test_a_seed_the_episode_cap_stopped_goes_on_when_the_cap_is_raised_later(tmp_path):
    """Episodes of ~31 steps, 3 at most, a budget of 62: seeds 0, 1, 3 reach the budget in 2
    episodes, seed 2 (61 steps) stops at the cap. A budget of 150 lets only 0, 1, 3 go on (to the
    cap); 6 episodes then lets every seed go on: equal to asking for both from the start."""
    base = dict(seeds=[0, 1, 2, 3], max_steps=40)
    whole = runner.RunFolder.create(str(tmp_path / "whole"), "x")
    runner.start(resolve_config(episodes=6, env_steps=150, **base), whole, progress=False)
    part = runner.RunFolder.create(str(tmp_path / "part"), "x")
    runner.start(resolve_config(episodes=3, env_steps=62, **base), part, progress=False)
    assert episodes(part).groupby("seed").size().tolist() == [2, 2, 3, 2]    # seed 2 held by the cap
    for lengths in (dict(env_steps=150), dict(episodes=6)):
        longer = runner.lengthen(part, runner.resumable_config(part, lengthen=True), **lengths)
        runner.resume(part, longer, progress=False)
    pd.testing.assert_frame_equal(episodes(whole), episodes(part))


def test_a_budget_stops_a_seed_at_exactly_its_steps_also_when_lengthened(tmp_path):
    """The corridor without slip, always "right": every episode takes 9 steps. A budget of 18 is
    met exactly at the end of episode 2 (the boundary counts: no third episode); more episodes
    allowed with the same budget add none; a budget of 27 then adds exactly one episode per seed."""
    config = resolve_config(env="corridor", agent="constant", action="right", slip=0.0, seeds=[0, 1], env_steps=18)
    folder = runner.RunFolder.create(str(tmp_path / "r"), "x")
    runner.start(config, folder, progress=False)
    steps = lambda: episodes(folder).groupby("seed")["steps"].agg(["count", "sum"]).values.tolist()  # noqa: E731
    assert steps() == [[2, 18], [2, 18]]
    for lengths, expect in ((dict(episodes=30), [2, 18]), (dict(env_steps=27), [3, 27])):
        longer = runner.lengthen(folder, runner.resumable_config(folder, lengthen=True), **lengths)
        runner.resume(folder, longer, progress=False)
        assert steps() == [expect, expect], lengths


def test_a_finished_run_keeps_what_evaluate_and_lengthening_read_and_a_damaged_one_loses_nothing(
        tmp_path, capsys):
    """Once finished, checkpoint.prev.pt goes (a third of the disk); checkpoint.pt and
    checkpoint.extend.pt stay. With checkpoint.pt then damaged, lengthening goes on from where
    the seeds stopped and equals the longer run; with both damaged it says what to do, and
    episodes.csv is as it was."""
    base = dict(seeds=[0, 1, 2], checkpoint_every=1, max_steps=60)
    whole = runner.RunFolder.create(str(tmp_path / "whole"), "x")
    runner.start(resolve_config(episodes=6, **base), whole, progress=False)
    folder = runner.RunFolder.create(str(tmp_path / "r"), "x")
    runner.start(resolve_config(episodes=4, **base), folder, progress=False)
    assert sorted(p.name for p in folder.path.glob("*.pt")) == ["checkpoint.extend.pt", "checkpoint.pt"]
    copy = tmp_path / "copy"
    shutil.copytree(folder.path, copy)
    latest = folder.file("checkpoint.pt")
    latest.write_bytes(latest.read_bytes()[: latest.stat().st_size // 2])
    capsys.readouterr()
    runner.resume(folder, runner.lengthen(folder, runner.resumable_config(folder, lengthen=True), episodes=6),
                  progress=False)
    err = capsys.readouterr().err
    assert "cut short" in err and "continuing from checkpoint.extend.pt" in err
    pd.testing.assert_frame_equal(episodes(whole), episodes(folder))
    damaged = runner.RunFolder(copy)
    rows = damaged.file("episodes.csv").read_bytes()
    for name in ("checkpoint.pt", "checkpoint.extend.pt"):
        damaged.file(name).write_bytes(b"not a checkpoint")
    with pytest.raises(runner.RunError, match="start it again"):
        runner.resume(damaged, runner.lengthen(damaged, runner.resumable_config(damaged, lengthen=True), episodes=6),
                      progress=False)
    assert damaged.file("episodes.csv").read_bytes() == rows
