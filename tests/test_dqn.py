"""DQN from TorchRL parts: its schedule (learning starts, train frequency, epsilon, target
copies) by hand count, its TD target by hand, greedy actions from each seed's own
network, refusals. (Seed independence and the shared parts: test_neural.py.)"""
import copy

import pytest
import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import Categorical
from torchrl.modules import MLP, QValueActor
from torchrl.objectives import DQNLoss

from trl_dgpq.agents.dqn import DQN, DQNConfig
from trl_dgpq.agents.neural import build_per_seed
from trl_dgpq.collectors.experiment import resolve_config


def transition(obs_dim=3, n=1, terminated=False, truncated=False):
    flag = torch.full((n, 1), terminated)
    return TensorDict({"observation": torch.rand(n, obs_dim), "action": torch.randint(2, (n,)),
                       "next": {"observation": torch.rand(n, obs_dim), "reward": torch.rand(n, 1),
                                "done": flag | truncated, "terminated": flag.clone()}}, batch_size=[n])


def sb3_schedule(total, learning_starts, train_freq, gradient_steps, target_update_interval, exploration_fraction,
                 eps_start=1.0, eps_end=0.05):
    """Stable-Baselines3's DQN schedule for one env, transcribed from its source (2.x:
    ``OffPolicyAlgorithm.learn`` / ``collect_rollouts`` / ``_sample_action``, ``DQN._on_step``,
    ``get_linear_fn``), independent of ours. Returns per env step t = 1..total: (how the action
    was chosen: "random" or the epsilon it was drawn with, [events after the env step in order])."""
    def linear(progress_remaining):  # get_linear_fn(eps_start, eps_end, exploration_fraction)
        done = 1 - progress_remaining
        return eps_end if done > exploration_fraction else eps_start + done * (eps_end - eps_start) / exploration_fraction
    num_timesteps, n_calls, exploration_rate, out = 0, 0, 0.0, []
    while num_timesteps < total:
        for _ in range(train_freq):  # collect_rollouts: train_freq steps
            how = "random" if num_timesteps < learning_starts else exploration_rate
            num_timesteps += 1
            progress_remaining = 1.0 - num_timesteps / total
            n_calls += 1  # _on_step
            events = ["copy"] if n_calls % max(target_update_interval, 1) == 0 else []
            exploration_rate = linear(progress_remaining)
            out.append((how, events))
        if num_timesteps > 0 and num_timesteps > learning_starts:  # train after the rollout
            out[-1][1].extend(["update"] * (gradient_steps if gradient_steps >= 0 else train_freq))
    return out[:total]


def our_schedule(cfg, total):
    """The same trace of our DQN: how each action was chosen, then what each step did. (The
    first 16 updates are made; the rest, only counted: their arithmetic is not the schedule's.)"""
    agent = DQN(cfg, [0], 3, 2)
    events = []
    agent.target.copy_ = (lambda copy: lambda: (events.append("copy"), copy()))(agent.target.copy_)
    made = []

    def update(batch, real=agent.update):
        events.append("update")
        if len(made) < 16:
            made.append(real(batch))
    agent.update = update
    out = []
    for _ in range(total):
        how = "random" if agent.steps < cfg.learning_starts else agent.eps
        agent.observe(transition())
        out.append((how, list(events)))
        events.clear()
    return out


@pytest.mark.parametrize("zoo", [
    # CartPole-v1's zoo settings at a twentieth of the budget; Acrobot-v1's (gradient_steps -1, learning
    # starts 0) and MountainCar-v0's; and a case where train_freq does not divide learning_starts
    dict(total=2_600, learning_starts=1_000, train_freq=256, gradient_steps=128, target_update_interval=10,
         exploration_fraction=0.16, eps_end=0.04),
    dict(total=600, learning_starts=0, train_freq=4, gradient_steps=-1, target_update_interval=250,
         exploration_fraction=0.12, eps_end=0.1),
    dict(total=1_500, learning_starts=100, train_freq=16, gradient_steps=8, target_update_interval=60,
         exploration_fraction=0.2, eps_end=0.07),
    dict(total=100, learning_starts=10, train_freq=3, gradient_steps=2, target_update_interval=7,
         exploration_fraction=0.5, eps_end=0.2),
])
def test_schedule_is_stable_baselines3s(zoo):
    """Random actions before learning_starts, epsilon after each step as SB3's linear schedule
    over exploration_fraction of the budget, target copies every target_update_interval env steps
    and before that step's updates, gradient_steps updates every train_freq-th step once more than
    learning_starts steps are taken -- step by step as SB3's own loop. (SB3's very first action,
    with learning_starts 0, is greedy: its exploration_rate is 0 until the first step; ours is
    eps_init. That one action is left out.)"""
    z = dict(zoo)
    total, fraction = z.pop("total"), z.pop("exploration_fraction")
    ours_z = dict(z, gradient_steps=z["train_freq"] if z["gradient_steps"] == -1 else z["gradient_steps"])
    cfg = DQNConfig(hidden=(8,), batch_size=4, buffer_size=10_000, eps_init=1.0,
                    exploration_steps=int(fraction * total), **ours_z)
    ours = our_schedule(cfg, total)
    sb3 = sb3_schedule(total, z["learning_starts"], z["train_freq"], z["gradient_steps"],
                       z["target_update_interval"], fraction, eps_end=z["eps_end"])
    if z["learning_starts"] == 0:
        ours, sb3 = ours[1:], sb3[1:]
    assert [events for _, events in ours] == [events for _, events in sb3]
    for (how, _), (expect, _) in zip(ours, sb3):
        assert how == expect if expect == "random" else how == pytest.approx(expect, abs=1e-12)


