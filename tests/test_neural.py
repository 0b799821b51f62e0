"""The seed-batched neural learners' shared parts, each against an independent
computation: per-seed Adam, torch's own clip_grad_norm_ per seed, per-seed means,
per-seed replay, frozen finished seeds, and a seed alone = the seed in any batch."""
import pandas as pd
import pytest
import torch
from tensordict import TensorDict
from torch import nn

from trl_dgpq.agents.neural import (SeedReplay, SeedStack, build_per_seed, clip_grad_norm_per_seed, keep_rows,
                                    seed_mean)
from trl_dgpq.collectors.experiment import TIMING_COLUMNS, build, resolve_config, run_experiment
from trl_dgpq.collectors.online import OnlineCollector


def test_adam_on_stacked_parameters_is_adam_per_seed():
    g = torch.Generator().manual_seed(0)
    stacked = nn.Parameter(torch.randn(3, 5, 4, generator=g))
    alone = [nn.Parameter(stacked.detach()[i].clone()) for i in range(3)]
    opt = torch.optim.Adam([stacked], lr=0.1)
    opts = [torch.optim.Adam([p], lr=0.1) for p in alone]
    for _ in range(4):
        grad = torch.randn(3, 5, 4, generator=g)
        stacked.grad = grad.clone()
        opt.step()
        for i, (p, o) in enumerate(zip(alone, opts)):
            p.grad = grad[i].clone()
            o.step()
    assert all(torch.equal(stacked.detach()[i], alone[i].detach()) for i in range(3))


def test_gradient_clipping_is_torchs_per_seed():
    g = torch.Generator().manual_seed(1)
    params = [nn.Parameter(torch.zeros(3, 4, 2)), nn.Parameter(torch.zeros(3, 6))]
    grads = [torch.randn(3, 4, 2, generator=g) * s for s in (1.0, 5.0) for _ in [0]][:1] + [torch.randn(3, 6,
                                                                                                     generator=g)]
    grads[0][1] *= 100  # seed 1 clipped hard, seed 0 and 2 less or not at all
    for p, gr in zip(params, grads):
        p.grad = gr.clone()
    norms = clip_grad_norm_per_seed(params, max_norm=3.0)
    for i in range(3):
        ref = [nn.Parameter(torch.zeros_like(p[i])) for p in params]
        for r, gr in zip(ref, grads):
            r.grad = gr[i].clone()
        expect = nn.utils.clip_grad_norm_(ref, 3.0)
        assert float(norms[i]) == pytest.approx(float(expect), rel=1e-6)
        for r, p in zip(ref, params):
            torch.testing.assert_close(p.grad[i], r.grad, rtol=1e-6, atol=0)
    assert float(norms[1]) > 3.0 and params[0].grad[1].norm() < grads[0][1].norm() / 10


def test_a_seed_below_the_clip_threshold_is_left_exactly_as_it_was():
    """Seed 0's norm is under max_norm, seed 1's over: seed 0's gradients are bit for bit what they
    were (the scale is capped at 1, never above), seed 1's are scaled down to the threshold."""
    g = torch.Generator().manual_seed(2)
    params = [nn.Parameter(torch.zeros(2, 5, 3)), nn.Parameter(torch.zeros(2, 3))]
    grads = [torch.randn(2, 5, 3, generator=g), torch.randn(2, 3, generator=g)]
    grads[0][0] *= 0.01
    grads[1][0] *= 0.01
    grads[0][1] *= 10
    for p, gr in zip(params, grads):
        p.grad = gr.clone()
    norms = clip_grad_norm_per_seed(params, max_norm=1.0)
    assert float(norms[0]) < 1.0 < float(norms[1])
    assert all(torch.equal(p.grad[0], gr[0]) for p, gr in zip(params, grads))
    clipped = torch.cat([p.grad[1].flatten() for p in params]).norm()
    assert float(clipped) == pytest.approx(1.0, rel=1e-5)


