"""TD3: its losses equal TorchRL's TD3Loss on one seed's networks; target policy smoothing,
the delayed actor and the exploration by hand. (Seed independence, exact resume and plain
checkpoints: test_neural.py, test_state.py, test_plain_checkpoints.py.)"""
import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.data import Bounded
from torchrl.modules import MLP, TanhModule, ValueOperator
from torchrl.objectives import TD3Loss

from trl_dgpq.agents.neural import build_per_seed
from trl_dgpq.agents.td3 import TD3, TD3Config, TwinCritic
from trl_dgpq.collectors.experiment import build, resolve_config

SYM = Bounded(-torch.ones(1), torch.ones(1), shape=(1,))  # [-1, 1]: TorchRL's noise units are the box's
SMALL = dict(actor_hidden=(16,), critic_hidden=(16, 16))


def batch_of(n, S=1, obs_dim=3, low=-1.0, seed=0):
    g = torch.Generator().manual_seed(seed)
    terminated = torch.rand(S, n, 1, generator=g) < 0.3
    return TensorDict({"observation": torch.randn(S, n, obs_dim, generator=g),
                       "action": low + (1 - low) * torch.rand(S, n, 1, generator=g),
                       "next": {"observation": torch.randn(S, n, obs_dim, generator=g),
                                "reward": torch.randn(S, n, 1, generator=g),
                                "done": terminated.clone(), "terminated": terminated}}, batch_size=[S, n])


class Single(nn.Module):
    """One critic of a pair as TorchRL's TD3Loss takes it: (observation, action) -> Q."""

    def __init__(self, mlp):
        super().__init__()
        self.mlp = mlp

    def forward(self, observation, action):
        return self.mlp(torch.cat([observation, action], -1))