def test_stacked_learner_follows_a_plain_per_seed_dqn():
    """Three seeds learning as one equal three plain one-seed DQNs written here with torch alone
    (nn.Linear, F.smooth_l1_loss, clip_grad_norm_, Adam, the SB3 schedule above), each fed the
    minibatches the stacked learner drew for that seed -- which must be that seed's own
    transitions --, over 150 updates with clipping biting: the weights agree to float32
    rounding. Any coupling of seeds (a mean over seeds, a shared clip, a shared Adam state),
    a target copied at other times, or another loss moves them apart."""
    cfg = DQNConfig(hidden=(16,), lr=3e-3, batch_size=8, buffer_size=64, learning_starts=10, train_freq=2,
                    gradient_steps=3, target_update_interval=7, max_grad_norm=0.3, gamma=0.9)
    seeds, S, steps = [0, 3, 7], 3, 110
    agent = DQN(cfg, seeds, 3, 2)
    g = torch.Generator().manual_seed(0)
    data = [transition(n=S) for _ in range(steps)]
    for t in data:  # rewards that depend on the action, so that the networks learn something
        t["next", "reward"] = (t["action"][:, None] == (t["observation"][:, :1] > 0.5)).float() \
            + 0.1 * torch.randn(S, 1, generator=g)
    drawn = []
    agent.update = (lambda update: lambda batch: (drawn.append(batch.clone()), update(batch)))(agent.update)
    (w1, b1), (w2, b2) = [(layer.weight.detach().clone(), layer.bias.detach().clone())
                          for layer in (agent.qnet.net[0], agent.qnet.net[2])]
    for t in data:
        agent.observe(t.clone())
    assert len(drawn) == 3 * sum(1 for k in range(1, steps + 1) if k % 2 == 0 and k > 10) == 150

    for i in range(S):
        own = torch.cat([torch.cat([t["observation"][i], t["action"][i:i + 1].float(), t["next", "reward"][i]])
                         for t in data])
        online = nn.Sequential(nn.Linear(3, 16), nn.ReLU(), nn.Linear(16, 2))
        with torch.no_grad():
            for layer, w, b in ((online[0], w1, b1), (online[2], w2, b2)):
                layer.weight.copy_(w[i].T)
                layer.bias.copy_(b[i])
        target = copy.deepcopy(online)
        optim = torch.optim.Adam(online.parameters(), lr=3e-3)
        batches = iter(batch[i] for batch in drawn)
        for step in range(1, steps + 1):
            if step % 7 == 0:
                target.load_state_dict(online.state_dict())
            if step % 2 or step <= 10:
                continue
            for _ in range(3):
                b = next(batches)
                rows = torch.cat([b["observation"], b["action"][:, None].float(), b["next", "reward"]], 1)
                assert all(((own.view(steps, 5) - row).abs().sum(1) == 0).any() for row in rows)  # its own data
                q = online(b["observation"]).gather(1, b["action"][:, None])[:, 0]
                with torch.no_grad():
                    y = b["next", "reward"][:, 0] + 0.9 * (~b["next", "terminated"][:, 0]) * \
                        target(b["next", "observation"]).max(1).values
                optim.zero_grad()
                nn.functional.smooth_l1_loss(q, y).backward()
                nn.utils.clip_grad_norm_(online.parameters(), 0.3)
                optim.step()
        torch.testing.assert_close(agent.qnet.net[0].weight[i].T, online[0].weight, rtol=1e-4, atol=1e-5)
        torch.testing.assert_close(agent.qnet.net[2].bias[i], online[2].bias, rtol=1e-4, atol=1e-5)
        torch.testing.assert_close(agent.target.net.net[2].weight[i].T, target[2].weight, rtol=1e-4, atol=1e-5)


