"""The F-16 model (issue 19, first part): the exact discretisation against an independent
integration, and the unstable mode."""
import numpy as np
import pytest
import torch

from trl_dgpq.envs.f16.dynamics import A, V_T0, continuous, discretise


def rk4(a, b, x, u, dt, n):
    """Classical Runge-Kutta on x' = a x + b u with u held, n substeps of dt / n (numpy)."""
    h = dt / n
    f = lambda x: a @ x + b * u  # noqa: E731
    for _ in range(n):
        k1 = f(x)
        k2 = f(x + h / 2 * k1)
        k3 = f(x + h / 2 * k2)
        k4 = f(x + h * k3)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


@pytest.mark.parametrize("u", [0.0, 1.0, -2.0])
def test_exact_discretisation_equals_a_fine_rk4_integration(u):
    a, b = (t.numpy() for t in continuous())
    ad, bd = (t.numpy() for t in discretise(0.05))
    x = np.array([30.0, 5.0, 0.02, -0.01, 0.03])
    for _ in range(40):  # two seconds, the error does not build up
        expect = rk4(a, b, x, u, 0.05, 200)
        got = ad @ x + bd * u
        np.testing.assert_allclose(got, expect, rtol=1e-9, atol=1e-9)
        x = expect


def test_the_published_eigenvalues_and_one_unstable_mode():
    eig = np.sort_complex(np.linalg.eigvals(A.numpy()))
    np.testing.assert_allclose(eig, np.sort_complex(np.array([-1.912, -0.151 + 0.115j, -0.151 - 0.115j, 0.098])),
                               atol=1.5e-3)
    ad, _ = discretise(0.05)
    moduli = np.abs(np.linalg.eigvals(ad.numpy()))
    assert (moduli > 1 + 1e-6).sum() == 1  # the unstable mode, exp(0.098 * 0.05)
    assert np.isclose(moduli.max(), np.exp(0.09755 * 0.05), rtol=1e-5)
    assert np.isclose(moduli, 1.0).sum() == 1  # altitude integrates: a unit root


def test_altitude_integrates_the_climb_rate():
    a, _ = continuous()
    x = torch.tensor([0.0, 0.0, 0.01, 0.03, 0.0], dtype=torch.float64)
    assert float((a @ x)[0]) == pytest.approx(V_T0 * 0.02)


from trl_dgpq.envs.f16.env import F16Env  # noqa: E402
from torchrl.envs.utils import check_env_specs  # noqa: E402


def rollout(env, policy):
    """Each seed's first episode: (return, terminated, last state) per seed."""
    td = env.reset()
    S = env.num_seeds
    total, running = torch.zeros(S, dtype=torch.float64), torch.ones(S, dtype=torch.bool)
    terminated, last = torch.zeros(S, dtype=torch.bool), torch.zeros(S, 5, dtype=torch.float64)
    while running.any():
        td["action"] = policy(td)
        out, td = env.step_and_maybe_reset(td)
        nxt = out["next"]
        total += torch.where(running, nxt["reward"][:, 0], 0.0)
        ended = running & nxt["done"][:, 0]
        terminated |= ended & nxt["terminated"][:, 0]
        last[ended] = nxt["observation"][ended] * env.scale
        running &= ~ended
    return total, terminated, last


def test_specs_and_a_step_by_hand():
    env = F16Env([0, 1], noise_v=0.0, noise_alpha=0.0)
    check_env_specs(env)
    td = env.reset()
    td["action"] = torch.tensor([2, 0])  # elevator +1, -1
    out = env.step(td)["next"]
    ad, bd = discretise(0.05)
    x0 = torch.tensor([20.0, 0.0, 0.01, 0.01, 0.0], dtype=torch.float64)  # h0, pitch0 by default
    for i, e in enumerate((1.0, -1.0)):
        x = ad @ x0 + bd * e
        hdot = V_T0 * (x[3] - x[2])
        assert float(out["reward"][i]) == pytest.approx(-abs(float(x[0])) / 100 - abs(float(hdot)) / 100 - 1.0)
        torch.testing.assert_close(out["observation"][i] * env.scale, x)


def decision_by_hand(x, e, steps):
    """(state, summed reward) after ``steps`` simulator steps of 0.05 s with elevator ``e`` held:
    Runge-Kutta on the continuous model, the reward of each step by its formula."""
    a, b = (t.numpy() for t in continuous())
    total = 0.0
    for _ in range(steps):
        x = rk4(a, b, x, e, 0.05, 50)
        total += -abs(x[0]) / 100 - abs(V_T0 * (x[3] - x[2])) / 100 - abs(e)
    return x, total


def test_a_decision_of_five_steps_holds_the_elevator_and_sums_their_rewards():
    env = F16Env([0, 1], noise_v=0.0, noise_alpha=0.0, decision_steps=5)
    td = env.reset()
    td["action"] = torch.tensor([0, 1])  # elevator -1 (nose up), 0
    out = env.step(td)["next"]
    for i, e in enumerate((-1.0, 0.0)):
        x, reward = decision_by_hand(np.array([20.0, 0.0, 0.01, 0.01, 0.0]), e, 5)
        assert float(out["reward"][i]) == pytest.approx(reward, rel=1e-9)
        np.testing.assert_allclose((out["observation"][i] * env.scale).numpy(), x, rtol=1e-8, atol=1e-10)


