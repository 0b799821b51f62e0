"""DQN from TorchRL parts: its schedule (learning starts, train frequency, epsilon, target
copies) by hand count, its TD target by hand, seeds independent, refusals."""
import pytest
import torch
from tensordict import TensorDict

from trl_dgpq.agents.dqn import DQNConfig, Learner
from trl_dgpq.collectors.experiment import build, resolve_config
from trl_dgpq.collectors.online import OnlineCollector


def transition(obs_dim=3, n=1, terminated=False):
    flag = torch.full((n, 1), terminated)
    return TensorDict({"observation": torch.rand(n, obs_dim), "action": torch.randint(2, (n,)),
                       "next": {"observation": torch.rand(n, obs_dim), "reward": torch.rand(n, 1),
                                "done": flag, "terminated": flag.clone()}}, batch_size=[n])


def trace(cfg, steps, read):
    """``read(learner)`` after each of ``steps`` transitions given to a fresh learner."""
    learner = Learner(cfg, 3, 2, 0)
    out = []
    for _ in range(steps):
        learner.learn(transition())
        out.append(read(learner))
    return out


def target_equals_online(learner):
    online = learner.loss.value_network_params.flatten_keys()
    target = learner.loss.target_value_network_params.flatten_keys()
    return all(torch.equal(online[k], target[k]) for k in online.keys())


def test_updates_start_and_repeat_on_schedule():
    """learning_starts 10, batch 4, train_freq 3, gradient_steps 2: updates at steps 12, 15, 18, ...
    (multiples of 3 once 10 transitions are stored), two each."""
    cfg = DQNConfig(hidden=(8,), batch_size=4, buffer_size=50, learning_starts=10, train_freq=3, gradient_steps=2,
                    target_update_interval=1000)
    counts = trace(cfg, 20, lambda learner: learner.updates)
    expect = [2 * sum(1 for k in range(1, n + 1) if k % 3 == 0 and k >= 10) for n in range(1, 21)]
    assert counts == expect and counts[-1] == 6


def test_no_update_before_a_minibatch_is_stored():
    """learning_starts 0, batch 4, every step: the first update is at step 4 (not from one stored
    transition sampled four times)."""
    cfg = DQNConfig(hidden=(8,), batch_size=4, buffer_size=50, learning_starts=0, train_freq=1, gradient_steps=1)
    assert trace(cfg, 8, lambda learner: learner.updates) == [0, 0, 0, 1, 2, 3, 4, 5]


def test_epsilon_falls_linearly_then_stays():
    cfg = DQNConfig(hidden=(8,), batch_size=4, buffer_size=50, learning_starts=1000, eps_init=1.0, eps_end=0.2,
                    exploration_steps=8)
    eps = trace(cfg, 12, lambda learner: round(float(learner.explore.eps), 6))
    assert eps == [0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2, 0.2, 0.2, 0.2, 0.2]


def test_target_network_copies_every_interval_steps():
    cfg = DQNConfig(hidden=(8,), batch_size=2, buffer_size=50, learning_starts=2, train_freq=1, gradient_steps=1,
                    target_update_interval=4, lr=0.05)
    equal = trace(cfg, 12, target_equals_online)
    # equal from the start until the first update (step 2); copied at env steps 4, 8, 12 (after that
    # step's update); learning changes the online net in between
    assert [i + 1 for i, e in enumerate(equal) if e] == [1, 4, 8, 12]


def test_td_target_by_hand():
    """The loss is the Huber loss of Q(s, a) - (r + gamma (1 - terminated) max_a' Q_target(s', a'))."""
    cfg = DQNConfig(hidden=(8,), gamma=0.7, batch_size=4, buffer_size=10)
    learner = Learner(cfg, 3, 2, 0)
    batch = torch.cat([transition(terminated=False, n=3), transition(terminated=True, n=2)])
    with torch.no_grad():
        learner.loss.target_value_network_params.apply_(lambda p: p.mul_(0.5))  # target != online
    loss = learner.loss(batch.clone())["loss"]
    online = learner.actor[0]
    with learner.loss.target_value_network_params.to_module(learner.actor):
        q_next = learner.actor[0](batch["next", "observation"]).max(-1).values
    with torch.no_grad():
        q = online(batch["observation"]).gather(-1, batch["action"][:, None])[:, 0]
        y = batch["next", "reward"][:, 0] + 0.7 * (~batch["next", "terminated"][:, 0]) * q_next
    assert loss.item() == pytest.approx(torch.nn.functional.smooth_l1_loss(q, y).item(), rel=1e-5)


def test_greedy_action_is_the_argmax():
    learner = Learner(DQNConfig(hidden=(8,), eps_init=0.0, eps_end=0.0), 3, 4, 0)
    obs = torch.rand(1, 3)
    with torch.no_grad():
        expect = learner.actor[0](obs).argmax(-1)
    assert torch.equal(learner.act(obs, False), expect)


def test_learners_leave_torchs_global_generator_alone():
    torch.manual_seed(5)
    expected = torch.rand(3)
    torch.manual_seed(5)
    env, agent = build(resolve_config(agent="dqn", seeds=[0, 1], episodes=2, batch_size=8, learning_starts=8,
                                      hidden=(8,), max_steps=20))
    OnlineCollector(env, agent, 2, progress=False).run()
    assert torch.equal(torch.rand(3), expected)


def test_continuous_actions_are_refused():
    with pytest.raises(ValueError, match="dqn needs discrete actions"):
        resolve_config(env="liquidation", agent="dqn", action_levels=0)


@pytest.mark.parametrize("bad", [dict(batch_size=0), dict(buffer_size=4, batch_size=8), dict(train_freq=0),
                                 dict(eps_end=0.5, eps_init=0.2), dict(lr=0.0), dict(target_update_interval=0)])
def test_bad_settings_are_refused(bad):
    with pytest.raises(ValueError):
        resolve_config(agent="dqn", **bad)
