"""DQN from TorchRL parts: its schedule (learning starts, train frequency, epsilon, target
copies) by hand count, its TD target by hand, greedy actions from each seed's own
network, refusals. (Seed independence and the shared parts: test_neural.py.)"""
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


def trace(cfg, steps, read, seeds=(0,)):
    """``read(agent)`` after each of ``steps`` transitions given to a fresh agent."""
    agent = DQN(cfg, list(seeds), 3, 2)
    out = []
    for _ in range(steps):
        agent.observe(transition(n=len(seeds)))
        out.append(read(agent))
    return out


def target_equals_online(agent):
    return all(torch.equal(p, q) for p, q in zip(agent.qnet.parameters(), agent.target.parameters()))


def test_updates_start_and_repeat_on_schedule():
    """learning_starts 10, batch 4, train_freq 3, gradient_steps 2: updates at steps 12, 15, 18, ...
    (multiples of 3 once 10 transitions are stored), two each."""
    cfg = DQNConfig(hidden=(8,), batch_size=4, buffer_size=50, learning_starts=10, train_freq=3, gradient_steps=2,
                    target_update_interval=1000)
    counts = trace(cfg, 20, lambda agent: int(agent.updates[0]))
    expect = [2 * sum(1 for k in range(1, n + 1) if k % 3 == 0 and k >= 10) for n in range(1, 21)]
    assert counts == expect and counts[-1] == 6


def test_no_update_before_a_minibatch_is_stored():
    """learning_starts 0, batch 4, every step: the first update is at step 4 (not from one stored
    transition sampled four times)."""
    cfg = DQNConfig(hidden=(8,), batch_size=4, buffer_size=50, learning_starts=0, train_freq=1, gradient_steps=1)
    assert trace(cfg, 8, lambda agent: int(agent.updates[0])) == [0, 0, 0, 1, 2, 3, 4, 5]


def test_epsilon_falls_linearly_then_stays():
    cfg = DQNConfig(hidden=(8,), batch_size=4, buffer_size=50, learning_starts=1000, eps_init=1.0, eps_end=0.2,
                    exploration_steps=8)
    eps = trace(cfg, 12, lambda agent: round(agent.eps, 12))
    assert eps == [0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2, 0.2, 0.2, 0.2, 0.2]


def test_exploration_takes_random_actions_at_the_rate_epsilon():
    """eps = 0.3 throughout: about 30% of actions are not the greedy one's... half of them
    (two actions: a random pick is the greedy one half the time), and every action occurs."""
    agent = DQN(DQNConfig(hidden=(8,), eps_init=0.3, eps_end=0.3), list(range(200)), 3, 2)
    td = TensorDict({"observation": torch.rand(200, 3)}, batch_size=[200])
    greedy = agent.greedy(td["observation"])
    differ = torch.stack([agent.act(td) != greedy for _ in range(50)]).double().mean()
    assert abs(float(differ) - 0.15) < 0.01


def test_target_network_copies_every_interval_steps():
    cfg = DQNConfig(hidden=(8,), batch_size=2, buffer_size=50, learning_starts=2, train_freq=1, gradient_steps=1,
                    target_update_interval=4, lr=0.05)
    equal = trace(cfg, 12, target_equals_online)
    # equal from the start until the first update (step 2); copied at env steps 4, 8, 12 (after that
    # step's update); learning changes the online net in between
    assert [i + 1 for i, e in enumerate(equal) if e] == [1, 4, 8, 12]


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
    for _ in range(4):
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
