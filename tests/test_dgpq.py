import math

import pytest
import torch
from tensordict import TensorDict

from trl_dgpq.bounds import section5
from trl_dgpq.config import with_overrides
from trl_dgpq.dgpq import DGPQ, DGPQConfig, argmax_random_ties
from trl_dgpq.qhat import LipschitzQ
from trl_dgpq.rng import TIE_STREAM, SeedStreams

D = torch.float64


def t(*v):
    return torch.tensor(v[0] if len(v) == 1 else v, dtype=D)


# ---------------------------------------------------------------- Q̂ (Eq. 7)
def test_eq7_values_and_vmax_cap():
    q = LipschitzQ(1, 2, 2, lipschitz=2.0, v_max=2.5)
    assert torch.equal(q(t([0.3, 0.3])), t([[2.5, 2.5]]))  # empty: V_max everywhere
    q.insert(t([[0.5, 0.5]]), torch.tensor([0]), t([1.0]), torch.tensor([True]))
    for x, expect in [((0.5, 0.5), 1.0), ((0.7, 0.5), 1.4), ((0.6, 0.4), 1.4), ((0.9, 0.9), 2.5)]:
        v = q(t([x]))
        assert v[0, 0].item() == pytest.approx(expect)       # min(V_max, mu + L |x - s|_1)
        assert v[0, 1].item() == 2.5                           # other action untouched
    q2 = LipschitzQ(1, 1, 2, lipschitz=2.0, v_max=9.0, metric="l2")
    q2.insert(t([[0.0, 0.0]]), torch.tensor([0]), t([1.0]), torch.tensor([True]))
    assert q2(t([[0.3, 0.4]])).item() == pytest.approx(1.0 + 2.0 * 0.5)


def test_insert_prunes_only_dominated_pairs_of_the_same_action():
    q = LipschitzQ(1, 2, 2, lipschitz=2.0, v_max=10.0, capacity=2)
    one, a0, a1 = torch.tensor([True]), torch.tensor([0]), torch.tensor([1])
    q.insert(t([[0.5, 0.5]]), a0, t([1.0]), one)
    q.insert(t([[0.5, 0.5]]), a1, t([5.0]), one)
    q.insert(t([[0.9, 0.9]]), a0, t([0.9]), one)  # 0.9 + 2*0.8 > 1: keeps (0.5, 0.5)
    assert q.size().item() == 3
    q.insert(t([[0.6, 0.5]]), a1, t([0.0]), one)  # dominates action 1's pair only
    assert q.valid[0, 0].sum().item() == 2 and q.valid[0, 1].sum().item() == 1
    q.insert(t([[0.6, 0.5]]), a0, t([0.5]), one)  # 0.5 + 2*0.1 <= 1 prunes (0.5,0.5); 0.5+2*0.7 > 0.9 keeps (0.9,0.9)
    mus = sorted(q.mu[0, 0][q.valid[0, 0]].tolist())
    assert mus == [0.5, 0.9]
    assert q(t([[0.5, 0.5]]))[0, 0].item() == pytest.approx(0.7)
    q.insert(t([[0.1, 0.9]]), a0, t([0.2]), one)  # fills a third slot of action 0: capacity grows
    assert q.capacity >= 3 and q.valid[0, 0].sum().item() == 3


def test_masked_insert_touches_only_selected_seeds():
    q = LipschitzQ(3, 2, 1, lipschitz=1.0, v_max=4.0)
    q.insert(t([0.5], [0.5], [0.5]), torch.tensor([0, 1, 0]), t(1.0, 1.0, 1.0), torch.tensor([True, False, True]))
    assert q.size().tolist() == [1, 0, 1]


# ---------------------------------------------------------------- step 1
def test_ties_are_uniform_from_the_seed_stream():
    u = SeedStreams(range(4000), stream=7).uniform(4)
    q = torch.zeros(4000, 4, dtype=D)
    counts = torch.bincount(argmax_random_ties(q, u), minlength=4)
    assert (counts > 850).all() and (counts < 1150).all()
    q[:, 2] = 1.0
    assert (argmax_random_ties(q, u) == 2).all()
    q[:, 1] = 1.0 - 1e-2                                   # close, but not a tie
    assert (argmax_random_ties(q, u) == 2).all()


def test_act_breaks_ties_with_the_tie_stream_of_each_seed():
    """Empty Q̂: every action ties, so the choice is argmax of the seed's tie-stream draws."""
    seeds = [0, 5, 9]
    ag = DGPQ(config(), seeds=seeds, state_dim=2, num_actions=4)
    ref = SeedStreams(seeds, stream=TIE_STREAM)
    obs = torch.zeros(3, 2, dtype=torch.float32)           # float32 observations are accepted
    taken = []
    for _ in range(40):
        a = ag.select_action(obs)
        assert torch.equal(a, ref.uniform(4).argmax(-1))
        taken.append(a)
    assert len(torch.stack(taken).unique()) == 4           # not list order (always 0)


def test_float32_observations_after_a_qhat_insert():
    ag = agent_1d()
    step(ag, 0.5, 0, 1.0, 0.6)                              # overwrites Q̂ (see below)
    assert ag.qhat.size().item() == 1
    td = TensorDict({"observation": torch.tensor([[0.5]], dtype=torch.float32)}, batch_size=[1])
    assert ag.act(td).item() == 1                           # Q̂_0(0.5) < V_max = Q̂_1(0.5)


# ---------------------------------------------------------------- steps 3-6
def config(**kw):
    """DGPQConfig with settings by name (nested GP settings included)."""
    return with_overrides(DGPQConfig(), kw)


def agent_1d(seeds=(0,), **kw):
    cfg = dict(gamma=0.5, lipschitz=1.0, v_max=10.0, sigma_tol2=0.1, eps1=0.01, noise_var=0.1,
               lengthscale=0.1, outputscale=1.0, gp="exact")
    return DGPQ(config(**{**cfg, **kw}), seeds=list(seeds), state_dim=1, num_actions=2)