def test_leaving_the_envelope_costs_the_remaining_simulator_steps():
    """Out after the first decision of 5 steps, with 9 of 10 decisions left: 45 steps at
    h_max / 100 each, on top of the decision's own reward."""
    x, reward = decision_by_hand(np.array([20.0, 0.0, 0.01, 0.01, 0.0]), -1.0, 5)
    h_max = (20.0 + abs(x[0])) / 2                   # between the start and where the decision ends
    assert abs(x[0]) > h_max > 20.0
    env = F16Env([0], noise_v=0.0, noise_alpha=0.0, decision_steps=5, max_steps=10, h_max=h_max)
    td = env.reset()
    td["action"] = torch.tensor([0])
    out = env.step(td)["next"]
    assert bool(out["terminated"][0])
    assert float(out["reward"][0]) == pytest.approx(reward - 45 * h_max / 100, rel=1e-9)



def test_airspeed_and_angle_of_attack_noises_are_two_draws_of_the_seeds_stream():
    """One step holding the elevator: the state is the noiseless step plus noise_v times the seed's
    first normal draw on V_T and noise_alpha times its second on alpha (not the first again)."""
    from trl_dgpq.rng import ENV_STREAM, SeedStreams
    env = F16Env([3], noise_v=2.0, noise_alpha=1e-3)
    td = env.reset()
    td["action"] = torch.tensor([1])
    got = env.step(td)["next", "state"][0].numpy()
    x, _ = decision_by_hand(np.array([20.0, 0.0, 0.01, 0.01, 0.0]), 0.0, 1)
    draw = SeedStreams([3], ENV_STREAM).normal(2)[0].numpy()
    assert abs(draw[0] - draw[1]) > 0.1
    np.testing.assert_allclose(got, x + [0.0, 2.0 * draw[0], 1e-3 * draw[1], 0.0, 0.0], rtol=1e-9, atol=1e-10)


def test_leaving_the_envelope_later_costs_exactly_the_steps_left():
    """Nose up, 2 simulator steps per decision, 10 decisions: h_max between the altitude errors
    after the 3rd and 4th decisions (by hand), so the 4th leaves the envelope with 6 decisions, 12
    simulator steps, left: its reward is its own minus 12 h_max / 100; the first three are inside."""
    x, rewards, heights = np.array([20.0, 0.0, 0.01, 0.01, 0.0]), [], []
    for _ in range(4):
        x, r = decision_by_hand(x, -1.0, 2)
        rewards.append(r)
        heights.append(abs(x[0]))
    assert heights == sorted(heights) and abs(x[2:]).max() < 0.5 and abs(x[4]) < 1.0
    h_max = (heights[2] + heights[3]) / 2
    env = F16Env([0], noise_v=0.0, noise_alpha=0.0, decision_steps=2, max_steps=10, h_max=h_max)
    td = env.reset()
    for k in range(4):
        td["action"] = torch.tensor([0])
        out, td = env.step_and_maybe_reset(td)
        assert bool(out["next", "terminated"][0]) == (k == 3)
        left = 12 if k == 3 else 0
        assert float(out["next", "reward"][0]) == pytest.approx(rewards[k] - left * h_max / 100, rel=1e-9)


def test_airspeed_is_outside_the_envelope():
    """Airspeed noise of 1 ft/s against an airspeed scale of 0.01 ft/s: V_T leaves [-0.01, 0.01]
    at once, and the episode runs its 30 steps (the other components stay well inside)."""
    env = F16Env([0, 1], noise_v=1.0, vt_scale=0.01, max_steps=30)
    td = env.reset()
    for _ in range(30):
        td["action"] = torch.ones(2, dtype=torch.long)
        out, td = env.step_and_maybe_reset(td)
        assert not out["next", "terminated"].any()
        assert (out["next", "state"][:, 1].abs() > 0.01).all()
    assert out["next", "truncated"].all()

def test_doing_nothing_diverges_and_leaving_the_envelope_costs_the_rest():
    env = F16Env([0, 1, 2], max_steps=4000)
    total, terminated, _ = rollout(env, lambda td: torch.ones(3, dtype=torch.long))
    assert bool(terminated.all())  # the unstable mode left the envelope
    assert float(total.max()) < -4000 * 1.0  # ending early cost the remaining steps at h_max / 100 = 10 each


def test_a_seed_does_not_depend_on_its_batch():
    a, *_ = rollout(F16Env([4], max_steps=50), lambda td: torch.ones(1, dtype=torch.long))
    b, *_ = rollout(F16Env([9, 4], max_steps=50), lambda td: torch.ones(2, dtype=torch.long))
    assert torch.equal(a[0], b[1]) and not torch.equal(b[0], b[1])


@pytest.mark.parametrize("bad", [dict(h0=2000.0), dict(pitch0=0.6, attitude_max=0.5), dict(dt=0.0),
                                 dict(noise_v=-1.0)])
def test_impossible_settings_are_refused(bad):
    with pytest.raises(ValueError):
        F16Env([0], **bad)


from trl_dgpq.agents import agent_class  # noqa: E402
from trl_dgpq.envs.f16.baselines import lqr_gain  # noqa: E402