def test_warm_up_actions_are_random_then_greedy_at_epsilon_zero():
    """learning_starts 30, epsilon 0: the first 30 actions are uniform draws (both actions occur,
    not only the greedy one), every later one is the greedy action."""
    cfg = DQNConfig(hidden=(8,), batch_size=4, buffer_size=100, learning_starts=30, eps_init=0.0, eps_end=0.0,
                    target_update_interval=1000, train_freq=1000)
    agent = DQN(cfg, list(range(8)), 3, 2)
    td = TensorDict({"observation": torch.rand(8, 3)}, batch_size=[8])
    same = []
    for _ in range(40):
        same.append(bool((agent.act(td) == agent.greedy(td["observation"])).all()))
        agent.observe(transition(n=8))
    assert not all(same[:30]) and all(same[30:])


def test_exploration_takes_random_actions_at_the_rate_epsilon():
    """eps = 0.3 throughout: about 30% of actions are not the greedy one's... half of them
    (two actions: a random pick is the greedy one half the time), and every action occurs."""
    agent = DQN(DQNConfig(hidden=(8,), eps_init=0.3, eps_end=0.3), list(range(200)), 3, 2)
    td = TensorDict({"observation": torch.rand(200, 3)}, batch_size=[200])
    greedy = agent.greedy(td["observation"])
    differ = torch.stack([agent.act(td) != greedy for _ in range(50)]).double().mean()
    assert abs(float(differ) - 0.15) < 0.01


def test_exploration_draws_every_action_the_last_included():
    """epsilon 1 with 5 actions: every action, 4 included, is drawn, each about a fifth of the time."""
    agent = DQN(DQNConfig(hidden=(8,), eps_init=1.0, eps_end=1.0), list(range(50)), 3, 5)
    td = TensorDict({"observation": torch.rand(50, 3)}, batch_size=[50])
    counts = torch.bincount(torch.cat([agent.act(td) for _ in range(40)]), minlength=5)
    assert counts.numel() == 5 and (counts - 400).abs().max() < 80


def test_target_copy_goes_from_online_to_target():
    """After a copy the target holds what the online network held, and the online network is
    unchanged (a copy the wrong way round also leaves the two equal)."""
    agent = DQN(DQNConfig(hidden=(8,)), [0, 1], 3, 2)
    with torch.no_grad():
        for p in agent.target.parameters():
            p.mul_(0.5)
    online = [p.clone() for p in agent.qnet.parameters()]
    agent.target.copy_()
    assert all(torch.equal(p, q) for p, q in zip(agent.qnet.parameters(), online))
    assert all(torch.equal(p, q) for p, q in zip(agent.target.parameters(), online))


def test_td_target_by_hand_and_as_torchrls_dqn_loss():
    """Per element: the Huber loss of Q(s, a) - (r + gamma (1 - terminated) max_a' Q_target(s', a')),
    seed 1's from seed 1's own networks; and TorchRL's DQNLoss on that seed's networks agrees."""
    agent = DQN(DQNConfig(hidden=(8,), gamma=0.7, batch_size=4, buffer_size=10), [3, 8], 3, 2)
    batch = torch.stack([torch.cat([transition(n=2), transition(truncated=True), transition(terminated=True, n=2)])
                         for _ in range(2)])  # a truncated step (a time limit) still bootstraps
    with torch.no_grad():
        for p in agent.target.parameters():
            p.mul_(0.5)  # target != online
    loss = agent.td_loss(batch.clone())  # (S, B)
    make = lambda: MLP(in_features=3, out_features=2, num_cells=[8], activation_class=nn.ReLU)  # noqa: E731
    online, target = build_per_seed(make, [8])[0], build_per_seed(make, [8])[0]
    with torch.no_grad():
        for p in target.parameters():
            p.mul_(0.5)
    b = batch[1]
    with torch.no_grad():
        q = online(b["observation"]).gather(-1, b["action"][:, None])[:, 0]
        q_next = target(b["next", "observation"]).max(-1).values
        y = b["next", "reward"][:, 0] + 0.7 * (~b["next", "terminated"][:, 0]) * q_next
        expect = torch.nn.functional.smooth_l1_loss(q, y, reduction="none")
    torch.testing.assert_close(loss[1], expect, rtol=1e-5, atol=1e-7)

    spec = Categorical(2)
    reference = DQNLoss(QValueActor(online, in_keys=["observation"], spec=spec), loss_function="smooth_l1",
                        delay_value=True, action_space=spec, reduction="none")
    reference.make_value_estimator(gamma=0.7)
    with torch.no_grad():
        reference.target_value_network_params.apply_(lambda p: p.mul_(0.5))
    torch.testing.assert_close(reference(b.clone())["loss"], expect, rtol=1e-5, atol=1e-7)


