"""Small direct checks of the seed-batched learners' parts (agents/neural.py, dqn.py, ddpg.py),
each against values computed here: torch's own nn.Linear, the seeds' random streams read by
hand, bytes counted in the replay's storage, a restored learner against the original.
(Fast: none trains for more than a few dozen steps.)"""
import pytest
import torch
from tensordict import TensorDict, TensorDictBase
from torch import nn
from torchrl.data import Bounded

from conftest import through_disk
from trl_dgpq.agents.ddpg import DDPG, Critic, DDPGConfig
from trl_dgpq.agents.dqn import DQN, DQNConfig
from trl_dgpq.agents.neural import (SeedLinear, SeedReplay, SeedStack, build_per_seed, clip_grad_norm_per_seed,
                                    keep_rows, seed_rows)
from trl_dgpq.collectors.experiment import build, memory_estimate, resolve_config
from trl_dgpq.rng import LEARNER_STREAM, SeedStreams, stream_id

# an action box with its seed dimension, as the envs give it: two actions, asymmetric bounds
BOX2 = Bounded(torch.tensor([[-1.0, 0.0]]), torch.tensor([[2.0, 0.5]]), shape=(1, 2))


def same_state(x, y, where="state"):
    """Nested dicts / lists / TensorDicts of tensors and plain values, equal to the last bit (NaN
    equal to NaN: the replay's rows not yet written hold whatever memory held)."""
    if isinstance(x, TensorDictBase):
        x, y = x.to_dict(), y.to_dict()
    if torch.is_tensor(x):
        torch.testing.assert_close(x, y, rtol=0, atol=0, equal_nan=True, msg=where)
    elif isinstance(x, dict):
        assert x.keys() == y.keys(), where
        for k in x:
            same_state(x[k], y[k], f"{where}.{k}")
    elif isinstance(x, (list, tuple)):
        assert len(x) == len(y), where
        for i, (u, v) in enumerate(zip(x, y)):
            same_state(u, v, f"{where}[{i}]")
    else:
        assert x == y, where


def transitions(steps, S, obs_dim=3, action=("discrete", 2), seed=0, done_at=()):
    """``steps`` transitions (S,) with float64 observations (as the envs give them); seed 1
    (if any) done at the steps in ``done_at``, seed 0 never."""
    g = torch.Generator().manual_seed(seed)
    out = []
    for t in range(steps):
        if action[0] == "discrete":
            a = torch.randint(action[1], (S,), generator=g)
        else:
            a = torch.rand(S, action[1], generator=g, dtype=torch.float64)
        done = torch.zeros(S, 1, dtype=torch.bool)
        if S > 1 and t in done_at:
            done[1] = True
        out.append(TensorDict({
            "observation": torch.rand(S, obs_dim, generator=g, dtype=torch.float64), "action": a,
            "next": {"observation": torch.rand(S, obs_dim, generator=g, dtype=torch.float64),
                     "reward": torch.rand(S, 1, generator=g, dtype=torch.float64),
                     "done": done, "terminated": done.clone()}}, batch_size=[S]))
    return out


def drive(agent, data, active=None):
    acts = []
    for t in data:
        acts.append(agent.act(t))
        agent.observe(t, active)
    return acts


# --- neural.py: the stacked layers ---------------------------------------------------------------

def test_seed_linear_is_each_seeds_nn_linear_on_any_batch_shape():
    """weight (S, in, out) holds each seed's nn.Linear weight transposed; an input (S, 2, 5, in)
    gives (S, 2, 5, out), seed i's slice = seed i's own layer on it."""
    g = torch.Generator().manual_seed(3)
    layers = [nn.Linear(4, 3) for _ in range(3)]
    with torch.no_grad():
        for layer in layers:
            layer.weight.copy_(torch.randn(3, 4, generator=g))
            layer.bias.copy_(torch.randn(3, generator=g))
    stacked = SeedLinear(layers)
    assert stacked.weight.shape == (3, 4, 3) and stacked.bias.shape == (3, 3)
    x = torch.randn(3, 2, 5, 4, generator=g)
    with torch.no_grad():
        y = stacked(x)
        assert y.shape == (3, 2, 5, 3)
        for i, layer in enumerate(layers):
            torch.testing.assert_close(y[i], x[i] @ layer.weight.T + layer.bias)


