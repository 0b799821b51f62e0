"""DDPG from TorchRL parts: the course's sizes, OU noise from each seed's own stream, and
the `course` settings (each of the course agent's four choices) against hand computations.
(Seed independence and the shared parts: test_neural.py.)"""
import math

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule, TensorDictSequential
from torchrl.data import Bounded, LazyTensorStorage
from torchrl.modules import MLP, TanhModule, ValueOperator
from torchrl.objectives import DDPGLoss, SoftUpdate

from trl_dgpq.agents.ddpg import DDPG, Critic, DDPGConfig
from trl_dgpq.agents.neural import build_per_seed
from trl_dgpq.collectors.experiment import build, resolve_config
from trl_dgpq.collectors.online import OnlineCollector
from trl_dgpq.rng import SeedStreams, stream_id

SMALL = dict(env="liquidation", agent="ddpg", trades=15, batch_size=8, buffer_size=100, episodes=4)
BOX = Bounded(torch.zeros(1), torch.ones(1), shape=(1,))


def test_the_course_sizes_stacked_over_seeds():
    env, agent = build(resolve_config(env="liquidation", agent="ddpg", seeds=[0, 1]))
    assert isinstance(agent.replay.storage, LazyTensorStorage) and agent.replay.capacity == 10_000
    widths = [tuple(v.shape) for k, v in agent.actor.state_dict().items() if k.endswith("weight")]
    assert widths == [(2, 8, 24), (2, 24, 48), (2, 48, 1)]  # two seeds' 8 -> 24 -> 48 -> 1 (in, out)
    a = agent.act(env.reset())
    assert a.shape == (2, 1) and a.dtype == torch.float64 and ((0 <= a) & (a <= 1)).all()