@pytest.mark.parametrize("dt, r", [(0.05, 0.3), (0.25, 0.1), (1.0, 0.1)])
def test_lqr_gain_solves_the_discrete_riccati_equation(dt, r):
    scipy_linalg = pytest.importorskip("scipy.linalg")
    a, b = discretise(dt)
    rate = torch.tensor([0.0, 0.0, -V_T0, V_T0, 0.0], dtype=torch.float64) / 100
    q = torch.diag(torch.tensor([1e-4, 0, 0, 0, 0], dtype=torch.float64)) + torch.outer(rate, rate)
    p = scipy_linalg.solve_discrete_are(a.numpy(), b.numpy()[:, None], q.numpy(), np.array([[r]]))
    k = (b.numpy() @ p @ a.numpy()) / (r + b.numpy() @ p @ b.numpy())
    np.testing.assert_allclose(lqr_gain(a, b, q, r).numpy(), k, rtol=1e-12)


def test_lqr_gain_refuses_a_mode_the_elevator_cannot_reach():
    """x1 doubles every step and u never moves it: no gain stabilises it, so no solution to return."""
    a, b = torch.diag(torch.tensor([2.0, 0.5], dtype=torch.float64)), torch.tensor([0.0, 1.0], dtype=torch.float64)
    with pytest.raises(ValueError, match="did not converge in 64 doublings"):
        lqr_gain(a, b, torch.eye(2, dtype=torch.float64), 1.0)


@pytest.mark.parametrize("agent, most", [("lqr", 25.0), ("pd", 30.0)])
def test_the_controllers_hold_altitude_where_doing_nothing_diverges(agent, most):
    """Seeds 0-7, one default episode (200 steps) each: the altitude error at the end (20 ft at
    the start; the measured ends: LQR ≤ 19.4 ft, PD ≤ 25.2 ft, doing nothing ≥ 95.9 ft)."""
    env = F16Env(list(range(8)))
    cls = agent_class(agent, "f16")
    policy = cls.make(cls.Config(), env.info, list(range(8)))
    ret, terminated, last = rollout(env, lambda td: policy.act(td))
    assert not terminated.any() and last[:, 0].abs().max() < most
    nothing_ret, _, nothing_last = rollout(F16Env(list(range(8))), lambda td: torch.ones(8, dtype=torch.long))
    assert nothing_last[:, 0].abs().min() > 80 and (ret > nothing_ret).all()


# ------------------------------------------------------------ analysis (envs/f16/analysis.py)
import pandas as pd  # noqa: E402

from trl_dgpq.envs.f16 import analysis  # noqa: E402


def episodes(returns: dict) -> pd.DataFrame:
    """{seed: [return per episode]} as the runner's rows."""
    return pd.DataFrame([dict(seed=s, episode=i + 1, steps=200, **{"return": r})
                         for s, rs in returns.items() for i, r in enumerate(rs)])


def test_stable_flight_is_the_first_episode_whose_last_ten_meet_the_threshold():
    # seed 0: -100 for 5 episodes, then -30
    r0 = [-100.0] * 5 + [-30.0] * 15
    # by hand: at episode e >= 10 the window holds max(0, 5 - (e - 10)) values of -100
    # e = 14: one -100 -> (-100 - 270) / 10 = -37 (met); e = 13: two -> -44 (not met)
    df = episodes({0: r0, 1: [-130.0] * 20, 2: [-41.0] * 10})
    got = analysis.episodes_to_stable(df)
    assert got[0] == 14 and np.isnan(got[1]) and got[2] == 10  # -41 meets ">= -41"; 9 episodes would not


def test_reward_blocks_are_the_median_and_quartiles_of_each_seeds_block_mean():
    df = episodes({0: [-10.0, -20.0, -30.0, -40.0], 1: [-50.0, -50.0, 0.0, 0.0], 2: [-1.0, -3.0, -5.0, -7.0]})
    b = analysis.blocks(df, 2)
    # block means: seed 0 -15, -35; seed 1 -50, 0; seed 2 -2, -6
    assert list(b.index) == [1.5, 3.5]
    assert list(b["median"]) == [-15.0, -6.0]
    assert b["q25"].iloc[0] == pytest.approx(-32.5) and b["q75"].iloc[1] == pytest.approx(-3.0)
    assert analysis.window_reward(df, 2, 3) == pytest.approx((-20 - 30 - 50 + 0 - 3 - 5) / 6)


def test_the_report_row_never_shows_a_window_the_run_did_not_cover():
    """A 100-episode run: no "100-200" (episode 100 alone is not GWH14's window), and "late" is
    its last 10 episodes (91-100), not the whole run; at 1,000 episodes late is GWH14's 900-1000."""
    timed = lambda df: df.assign(wall_s=0.2, cpu_s=0.2, us_per_step=1e3)  # noqa: E731 (ms per seed-step)
    short = timed(episodes({0: [-200.0] * 90 + [-50.0] * 10}))
    cells = [c.strip() for c in analysis.row("f16-dgpq-lq5", short).strip("|").split("|")]
    assert cells[3] == "- (not run to 200)" and cells[4] == "-50 (91-100)"
    long = timed(episodes({0: [-200.0] * 900 + [-40.0] * 100}))
    cells = [c.strip() for c in analysis.row("f16-dgpq-lq5", long).strip("|").split("|")]
    assert cells[3] == "-200" and cells[4] == "-40 (901-1000)"
    assert analysis.late_window(150) == (141, 150)