def step(agent, s, a, r, s_next, terminal=False):
    return agent.learn(t([[s]]), torch.tensor([a]), t([r]), t([[s_next]]), torch.tensor([terminal]))


def test_q_target_bootstraps_on_qhat_except_at_terminal():
    ag = agent_1d()
    assert ag.q_target(t([1.0]), t([[0.2]]), torch.tensor([False])).item() == pytest.approx(1.0 + 0.5 * 10.0)
    assert ag.q_target(t([1.0]), t([[0.2]]), torch.tensor([True])).item() == pytest.approx(1.0)
    # With Q̂_0(0.2) = 3 + |0.2 - 0.2| and Q̂_1 = V_max = 10 the bootstrap is the max, 10, not 3.
    ag.qhat.insert(t([[0.2]]), torch.tensor([0]), t([3.0]), torch.tensor([True]))
    assert ag.q_target(t([1.0]), t([[0.2]]), torch.tensor([False])).item() == pytest.approx(1.0 + 0.5 * 10.0)
    ag.qhat.insert(t([[0.2]]), torch.tensor([1]), t([4.0]), torch.tensor([True]))
    assert ag.q_target(t([1.0]), t([[0.2]]), torch.tensor([False])).item() == pytest.approx(1.0 + 0.5 * 4.0)
    # Per seed: the max is over each seed's own actions, never across seeds.
    two = agent_1d(seeds=(0, 1))
    for a in (0, 1):
        two.qhat.insert(t([[0.2], [0.2]]), torch.tensor([a, a]), t([3.0, 4.0]), torch.tensor([True, True]))
    q = two.q_target(t([1.0, 1.0]), t([[0.2], [0.2]]), torch.tensor([False, False]))
    assert q.tolist() == pytest.approx([1.0 + 0.5 * 3.0, 1.0 + 0.5 * 4.0])


def test_slack_once_bootstraps_on_qhat_less_eps1_except_at_terminal():
    ag = agent_1d(slack="once", eps1=0.25)
    assert ag.q_target(t([1.0]), t([[0.2]]), torch.tensor([False])).item() == pytest.approx(1.0 + 0.5 * 9.75)
    assert ag.q_target(t([1.0]), t([[0.2]]), torch.tensor([True])).item() == pytest.approx(1.0)
    ag.qhat.insert(t([[0.2]]), torch.tensor([0]), t([3.0]), torch.tensor([True]))
    ag.qhat.insert(t([[0.2]]), torch.tensor([1]), t([4.0]), torch.tensor([True]))
    assert ag.q_target(t([1.0]), t([[0.2]]), torch.tensor([False])).item() == pytest.approx(1.0 + 0.5 * 3.75)
    # ... and so the overwrite at a state whose successor was overwritten carries one eps1, not two:
    # Q̂(0.2) = 4 for both actions after the inserts below (Q̂_0(0.1) = 4 + 10 * 0.1 = 5), so a
    # confident sample at 0.1 going to 0.2 with reward 0 and gamma 1 gives 4 - eps1 + eps1 = 4
    # under "once", 4 + eps1 under Algorithm 1.
    for slack, expect in [("once", 4.0), ("algorithm-1", 4.25)]:
        ag = agent_1d(slack=slack, eps1=0.25, gamma=1.0, lipschitz=10.0, noise_var=1e-6, sigma_tol2=0.01)
        for a in (0, 1):
            ag.qhat.insert(t([[0.2]]), torch.tensor([a]), t([4.0]), torch.tensor([True]))
        out = step(ag, 0.1, 0, 0.0, 0.2)
        assert out["update"].item()
        assert ag.qhat(t([[0.1]]))[0, 0].item() == pytest.approx(expect, abs=1e-4)


def test_one_confident_sample_overwrites_qhat_and_resets_every_gp():
    ag = agent_1d()
    out = step(ag, 0.4, 1, 5.0, 0.5)          # q = 5 + 0.5*10 = 10 = Q̂: GP learns, no overwrite
    assert out["learn"].item() and not out["update"].item()
    assert ag.gp.size.tolist() == [[0, 1]]
    out = step(ag, 0.4, 1, 5.0, 0.5)          # sigma1^2 = 0.0909 <= sigma_tol2: the gate blocks the add
    assert not out["learn"].item() and ag.gp.size.tolist() == [[0, 1]]
    out = step(ag, 0.5, 0, 1.0, 0.6)          # q = 6, Q̂ = 10: sigma1^2 = 1 > 0.1 >= sigma2^2 = 1/11
    mean = 10.0 + (6.0 - 10.0) / 1.1           # prior mean Q̂ + GP residual mean
    assert out["learn"].item() and out["update"].item()
    assert out["var2"].item() == pytest.approx(1 - 1 / 1.1)
    assert ag.qhat(t([[0.5]]))[0, 0].item() == pytest.approx(mean + 0.01)   # mean + eps1
    assert ag.qhat(t([[0.5]]))[0, 1].item() == 10.0
    assert ag.gp.size.tolist() == [[0, 0]]     # every action's GP emptied
    assert ag.qhat_updates.item() == 1


def test_an_overwrite_empties_only_that_seeds_gps():
    ag = agent_1d(seeds=(0, 1))
    x = t([[0.4], [0.4]])
    ag.learn(x, torch.tensor([1, 1]), t([5.0, 5.0]), t([[0.5], [0.5]]), torch.tensor([False, False]))
    assert ag.gp.size.tolist() == [[0, 1], [0, 1]]          # q = Q̂: both learn, neither overwrites
    out = ag.learn(t([[0.5], [0.9]]), torch.tensor([0, 0]), t([1.0, 5.0]), t([[0.6], [0.9]]),
                   torch.tensor([False, False]))
    assert out["update"].tolist() == [True, False]         # seed 0: q = 6 < 10; seed 1: q = 10
    assert ag.gp.size.tolist() == [[0, 0], [1, 1]]          # seed 1 keeps both points
    assert ag.qhat.size().tolist() == [1, 0]