def test_greedy_action_is_the_argmax_of_the_seeds_own_network():
    agent = DQN(DQNConfig(hidden=(8,), eps_init=0.0, eps_end=0.0), [4, 9], 3, 4)
    obs = torch.rand(2, 3)
    nets = build_per_seed(lambda: MLP(in_features=3, out_features=4, num_cells=[8], activation_class=nn.ReLU), [4, 9])
    with torch.no_grad():
        expect = torch.stack([nets[i](obs[i]).argmax(-1) for i in range(2)])
    assert torch.equal(agent.act(TensorDict({"observation": obs}, batch_size=[2])), expect)


def test_continuous_actions_are_refused():
    with pytest.raises(ValueError, match="dqn needs discrete actions"):
        resolve_config(env="liquidation", agent="dqn", action_levels=0)


@pytest.mark.parametrize("bad", [dict(batch_size=0), dict(buffer_size=4, batch_size=8), dict(train_freq=0),
                                 dict(eps_end=0.5, eps_init=0.2), dict(lr=0.0), dict(target_update_interval=0)])
def test_bad_settings_are_refused(bad):
    with pytest.raises(ValueError):
        resolve_config(agent="dqn", **bad)


@pytest.mark.parametrize("clip, moved", [(10.0, 1.0), (1e-10, 0.02)])
def test_clipping_reaches_the_optimiser(clip, moved):
    """Adam's first step moves a parameter by lr g / (|g| + 1e-8): lr itself for a gradient of any
    usual size, but under 2 % of lr once the whole gradient is clipped to norm 1e-10 (each
    element then at most 1e-10). Without clipping both would move by lr."""
    cfg = DQNConfig(hidden=(8,), learning_starts=4, batch_size=4, train_freq=1, gradient_steps=1, lr=1e-3,
                    max_grad_norm=clip)
    agent = DQN(cfg, [0], 3, 2)
    before = [p.clone() for p in agent.qnet.parameters()]
    for _ in range(5):  # the first update after the 5th step (more than learning_starts)
        agent.observe(transition())
    assert int(agent.updates[0]) == 1
    step = max(float((p - b).abs().max()) for p, b in zip(agent.qnet.parameters(), before))
    assert step == pytest.approx(1e-3, rel=1e-3) if moved == 1.0 else step < moved * 1e-3


def test_a_time_limit_is_stored_as_not_terminated():
    """A truncated step (done, not terminated) must bootstrap: the replay keeps `terminated` False."""
    agent = DQN(DQNConfig(hidden=(8,)), [0, 1], 3, 2)
    agent.observe(transition(n=2, truncated=True))
    stored = agent.replay.sample(4)
    assert stored["next", "done"].all() and not stored["next", "terminated"].any()


def test_memory_estimate_is_the_full_replay_as_stored_both_observations_counted():
    """The square (2-D observations), 3 seeds, a buffer of 8: filled by 8 real steps, the replay
    holds per transition the observation and the next one (2 x 2 float32), the reward (float32),
    the action (int64) and done and terminated (bool): 16 + 4 + 8 + 2 = 30 bytes, 3 x 8 x 30 = 720
    in all; the estimate a run checks its memory by says the same (one observation: 528)."""
    from trl_dgpq.collectors.experiment import build, memory_estimate
    config = resolve_config(env="square", agent="dqn", seeds=[0, 1, 2], buffer_size=8, batch_size=4,
                            learning_starts=100)
    env, agent = build(config)
    td = env.reset()
    for _ in range(8):
        td["action"] = agent.act(td)
        td, td_next = env.step_and_maybe_reset(td)
        agent.observe(td)
        td = td_next
    stored = agent.replay.storage._storage   # TorchRL's LazyTensorStorage, (capacity, S)
    assert sum(t.nbytes for t in stored.values(True, True)) == 3 * 8 * (2 * 2 * 4 + 4 + 8 + 2) == 720
    assert memory_estimate(config) == 720