# ------------------------------------------------------------ issue 30: what mutation testing found untested
from trl_dgpq.envs.f16.baselines import LQRConfig, LQRPolicy, PDConfig, PDPolicy, quantised  # noqa: E402
from trl_dgpq.envs.f16.dynamics import B  # noqa: E402


def continuous_by_hand(a4, b4):
    """The 5-D model (h first, hdot = V_T0 (theta - alpha)) around a 4-D (A, B), in numpy."""
    a, b = np.zeros((5, 5)), np.zeros(5)
    a[1:, 1:], b[1:] = np.asarray(a4), np.asarray(b4)
    a[0, 2], a[0, 3] = -V_T0, V_T0
    return a, b


def discretised_by_scipy(dt, model=None):
    """(A_d, B_d) of the 5-D model for an elevator held ``dt`` seconds, by scipy's matrix exponential
    (``model``: another 4-D (A, B) than the linearisation)."""
    scipy_linalg = pytest.importorskip("scipy.linalg")
    a, b = (t.numpy() for t in continuous()) if model is None else continuous_by_hand(*model)
    m = np.zeros((6, 6))
    m[:5, :5], m[:5, 5] = a, b
    e = scipy_linalg.expm(m * dt)
    return e[:5, :5], e[:5, 5]


def lqr_gain_by_hand(dt, r=0.3, model=None):
    """K of the LQR for x'Qx (Q: (h/100)^2 + (hdot/100)^2) + r u^2, from scipy's Riccati solver
    on the model discretised by scipy's matrix exponential (a decision of ``dt`` seconds)."""
    scipy_linalg = pytest.importorskip("scipy.linalg")
    ad, bd = discretised_by_scipy(dt, model)
    rate = np.array([0.0, 0.0, -V_T0, V_T0, 0.0]) / 100
    q = np.diag([1e-4, 0, 0, 0, 0]) + np.outer(rate, rate)
    p = scipy_linalg.solve_discrete_are(ad, bd[:, None], q, np.array([[r]]))
    return (bd @ p @ ad) / (r + bd @ p @ bd)


def test_the_model_is_float64_as_published():
    """B's entries reach the 5-D model unrounded (a float32 copy would lose them after 7 digits)."""
    a, b = continuous()
    assert a.dtype == b.dtype == torch.float64
    assert torch.equal(b[1:], B) and b[0] == 0 and torch.equal(a[1:, 1:], A)


@pytest.mark.parametrize("start, inside", [(dict(h0=500.0, h_max=400.0), dict(h0=399.0, h_max=400.0)),
                                           (dict(h0=-400.0, h_max=400.0), dict(h0=-399.0, h_max=400.0)),
                                           (dict(pitch0=0.2, attitude_max=0.2), dict(pitch0=0.19, attitude_max=0.2)),
                                           (dict(pitch0=-0.25, attitude_max=0.2), dict(pitch0=-0.19, attitude_max=0.2)),
                                           (dict(h0=-300.0, h0_spread=100.0, h_max=400.0),
                                            dict(h0=-300.0, h0_spread=99.0, h_max=400.0)),
                                           (dict(pitch0=0.1, pitch0_spread=0.1, attitude_max=0.2),
                                            dict(pitch0=0.1, pitch0_spread=0.09, attitude_max=0.2))])
def test_a_start_on_or_outside_the_envelope_is_refused_in_our_words(start, inside):
    """Each setting within its own range, a start on or beyond the envelope's edge (h0 alone,
    pitch0 alone, or with their spreads): cross_check refuses it, naming both; just inside is
    accepted."""
    with pytest.raises(ValueError, match=r"every start \(h0 .* \+- .*, pitch0 .* \+- .*\) must be inside the "
                                         r"envelope \(h_max "):
        F16Env([0], **start)
    F16Env([0], **inside)


def test_specs_bound_the_observation_and_name_three_actions():
    env = F16Env([0, 1])
    obs = env.observation_spec["observation"]
    assert obs.dtype == torch.float64 and obs.shape == (2, 5)
    assert torch.equal(obs.space.low, -torch.ones(2, 5, dtype=torch.float64))
    assert torch.equal(obs.space.high, torch.ones(2, 5, dtype=torch.float64))
    assert env.action_spec.space.n == 3 and env.action_names == ("nose-up", "hold", "nose-down")
    assert env.elevator(torch.tensor([0, 1, 2])).dtype == torch.float64
    assert env.elevator(torch.tensor([0, 1, 2])).tolist() == [-1.0, 0.0, 1.0]


def test_the_observation_is_the_state_over_the_envelopes_half_widths():
    """Half-widths no float32 holds exactly: the observation is the float64 quotient."""
    env = F16Env([0], h0=100.0, pitch0=0.05, h_max=333.3, vt_scale=77.7, attitude_max=0.33, rate_max=0.77)
    obs = env.reset()["observation"][0]
    assert obs.tolist() == [100.0 / 333.3, 0.0, 0.05 / 0.33, 0.05 / 0.33, 0.0]
    td = env.reset()
    td["action"] = torch.tensor([2])
    nxt = env.step(td)["next"]
    x = nxt["state"][0].tolist()
    assert nxt["observation"][0].tolist() == [x[0] / 333.3, x[1] / 77.7, x[2] / 0.33, x[3] / 0.33, x[4] / 0.77]