def test_sigma_tol2_delays_the_update_until_the_gp_is_confident():
    ag = agent_1d(sigma_tol2=0.05)             # one sample leaves 0.0909, two leave 0.0476
    out = step(ag, 0.5, 0, 1.0, 0.6)
    assert out["learn"].item() and not out["update"].item()
    out = step(ag, 0.5, 0, 1.0, 0.6)
    assert out["update"].item()
    mean = 10.0 + 2 * (6.0 - 10.0) / 2.1
    assert ag.qhat(t([[0.5]]))[0, 0].item() == pytest.approx(mean + 0.01)


def test_overwrite_needs_a_value_2eps1_below_qhat():
    ag = agent_1d(eps1=0.5)                    # 2 eps1 = 1 > Q̂ - mean = (10 - 9)/1.1
    out = step(ag, 0.5, 0, 4.0, 0.6)           # q = 9
    assert out["learn"].item() and not out["update"].item()
    ag = agent_1d(eps1=0.4)                    # 2 eps1 = 0.8 < 0.909
    assert step(ag, 0.5, 0, 4.0, 0.6)["update"].item()


def test_no_overwrite_without_an_add_even_where_the_gp_is_confident_and_low():
    """Exact GP, RBF l = 0.1, s_f^2 = 1, noise 0.1; gamma = 0.5, V_max = 10, so r = 4 gives
    q = 9, residual -1. Points at 0.5 and 0.6 (corr c = e^-0.5): at each add, -mean2 is
    1/1.1 = 0.909 and (1+c)/(1.1+c) = 0.941, both <= 2 eps1 = 0.98: no overwrite. At the
    midpoint 0.55 (corr c_m = e^-0.125 to both) var = 1 - 2 c_m^2/(1.1+c) = 0.087 <= 0.1, so
    the gate blocks the add, although -mean = 2 c_m/(1.1+c) = 1.034 > 0.98: Algorithm 1 needs
    sigma1^2 > sigma_tol2 for step 6, so Q̂ stays empty."""
    ag = agent_1d(eps1=0.49)
    c, cm = math.exp(-0.5), math.exp(-0.125)
    for s in (0.5, 0.6):
        out = ag.learn(t([[s]]), torch.tensor([0]), t([4.0]), t([[0.9]]), torch.tensor([False]))
        assert out["learn"].item() and not out["update"].item()
    out = ag.learn(t([[0.55]]), torch.tensor([0]), t([4.0]), t([[0.9]]), torch.tensor([False]))
    assert out["var2"].item() == pytest.approx(1 - 2 * cm ** 2 / (1.1 + c))
    assert out["mean2"].item() == pytest.approx(-2 * cm / (1.1 + c))
    assert not out["learn"].item() and not out["update"].item()
    assert ag.qhat.size().tolist() == [0] and ag.qhat_updates.tolist() == [0]


def test_inactive_seeds_learn_nothing():
    ag = DGPQ(config(gp="exact"), seeds=[0, 1], state_dim=1, num_actions=2)
    out = ag.learn(t([0.5], [0.5]), torch.tensor([0, 0]), t(-1.0, -1.0), t([0.6], [0.6]),
                     torch.tensor([False, False]), active=torch.tensor([False, True]))
    assert out["learn"].tolist() == [False, True]
    assert ag.qhat.size().tolist() == [0, 1]


# ---------------------------------------------------------------- Section 5
def test_section5_reproduces_the_report_values():
    eps1, tol = section5(eps=1.0, delta=0.96, gamma=0.01, r_max=2.0, lipschitz=9.0, num_actions=4, noise_var=0.1)
    assert eps1 == pytest.approx(0.33, rel=1e-12)
    # By hand: r = 0.99/27, N_S = ceil(1/(pi r^2)) = 237, kappa = 4*237*(6/0.99^2 + 1) = 6751.49,
    # sigma_tol2 = 0.2 * 0.99^4 / (36 ln(24*237*6752.49/0.96)). Dropping /delta gives 3.0558e-4,
    # dropping kappa's +1 gives 3.0753e-4.
    assert tol == pytest.approx(3.0487093e-4, rel=1e-6)
    with pytest.raises(ValueError, match="gamma"):
        section5(1.0, 0.96, 1.0, 2.0, 9.0, 4, 0.1)
    cfg = config(sigma_tol2=None, eps1=None, eps=1.0, delta=0.96, r_max=2.0, lipschitz=9.0,
                 covering="unit-square").resolve(4)
    assert math.isclose(cfg.sigma_tol2, tol) and math.isclose(cfg.eps1, eps1)
    # an agent built from such a config derives them for its own actions (4 here: the values above)
    ag = DGPQ(config(sigma_tol2=None, eps1=None, eps=1.0, delta=0.96, r_max=2.0, lipschitz=9.0, gamma=0.01,
                     covering="unit-square"), seeds=[0], state_dim=2, num_actions=4)
    assert math.isclose(ag.cfg.sigma_tol2, tol) and math.isclose(ag.cfg.eps1, eps1)


@pytest.mark.parametrize("bad,match", [(dict(gamma=1.5), "gamma"), (dict(noise_var=-0.1), "noise_var"),
                                       (dict(metric="l3"), "metric"),
                                       (dict(sigma_tol2=None), "Section 5"), (dict(budget=0), "budget")])
def test_config_rejects_bad_values(bad, match):
    with pytest.raises(ValueError, match=match):
        config(**bad).resolve(4)