def test_losses_equal_torchrls_td3_loss_on_one_seeds_networks():
    """Seed 5's per-element losses equal TD3Loss's (squared errors, reduction "none") on seed 5's
    own networks: twin critics against min(Q1', Q2') at the target actor's smoothed action (the
    same Gaussian draws: TorchRL's from torch's generator, seeded alike), the actor's -Q1;
    target networks apart from the online ones."""
    cfg = TD3Config(gamma=0.9, policy_noise=0.4, noise_clip=0.3, **SMALL)
    agent = TD3(cfg, [2, 5], 3, SYM)
    with torch.no_grad():
        for name in ("target_actor", "target_critic"):
            for p in agent.nets[name].parameters():
                p.mul_(0.7)
    batch = batch_of(32, S=2)
    mlp, twin = build_per_seed(lambda: nn.ModuleList([
        MLP(in_features=3, out_features=1, num_cells=[16], activation_class=nn.ReLU),
        TwinCritic(3, 1, (16, 16))]), [5])[0]
    actor = TensorDictSequential(TensorDictModule(mlp, ["observation"], ["raw"]),
                                 TanhModule(in_keys=["raw"], out_keys=["action"], low=SYM.space.low,
                                            high=SYM.space.high))
    qvalue = ValueOperator(Single(MLP(in_features=4, out_features=1, num_cells=[16, 16], activation_class=nn.ReLU)),
                           in_keys=["observation", "action"])
    reference = TD3Loss(actor, qvalue, action_spec=SYM, policy_noise=0.4, noise_clip=0.3, loss_function="l2",
                        reduction="none")
    reference.make_value_estimator(gamma=0.9)
    with torch.no_grad():  # TD3Loss draws its twins' weights afresh: give them seed 5's Q1 and Q2
        for params, scale in ((reference.qvalue_network_params, 1.0), (reference.target_qvalue_network_params, 0.7)):
            leaves = list(params.flatten_keys(".").values())
            for leaf, p1, p2 in zip(leaves, twin.q1.parameters(), twin.q2.parameters(), strict=True):
                leaf.data[0].copy_(p1 * scale)
                leaf.data[1].copy_(p2 * scale)
        for key, p in reference.target_actor_network_params.flatten_keys(".").items():
            if not key.endswith(("_low", "_high")):
                p.mul_(0.7)
    torch.manual_seed(11)
    noise = torch.randn(32, 1)
    torch.manual_seed(11)
    ref = reference(batch[1].clone())
    ours = agent.value_loss(batch, torch.stack([torch.zeros(32, 1), noise]))
    torch.testing.assert_close(ours[1], ref["loss_qvalue"], rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(agent.actor_loss(batch)[1], ref["loss_actor"], rtol=1e-5, atol=1e-6)


def test_target_policy_noise_is_scaled_clipped_then_the_action_boxed():
    """Box [0, 1] (half-width 0.5): noise 0.2 x 0.5 per unit draw, clipped at 0.5 x 0.5; the sum
    clipped to the box."""
    box = Bounded(torch.zeros(1), torch.ones(1), shape=(1,))
    agent = TD3(TD3Config(**SMALL), [0], 3, box)
    obs = torch.randn(1, 4, 3)
    with torch.no_grad():
        base = agent.nets["target_actor"](obs)
        got = agent.target_action(obs, torch.tensor([[[0.0], [1.0], [10.0], [-10.0]]]))
    expect = (base + torch.tensor([[[0.0], [0.1], [0.25], [-0.25]]])).clamp(0, 1)
    torch.testing.assert_close(got, expect)
    with torch.no_grad():
        far = agent.target_action(obs, torch.full((1, 4, 1), 1e6))
    assert (far <= 1).all() and (far >= 0).all()


@pytest.mark.parametrize("delay", [2, 3])
def test_actor_and_targets_move_every_policy_delay_critic_steps(delay):
    """policy_delay d: the critic moves at every update, the actor and both targets only at every
    d-th; the checkpoint counts the critic's steps."""
    agent = TD3(TD3Config(policy_delay=delay, batch_size=8, buffer_size=64, learning_starts=0, **SMALL), [0, 1], 3,
                SYM)
    batch = batch_of(8, S=2)
    moved = []
    for _ in range(2 * delay):
        before = {k: v.clone() for k, v in agent.nets.state_dict().items()}
        agent.update(batch)
        after = agent.nets.state_dict()
        moved.append({name for name in ("actor", "critic", "target_actor", "target_critic")
                      if any(not torch.equal(before[k], after[k]) for k in before if k.startswith(name + "."))})
    assert moved == ([{"critic"}] * (delay - 1) + [{"critic", "actor", "target_actor", "target_critic"}]) * 2
    assert agent.state_dict()["critic_steps"] == 2 * delay


def test_warm_up_is_uniform_in_the_box_then_noise_around_the_actor():
    """learning_starts 50 on [0, 1]: the first 50 actions spread over the box (mean about 0.5,
    none near the actor's); later ones lie within a few noise s.d. (0.1 x 0.5) of the actor's."""
    box = Bounded(torch.zeros(1), torch.ones(1), shape=(1,))
    agent = TD3(TD3Config(learning_starts=50, **SMALL), list(range(64)), 3, box)
    td = TensorDict({"observation": torch.randn(64, 3)}, batch_size=[64])
    greedy = agent.exploit(td)
    warm = []
    for _ in range(50):  # the step counter as observe() would move it, without learning
        warm.append(agent.act(td))
        agent.steps += 1
    warm = torch.stack(warm)
    assert abs(float(warm.mean()) - 0.5) < 0.02 and float((warm - greedy).abs().mean()) > 0.2
    later = torch.stack([agent.act(td) for _ in range(20)]) - greedy
    inside = greedy.gt(0.2) & greedy.lt(0.8)  # away from the box's faces, where clipping bites
    assert float(later[:, inside].std()) == pytest.approx(0.05, rel=0.1)


def test_td3_runs_on_liquidation_and_refuses_discrete_actions():
    env, agent = build(resolve_config(env="liquidation", agent="td3", seeds=[0, 1]))
    assert agent.act(env.reset()).shape == (2, 1)
    with pytest.raises(ValueError, match="td3"):
        resolve_config(env="square", agent="td3")


def test_exploration_never_leaves_the_action_box():
    """Noise of 40 half-widths on [0, 1] after the warm-up: every action given lies in the box, and
    some sit on each face (the clip, not luck, keeps them there: liquidation refuses anything else)."""
    box = Bounded(torch.zeros(1), torch.ones(1), shape=(1,))
    agent = TD3(TD3Config(learning_starts=0, expl_noise=40.0, **SMALL), list(range(64)), 3, box)
    td = TensorDict({"observation": torch.randn(64, 3)}, batch_size=[64])
    got = torch.stack([agent.act(td) for _ in range(10)])
    assert bool(((got >= 0) & (got <= 1)).all())
    assert bool((got == 0).any()) and bool((got == 1).any())


def test_td3_memory_estimate_is_the_full_replay_as_stored():
    """Liquidation (8 observations, 1 action), 2 seeds, a buffer of 8 filled by 8 steps: per
    transition observation and next (2 x 8 float32), action and reward (float32), done and
    terminated (bool): 64 + 4 + 4 + 2 = 74 bytes, 2 x 8 x 74 = 1184, as the estimate says."""
    from trl_dgpq.collectors.experiment import build, memory_estimate, resolve_config
    config = resolve_config(env="liquidation", agent="td3", seeds=[0, 1], buffer_size=8, batch_size=8,
                            actor_hidden=(4,), critic_hidden=(4,))
    env, agent = build(config)
    td = env.reset()
    for _ in range(8):
        td["action"] = agent.act(td)
        td, td_next = env.step_and_maybe_reset(td)
        agent.observe(td)
        td = td_next
    stored = agent.replay.storage._storage
    assert sum(t.nbytes for t in stored.values(True, True)) == 2 * 8 * (2 * 8 * 4 + 4 + 4 + 2) == 1184
    assert memory_estimate(config) == 1184


def test_a_time_limit_bootstraps_and_a_termination_does_not():
    """The TD target y = r + gamma (1 - terminated) min(Q1', Q2'): a step cut by a time limit
    (done, not terminated: a domain's max_steps) bootstraps like any other, a terminal one does
    not. Target critics made constant (Q1' = 5, Q2' = 7: min 5 whatever the action) and online
    ones zero, so each element's loss is 2 y^2 by hand: rewards 1, -1, 2 with gamma 0.9 give
    y = 1 + 4.5, -1 + 4.5 (truncated) and 2 (terminated): 60.5, 24.5, 8."""
    agent = TD3(TD3Config(gamma=0.9, **SMALL), [0], 3, SYM)
    with torch.no_grad():
        for name in ("critic", "target_critic"):
            for v in agent.nets[name].state_dict().values():
                v.zero_()
        target = agent.nets["target_critic"].state_dict()
        target["net.net.q1.4.bias"].fill_(5.0)
        target["net.net.q2.4.bias"].fill_(7.0)
    done = torch.tensor([[[False], [True], [True]]])
    terminated = torch.tensor([[[False], [False], [True]]])
    g = torch.Generator().manual_seed(0)
    batch = TensorDict({"observation": torch.randn(1, 3, 3, generator=g), "action": torch.rand(1, 3, 1, generator=g),
                        "next": {"observation": torch.randn(1, 3, 3, generator=g),
                                 "reward": torch.tensor([[[1.0], [-1.0], [2.0]]]),
                                 "done": done, "terminated": terminated}}, batch_size=[1, 3])
    loss = agent.value_loss(batch, torch.randn(1, 3, 1, generator=g))
    torch.testing.assert_close(loss, torch.tensor([[60.5, 24.5, 8.0]]))


# a box not at 0, two actions; one seed's spec, as an env describes it (EnvInfo: shape (1, ...))
BOX2 = Bounded(torch.tensor([[-2.0, 0.0]]), torch.tensor([[3.0, 1.0]]), shape=(1, 2))


def test_actions_are_each_seeds_own_draws_mapped_onto_the_box_exactly():
    """On [-2, 3] x [0, 1], seeds 4 and 9: a warm-up action is low + (high - low) u with u the
    seed's "td3.explore" uniform draws in float32; after it, the actor's action plus that
    stream's normal draws x expl_noise x half-width, clipped to the box; float64 both, from a
    float64 observation (exploit too, without noise)."""
    from trl_dgpq.rng import SeedStreams, stream_id
    cfg = TD3Config(learning_starts=1, expl_noise=0.3, **SMALL)
    agent = TD3(cfg, [4, 9], 3, BOX2)
    stream = SeedStreams([4, 9], stream_id("td3.explore"))
    low, high = torch.tensor([-2.0, 0.0]), torch.tensor([3.0, 1.0])
    td = TensorDict({"observation": torch.randn(2, 3, dtype=torch.float64)}, batch_size=[2])
    warm = agent.act(td)
    assert warm.dtype == torch.float64
    assert torch.equal(warm, (low + (high - low) * stream.uniform(2).to(torch.float32)).to(torch.float64))
    agent.steps = 1
    with torch.no_grad():
        mean = agent.actor(td["observation"].to(torch.float32))
    noise = stream.normal(2).to(torch.float32) * 0.3 * torch.tensor([2.5, 0.5])
    got = agent.act(td)
    assert got.dtype == torch.float64 and torch.equal(got, (mean + noise).clamp(low, high).to(torch.float64))
    greedy = agent.exploit(td)
    assert greedy.dtype == torch.float64 and torch.equal(greedy, mean.to(torch.float64))


def test_target_smoothing_draws_from_its_own_stream(monkeypatch):
    """update's smoothing noise is the seeds' "td3.smoothing" normal draws, (S, B, act_dim)."""
    from trl_dgpq.rng import SeedStreams, stream_id
    agent = TD3(TD3Config(**SMALL), [4, 9], 3, BOX2)
    seen = []
    monkeypatch.setattr(agent, "value_loss", lambda batch, noise: seen.append(noise) or
                        TD3.value_loss(agent, batch, noise))
    batch = batch_of(8, S=2)
    batch["action"] = torch.rand(2, 8, 2)
    agent.update(batch)
    assert torch.equal(seen[0], SeedStreams([4, 9], stream_id("td3.smoothing")).normal(8, 2).to(torch.float32))


def test_smoothed_target_actions_stay_in_the_box_on_both_faces():
    """noise_clip 10 half-widths: a huge draw either way lands each target action on that face."""
    agent = TD3(TD3Config(policy_noise=1.0, noise_clip=10.0, **SMALL), [0], 3, BOX2)
    obs = torch.randn(1, 5, 3)
    with torch.no_grad():
        up = agent.target_action(obs, torch.full((1, 5, 2), 1e6))
        down = agent.target_action(obs, torch.full((1, 5, 2), -1e6))
    assert torch.equal(up, torch.tensor([3.0, 1.0]).expand(1, 5, 2))
    assert torch.equal(down, torch.tensor([-2.0, 0.0]).expand(1, 5, 2))


def test_the_actor_loss_leaves_the_critics_without_gradients():
    agent = TD3(TD3Config(**SMALL), [0, 1], 3, SYM)
    agent.actor_loss(batch_of(8, S=2)).sum().backward()
    assert not agent.critic.flat.grad.any()  # the critics' gradient buffer untouched
    assert all(bool(p.grad.any()) for p in agent.actor.parameters())
    assert all(p.requires_grad for p in agent.critic.parameters())


def test_each_optimiser_steps_by_its_own_learning_rate():
    """Adam's first step moves each weight by at most its lr (|m / sqrt(v)| = 1), most by nearly
    that: the critics by critic_lr 0.05, the actor by actor_lr 0.02 (policy_delay 1)."""
    agent = TD3(TD3Config(critic_lr=0.05, actor_lr=0.02, policy_delay=1, **SMALL), [0, 1], 3, SYM)
    before = {k: v.clone() for k, v in agent.nets.state_dict().items()}
    agent.update(batch_of(8, S=2))
    after = agent.nets.state_dict()
    for name, lr in (("critic", 0.05), ("actor", 0.02)):
        steps = torch.cat([(after[k] - before[k]).abs().flatten() for k in before
                           if k.startswith(name + ".") and k.endswith(("weight", "bias"))])
        assert float(steps.max()) <= lr * 1.0001 and float(steps.max()) > lr * 0.99


def test_learning_starts_after_learning_starts_steps_as_the_papers_loop():
    """Fujimoto et al.'s loop trains once t >= start_timesteps (t from 0): the first update comes
    with the (learning_starts + 1)-th step, the step counter then at learning_starts + 1."""
    agent = TD3(TD3Config(learning_starts=5, batch_size=1, buffer_size=8, **SMALL), [0], 3, SYM)
    agent.steps = 5
    assert agent.wants_update() == 0
    agent.steps = 6
    assert agent.wants_update() == 1


def test_td3_names_itself_when_the_env_has_no_action_box():
    """resolve_config, make and memory_bytes each ask the env for a box as "td3" (the refusal names it)."""
    from trl_dgpq.envs import env_class
    info = env_class("square").describe()
    for call in (lambda: TD3.resolve_config(TD3Config(), info), lambda: TD3.make(TD3Config(), info, [0]),
                 lambda: TD3.memory_bytes(TD3Config(), info, 1)):
        with pytest.raises(ValueError, match="^td3 needs a continuous"):
            call()


def test_memory_estimate_counts_every_action_dimension():
    """An env of 3 observations and a 2-action box: 4 (2 x 3 + 2 + 1) + 2 = 38 bytes a transition."""
    class Info:
        observation_dim = 3

        @staticmethod
        def action_box(agent):
            return BOX2
    assert TD3.memory_bytes(TD3Config(buffer_size=10), Info(), 4) == 4 * 10 * 38


def test_a_buffer_smaller_than_a_minibatch_is_refused_by_name():
    with pytest.raises(ValueError, match="batch_size <= buffer_size, got 64 and 10"):
        TD3Config(batch_size=64, buffer_size=10).cross_check()


def test_an_earlier_versions_checkpoint_loads_each_optimisers_moments_into_its_buffer():
    """A checkpoint written before the flat buffers holds torch's Adam per layer tensor, in the
    order of actor.parameters() and critic.parameters(): loaded into a TD3, each moment lands
    in its own tensor's rows, for the actor and for the twin critics."""
    agent = TD3(TD3Config(policy_delay=1, **SMALL), [0, 1], 3, SYM)
    agent.update(batch_of(8, S=2))
    state = agent.state_dict()
    g = torch.Generator().manual_seed(7)
    old = []
    for params in (list(agent.actor.parameters()), list(agent.critic.parameters())):
        per = {i: dict(step=torch.tensor(1.0), exp_avg=torch.randn(p.shape, generator=g),
                       exp_avg_sq=torch.rand(p.shape, generator=g)) for i, p in enumerate(params)}
        old.append(dict(state=per, param_groups=[{**state["optimizers"][0]["param_groups"][0], "foreach": True,
                                                  "fused": None, "params": list(range(len(params)))}]))
    state["optimizers"] = old
    again = TD3(TD3Config(policy_delay=1, **SMALL), [0, 1], 3, SYM)
    again.load_state_dict(state)
    for optim, per in zip(again.optimizers, old):
        views = optim.seed_tensors()
        n = len(per["state"])
        assert len(views) == 2 * n
        for i in range(n):
            assert torch.equal(views[i], per["state"][i]["exp_avg"])
            assert torch.equal(views[n + i], per["state"][i]["exp_avg_sq"])
    again.update(batch_of(8, S=2))  # and it learns on from there