def test_losses_and_soft_update_equal_torchrls_on_one_seeds_networks():
    """Seed 5's row of our per-element losses equals TorchRL's DDPGLoss (reduction "none") on
    seed 5's own networks (built from its generator), target networks apart from the online
    ones; our soft update equals SoftUpdate's."""
    agent = DDPG(DDPGConfig(gamma=0.9), [2, 5], 3, BOX)
    with torch.no_grad():
        for name in ("target_actor", "target_critic"):
            for p in agent.nets[name].parameters():
                p.mul_(0.7)
    batch = batch_of(16, S=2)
    mlp, critic = build_per_seed(lambda: torch.nn.ModuleList([
        MLP(in_features=3, out_features=1, num_cells=[24, 48], activation_class=torch.nn.ReLU),
        Critic(3, 1, (24, 48))]), [5])[0]
    actor = TensorDictSequential(TensorDictModule(mlp, ["observation"], ["raw"]),
                                 TanhModule(in_keys=["raw"], out_keys=["action"], low=BOX.space.low,
                                            high=BOX.space.high))
    reference = DDPGLoss(actor, ValueOperator(critic, in_keys=["observation", "action"]), delay_actor=True,
                         delay_value=True, reduction="none")
    reference.make_value_estimator(gamma=0.9)
    updater = SoftUpdate(reference, tau=0.05)  # (before the targets move: it starts them at the online nets)
    with torch.no_grad():
        for params in (reference.target_actor_network_params, reference.target_value_network_params):
            for key, p in params.flatten_keys(".").items():
                if not key.endswith(("_low", "_high")):  # the box's bounds, not weights
                    p.mul_(0.7)
    ref = reference(batch[1].clone())
    torch.testing.assert_close(agent.value_loss(batch)[1], ref["loss_value"], rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(agent.actor_loss(batch)[1], ref["loss_actor"], rtol=1e-5, atol=1e-6)
    updater.step()
    agent.nets["target_critic"].soft_update_(0.05)
    ours = {k.split(".", 2)[2]: p[1] for k, p in agent.nets["target_critic"].named_parameters()}
    theirs = {k.split(".", 1)[1]: p for k, p in reference.target_value_network_params.flatten_keys(".").items()}
    assert ours.keys() == theirs.keys() and len(ours) == 6
    for k in ours:  # ours stack each weight transposed, (in, out)
        torch.testing.assert_close(ours[k].T if k.endswith("weight") else ours[k], theirs[k], rtol=1e-6, atol=1e-7)


def ou_trace(cfg, seeds, new_episode_at=(), steps=6):
    """The agent's noise after each act, new episodes flagged at the given steps."""
    agent = DDPG(cfg, seeds, 3, BOX)
    td = TensorDict({"observation": torch.rand(len(seeds), 3)}, batch_size=[len(seeds)])
    out = []
    for t in range(steps):
        agent.new_episode[:] = t == 0 or t in new_episode_at
        agent.act(td)
        out.append(agent.noise.clone())
    return out


@pytest.mark.parametrize("kind, reset, dt", [("normal", True, 1.0), ("uniform", False, 1.0), ("uniform", True, 1.0),
                                             ("normal", True, 0.25)])
def test_ou_noise_by_hand(kind, reset, dt):
    """x_t = x_{t-1} + theta (0 - x_{t-1}) dt + sigma sqrt(dt) d_t with d_t the seed's own N(0, 1) or
    U[0, 1) draws, x restarting from 0 at a new episode only if ou_reset (dt 0.25: the drift a
    quarter, the diffusion a half)."""
    cfg = DDPGConfig(ou_theta=0.3, ou_sigma=0.5, ou_noise=kind, ou_reset=reset, ou_dt=dt)
    got = ou_trace(cfg, [2, 5], new_episode_at=(3,))
    rng = SeedStreams([2, 5], stream_id("ddpg.ou"))
    x = torch.zeros(2, 1, dtype=torch.float64)
    for t, g in enumerate(got):
        if t == 3 and reset:
            x = torch.zeros_like(x)
        d = rng.uniform(1) if kind == "uniform" else rng.normal(1)
        x = x - 0.3 * x * dt + 0.5 * dt ** 0.5 * d
        torch.testing.assert_close(g.double(), x, rtol=1e-5, atol=1e-6)


def test_course_noise_drifts_to_sigma_over_two_theta():
    """Uniform increments: the noise's long-run mean is sigma E[U] / theta = 0.2 * 0.5 / 0.15 = 0.667
    (the course's bias towards selling), the normal one's is 0."""
    for kind, mean in (("uniform", 0.2 * 0.5 / 0.15), ("normal", 0.0)):
        trace = torch.stack(ou_trace(DDPGConfig(ou_noise=kind, ou_reset=False), list(range(64)), steps=200)[50:])
        assert abs(float(trace.mean()) - mean) < 0.03


def test_course_initial_weights_use_out_features():
    """Hidden weights in +-1/sqrt(out_features) (torch's default is +-1/sqrt(in_features): 8 inputs
    would give 0.35, not 0.20), output layers in +-3e-3."""
    agent = DDPG(DDPGConfig(init="course"), list(range(4)), 8, BOX)
    params = {**{f"actor.{k}": v for k, v in agent.actor.state_dict().items()},
              **{f"critic.{k}": v for k, v in agent.critic.state_dict().items()}}
    weights = {k: v for k, v in params.items() if k.endswith("weight")}
    assert len(weights) == 6
    for k, w in weights.items():
        out = w.shape[2]  # stacked (S, in, out)
        lim = 3e-3 if out == 1 else 1 / math.sqrt(out)
        assert w.abs().max() <= lim and w.abs().max() > 0.9 * lim, k
    default = DDPG(DDPGConfig(), list(range(4)), 8, BOX).actor.state_dict()
    first = [v for k, v in default.items() if k.endswith("0.weight")][0]
    assert first.abs().max() > 1 / math.sqrt(24)


def batch_of(n, S=1, obs_dim=3, seed=0):
    g = torch.Generator().manual_seed(seed)
    f = lambda *s: torch.rand(*s, generator=g)  # noqa: E731
    terminated = f(S, n, 1) < 0.3
    done = terminated | (f(S, n, 1) < 0.3)  # some truncated: they still bootstrap
    return TensorDict({"observation": f(S, n, obs_dim), "action": f(S, n, 1),
                       "next": {"observation": f(S, n, obs_dim), "reward": f(S, n, 1), "done": done,
                                "terminated": terminated}}, batch_size=[S, n])


def test_critic_then_actor_steps_the_actor_against_the_updated_critic():
    """The course's order by hand, from TorchRL's loss terms: a critic step on the value loss,
    then an actor step on the actor loss evaluated with the updated critic, then the soft
    update -- three times. `critic-then-actor` equals it; `joint` (both gradients at the old
    critic) does not."""
    batches = [batch_of(16, seed=k) for k in range(3)]
    by_hand = DDPG(DDPGConfig(), [0], 3, BOX)
    for b in batches:
        for optim, term in ((by_hand.critic_optim, by_hand.value_loss), (by_hand.actor_optim, by_hand.actor_loss)):
            optim.zero_grad()
            term(b.clone()).mean().backward()
            optim.step()
        for name in ("target_actor", "target_critic"):
            by_hand.nets[name].soft_update_(1e-3)
    for update, same in (("critic-then-actor", True), ("joint", False)):
        agent = DDPG(DDPGConfig(update=update), [0], 3, BOX)
        for b in batches:
            agent.update(b.clone())
        same_actor = all(torch.equal(p, q) for p, q in zip(agent.actor.parameters(), by_hand.actor.parameters()))
        assert same_actor == same, update
        assert all(torch.equal(p, q) for p, q in zip(agent.critic.parameters(), by_hand.critic.parameters()))


@pytest.mark.parametrize("above, first_update", [(False, 8), (True, 9)])
def test_learning_starts_with_a_minibatch_or_more_than_one(above, first_update):
    agent = DDPG(DDPGConfig(batch_size=8, start_above_batch=above), [0], 3, BOX)
    counts = []
    for t in range(10):
        agent.observe(batch_of(1, seed=t)[:, 0])
        counts.append(int(agent.updates[0]))
    assert counts.index(1) + 1 == first_update


def test_exploration_noise_restarts_each_episode():
    env, agent = build(resolve_config(seeds=[0], **SMALL))
    col = OnlineCollector(env, agent, 1, progress=False)
    col.run()
    assert bool(agent.new_episode[0])
    rng = SeedStreams([0], stream_id("ddpg.ou"))
    rng.counter = agent.noise_rng.counter
    agent.act(col.td)  # the first step of the next episode: 0 + sigma N(0, 1)
    assert float(agent.noise[0, 0]) == pytest.approx(0.2 * float(rng.normal(1)[0, 0]), rel=1e-6)


@pytest.mark.parametrize("settings, match", [
    (dict(env="liquidation", action_levels=21), "action_levels=0"),
    (dict(env="square"), "continuous"),
    (dict(env="liquidation", batch_size=200, buffer_size=100), "batch_size"),
    (dict(env="liquidation", ou_noise="gauss"), "ou_noise"),
])
def test_refused_settings(settings, match):
    with pytest.raises(ValueError, match=match):
        resolve_config(agent="ddpg", **settings)


@pytest.mark.parametrize("update", ["joint", "critic-then-actor"])
def test_each_network_moves_by_its_own_learning_rate(update):
    """Adam's first step moves every parameter with a gradient by lr (g / |g|, bias-corrected):
    the actor's by actor_lr, the critic's by critic_lr (swapped rates fail this); the targets by
    tau times that."""
    cfg = DDPGConfig(actor_lr=2e-4, critic_lr=3e-3, target_update=0.01, update=update)
    agent = DDPG(cfg, [0, 1], 3, BOX)
    before = {k: v.clone() for k, v in agent.nets.state_dict().items()}
    agent.update(batch_of(16, S=2))
    after = agent.nets.state_dict()
    for net, lr in (("actor", 2e-4), ("critic", 3e-3)):
        moved = torch.cat([(after[k] - before[k]).abs().flatten() for k in before if k.startswith(net + ".")])
        assert moved.max().item() == pytest.approx(lr, rel=1e-3), net
        target = torch.cat([(after[k] - before[k]).abs().flatten() for k in before if k.startswith(f"target_{net}.")])
        assert target.max().item() == pytest.approx(0.01 * lr, rel=0.03), net   # float32 differences