def test_section5_covering_from_the_env_state_box():
    """covering "env": the unit box under L1 needs ceil(1/r)^2 = 28^2 = 784 balls of radius
    r = 0.99/27 (a cube of side r fits in each), so sigma_tol2 = 2.6821e-4 (by hand)."""
    from trl_dgpq.bounds import box_covering
    assert box_covering([0, 0], [1, 1], "l1")(0.99 / 27) == 784
    assert box_covering([0, 0], [1, 1], "linf")(0.25) == 4                  # cubes of side 0.5
    assert box_covering([0, 0, 0], [1, 2, 1], "l2")(math.sqrt(3) / 2) == 2  # cubes of side 1
    cfg = config(sigma_tol2=None, eps1=None, eps=1.0, delta=0.96, r_max=2.0, lipschitz=9.0)
    assert cfg.resolve(4, state_box=([0.0, 0.0], [1.0, 1.0])).sigma_tol2 == pytest.approx(2.6821087e-4, rel=1e-6)
    ag = DGPQ(config(sigma_tol2=None, eps1=None, eps=1.0, delta=0.96, r_max=2.0, lipschitz=9.0), seeds=[0],
              state_dim=2, num_actions=4, state_box=([0.0, 0.0], [1.0, 1.0]))     # an agent built with the box
    assert ag.cfg.sigma_tol2 == pytest.approx(2.6821087e-4, rel=1e-6)
    with pytest.raises(ValueError, match="state box"):
        config(sigma_tol2=None, eps1=None, eps=1.0, delta=0.96, r_max=2.0).resolve(4)


def test_state_scale_weights_dimensions_and_drops_zeros():
    """state_scale (0, 2) on the square: Q̂ and the GPs see 2 * y only, so two states that
    differ only in x are one state, and distances in y double."""
    from trl_dgpq.collectors.experiment import build, resolve_config
    env, agent = build(resolve_config(seeds=[0], state_scale=(0.0, 2.0)))
    assert agent.qhat.s.shape[-1] == 1
    obs = torch.tensor([[0.3, 0.25]], dtype=torch.float64)
    assert agent.features(obs).tolist() == [[0.5]]
    agent.update_qhat(agent.features(obs), torch.tensor([1]), torch.tensor([0.0], dtype=torch.float64),
                      torch.tensor([True]))
    q = agent.qhat_values(agent.features(torch.tensor([[0.9, 0.35]], dtype=torch.float64)))
    assert float(q[0, 1]) == pytest.approx(0.0 + 1.0 * 2 * 0.1)  # L_Q * |2 * 0.35 - 2 * 0.25|


@pytest.mark.parametrize("scale, match", [((1.0, 2.0, 3.0), "1 or 2 weights"), ((0.0, 0.0), "not all 0"),
                                          ((-1.0,), "state_scale")])
def test_state_scale_refuses_bad_weights(scale, match):
    from trl_dgpq.collectors.experiment import resolve_config
    with pytest.raises(ValueError, match=match):
        resolve_config(seeds=[0], state_scale=scale)



# ---------------------------------------------------------------- storage and the kernel's schedule
def test_the_memory_estimate_is_q_hats_storage_and_each_gps():
    """3 seeds x 4 actions on the square (2 coordinates): Q̂ holds 64 pairs of (2 coordinates, a value)
    in float64 per seed and action, 3 x 4 x 64 x 3 x 8 = 18,432 bytes, as allocated; each sparse GP
    with budget 100 (m = 101 basis slots) 8 (2m + m + 2 m^2) = 8 (202 + 101 + 20,402) = 165,640 bytes;
    each exact GP of capacity 64, 8 x 64 x (2 + 2 + 64) = 34,816."""
    from trl_dgpq.collectors.experiment import build, memory_estimate, resolve_config
    for gp, per_gp in (("sparse", 165_640), ("exact", 34_816)):
        config = resolve_config(env="square", preset="shaped", seeds=[0, 1, 2], episodes=1, gp=gp, budget=100,
                                capacity=64, qhat_capacity=64)
        _, agent = build(config)
        allocated = sum(v.numel() * v.element_size() for v in (agent.qhat.s, agent.qhat.mu))
        assert allocated == 18_432
        assert memory_estimate(config) == 18_432 + 3 * 4 * per_gp


def test_the_growth_a_step_may_allocate_is_q_hats_doubling_and_the_exact_gps():
    """Capacity 1 for Q̂ and for the exact GP, 1 seed, 2 actions, 1 dimension: nothing to grow at the
    start; after one add (q = Q̂: no overwrite) the GP of action 1 is full and every GP of the seed
    doubles its buffers at the next add; after an overwrite Q̂ is full too and doubling copies its
    (2 actions x 1 slot) x (1 coordinate + 1 value) x 8 bytes into twice that, 64 bytes. A sparse GP has
    a fixed budget: only Q̂'s."""
    ag = agent_1d(qhat_capacity=1, capacity=1)
    assert ag.growth_bytes() == 0
    step(ag, 0.4, 1, 5.0, 0.5)                            # GP_1 takes a point, Q̂ unchanged
    gp_doubling = ag.gp.growth_bytes()
    assert gp_doubling > 0 and ag.growth_bytes() == gp_doubling
    step(ag, 0.5, 0, 1.0, 0.6)                            # an overwrite: Q̂ full, every GP emptied
    assert ag.qhat.size().tolist() == [1] and ag.gp.size.tolist() == [[0, 0]]
    assert ag.growth_bytes() == 64 + ag.gp.growth_bytes()
    sparse = agent_1d(qhat_capacity=1, gp="sparse")
    step(sparse, 0.5, 0, 1.0, 0.6)
    assert sparse.qhat.size().tolist() == [1] and sparse.growth_bytes() == 64