def test_a_stack_refuses_layers_it_cannot_stack_and_inputs_for_other_seed_counts():
    """Only nn.Linear layers carry parameters it can stack (a LayerNorm's would be silently
    shared); activations without parameters are fine. The seeds are the first dimension."""
    with pytest.raises(TypeError, match="LayerNorm"):
        SeedStack(build_per_seed(lambda: nn.Sequential(nn.Linear(2, 3), nn.LayerNorm(3)), [0, 1]))
    stack = SeedStack(build_per_seed(lambda: nn.Sequential(nn.Linear(2, 3), nn.Tanh(), nn.Linear(3, 1)), [0, 1]))
    assert stack.num_seeds == 2 and stack(torch.zeros(2, 4, 2)).shape == (2, 4, 1)
    with pytest.raises(ValueError, match=r"expected 2 seeds at dim 0, got input of shape \(3, 2\)"):
        stack(torch.zeros(3, 2))


def test_keep_rows_keeps_seed_rows_of_every_buffer_by_its_layout_and_nothing_when_no_row_is_kept():
    """Two buffers of one layout (parameters and a moment) and one of another; rows of 1-D biases
    kept like those of matrices; no row kept: nothing put back."""
    a = SeedStack(build_per_seed(lambda: nn.Sequential(nn.Linear(1, 2), nn.Linear(2, 1)), [0, 1, 2]))
    b = SeedStack(build_per_seed(lambda: nn.Sequential(nn.Linear(2, 1)), [0, 1, 2]))
    moment = torch.zeros_like(a.flat.data)
    bufs = [(a.flat.data, a.flat), (moment, a.flat), (b.flat.data, b.flat)]
    before = [t.clone() for t, _ in bufs]
    with keep_rows(lambda: bufs, torch.tensor([True, False, True])):
        for t, _ in bufs:
            t.add_(100)
    # by hand: a's layout: weight (3, 1, 2) at 0, bias (3, 2) at 16, weight (3, 2, 1) at 32, bias (3, 1) at 48;
    # b's: weight (3, 2, 1) at 0, bias (3, 1) at 16
    kept_a = [0, 1, 4, 5, 16, 17, 20, 21, 32, 33, 36, 37, 48, 50]
    kept_b = [0, 1, 4, 5, 16, 18]
    for (t, _), old, kept in zip(bufs, before, (kept_a, kept_a, kept_b)):
        moved = [i for i in range(len(t)) if i not in kept]
        assert torch.equal(t[kept], old[kept]) and torch.equal(t[moved], old[moved] + 100)
    with keep_rows(lambda: bufs, torch.zeros(3, dtype=torch.bool)):
        a.flat.data.mul_(2)
    assert torch.equal(a.flat.data[kept_a], 2 * before[0][kept_a])


def test_seed_rows_computes_those_seeds_alone_with_the_whole_batchs_bits():
    """Outputs and gradients of seeds 0 and 2 of 3 as the whole batch's, bit for bit; seed 1's
    gradient rows untouched (zero); the input must have their count of rows; afterwards every
    seed again. Checked against each seed's own nn.Sequential."""
    make = lambda: nn.Sequential(nn.Linear(3, 4), nn.ReLU(), nn.Linear(4, 2))  # noqa: E731
    stack = SeedStack(build_per_seed(make, [0, 1, 2]))
    x = torch.rand(3, 5, 3)
    stack(x).square().sum().backward()
    whole = [p.grad.clone() for p in stack.parameters()]
    stack.flat.grad.zero_()
    rows = torch.tensor([0, 2])
    with seed_rows(stack, rows):
        y = stack(x[rows])
        with pytest.raises(ValueError, match=r"expected 2 seeds at dim 0, got input of shape \(3, 5, 3\)"):
            stack(x)
    y.square().sum().backward()
    plain = build_per_seed(make, [2])[0]
    torch.testing.assert_close(y[1], plain(x[2]))   # seed 2's own network
    assert torch.equal(y, stack(x)[rows])
    for g, w in zip((p.grad for p in stack.parameters()), whole):
        assert torch.equal(g[rows], w[rows]) and not bool(g[1].any())
    assert stack(x).shape == (3, 5, 2)   # every seed again


