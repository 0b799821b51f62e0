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
    x0 = torch.tensor([100.0, 0.0, 0.01, 0.01, 0.0], dtype=torch.float64)
    for i, e in enumerate((1.0, -1.0)):
        x = ad @ x0 + bd * e
        hdot = V_T0 * (x[3] - x[2])
        assert float(out["reward"][i]) == pytest.approx(-abs(float(x[0])) / 100 - abs(float(hdot)) / 100 - 1.0)
        torch.testing.assert_close(out["observation"][i] * env.scale, x)


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


def test_lqr_gain_solves_the_discrete_riccati_equation():
    scipy_linalg = pytest.importorskip("scipy.linalg")
    a, b = discretise(0.05)
    rate = torch.tensor([0.0, 0.0, -V_T0, V_T0, 0.0], dtype=torch.float64) / 100
    q = torch.diag(torch.tensor([1e-4, 0, 0, 0, 0], dtype=torch.float64)) + torch.outer(rate, rate)
    p = scipy_linalg.solve_discrete_are(a.numpy(), b.numpy()[:, None], q.numpy(), np.array([[0.3]]))
    k = (b.numpy() @ p @ a.numpy()) / (0.3 + b.numpy() @ p @ b.numpy())
    np.testing.assert_allclose(lqr_gain(a, b, q, 0.3).numpy(), k, rtol=1e-6)


@pytest.mark.parametrize("agent, most", [("lqr", 25.0), ("pd", 50.0)])
def test_the_controllers_hold_altitude_where_doing_nothing_diverges(agent, most):
    """Seeds 0-7, one default episode (200 steps) each: the altitude error at the end."""
    env = F16Env(list(range(8)))
    cls = agent_class(agent, "f16")
    policy = cls.make(cls.Config(), env.info, list(range(8)))
    ret, terminated, last = rollout(env, lambda td: policy.act(td))
    assert not terminated.any() and last[:, 0].abs().max() < most
    nothing_ret, _, nothing_last = rollout(F16Env(list(range(8))), lambda td: torch.ones(8, dtype=torch.long))
    assert nothing_last[:, 0].abs().min() > 100 and (ret > nothing_ret).all()