def test_the_kernel_is_trained_with_its_settings_once_a_gp_holds_enough_new_points(monkeypatch):
    """Manifold kernel, every 2 new points if the GP then holds at least 2: the fit is called with
    the config's steps, learning rate and minimum, for the GPs due only, each counted once per
    seed; a GP holding exactly the minimum is due."""
    import trl_dgpq.dgpq as dgpq_module
    calls = []
    monkeypatch.setattr(dgpq_module, "fit", lambda gp, due, **kw: calls.append((due.clone(), kw)))
    ag = agent_1d(seeds=(0, 1), kernel="manifold", kernel_train_every=2, kernel_min_points=2,
                  kernel_train_steps=7, kernel_lr=0.003, sigma_tol2=1e-6, eps1=100.0)   # no overwrite: GPs keep points
    two = torch.tensor([False, False])
    ag.learn(t([[0.1], [0.1]]), torch.tensor([1, 1]), t([5.0, 5.0]), t([[0.5], [0.5]]), two)
    assert calls == [] and ag.gp.size.tolist() == [[0, 1], [0, 1]]
    ag.learn(t([[0.3], [0.3]]), torch.tensor([1, 0]), t([5.0, 5.0]), t([[0.5], [0.5]]), two)
    assert ag.gp.size.tolist() == [[0, 2], [1, 1]]          # seed 0's GP_1 holds 2 = the minimum
    (due, kw), = calls
    assert due.tolist() == [[False, True], [False, False]]
    assert kw == dict(steps=7, lr=0.003, min_points=2)
    assert ag.kernel_fits.tolist() == [1, 0] and ag.since_fit.tolist() == [[0, 0], [1, 1]]
    assert ag.kernel_fits.dtype == ag.since_fit.dtype == torch.long   # counts: 1, not 1.0, in episodes.csv


def test_observe_learns_from_the_reward_shaped_by_the_envs_potential_at_its_own_gamma():
    """A transition with potentials Φ(s) = 0.5 and Φ(s') = 2, reward 1, gamma 0.5: DGPQ learns from
    1 + 0.5 x 2 - 0.5 = 1.5, so q_t = 1.5 + 0.5 V_max = 6.5 (Q̂ empty); at a terminal s' Φ(s') is 0:
    1 - 0.5 = 0.5, with no bootstrap."""
    for terminated, expect in ((False, 6.5), (True, 0.5)):
        ag = agent_1d()
        td = TensorDict({"observation": t([[0.5]]), "action": torch.tensor([0]), "potential": t([0.5]),
                         "next": TensorDict({"observation": t([[0.6]]), "reward": t([1.0]), "potential": t([2.0]),
                                             "terminated": torch.tensor([terminated])}, [1])}, [1])
        assert ag.observe(td)["q_target"].item() == pytest.approx(expect)


def test_an_overwrite_leaves_the_memo_of_q_hat_at_s_next_current():
    """After step 6 the memoised Q̂(s_{t+1}) is brought up to date with the new pair rather than
    thrown away (the next step's action reads it): its version is Q̂'s and its values are a fresh
    evaluation's, min(10, 6 + L d) at s' = 0.6 for action 0."""
    ag = agent_1d()
    s_next = t([[0.6]])
    out = ag.learn(t([[0.5]]), torch.tensor([0]), t([1.0]), s_next, torch.tensor([False]))
    assert out["update"].item()
    m_s, m_version, m_q = ag._memo
    assert m_s is s_next and m_version == ag.qhat.version
    assert torch.equal(m_q, ag.qhat(s_next)) and m_q[0, 0].item() < 10.0


def test_the_episode_counters_are_per_seed():
    """Each counter the CSV records is one number per seed: Q̂'s pairs, its overwrites, the points its
    GPs hold over every action, the adds."""
    ag = agent_1d(seeds=(0, 1))                    # q = 5 + 0.5 x 10 = Q̂: every add, no overwrite
    ag.learn(t([[0.1], [0.1]]), torch.tensor([0, 0]), t([5.0, 5.0]), t([[0.5], [0.5]]), torch.tensor([False, False]))
    ag.learn(t([[0.9], [0.9]]), torch.tensor([0, 0]), t([5.0, 5.0]), t([[0.5], [0.5]]), torch.tensor([False, False]),
             active=torch.tensor([True, False]))
    assert ag.gp.size.tolist() == [[2, 0], [1, 0]]  # summed over actions 2 and 1; over seeds it would be 3 and 0
    stats = ag.episode_stats()
    assert sorted(stats) == ["gp_adds", "gp_size", "qhat_size", "qhat_updates"]
    assert {k: v.tolist() for k, v in stats.items()} == dict(qhat_size=[0, 0], qhat_updates=[0, 0],
                                                             gp_size=[2, 1], gp_adds=[2, 1])


def test_step_6_at_its_boundaries_sigma2_equal_to_the_tolerance_and_a_gap_of_exactly_2_eps1():
    """Noise 1 and k(x, x) = 1 make the algebra exact: one point leaves sigma2^2 = 1 - 1/2 = 0.5 and a
    residual of -4 (r = 1: q = 1 + 0.5 x 10 = 6 against Q̂ = 10) a mean of -2. Algorithm 1 overwrites
    when sigma2^2 <= sigma_tol2 (so at 0.5) and Q̂ - mean > 2 eps1 strictly (so not at eps1 = 1)."""
    out = step(agent_1d(noise_var=1.0, sigma_tol2=0.5, eps1=0.01), 0.5, 0, 1.0, 0.6)
    assert (out["var1"].item(), out["var2"].item(), out["mean2"].item()) == (1.0, 0.5, -2.0) and out["update"].item()
    assert not step(agent_1d(noise_var=1.0, sigma_tol2=0.5, eps1=1.0), 0.5, 0, 1.0, 0.6)["update"].item()
    assert step(agent_1d(noise_var=1.0, sigma_tol2=0.5, eps1=0.999), 0.5, 0, 1.0, 0.6)["update"].item()