def test_learned_buffers_refuse_a_network_with_parameters_outside_its_stacks():
    env, agent = build(resolve_config(env="liquidation", agent="ddpg", seeds=[0, 1], episodes=1))
    assert len(agent.learned_buffers()) == 4   # actor, critic and their targets; Adam's moments not made yet
    agent.nets["extra"] = nn.Linear(2, 2)
    with pytest.raises(TypeError, match="parameters outside its SeedStacks"):
        agent.learned_buffers()


def test_each_seeds_initial_weights_come_from_its_learner_stream_by_hand():
    """Seed i's network is built under torch.manual_seed(its learner stream's seed_for_torch), torch's
    global generator left where it was."""
    make = lambda: nn.Sequential(nn.Linear(3, 4), nn.ReLU(), nn.Linear(4, 2))  # noqa: E731
    before = torch.random.get_rng_state()
    nets = build_per_seed(make, [5, 11])
    assert torch.equal(torch.random.get_rng_state(), before)
    for net, torch_seed in zip(nets, SeedStreams([5, 11], LEARNER_STREAM).seed_for_torch()):
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(torch_seed)
            expect = make()
        assert all(torch.equal(p, q) for p, q in zip(net.parameters(), expect.parameters()))


def test_a_stack_leaves_the_seeds_own_networks_as_they_were():
    """Stacking copies: the per-seed networks it was built from keep their nn.Linear layers and
    compute what they did."""
    nets = build_per_seed(lambda: nn.Sequential(nn.Linear(3, 4), nn.ReLU(), nn.Linear(4, 2)), [0, 1])
    x = torch.rand(5, 3, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        before = [net(x) for net in nets]
        stack = SeedStack(nets)
        assert all(type(net[0]) is nn.Linear and type(net[2]) is nn.Linear for net in nets)
        assert all(torch.equal(net(x), b) for net, b in zip(nets, before))
        torch.testing.assert_close(stack(torch.stack([x, x]))[0], before[0])


def test_clipping_tiny_gradients_is_torchs_with_its_epsilon():
    """Norms near 1e-5, one parameter tensor: the 1e-6 in max_norm / (norm + 1e-6) weighs 5-10 %
    here, and the clipped gradients equal torch's clip_grad_norm_ per seed."""
    g = torch.Generator().manual_seed(7)
    p = nn.Parameter(torch.zeros(2, 4))
    grad = torch.randn(2, 4, generator=g)
    grad = grad / grad.norm(dim=1, keepdim=True) * torch.tensor([[2e-5], [5e-6]])  # seed 0 above, seed 1 below
    p.grad = grad.clone()
    norms = clip_grad_norm_per_seed([p], max_norm=1e-5)
    for i in range(2):
        ref = nn.Parameter(torch.zeros(4))
        ref.grad = grad[i].clone()
        expect = nn.utils.clip_grad_norm_([ref], 1e-5)
        assert float(norms[i]) == pytest.approx(float(expect), rel=1e-5)
        torch.testing.assert_close(p.grad[i], ref.grad, rtol=1e-6, atol=0)
    assert float(p.grad[0].norm()) == pytest.approx(1e-5 * 2e-5 / (2e-5 + 1e-6), rel=1e-5)


# --- neural.py: the replay ---------------------------------------------------------------------

def test_replay_rows_are_the_seeds_own_replay_stream_drawn_by_hand():
    """Row of each draw = floor(u * stored) with u the seed's 'neural.replay' stream; before the
    memory is full over what is stored only, after wrapping over all capacity rows (row r then
    holds the latest step written there)."""
    replay = SeedReplay(capacity=10, seeds=[2, 9])
    rng = SeedStreams([2, 9], stream_id("neural.replay"))
    add = lambda t: replay.add(TensorDict({"x": torch.tensor([[t], [1000.0 + t]])}, batch_size=[2]))  # noqa: E731
    for t in range(6):
        add(float(t))
    assert len(replay) == 6 and replay.written == 6
    rows = (rng.uniform(50) * 6).long()
    got = replay.sample(50)["x"][..., 0]
    assert torch.equal(got, torch.stack([rows[0].double(), rows[1].double() + 1000]).to(got.dtype))
    for t in range(6, 13):  # steps 10, 11, 12 overwrite rows 0, 1, 2
        add(float(t))
    assert len(replay) == 10 and replay.written == 13
    rows = (rng.uniform(200) * 10).long()
    step = torch.where(rows < 3, rows + 10, rows).double()
    got = replay.sample(200)["x"][..., 0]
    assert torch.equal(got, torch.stack([step[0], step[1] + 1000]).to(got.dtype))
    assert set(rows[0].tolist()) == set(range(10))


def test_a_restored_replay_holds_and_draws_what_the_original_does():
    replay = SeedReplay(capacity=5, seeds=[0, 1])
    for t in range(7):
        replay.add(TensorDict({"x": torch.full((2, 1), float(t))}, batch_size=[2]))
    replay.sample(3)
    fresh = SeedReplay(capacity=5, seeds=[0, 1])
    fresh.load_state_dict(through_disk(replay.state_dict()))
    assert (len(fresh), fresh.written) == (5, 7)
    for r in (replay, fresh):
        r.add(TensorDict({"x": torch.full((2, 1), 7.0)}, batch_size=[2]))  # overwrites row 2 (step 2)
    assert torch.equal(fresh.sample(40)["x"], replay.sample(40)["x"])
    assert sorted(set(fresh.storage[:]["x"][:, 0, 0].tolist())) == [3.0, 4.0, 5.0, 6.0, 7.0]


# --- neural.py: the learner base ----------------------------------------------------------------

def test_the_stored_transition_is_float32_with_its_flags_and_actions_as_they_were():
    agent = DQN(DQNConfig(hidden=(4,), learning_starts=100), [0, 1], 3, 2)
    td = transitions(1, 2)[0]
    td["next", "truncated"] = torch.zeros(2, 1, dtype=torch.bool)  # an entry not stored
    stored = agent.stored(td)
    assert set(stored.keys(True, True)) == {"observation", "action", ("next", "observation"), ("next", "reward"),
                                            ("next", "done"), ("next", "terminated")}
    for key in ("observation", ("next", "observation"), ("next", "reward")):
        assert stored[key].dtype == torch.float32
        torch.testing.assert_close(stored[key], td[key].float(), rtol=0, atol=0)
    assert stored["action"].dtype == torch.long and torch.equal(stored["action"], td["action"])
    assert stored["next", "done"].dtype == torch.bool and stored["next", "terminated"].dtype == torch.bool


def test_observe_counts_updates_of_active_seeds_and_remembers_who_starts_an_episode():
    """DQN, an update after every step from the 3rd (learning_starts 2): after 6 steps 4 updates,
    seed 1 inactive for the last 2 has 2; new_episode is the last step's done."""
    agent = DQN(DQNConfig(hidden=(4,), batch_size=2, learning_starts=2, train_freq=1, gradient_steps=1), [0, 1], 3, 2)
    data = transitions(6, 2, done_at=(5,))
    drive(agent, data[:4])
    assert agent.updates.tolist() == [2, 2] and agent.steps == 4
    assert agent.new_episode.tolist() == [False, False]
    drive(agent, data[4:], active=torch.tensor([True, False]))
    assert agent.updates.tolist() == [4, 2] and agent.steps == 6
    assert agent.updates.dtype == torch.long  # counts, written as integers
    assert agent.new_episode.tolist() == [False, True]
    # the target follows by copies only: no gradient ever reaches it
    assert all(not p.requires_grad and p.grad is None for p in agent.target.parameters())
    stats = agent.episode_stats()["updates"]
    stats += 1  # a copy, not the learner's own counter
    assert agent.updates.tolist() == [4, 2]


def make_dqn(seeds):
    return DQN(DQNConfig(hidden=(8,), batch_size=4, buffer_size=50, learning_starts=3, train_freq=2, gradient_steps=2,
                         target_update_interval=5, eps_init=0.9, eps_end=0.3, exploration_steps=20), seeds, 3, 2)


def make_ddpg(seeds):
    return DDPG(DDPGConfig(actor_hidden=(8,), critic_hidden=(8, 8), batch_size=4, buffer_size=50, ou_sigma=0.3),
                seeds, 3, BOX2)


@pytest.mark.parametrize("make, action", [(make_dqn, ("discrete", 2)), (make_ddpg, ("box", 2))], ids=["dqn", "ddpg"])
def test_a_restored_learner_is_the_original_and_continues_as_it(make, action):
    """12 steps (seed 1's episode ends at the 12th, seed 0's goes on), saved through a file, loaded
    into a fresh learner: its state is the saved one, and 10 more steps give the same actions
    (exploration streams, OU noise, epsilon) and the same networks, optimisers, replay."""
    data = transitions(22, 2, action=action, seed=4, done_at=(11,))
    a = make([0, 1])
    drive(a, data[:12])
    state = through_disk(a.state_dict())
    b = make([0, 1])
    b.load_state_dict(state)
    same_state(b.state_dict(), state)
    nets = {"dqn": {"qnet", "target"}, "ddpg": {"actor", "critic", "target_actor", "target_critic"}}
    assert {k.split(".")[0] for k in state["nets"]} == nets[type(a).__name__.lower()]  # checkpoints' names
    assert b.steps == 12 and b.new_episode.tolist() == [False, True]
    acts_a, acts_b = drive(a, data[12:]), drive(b, data[12:])
    assert all(torch.equal(x, y) for x, y in zip(acts_a, acts_b))
    same_state(a.state_dict(), b.state_dict())
    assert int(a.updates[0]) > 4
    with pytest.raises(ValueError, match=f"{type(a).__name__.lower()} state is for 2 seeds, not 3"):
        make([0, 1, 2]).load_state_dict(state)
    with pytest.raises(ValueError, match=r"^this checkpoint holds one learner per seed \(an earlier version\); it "
                                         r"cannot be resumed by the seed-batched learners: start the run again$"):
        make([0, 1]).load_state_dict({**state, "learners": [{}, {}]})


# --- dqn.py -----------------------------------------------------------------------------------------

def test_dqn_explores_with_its_own_stream_by_hand():
    """Each action draws two uniforms (u0, u1) from the seed's 'dqn.explore' stream: the random
    action floor(u1 n_actions) is taken if u0 < epsilon (and always in the warm-up), else the
    greedy one. Epsilon 0.9 falling to 0.3 over 20 steps (after t steps: 0.3 + 0.6 (1 - t / 20))."""
    agent = DQN(DQNConfig(hidden=(8,), eps_init=0.9, eps_end=0.3, exploration_steps=20, learning_starts=2,
                          train_freq=1000, target_update_interval=1000), list(range(6)), 3, 5)
    rng = SeedStreams(list(range(6)), stream_id("dqn.explore"))
    explored = 0
    for t, td in enumerate(transitions(30, 6, action=("discrete", 5), seed=1)):
        eps = 0.3 + 0.6 * max(0.0, 1 - t / 20)
        assert agent.eps == pytest.approx(eps, abs=1e-12)
        u = rng.uniform(2)
        random = (u[:, 1] * 5).long()
        greedy = agent.greedy(td["observation"])
        explore = u[:, 0] < eps if t >= 2 else torch.ones(6, dtype=torch.bool)
        assert torch.equal(agent.act(td), torch.where(explore, random, greedy)), t
        assert torch.equal(agent.exploit(td), greedy)
        explored += int(((random != greedy) & explore).sum())
        agent.observe(td)
    assert explored > 20


def test_dqn_settings_at_their_bounds_are_accepted_and_beyond_them_refused_in_words():
    DQNConfig(batch_size=8, buffer_size=8).cross_check()
    DQNConfig(eps_init=0.2, eps_end=0.2).cross_check()
    with pytest.raises(ValueError, match="need 1 <= batch_size <= buffer_size, got 9 and 8"):
        DQNConfig(batch_size=9, buffer_size=8).cross_check()
    with pytest.raises(ValueError, match="need 0 <= eps_end <= eps_init <= 1, got 0.3 and 0.2"):
        DQNConfig(eps_init=0.2, eps_end=0.3).cross_check()


def test_dqn_built_for_an_env_takes_its_observations_and_actions():
    env, agent = build(resolve_config(env="square", agent="dqn", seeds=[0, 1], hidden=(8,)))
    td = env.reset()
    first, last = agent.qnet.net[0], agent.qnet.net[-1]
    assert first.weight.shape == (2, env.info.observation_dim, 8)
    assert last.weight.shape == (2, 8, env.info.num_actions("dqn")) == (2, 8, agent.n_actions)
    assert agent.act(td).shape == (2,)


# --- ddpg.py ------------------------------------------------------------------------------------

def test_ddpg_exploit_is_each_seeds_actor_mapped_onto_the_box_without_noise():
    """low + (high - low) (tanh(mlp(s)) + 1) / 2 per action with seed i's own MLP, float64; the OU
    noise and its stream are not touched."""
    agent = make_ddpg([3, 6])
    mlps = build_per_seed(lambda: nn.ModuleList([nn.Sequential(nn.Linear(3, 8), nn.ReLU(), nn.Linear(8, 2))]), [3, 6])
    obs = torch.rand(2, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    got = agent.exploit(TensorDict({"observation": obs}, batch_size=[2]))
    assert got.dtype == torch.float64 and got.shape == (2, 2)
    low, high = torch.tensor([-1.0, 0.0]), torch.tensor([2.0, 0.5])
    with torch.no_grad():
        for i in range(2):
            raw = mlps[i][0](obs[i].float())
            torch.testing.assert_close(got[i].float(), low + (high - low) * (raw.tanh() + 1) / 2)
    assert agent.noise_rng.counter == 0 and not agent.noise.any()


def test_ddpg_act_adds_the_noise_and_clips_to_the_box():
    """sigma 5: most noisy actions leave the box and are clipped onto its bounds, per action."""
    agent = DDPG(DDPGConfig(actor_hidden=(8,), critic_hidden=(8, 8), ou_sigma=5.0), list(range(8)), 3, BOX2)
    td = TensorDict({"observation": torch.rand(8, 3, dtype=torch.float64)}, batch_size=[8])
    pure = agent.exploit(td)
    low, high = torch.tensor([-1.0, 0.0], dtype=torch.float64), torch.tensor([2.0, 0.5], dtype=torch.float64)
    for _ in range(3):
        got = agent.act(td)
        assert got.dtype == torch.float64
        expect = torch.minimum(torch.maximum(pure + agent.noise.double(), low), high)
        torch.testing.assert_close(got, expect, rtol=1e-6, atol=1e-6)
    assert bool((got == low).any()) and bool((got == high).any()) and bool(((got > low) & (got < high)).any())


def test_ddpg_memory_estimate_is_the_full_replay_as_stored():
    """Liquidation (8 observations, 1 action), 3 seeds, a buffer of 8 filled by 8 steps: per
    transition observation and next (2 x 8 float32), action and reward (float32), done and
    terminated (bool): 64 + 4 + 4 + 2 = 74 bytes, 3 x 8 x 74 = 1776, as the estimate says."""
    config = resolve_config(env="liquidation", agent="ddpg", seeds=[0, 1, 2], buffer_size=8, batch_size=8)
    env, agent = build(config)
    td = env.reset()
    assert env.info.observation_dim == 8
    for _ in range(8):
        td["action"] = agent.act(td)
        td, td_next = env.step_and_maybe_reset(td)
        agent.observe(td)
        td = td_next
    stored = agent.replay.storage._storage
    assert sum(t.nbytes for t in stored.values(True, True)) == 3 * 8 * (2 * 8 * 4 + 4 + 4 + 2) == 1776
    assert memory_estimate(config) == 1776


def test_ddpg_memory_estimate_counts_every_action_dimension():
    """Two actions, 3 observations, 2 seeds, a buffer of 6: 2 x 3 x 4 + 2 x 4 + 4 + 2 = 38 bytes a
    transition, 2 x 6 x 38 = 456, as stored."""
    class Info:
        observation_dim = 3

        @staticmethod
        def action_box(who):
            return BOX2
    cfg = DDPGConfig(actor_hidden=(4,), critic_hidden=(4, 4), buffer_size=6, batch_size=6)
    agent = DDPG(cfg, [0, 1], 3, BOX2)
    for td in transitions(6, 2, action=("box", 2)):
        agent.observe(td)
    stored = agent.replay.storage._storage
    assert sum(t.nbytes for t in stored.values(True, True)) == 2 * 6 * 38 == 456
    assert DDPG.memory_bytes(cfg, Info, 2) == 456


def test_ddpg_actions_at_the_top_of_the_box_stay_inside_it():
    """Box [-0.3, 1.1] and an actor saturated (tanh = 1): -0.3 + (1.1 + 0.3) is 1.2e-7 above 1.1 in
    float32; the action given, with or without noise, is 1.1 itself, never outside the box."""
    box = Bounded(torch.tensor([[-0.3]]), torch.tensor([[1.1]]), shape=(1, 1))
    agent = DDPG(DDPGConfig(actor_hidden=(4,), critic_hidden=(4, 4), ou_sigma=0.0), [0, 1], 3, box)
    with torch.no_grad():
        agent.actor.mlp.net[-1].bias.fill_(50.0)
    td = TensorDict({"observation": torch.rand(2, 3, dtype=torch.float64)}, batch_size=[2])
    high = torch.tensor(1.1, dtype=torch.float32).double()
    assert float(agent.actor(td["observation"].float()).max()) > 1.1  # the map alone overshoots
    assert bool((agent.exploit(td) == high).all()) and bool((agent.act(td) == high).all())


def test_ddpg_batch_size_up_to_the_buffer_is_accepted():
    DDPGConfig(batch_size=8, buffer_size=8).cross_check()
    with pytest.raises(ValueError, match="need 1 <= batch_size <= buffer_size, got 9 and 8"):
        DDPGConfig(batch_size=9, buffer_size=8).cross_check()



def test_the_agents_name_themselves_when_the_env_has_the_other_kind_of_actions():
    square = build(resolve_config(env="square", agent="random", seeds=[0]))[0].info
    liquidation = build(resolve_config(env="liquidation", agent="ddpg", seeds=[0]))[0].info
    for call in (lambda: DDPG.resolve_config(DDPGConfig(), square), lambda: DDPG.make(DDPGConfig(), square, [0])):
        with pytest.raises(ValueError, match="ddpg needs a continuous"):
            call()
    for call in (lambda: DQN.resolve_config(DQNConfig(), liquidation), lambda: DQN.make(DQNConfig(), liquidation, [0])):
        with pytest.raises(ValueError, match="dqn needs discrete actions"):
            call()


def test_ddpg_critic_by_hand():
    """Q(s, a) = W3 relu(W2 [relu(W1 s + b1), a] + b2) + b3 from the critic's own layers (ReLU
    both times, not the MLP's default tanh)."""
    critic = Critic(3, 2, (5, 4))
    g = torch.Generator().manual_seed(1)
    s, a = torch.randn(6, 3, generator=g), torch.randn(6, 2, generator=g)
    l1, l2, l3 = critic.state[0], critic.head[0], critic.head[2]
    relu = lambda x: x.clamp(min=0)  # noqa: E731
    with torch.no_grad():
        h = relu(s @ l1.weight.T + l1.bias)
        expect = relu(torch.cat([h, a], 1) @ l2.weight.T + l2.bias) @ l3.weight.T + l3.bias
        torch.testing.assert_close(critic(s, a), expect)
        assert bool((s @ l1.weight.T + l1.bias < 0).any())  # the ReLUs bite


def test_course_initial_weights_take_both_signs():
    """uniform(-lim, lim): weights of every layer spread over both signs, near both ends."""
    agent = DDPG(DDPGConfig(init="course"), list(range(4)), 8, BOX2)
    for net in (agent.actor, agent.critic):
        for name, w in net.state_dict().items():
            if name.endswith("weight"):
                lim = 3e-3 if w.shape[2] == 1 or (net is agent.actor and w.shape[2] == 2) else 1 / w.shape[2] ** 0.5
                assert float(w.min()) < -0.8 * lim and float(w.max()) > 0.8 * lim, name


@pytest.mark.parametrize("inp, out, batch", [(48, 1, 128), (256, 1, 256)])
def test_a_stack_of_one_seed_computes_as_that_seed_in_a_batch(inp, out, batch):
    """At DDPG's and TD3's output layers torch's product of a single matrix (a batch of one) has
    other last bits than the same matrix's in a batch of more: a stack of one seed gives the
    outputs and gradients (weight, bias, input) that seed gets in a stack of three."""
    g = torch.Generator().manual_seed(inp * out)
    layers = [nn.Linear(inp, out) for _ in range(3)]
    with torch.no_grad():
        for layer in layers:
            layer.weight.copy_(torch.randn(out, inp, generator=g))
            layer.bias.copy_(torch.randn(out, generator=g))
    x, grad_y = torch.randn(3, batch, inp, generator=g), torch.randn(3, batch, out, generator=g)
    results = []
    for stack, xs, gy in ((SeedLinear(layers), x, grad_y), (SeedLinear(layers[:1]), x[:1], grad_y[:1])):
        xs = xs.clone().requires_grad_(True)
        y = stack(xs)
        y.backward(gy)
        results.append([t[0] for t in (y, stack.weight.grad, stack.bias.grad, xs.grad)])
    for batched, alone in zip(*results):
        assert torch.equal(batched, alone)

def test_an_update_with_finished_seeds_is_computed_for_the_active_ones_only():
    """While seed 0 of 3 has finished, each update gets the minibatch of seeds 1 and 2 (2, B) and
    the stacks compute those rows; with every seed active, all of them; after, nothing is left set."""
    env, agent = build(resolve_config(env="liquidation", agent="ddpg", seeds=[0, 1, 2], episodes=1, batch_size=4,
                                      buffer_size=50))
    seen, update = [], agent.update
    agent.update = lambda batch: (seen.append((tuple(batch.shape), agent.updating, agent.actor.mlp.rows)),
                                  update(batch))
    td = env.reset()
    for active in ([True] * 3,) * 5 + ([False, True, True],) * 2:
        td["action"] = agent.act(td)
        out, td = env.step_and_maybe_reset(td)
        agent.observe(out, torch.tensor(active))
    assert [s for s, _, _ in seen] == [(3, 4), (3, 4), (2, 4), (2, 4)]
    assert seen[0][1] is None and seen[0][2] is None
    assert seen[-1][1].tolist() == [1, 2] and seen[-1][2].tolist() == [1, 2]
    assert agent.updating is None and agent.actor.mlp.rows is None