def test_a_frozen_seed_keeps_its_weights_and_adams_moments_exactly():
    """Seeds 0-2 learn together, then seed 1 finishes: through later updates of the others its
    network, its target and Adam's first and second moments stay bit for bit as they were.
    (Adam's step count is one scalar, shared by the seeds; a frozen seed never
    steps again -- lengthening a run continues from before any seed stopped.)"""
    env, agent = build(resolve_config(seeds=[0, 1, 2], **dict(DQN_SMALL, learning_starts=4, batch_size=4)))
    td = env.reset()
    active = torch.ones(3, dtype=torch.bool)
    frozen = None
    for t in range(40):
        td["action"] = agent.act(td)
        out, td = env.step_and_maybe_reset(td)
        if t == 20:
            active[1] = False
            frozen = [x[1].clone() for x in agent.nets.state_dict().values()]
            moments = [v[1].clone() for v in agent.optimizers[0].seed_tensors()]
        agent.observe(out, active)
    now = [x[1] for x in agent.nets.state_dict().values()]
    assert len(now) == 12 and all(torch.equal(a, b) for a, b in zip(now, frozen))  # network and target
    now_moments = [v[1] for v in agent.optimizers[0].seed_tensors()]
    assert len(moments) == 12 and all(torch.equal(a, b) for a, b in zip(now_moments, moments))
    assert all(bool(v.any()) for v in moments)  # it had learned: its moments are not the zeros they start as
    assert int(agent.updates[1]) < int(agent.updates[0])  # the others went on learning


def test_seed_mean_is_the_sum_of_each_seeds_mean():
    loss = torch.rand(3, 16)  # (S, B)
    assert float(seed_mean(loss)) == pytest.approx(sum(float(loss[i].mean()) for i in range(3)), rel=1e-6)
    assert torch.equal(seed_mean(loss[1:2]), loss[1].mean())


def test_a_stack_computes_each_seeds_own_network():
    nets = build_per_seed(lambda: nn.Sequential(nn.Linear(3, 5), nn.ReLU(), nn.Linear(5, 2)), [4, 7])
    plain = build_per_seed(lambda: nn.Sequential(nn.Linear(3, 5), nn.ReLU(), nn.Linear(5, 2)), [7])[0]
    stack = SeedStack(nets)
    x = torch.rand(2, 6, 3)
    with torch.no_grad():
        torch.testing.assert_close(stack(x)[1], plain(x[1]))  # seed 7's net, whatever its position
        assert not torch.allclose(stack(x)[0], plain(x[0]))
        torch.testing.assert_close(stack(x[:, 0])[1], plain(x[1, 0]))  # one row per seed (acting)


def test_replay_samples_each_seeds_own_transitions_uniformly():
    replay = SeedReplay(capacity=4, seeds=[0, 1])
    for t in range(6):  # wraps: rows hold steps 4, 5, 2, 3
        replay.add(TensorDict({"x": torch.tensor([[100.0 + t], [200.0 + t]])}, batch_size=[2]))
    assert len(replay) == 4
    batch = replay.sample(4000)["x"][..., 0]  # (S, B)
    assert batch.shape == (2, 4000)
    assert set(batch[0].tolist()) == {102.0, 103.0, 104.0, 105.0}
    assert set(batch[1].tolist()) == {202.0, 203.0, 204.0, 205.0}
    counts = torch.bincount(batch[0].long() - 102)
    assert counts.min() > 850  # uniform: ~1000 each
    alone = SeedReplay(capacity=4, seeds=[1])
    for t in range(6):
        alone.add(TensorDict({"x": torch.tensor([[200.0 + t]])}, batch_size=[1]))
    fresh = SeedReplay(capacity=4, seeds=[0, 1])
    fresh.load_state_dict(replay.state_dict())
    replay.rng.counter = alone.rng.counter = 0
    assert torch.equal(replay.sample(7)["x"][1], alone.sample(7)["x"][0])  # a seed's draws are its own