def test_a_step_with_no_seed_active_learns_nothing_and_says_so_per_seed():
    """Every seed finished: learn and update False for each seed (bool, shape (S,)), the GPs, Q̂ and
    the counters untouched."""
    ag = agent_1d(seeds=(0, 1))
    out = ag.learn(t([[0.5], [0.5]]), torch.tensor([0, 0]), t([1.0, 1.0]), t([[0.6], [0.6]]),
                   torch.tensor([False, False]), active=torch.tensor([False, False]))
    assert {k: (v.dtype, v.tolist()) for k, v in out.items()} == dict(learn=(torch.bool, [False, False]),
                                                                      update=(torch.bool, [False, False]))
    assert ag.gp.size.sum().item() == 0 and ag.qhat.size().tolist() == [0, 0]
    assert ag.gp_adds.tolist() == [0, 0] and ag.qhat_updates.tolist() == [0, 0]


def test_q_hat_is_evaluated_once_per_step(monkeypatch):
    """Q̂(s_{t+1}) of step 3 is Q̂(s_t) of the next step's action and of its step 6 (memoised on the state
    tensor and Q̂'s version, and kept current by an overwrite): over three steps with overwrites, one
    evaluation each, plus the first state's."""
    calls = []
    evaluate = LipschitzQ.__call__
    monkeypatch.setattr(LipschitzQ, "__call__", lambda self, s: calls.append(1) or evaluate(self, s))
    ag = agent_1d()
    states = [t([[x]]) for x in (0.5, 0.6, 0.7, 0.8)]
    for k in range(3):
        a = ag.select_action(states[k])
        ag.learn(states[k], a, t([1.0]), states[k + 1], torch.tensor([False]))
    assert ag.qhat_updates.item() >= 1 and len(calls) == 1 + 3


def test_the_agent_uses_the_metric_and_the_kernel_it_is_given():
    """Q̂ measures distance in the config's metric (L-inf: a pair at (0, 0) bounds (0.3, 0.4) by
    mu + L max(0.3, 0.4) = 1.4, where L1 says 1.7); a kernel passed in is the GPs' own."""
    from trl_dgpq.gp import RBFKernel
    for metric, bound in (("linf", 1.4), ("l1", 1.7)):
        ag = DGPQ(config(metric=metric, v_max=10.0), seeds=[0], state_dim=2, num_actions=1)
        ag.qhat.insert(t([[0.0, 0.0]]), torch.tensor([0]), t([1.0]), torch.tensor([True]))
        assert ag.qhat_values(t([[0.3, 0.4]]))[0, 0].item() == pytest.approx(bound)
    kernel = RBFKernel(0.7, 2.0)
    assert DGPQ(config(), seeds=[0], state_dim=2, num_actions=1, kernel=kernel).gp.kernel is kernel


# ---------------------------------------------------------------- devices, dtypes and small contracts
def _tensors(x):
    """Every tensor in a (nested) state dict."""
    if isinstance(x, torch.Tensor):
        yield x
    elif isinstance(x, dict):
        for v in x.values():
            yield from _tensors(v)


@pytest.mark.parametrize("gp, kernel", [("sparse", "rbf"), ("exact", "manifold")])
def test_every_tensor_is_made_on_the_device_the_agent_is_given(gp, kernel):
    """With torch's default device set to "meta" (no data), a tensor made without ``device=`` lands
    there: an agent given device "cpu" must make its state, its scale, its actions and each step's
    outputs on the CPU (a GPU run would otherwise mix devices). sigma_tol2 tiny: no overwrite, so the
    GPs grow and the manifold kernel trains."""
    from trl_dgpq.collectors.experiment import build, resolve_config
    from trl_dgpq.gp.factory import make_kernel
    env, agent = build(resolve_config(seeds=[0, 1], state_scale=(0.5, 2.0), gp=gp, kernel=kernel,
                                      sigma_tol2=1e-12, kernel_train_every=3, kernel_min_points=3,
                                      kernel_train_steps=2))
    A = env.info.num_actions()
    gen = torch.Generator().manual_seed(0)
    obs = [torch.rand(2, 2, generator=gen, dtype=torch.float32) for _ in range(13)]
    kern = make_kernel(agent.cfg.gp, 2, [0, 1], A)        # made on the CPU; the GP moves it
    with torch.device("meta"):
        scale = DGPQ._scale(agent.cfg, env.info)
        ag = DGPQ(agent.cfg, [0, 1], 2, A, kernel=kern, device="cpu",
                  scale=scale)
        outs = []
        for s, s2 in zip(obs, obs[1:]):
            a = ag.select_action(ag.features(s))
            outs += [a, *ag.learn(ag.features(s), a, torch.ones(2, device="cpu"), ag.features(s2),
                                  torch.zeros(2, dtype=torch.bool, device="cpu")).values()]
        outs += list(ag.episode_stats().values())
    assert ag.gp_adds.tolist() == [12, 12] and (kernel == "rbf" or ag.kernel_fits.min() > 0)
    for x in [*scale, *outs, *_tensors(ag.state_dict()), *vars(ag).values()]:
        if isinstance(x, torch.Tensor):
            assert x.device.type == "cpu"


def test_features_and_counters_keep_their_dtypes():
    """Features are float64 whether scaled or not (a weight of 0.1 is float64's 0.1, not float32's);
    the episode counters are integers."""
    from trl_dgpq.collectors.experiment import build, resolve_config
    obs = torch.tensor([[0.3, 0.7]], dtype=torch.float32)
    _, plain = build(resolve_config(seeds=[0]))
    assert plain.features(obs).dtype == D and plain.features(obs).tolist() == obs.double().tolist()
    _, scaled = build(resolve_config(seeds=[0], state_scale=(0.1, 3.0)))
    f = scaled.features(obs)
    assert f.dtype == D and f.tolist() == [[float(obs[0, 0]) * 0.1, float(obs[0, 1]) * 3.0]]
    assert all(v.dtype == torch.long for v in scaled.episode_stats().values())