def test_observe_climb_appends_the_climb_rate_over_its_largest_value_in_the_envelope():
    """502 ft/s x (theta - alpha) / (2 x 502 x attitude_max), by hand: at the start alpha =
    theta, so 0; after a nose-down step, from the state's own theta and alpha. The first five
    coordinates are those without it, and the spec bounds six."""
    from torchrl.envs.utils import check_env_specs
    env = F16Env([0, 1], observe_climb=True, attitude_max=0.4)
    assert env.observation_spec["observation"].shape == (2, 6)
    check_env_specs(env)
    td = env.reset()
    assert td["observation"][:, 5].tolist() == [0.0, 0.0]
    td["action"] = torch.tensor([2, 0])
    nxt = env.step(td)["next"]
    x = nxt["state"]
    plain = F16Env([0], attitude_max=0.4)
    for i in range(2):
        assert nxt["observation"][i, 5].item() == pytest.approx(502.0 * (x[i, 3] - x[i, 2]).item() / (2 * 502.0 * 0.4),
                                                                 rel=1e-12)
        assert torch.equal(nxt["observation"][i, :5], plain.observation(x[i:i + 1])[0])
    assert (nxt["observation"][:, 5] != 0).all()
    assert plain.observation(x).shape == (2, 5)

def test_the_elevator_deflection_scales_the_control():
    """elevator_deg 0.7: actions -1, 0, +1 deflect -0.7, 0, +0.7 degrees (Runge-Kutta by hand);
    the reward charges |action|, not degrees."""
    env = F16Env([0, 1, 2], noise_v=0.0, noise_alpha=0.0, elevator_deg=0.7)
    td = env.reset()
    td["action"] = torch.tensor([0, 1, 2])
    out = env.step(td)["next"]
    a, b = (t.numpy() for t in continuous())
    for i, e in enumerate((-1.0, 0.0, 1.0)):
        x = rk4(a, b, np.array([20.0, 0.0, 0.01, 0.01, 0.0]), 0.7 * e, 0.05, 50)
        np.testing.assert_allclose(out["state"][i].numpy(), x, rtol=1e-10, atol=1e-13)
        expect = -abs(x[0]) / 100 - abs(V_T0 * (x[3] - x[2])) / 100 - abs(e)
        assert float(out["reward"][i]) == pytest.approx(expect, rel=1e-10)


def test_each_bounded_component_alone_leaves_the_envelope():
    """Rows placed by hand: |h| 1,010 ft (h_max 1,000), alpha 0.6, theta 0.6 (0.5), q 1.2 rad/s (1),
    V_T 200 ft/s (no envelope), all inside: one step ends exactly the first four."""
    env = F16Env(list(range(6)), noise_v=0.0, noise_alpha=0.0)
    td = env.reset()
    env.state[:] = torch.tensor([[-1010.0, 0, 0, 0, 0], [0, 0, 0.6, 0, 0], [0, 0, 0, 0.6, 0], [0, 0, 0, 0, 1.2],
                                 [0, 200.0, 0, 0, 0], [20.0, 0, 0.01, 0.01, 0]], dtype=torch.float64)
    td["action"] = torch.ones(6, dtype=torch.long)
    out = env.step(td)["next"]
    assert out["terminated"][:, 0].tolist() == [True, True, True, True, False, False]
    assert (out["state"].abs()[:4].max(-1).values > torch.tensor([1000, 0.5, 0.5, 1.0], dtype=torch.float64)).all()


def test_the_envelopes_edge_is_inside():
    """theta after one step, to the last bit, as attitude_max: still inside (|theta| > the edge
    leaves); the next float below it: out."""
    env = F16Env([0], noise_v=0.0, noise_alpha=0.0)
    td = env.reset()
    td["action"] = torch.tensor([1])
    theta = float(env.step(td)["next", "state"][0, 3])
    assert 0.01 < theta < 0.02
    for edge, out in ((theta, False), (np.nextafter(theta, 0.0), True)):
        env = F16Env([0], noise_v=0.0, noise_alpha=0.0, attitude_max=float(edge))
        td = env.reset()
        td["action"] = torch.tensor([1])
        assert bool(env.step(td)["next", "terminated"][0]) == out


def test_quantised_rounds_to_the_nearest_setting_and_clips_beyond():
    """Commands in degrees with 2-degree settings: nearest of -2, 0, +2 (actions 0, 1, 2)."""
    command = torch.tensor([-9.0, -3.1, -2.9, -0.9, 0.9, 1.1, 2.9, 3.1, 40.0], dtype=torch.float64)
    assert quantised(command, 2.0).tolist() == [0, 0, 0, 1, 1, 2, 2, 2, 2]
    assert quantised(command, 2.0).dtype == torch.long