def test_keep_rows_restores_finished_seeds_only():
    stack = SeedStack(build_per_seed(lambda: nn.Sequential(nn.Linear(2, 3)), [0, 1, 2]))
    t = stack.flat.data
    before = t.clone()
    with keep_rows(lambda: [(t, stack.flat)], torch.tensor([False, True, False])):
        t.add_(10)
    # by hand: the weights (3, 2, 3) at 0-17, padding to 32 (whole lines of 16), the biases (3, 3) at 32-40
    kept = list(range(6, 12)) + list(range(35, 38))
    changed = [i for i in range(48) if i not in kept]
    assert torch.equal(t[kept], before[kept]) and torch.equal(t[changed], before[changed] + 10)


DQN_SMALL = dict(env="gym:CartPole-v1", agent="dqn", batch_size=16, learning_starts=32, train_freq=1,
                 gradient_steps=2, hidden=(64, 64), exploration_steps=200, target_update_interval=50,
                 max_grad_norm=0.5, episodes=8)
DDPG_SMALL = dict(env="liquidation", agent="ddpg", trades=15, batch_size=8, buffer_size=100, episodes=6)
TD3_SMALL = dict(env="liquidation", agent="td3", trades=15, batch_size=8, buffer_size=100, learning_starts=20,
                 actor_hidden=(16,), critic_hidden=(16, 16), episodes=6)


@pytest.mark.parametrize("cfg", [DQN_SMALL, DDPG_SMALL, TD3_SMALL], ids=["dqn", "ddpg", "td3"])
def test_seed_alone_equals_seed_in_batches_of_2_3_8(cfg):
    """Bitwise: episodes, and the finished learner's every tensor (a finished seed is frozen,
    so the batch's copy of it is the lone run's)."""
    def run(seeds):
        config = resolve_config(seeds=seeds, **cfg)
        env, agent = build(config)
        df = OnlineCollector(env, agent, cfg["episodes"], progress=False).run()
        state = {**agent.nets.state_dict(), "updates": agent.updates}
        return df[df.seed == 1].reset_index(drop=True).drop(columns=list(TIMING_COLUMNS)), \
            {k: v[seeds.index(1)] for k, v in state.items() if k.endswith(("weight", "bias", "updates"))}, df
    alone, alone_state, _ = run([1])
    assert alone.updates.iloc[-1] > 20
    for seeds in ([0, 1], [5, 1, 2], [3, 4, 5, 6, 7, 8, 9, 1]):
        rows, state, df = run(seeds)
        pd.testing.assert_frame_equal(rows, alone)
        assert state.keys() == alone_state.keys() and all(torch.equal(state[k], alone_state[k]) for k in state)
        assert df.groupby("seed").steps.sum().nunique() > 1 or cfg["env"] == "liquidation"  # seeds finished apart


@pytest.mark.parametrize("cfg", [DQN_SMALL, DDPG_SMALL, TD3_SMALL], ids=["dqn", "ddpg", "td3"])
def test_a_seed_learning_beside_finished_ones_is_the_seed_alone(cfg):
    """Bitwise, for every learner: seed 1 learns in a batch whose seeds 0 and 2 finish at steps 40
    and 50 (their updates left out of the batch's products from then on, ``seed_rows``) and ends
    with the networks, targets and Adam moments it has alone; the finished seeds keep theirs as
    they stopped with. (Liquidation's episodes are all as long here, so the run-level test above
    never has a seed finish before another for DDPG and TD3.)"""
    def seed_tensors(agent):   # the networks' and targets' weights and biases, Adam's moments
        return [x for k, x in agent.nets.state_dict().items() if k.endswith(("weight", "bias"))] + [
            x for o in agent.optimizers for x in o.seed_tensors()]

    def run(seeds, stop=None):
        env, agent = build(resolve_config(seeds=seeds, **cfg))
        td, active, kept = env.reset(), torch.ones(len(seeds), dtype=torch.bool), {}
        for t in range(70):
            for i, at in (stop or {}).items():
                if t == at:
                    active[i] = False
                    kept[i] = [x[i].clone() for x in seed_tensors(agent)]
            td["action"] = agent.act(td)
            out, td = env.step_and_maybe_reset(td)
            agent.observe(out, active)
        return agent, kept
    alone, _ = run([1])
    batch, kept = run([0, 1, 2], stop={0: 40, 2: 50})
    tensors = seed_tensors(batch)
    assert len(tensors) == len(seed_tensors(alone)) > 8
    assert all(torch.equal(b[1], a[0]) for b, a in zip(tensors, seed_tensors(alone)))
    for i in (0, 2):
        assert all(torch.equal(b[i], k) for b, k in zip(tensors, kept[i]))
    assert int(alone.updates[0]) > int(batch.updates[2]) > int(batch.updates[0]) > 0