def test_one_state_scale_weight_scales_every_dimension():
    from trl_dgpq.collectors.experiment import build, resolve_config
    _, agent = build(resolve_config(seeds=[0], state_scale=(4.0,)))
    assert agent.qhat.s.shape[-1] == 2
    assert agent.features(torch.tensor([[0.25, 0.5]])).tolist() == [[1.0, 2.0]]


def test_section5_covers_the_scaled_state_box():
    """covering "env" with state_scale (0, 3) on the unit square: the box Section 5 covers is the
    weighted, kept dimension only, [0, 3] -- one dimension, side 3."""
    from trl_dgpq.collectors.experiment import build, resolve_config
    cfg = dict(seeds=[0], sigma_tol2=None, eps1=None, eps=1.0, delta=0.5, r_max=2.0)
    env, agent = build(resolve_config(**cfg, state_scale=(0.0, 3.0)))
    assert DGPQ._state_box(agent.cfg.__class__(**{**vars(agent.cfg), "sigma_tol2": None}), env.info) == ([0.0], [3.0])
    _, two = build(resolve_config(**cfg, state_scale=(2.0, 0.5)))
    assert DGPQ._state_box(two.cfg.__class__(**{**vars(two.cfg), "eps1": None}), env.info) == ([0.0, 0.0], [2.0, 0.5])
    from trl_dgpq.bounds import box_covering
    eps1, sigma_tol2 = section5(1.0, 0.5, agent.cfg.gamma, 2.0, agent.cfg.lipschitz, env.info.num_actions(),
                                agent.cfg.gp.noise_var, box_covering([0.0], [3.0], agent.cfg.metric))
    assert (agent.cfg.eps1, agent.cfg.sigma_tol2) == (eps1, sigma_tol2)


@pytest.mark.parametrize("top", [1e6, -1e6, 0.5, 1e-3])
def test_ties_are_within_a_relative_1e_12(top):
    """Values within 1e-12 * max(|top|, 1) of the top tie (rounding of a sum is not a preference);
    further apart they do not. Below 1 the tolerance stays 1e-12 (0.9 of it ties at top 1e-3)."""
    tol = 1e-12 * max(abs(top), 1.0)
    u = torch.tensor([[0.1, 0.9, 0.5]], dtype=D)
    near = torch.tensor([[top, top - 0.9 * tol, top - 3 * tol]], dtype=D)
    assert argmax_random_ties(near, u).tolist() == [1]          # the near one ties, and has the larger u
    far = torch.tensor([[top, top - 1.5 * tol, top - 3 * tol]], dtype=D)
    assert argmax_random_ties(far, u).tolist() == [0]


def test_asking_for_section5_derives_what_is_not_given():
    assert DGPQConfig.implied({"eps": 0.1}) == {"sigma_tol2": None, "eps1": None}
    assert DGPQConfig.implied({"delta": 0.1, "eps1": 0.01}) == {"sigma_tol2": None}
    assert DGPQConfig.implied({"lipschitz": 2.0}) == {}


def test_section5_keeps_a_given_sigma_tol2_or_eps1():
    """Section 5 fills in only what is none: a given sigma_tol2 (or eps1) stays as given."""
    box = ([0.0, 0.0], [1.0, 1.0])
    derived = config(sigma_tol2=None, eps1=None, eps=1.0, delta=0.96, r_max=2.0).resolve(4, box)
    kept = config(sigma_tol2=0.25, eps1=None, eps=1.0, delta=0.96, r_max=2.0).resolve(4, box)
    assert (kept.sigma_tol2, kept.eps1) == (0.25, derived.eps1) and derived.sigma_tol2 != 0.25
    kept = config(sigma_tol2=None, eps1=0.5, eps=1.0, delta=0.96, r_max=2.0).resolve(4, box)
    assert (kept.sigma_tol2, kept.eps1) == (derived.sigma_tol2, 0.5)
    with pytest.raises(ValueError, match=r"^give sigma_tol2 and eps1, or eps, delta and r_max to derive them \(Sec"):
        config(sigma_tol2=None, eps1=None, eps=1.0).resolve(4, box)
    with pytest.raises(ValueError, match="^Section 5 with covering 'env' needs the env's state box$"):
        config(sigma_tol2=None, eps1=None, eps=1.0, delta=0.96, r_max=2.0).resolve(4)


def test_an_agent_derives_section5_for_its_own_actions_and_box():
    """DGPQ(...) resolves its config with its own action count and state box: 2 actions on a box
    of side 2 give other values than 4 actions on the unit square."""
    kw = dict(sigma_tol2=None, eps1=None, eps=1.0, delta=0.96, r_max=2.0)
    box = ([0.0, 0.0], [2.0, 2.0])
    ag = DGPQ(config(**kw), seeds=[0], state_dim=2, num_actions=2, state_box=box)
    want = config(**kw).resolve(2, box)
    assert (ag.cfg.eps1, ag.cfg.sigma_tol2) == (want.eps1, want.sigma_tol2)
    assert want.sigma_tol2 != config(**kw).resolve(4, box).sigma_tol2
    assert want.sigma_tol2 != config(**kw).resolve(2, ([0.0, 0.0], [1.0, 1.0])).sigma_tol2


def test_a_recorded_config_without_a_gp_section_upgrades_as_it_is():
    d = {"gamma": 0.5}
    assert DGPQConfig.upgrade(d) is d