def test_pd_commands_its_law_by_hand():
    cfg = PDConfig(k_h=0.01, k_hdot=0.003, k_theta=12.0, k_q=4.0)
    env = F16Env([0, 1], elevator_deg=0.5)
    policy = PDPolicy.make(cfg, env.info, [0, 1])
    x = torch.tensor([[10.0, 5.0, 0.02, 0.05, 0.1], [-30.0, 0.0, 0.01, -0.02, -0.3]], dtype=torch.float64)
    by_hand = [0.01 * h + 0.003 * V_T0 * (th - al) + 12.0 * th + 4.0 * q for h, _, al, th, q in x.tolist()]
    assert policy.command(x).tolist() == pytest.approx(by_hand, rel=1e-12)
    assert by_hand[0] > 0.75 and by_hand[1] < -0.75                     # beyond half a 0.5-degree setting
    assert policy.act({"state": x}).tolist() == [2, 0]


def test_lqr_policy_is_the_riccati_gain_of_one_decision():
    """5 simulator steps per decision, r = 0.1, 2-degree settings: the gain of the model held
    over 0.25 s, to 4e-10 of scipy's (float32 anywhere in Q, or stopping the recursion at an
    absolute 1e-8, moves it by 1e-9 to 4e-8); its command -Kx quantised to 2-degree settings."""
    env = F16Env([0, 1], decision_steps=5, elevator_deg=2.0)
    policy = LQRPolicy.make(LQRConfig(r=0.1), env.info, [0, 1])
    k = lqr_gain_by_hand(0.25, r=0.1)
    np.testing.assert_allclose(policy.gain.numpy(), k, rtol=4e-10)
    x = torch.tensor([[40.0, 3.0, 0.02, 0.05, 0.1], [-20.0, 0.0, 0.01, -0.01, -0.05]], dtype=torch.float64)
    command = -(x.numpy() @ k)
    np.testing.assert_allclose(policy.command(x).numpy(), command, rtol=1e-12)
    assert policy.act({"state": x}).tolist() == [int(np.clip(np.round(c / 2.0), -1, 1)) + 1 for c in command]
    np.testing.assert_allclose(LQRPolicy.make(LQRConfig(), F16Env([0]).info, [0]).gain.numpy(),
                               lqr_gain_by_hand(0.05, r=0.3), rtol=4e-10)


# ------------------------------------------------------------ the start spread (issue 28)
from tensordict import TensorDict  # noqa: E402


def reset_rows(env, rows):
    mask = torch.zeros(env.num_seeds, 1, dtype=torch.bool)
    mask[list(rows)] = True
    return env.reset(TensorDict(_reset=mask, batch_size=env.batch_size))


def starts(env, episodes, steps=(3,)):
    """The start state of each of ``episodes`` episodes per seed row, each episode ``steps[i %
    len]`` decisions long (ended by reset, as the collector's step_and_maybe_reset does)."""
    out = []
    for k in range(episodes):
        td = env.reset() if k == 0 else reset_rows(env, range(env.num_seeds))
        out.append(td["state"].clone())
        for _ in range(steps[k % len(steps)]):
            td = env.step(td.set("action", torch.ones(env.num_seeds, dtype=torch.long)))["next"]
    return torch.stack(out, 1)  # (S, episodes, 5)


def test_the_start_spread_draws_h_and_pitch_uniformly_around_h0_and_pitch0():
    env = F16Env(list(range(40)), h0=20.0, h0_spread=50.0, pitch0=0.01, pitch0_spread=0.02, noise_v=0.0,
                 noise_alpha=0.0)
    x = starts(env, 5).reshape(-1, 5)
    assert ((x[:, 0] - 20.0).abs() <= 50.0).all() and ((x[:, 2] - 0.01).abs() <= 0.02).all()
    assert torch.equal(x[:, 2], x[:, 3]) and (x[:, [1, 4]] == 0).all()   # alpha = theta; V_T, q at trim
    assert x[:, 0].std() == pytest.approx(100.0 / 12 ** 0.5, rel=0.15)   # uniform on a width of 100
    assert x[:, 0].unique().numel() == 200                                # a new draw every episode
    assert (x[:, 0] > 20.0).float().mean() == pytest.approx(0.5, abs=0.1)


def test_without_a_spread_every_episode_starts_at_h0_and_pitch0():
    x = starts(F16Env([0, 1]), 3)
    assert (x == torch.tensor([20.0, 0.0, 0.01, 0.01, 0.0], dtype=torch.float64)).all()


def test_a_seeds_starts_depend_neither_on_its_batch_nor_on_its_episodes_lengths():
    kw = dict(h0_spread=50.0, pitch0_spread=0.02)
    alone = starts(F16Env([3], **kw), 4, steps=(2,))[0]
    assert torch.equal(alone, starts(F16Env([1, 3, 9], **kw), 4, steps=(5, 1))[1])
    env = F16Env([1, 3, 9], **kw)                      # the others start new episodes, seed 3 does not
    first = env.reset()["state"][1].clone()
    for _ in range(3):
        reset_rows(env, [0, 2])
    assert torch.equal(first, alone[0]) and torch.equal(reset_rows(env, [1])["state"][1], alone[1])
    assert not torch.equal(alone, starts(F16Env([4], **kw), 4)[0])          # another seed, other starts