def test_the_last_seed_learning_at_ddpgs_own_sizes_is_the_seed_in_the_whole_batch():
    """At DDPG's liquidation widths (24, 48) and minibatch of 128, torch's batched product of one
    matrix has other last bits than the same matrix's in a batch of more: the last seed learning
    (seeds 0 and 2 finished at steps 140 and 150) must still be updated beside another row, so
    that its networks and Adam's moments are those of the batch where no seed finished."""
    cfg = dict(env="liquidation", agent="ddpg", batch_size=128, buffer_size=1_000, episodes=10)

    def run(stop):
        env, agent = build(resolve_config(seeds=[0, 1, 2], **cfg))
        td, active = env.reset(), torch.ones(3, dtype=torch.bool)
        for t in range(170):
            for i, at in stop.items():
                active[i] &= t != at
            td["action"] = agent.act(td)
            out, td = env.step_and_maybe_reset(td)
            agent.observe(out, active)
        return [x[1] for x in agent.nets.state_dict().values() if x.dim() > 1] + [
            x[1] for o in agent.optimizers for x in o.seed_tensors()]
    assert all(torch.equal(a, b) for a, b in zip(run({0: 140, 2: 150}), run({})))


def test_one_seed_of_ddpg_at_its_real_sizes_learns_as_in_a_batch():
    """DDPG at liquidation's defaults ((24, 48) networks, minibatches of 128), where torch's product
    of one matrix rounds otherwise than a batch's: seed 1 run alone for 170 steps (40 updates) ends
    with the networks and Adam moments it has in a batch of seeds 0-2."""
    cfg = dict(env="liquidation", agent="ddpg", batch_size=128, buffer_size=1_000, episodes=10)

    def run(seeds):
        env, agent = build(resolve_config(seeds=seeds, **cfg))
        td = env.reset()
        for _ in range(170):
            td["action"] = agent.act(td)
            out, td = env.step_and_maybe_reset(td)
            agent.observe(out)
        i = seeds.index(1)
        return [x[i] for x in agent.nets.state_dict().values() if x.dim() > 1] + [
            x[i] for o in agent.optimizers for x in o.seed_tensors()]
    assert all(torch.equal(a, b) for a, b in zip(run([1]), run([0, 1, 2])))


@pytest.mark.parametrize("cfg", [DQN_SMALL, DDPG_SMALL, TD3_SMALL], ids=["dqn", "ddpg", "td3"])
def test_learners_leave_torchs_global_generator_alone(cfg):
    torch.manual_seed(5)
    expected = torch.rand(3)
    torch.manual_seed(5)
    run_experiment(resolve_config(seeds=[0, 1], **dict(cfg, episodes=2)), progress=False)
    assert torch.equal(torch.rand(3), expected)


def test_an_old_per_seed_checkpoint_is_refused_in_one_line():
    env, agent = build(resolve_config(seeds=[0], **DDPG_SMALL))
    with pytest.raises(ValueError, match="one learner per seed"):
        agent.load_state_dict({"learners": [{}], "new_episode": torch.ones(1, dtype=torch.bool)})