def test_make_hands_the_envs_device_to_q_hat_and_the_gps(monkeypatch):
    """``make`` builds the agent on the env's device, and the agent hands it to the GPs it makes
    (on a CPU-only machine the device is seen where it is passed: the GP factory is watched)."""
    import trl_dgpq.dgpq as dgpq_module
    from trl_dgpq.collectors.experiment import build, resolve_config
    env, agent = build(resolve_config(seeds=[0, 1]))
    import dataclasses
    import inspect
    seen, make_gp = [], dgpq_module.make_gp
    device = torch.device("cpu", 0)     # a device the code would not name by itself
    monkeypatch.setattr(dgpq_module, "make_gp", lambda *a, **k: seen.append(
        inspect.signature(make_gp).bind(*a, **k).arguments.get("device")) or make_gp(*a, **k))
    qhat_devices, lipschitz_q = [], dgpq_module.LipschitzQ
    monkeypatch.setattr(dgpq_module, "LipschitzQ", lambda *a, **k: qhat_devices.append(
        inspect.signature(lipschitz_q).bind(*a, **k).arguments.get("device")) or lipschitz_q(*a, **k))
    DGPQ.make(agent.cfg, dataclasses.replace(env.info, device=device), [0, 1])
    assert seen == [device] and qhat_devices == [device]


def test_no_seed_active_answers_on_the_agents_device():
    from trl_dgpq.collectors.experiment import build, resolve_config
    _, agent = build(resolve_config(seeds=[0, 1]))
    s = torch.rand(2, 2, dtype=D)
    with torch.device("meta"):
        out = agent.learn(s, torch.zeros(2, dtype=torch.long, device="cpu"), torch.ones(2, device="cpu"), s,
                          torch.zeros(2, dtype=torch.bool, device="cpu"), active=torch.zeros(2, dtype=torch.bool,
                                                                                             device="cpu"))
    assert [(k, v.device.type, v.tolist()) for k, v in out.items()] == [("learn", "cpu", [False, False]),
                                                                        ("update", "cpu", [False, False])]


def test_float32_states_act_and_learn_as_their_float64_values():
    """Step 1 and steps 3-6 take states of any float dtype: float32 states (exact in float64) give
    the actions, Q̂ and GPs their float64 values give."""
    from trl_dgpq.collectors.experiment import build, resolve_config
    agents = [build(resolve_config(seeds=[0, 1], sigma_tol2=0.5))[1] for _ in range(2)]
    gen = torch.Generator().manual_seed(1)
    states = [torch.rand(2, 2, generator=gen).float() for _ in range(8)]
    for s, s2 in zip(states, states[1:]):
        for agent, cast in zip(agents, (lambda x: x, lambda x: x.double())):
            a = agent.select_action(cast(s))
            agent.learn(cast(s), a, torch.full((2,), -1.0), cast(s2), torch.zeros(2, dtype=torch.bool))
    assert agents[0].qhat_updates.sum() > 0 and agents[0].gp_adds.sum() > 0
    assert torch.equal(agents[0].qhat.mu, agents[1].qhat.mu) and torch.equal(agents[0].qhat.s, agents[1].qhat.s)
    for a, b in zip(agents[0].gp.state_dict().values(), agents[1].gp.state_dict().values()):
        assert torch.equal(a, b)
    s = torch.rand(2, 2, generator=gen).float()
    assert torch.equal(agents[0].select_action(s), agents[1].select_action(s.double()))


def test_make_derives_section5_from_the_env_box_when_given_an_unresolved_config():
    """``make`` on a config whose sigma_tol2 and eps1 are still to be derived gives the agent the
    env's state box, so it derives what ``resolve_config`` would."""
    from trl_dgpq.collectors.experiment import build, resolve_config
    kw = dict(seeds=[0], sigma_tol2=None, eps1=None, eps=1.0, delta=0.5, r_max=2.0, state_scale=(0.0, 3.0))
    env, resolved = build(resolve_config(**kw))
    unresolved = with_overrides(resolved.cfg, dict(sigma_tol2=None, eps1=None))
    made = DGPQ.make(unresolved, env.info, [0])
    assert (made.cfg.eps1, made.cfg.sigma_tol2) == (resolved.cfg.eps1, resolved.cfg.sigma_tol2)


def test_the_scaled_state_box_of_a_box_away_from_zero():
    """Each kept dimension's bounds times its weight: [-1, 1] x 3 and [2, 4] x 0.5; a dropped one gone."""
    from types import SimpleNamespace
    info = SimpleNamespace(observation_dim=3, device="cpu", state_box=lambda: ([-1.0, 5.0, 2.0], [1.0, 6.0, 4.0]))
    cfg = config(sigma_tol2=None, eps1=None, eps=1.0, delta=0.5, r_max=2.0, state_scale=(3.0, 0.0, 0.5))
    assert DGPQ._state_box(cfg, info) == ([-3.0, 1.0], [3.0, 2.0])


def test_continuous_actions_are_refused_naming_dgpq():
    """Each way in (resolve_config, make, the memory estimate) names the agent that refuses."""
    import dataclasses
    from trl_dgpq.collectors.experiment import build, resolve_config
    with pytest.raises(ValueError, match="^dgpq needs discrete actions"):
        resolve_config(env="liquidation", action_levels=0)
    env, agent = build(resolve_config(env="liquidation", seeds=[0]))
    from trl_dgpq.envs.liquidation.env import LiquidationEnv
    continuous = LiquidationEnv.describe(dataclasses.replace(env.info.config, action_levels=0))
    for call in (lambda: DGPQ.resolve_config(agent.cfg, continuous), lambda: DGPQ.make(agent.cfg, continuous, [0]),
                 lambda: DGPQ.memory_bytes(agent.cfg, continuous, 1)):
        with pytest.raises(ValueError, match="^dgpq needs discrete actions"):
            call()