def test_the_start_spread_continues_exactly_from_a_saved_state_and_an_older_state_loads():
    kw = dict(h0_spread=50.0, pitch0_spread=0.02)
    a = F16Env([2, 5], **kw)
    starts(a, 2)
    b = F16Env([2, 5], **kw)
    b.load_state_dict(a.state_dict())
    assert torch.equal(starts(a, 2), starts(b, 2))
    old = {k: v for k, v in F16Env([2, 5]).state_dict().items() if k not in ("episode", "start_rng")}
    F16Env([2, 5]).load_state_dict(old)        # a checkpoint from before the spread existed


# ------------------------------------------------------------ issue 28: potential-based shaping by the LQR's value
from trl_dgpq.agents.base import learning_reward  # noqa: E402
from trl_dgpq.envs.f16.presets import FLIGHT_05  # noqa: E402


def potential_by_hand(x, dt, steps, elevator_deg, r, gamma, model=None):
    """The noiseless, unquantised LQR flown from x: a decision of ``steps`` simulator steps holds
    u = -K x (K from scipy's Riccati solver and matrix exponential), each step costing the reward's
    |h|/100 + |hdot|/100 + |u|/elevator_deg; discounted per decision until gamma^t < 1e-3. With
    ``model`` (a 4-D (A, B)), the designer's: both the gain and the flight are that model's."""
    k = lqr_gain_by_hand(dt * steps, r, model)
    ad, bd = discretised_by_scipy(dt, model)
    cost, t = 0.0, 0
    while gamma ** t >= 1e-3:
        u = -k @ x
        for _ in range(steps):
            x = ad @ x + bd * u
            cost += gamma ** t * (abs(x[0]) / 100 + abs(V_T0 * (x[3] - x[2])) / 100 + abs(u) / elevator_deg)
        t += 1
    return -cost


@pytest.mark.parametrize("steps, elevator_deg, r, gamma", [(10, 1.0, 0.1, 0.9), (5, 2.0, 0.3, 0.95), (1, 1.0, 0.1, 0.5),
                                                         (10, 1.0, 0.1, 0.0), (10, 1.0, 0.1, 1e-4)])   # one decision
def test_the_potential_is_the_noiseless_lqr_flights_discounted_cost(steps, elevator_deg, r, gamma):
    env = F16Env([0], potential="lqr", decision_steps=steps, elevator_deg=elevator_deg, potential_r=r,
                 potential_gamma=gamma, **{k: v for k, v in FLIGHT_05.items() if k not in ("decision_steps",)})
    states = torch.tensor([[20.0, 0.0, 0.01, 0.01, 0.0], [-35.0, 4.0, -0.02, 0.03, 0.05], [0.0] * 5],
                          dtype=torch.float64)
    phi = env.potential(states)
    for x, value in zip(states.numpy(), phi.tolist()):
        assert value == pytest.approx(potential_by_hand(x, 0.05, steps, elevator_deg, r, gamma), rel=1e-9, abs=1e-12)


def test_a_wrong_model_is_a_fixed_draw_of_factors_within_the_error():
    """Each nonzero entry of A and B scaled by a factor in [1 - e, 1 + e], zeros kept, the same for a
    draw every time, another for another draw; error 0 is the linearisation itself."""
    from trl_dgpq.envs.f16.dynamics import B, perturbed
    assert perturbed(0.0, 7) == (A, B)
    a, b = perturbed(0.2, 3)
    ratio = torch.cat([(a / A)[A != 0], (b / B)[B != 0]])
    assert bool((ratio >= 0.8).all() and (ratio <= 1.2).all()) and float(ratio.std()) > 0.05   # spread, not one factor
    assert bool((a[A == 0] == 0).all()) and bool((b[B == 0] == 0).all())
    assert all(torch.equal(x, y) for x, y in zip(perturbed(0.2, 3), (a, b)))
    assert not torch.equal(perturbed(0.2, 4)[0], a)
    assert float(((perturbed(0.5, 3)[0] / A)[A != 0] - 1).abs().max()) > 0.2    # a larger error, further out


@pytest.mark.parametrize("error, draw", [(0.2, 0), (0.5, 1)])
def test_the_potential_from_a_wrong_model_is_that_models_lqr_flight(error, draw):
    """The designer's (wrong) linearisation gives both the gain and the flight whose cost Φ is,
    computed here by scipy on that model; it differs from the true model's Φ."""
    from trl_dgpq.envs.f16.dynamics import perturbed
    cfg = dict(potential="lqr", decision_steps=10, potential_gamma=0.9, potential_model_error=error,
               potential_model_draw=draw)
    env = F16Env([0], **cfg)
    x = torch.tensor([[20.0, 0.0, 0.01, 0.01, 0.0], [-35.0, 4.0, -0.02, 0.03, 0.05]], dtype=torch.float64)
    model = [t.numpy() for t in perturbed(error, draw)]
    phi = env.potential(x)
    for state, value in zip(x.numpy(), phi.tolist()):
        assert value == pytest.approx(potential_by_hand(state, 0.05, 10, 1.0, 0.1, 0.9, model), rel=1e-9)
    true = F16Env([0], potential="lqr", decision_steps=10, potential_gamma=0.9).potential(x)
    assert not torch.allclose(phi, true, rtol=1e-3)
    with pytest.raises(ValueError, match="the lqr potential's model error"):
        F16Env([0], potential="cost", potential_model_error=0.2)


@pytest.mark.parametrize("steps, gamma", [(10, 0.9), (5, 0.95)])
def test_the_cost_potential_is_the_states_own_cost_paid_for_ever(steps, gamma):
    """h 30 ft, theta - alpha 0.002 rad (hdot 1.004 ft/s): (0.3 + 0.01004) per simulator step, `steps` a
    decision, sum of gamma^t = 1 / (1 - gamma); the airspeed and pitch rate cost nothing."""
    env = F16Env([0], potential="cost", decision_steps=steps, potential_gamma=gamma)
    x = torch.tensor([[30.0, 7.0, 0.001, 0.003, 0.2], [-30.0, -7.0, 0.003, 0.001, -0.2]], dtype=torch.float64)
    assert env.potential(x).tolist() == pytest.approx([-(0.3 + 0.01004) * steps / (1 - gamma)] * 2, rel=1e-12)


def test_the_potential_rides_along_and_leaves_the_flight_and_its_reward_alone():
    """Seeds 0-2 with the potential and seed 1 alone without: the same flight and rewards, bit for bit;
    each step's "potential" is phi of that step's state, and seed 1's does not depend on its batch."""
    shaped = F16Env([0, 1, 2], potential="lqr", **FLIGHT_05)
    plain, alone = F16Env([1], **FLIGHT_05), F16Env([1], potential="lqr", **FLIGHT_05)
    assert "potential" not in plain.observation_spec.keys()
    tds = shaped.reset(), plain.reset(), alone.reset()
    for action in (0, 2, 1, 1, 0):
        nxt = [env.step(td.set("action", torch.full(env.batch_size, action)))["next"] for env, td in zip(
            (shaped, plain, alone), tds)]
        assert torch.equal(nxt[0]["reward"][1], nxt[1]["reward"][0]) and torch.equal(nxt[1]["reward"], nxt[2]["reward"])
        assert torch.equal(nxt[0]["state"][1], nxt[1]["state"][0])
        assert torch.equal(nxt[0]["potential"][1], nxt[2]["potential"][0])
        assert torch.equal(nxt[0]["potential"][:, 0], shaped.potential(nxt[0]["state"]))
        tds = [n.exclude("reward", "done", "terminated", "truncated") for n in nxt]
    check_env_specs(shaped)


def transition(reward, phi, phi_next, terminated):
    t = lambda v, dtype=torch.float64: torch.tensor(v, dtype=dtype)[:, None]  # noqa: E731
    return TensorDict({"potential": t(phi), "next": {"reward": t(reward), "potential": t(phi_next),
                                                     "terminated": t(terminated, torch.bool)}}, batch_size=[len(reward)])


def test_learners_learn_from_r_plus_gamma_phi_next_minus_phi_and_phi_of_an_end_is_zero():
    td = transition([-1.0, -2.0], [-10.0, -4.0], [-8.0, -3.0], [False, True])
    # by hand: -1 + 0.9 * -8 + 10 = 1.8; terminal: -2 + 0 + 4 = 2
    assert learning_reward(td, 0.9)[:, 0].tolist() == pytest.approx([1.8, 2.0], abs=1e-12)
    plain = td.exclude("potential", ("next", "potential"))
    assert learning_reward(plain, 0.9) is plain["next", "reward"]


@pytest.mark.parametrize("agent", ["dgpq", "dqn"])
def test_a_learner_given_a_potential_learns_what_it_would_from_the_shaped_reward(agent):
    """Two learners on the same transitions: one reads the env's reward and the potential, the other
    the shaped reward r + gamma phi' - phi directly; afterwards their states are equal to the bit."""
    from tests.test_state import assert_same_state
    from trl_dgpq.collectors.experiment import build, resolve_config
    config = resolve_config(env="f16", agent=agent, preset="flight-05-shaped", seeds=[0, 1], episodes=1,
                            **(dict(learning_starts=4, batch_size=4, train_freq=1) if agent == "dqn" else {}))
    env, a = build(config)
    b = build(config)[1]
    gamma = config["agent"]["gamma"]
    td = env.reset()
    for t in range(12):
        td = td.set("action", torch.tensor([t % 3, (t + 1) % 3]))
        td = env.step(td)
        a.observe(td)
        shaped = td.exclude("potential", ("next", "potential"))
        shaped["next", "reward"] = td["next", "reward"] + gamma * td["next", "potential"] - td["potential"]
        b.observe(shaped)
        td = td["next"].exclude("reward", "done", "terminated", "truncated")
    state_a, state_b = a.state_dict(), b.state_dict()
    if agent == "dqn":  # the replay's storage past the rows written is uninitialised memory: compare those rows
        rows = lambda learner: learner.replay.storage[: learner.replay.written]  # noqa: E731
        assert_same_state(rows(a), rows(b))
        assert a.replay.written == 12 and a.updates.tolist() == [8, 8]      # updates from the 5th step
        state_a["replay"] = state_b["replay"] = None
    assert_same_state(state_a, state_b)


def test_a_scripted_agent_stores_learns_and_saves_nothing():
    from trl_dgpq.agents.base import ScriptedAgent
    agent = ScriptedAgent()
    assert ScriptedAgent.memory_bytes(None, None, 8) == 0
    assert agent.observe(None) is None and agent.episode_stats() == {} and agent.state_dict() == {}
    assert agent.load_state_dict({}) is None
