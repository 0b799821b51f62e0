import math

import pandas as pd
import pytest
import torch

from trl_dgpq.collectors.experiment import TIMING_COLUMNS, build, resolve_config, run_experiment
from trl_dgpq.collectors.online import OnlineCollector
from trl_dgpq.config import find_leaf, from_dict, to_dict, with_overrides
from trl_dgpq.dgpq import DGPQ, DGPQConfig
from trl_dgpq.gp import ExactGP, ManifoldKernel, RBFKernel, fit

D = torch.float64


def step_data(n, seed=0):
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(n, 1, generator=g, dtype=D) * 2 - 1
    y = torch.where(x[:, 0] > 0, 1.0, -1.0).to(D) + 0.1 * torch.randn(n, generator=g, dtype=D)
    return x, y


@pytest.mark.parametrize("skip", [True, False])
def test_gram_matrices_are_psd(skip):
    k = ManifoldKernel(3, 2, hidden=(10, 7), lengthscale=0.3, skip=skip)
    x = torch.rand(3, 60, 2, dtype=D)
    x[:, 30:40] = x[:, :10]  # duplicates
    K = k(x, x)
    assert torch.allclose(K, K.mT)
    assert torch.linalg.eigvalsh(K).min() >= -1e-8
    torch.testing.assert_close(K.diagonal(dim1=-2, dim2=-1), k.diag(x))


def test_fit_lowers_nll_and_gradients_reach_every_parameter():
    x, y = step_data(60)
    gp = ExactGP(ManifoldKernel(2, 1, hidden=(10,), lengthscale=0.3), 0.1, 1, batch_shape=(2,))
    gp.set_data(torch.stack((x, x)), torch.stack((y, -y)))
    with torch.enable_grad():
        nll, ok = gp.neg_log_marginal_likelihood()
        nll.sum().backward()
    assert ok.all() and nll.shape == (2,)
    for name, p in gp.kernel.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
        assert (p.grad.reshape(2, -1).abs().sum(1) > 0).all(), f"no gradient reaches {name} of every GP"
    assert (gp.likelihood.raw_noise.grad.abs() > 0).all()
    gp.zero_grad()
    out = fit(gp, steps=40, lr=0.02)
    assert (out["nll_after"] < out["nll_before"] - 1.0).all() and not out["frozen"].any()
    m, v = gp.predict(torch.linspace(-1, 1, 20, dtype=D).expand(2, 20)[..., None])
    assert torch.isfinite(m).all() and (v >= 0).all()
    assert m[0, -1] > 0.5 and m[1, -1] < -0.5


def test_fit_shared_rbf_kernel_and_refuses_the_sparse_gp():
    x, y = step_data(40)
    gp = ExactGP(RBFKernel(1.0, 1.0), 0.5, 1)
    gp.set_data(x, y)
    out = fit(gp, steps=60, lr=0.05)
    assert out["nll_after"].item() < out["nll_before"].item()
    from trl_dgpq.gp import SparseOnlineGP
    with pytest.raises(TypeError, match="ExactGP"):
        fit(SparseOnlineGP(RBFKernel(), 0.1, 1))


def test_manifold_needs_the_exact_backend():
    with pytest.raises(ValueError, match="exact"):
        with_overrides(DGPQConfig(), dict(kernel="manifold", gp="sparse")).resolve(4)


def manifold_config(seeds, **kw):
    return resolve_config(preset="report", seeds=seeds, episodes=2, gp="exact", kernel="manifold",
                          kernel_train_every=25, kernel_min_points=5, kernel_train_steps=10, max_steps=100, **kw)


def training_config(seeds, **kw):
    """sigma_tol2 = 0.05 needs a few samples at a point, so GPs fill up (the kernel trains)
    and then Q̂ is overwritten (every GP of the seed is emptied): both paths in 2 episodes."""
    return resolve_config(preset="shaped", seeds=seeds, episodes=2, gp="exact", kernel="manifold", sigma_tol2=0.05,
                          kernel_train_every=5, kernel_min_points=5, kernel_train_steps=5, max_steps=60, **kw)


@pytest.mark.slow
def test_no_nan_over_2000_dgpq_steps():
    env, agent = build(manifold_config([0, 1]))
    df = OnlineCollector(env, agent, 10 ** 9, max_total_steps=2000, progress=False).run()
    assert agent.kernel_fits.sum() > 0
    for name, p in agent.gp.kernel.named_parameters():
        assert torch.isfinite(p).all(), name
    noise = agent.gp.likelihood.noise
    assert torch.isfinite(noise).all() and (noise > 0).all()
    assert torch.isfinite(agent.gp.L).all() and torch.isfinite(agent.gp.z).all()
    assert len(df) >= 2 and df["return"].notna().all()


def test_manifold_seeds_stay_independent_through_training_and_overwrites():
    drop = lambda df: df.drop(columns=list(TIMING_COLUMNS)).reset_index(drop=True)  # noqa: E731
    batch = drop(run_experiment(training_config([0, 1, 2]), progress=False))
    alone = drop(run_experiment(training_config([1]), progress=False))
    assert (batch.kernel_fits > 0).all() and (batch.groupby("seed").qhat_updates.max() > 0).all()
    pd.testing.assert_frame_equal(alone, batch[batch.seed == 1].reset_index(drop=True),
                                  check_exact=False, rtol=0, atol=1e-8)


def test_fit_trouble_keeps_last_good_parameters_and_logs(caplog):
    x, y = step_data(40)
    gp = ExactGP(ManifoldKernel(1, 1, hidden=(10,), lengthscale=0.3), 0.1, 1, batch_shape=(1,))
    gp.set_data(x[None], y[None])
    with caplog.at_level("WARNING"):
        out = fit(gp, steps=30, lr=1e4)  # absurd step size: blows up unless guarded
    for name, p in gp.kernel.named_parameters():
        assert torch.isfinite(p).all(), name
    assert torch.isfinite(gp.likelihood.noise).all() and torch.isfinite(gp.L).all()
    m, v = gp.predict(x[None, :5])
    assert torch.isfinite(m).all() and torch.isfinite(v).all()
    assert out["frozen"].all() and "kept their last good parameters" in caplog.text
    torch.testing.assert_close(out["nll_after"], out["nll_before"])  # back at the last good point


def test_fit_with_a_shared_kernel_refits_every_gp():
    """A shared RBF kernel trained on GP 0 changes GP 1 too: its posterior must be the one
    sklearn gives with the new hyperparameters, not the stale one."""
    x, y = step_data(30)
    gp = ExactGP(RBFKernel(1.0, 1.0), 0.1, 1, batch_shape=(2,))
    gp.set_data(torch.stack((x, x)), torch.stack((y, -y)))
    fit(gp, torch.tensor([True, False]), steps=30, lr=0.05)
    ls, os_, noise = gp.kernel.lengthscale.item(), gp.kernel.outputscale.item(), gp.likelihood.noise[1].item()
    assert abs(ls - 1.0) > 0.05  # the kernel did change
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel
    xq = torch.linspace(-1, 1, 7, dtype=D)[:, None]
    sk = GaussianProcessRegressor(ConstantKernel(os_, "fixed") * RBF(ls, "fixed"), alpha=noise,
                                  optimizer=None).fit(x.numpy(), -y.numpy())
    m_sk, s_sk = sk.predict(xq.numpy(), return_std=True)
    m, v = gp.predict(xq.expand(2, 7, 1))
    torch.testing.assert_close(m[1], torch.as_tensor(m_sk), atol=1e-8, rtol=0)
    torch.testing.assert_close(v[1], torch.as_tensor(s_sk ** 2), atol=1e-8, rtol=0)


def test_a_frozen_gp_stays_at_its_last_good_parameters(monkeypatch):
    """GP 0's loss is non-finite once, at the 6th evaluation: it is frozen at the parameters
    of the 5th and must not move again (Adam's momentum would keep moving it, and its loss
    is finite again by the end), while GP 1 trains on."""
    x, y = step_data(40)
    gp = ExactGP(ManifoldKernel(2, 1, hidden=(10,), lengthscale=0.3), 0.1, 1, batch_shape=(2,))
    gp.set_data(torch.stack((x, x)), torch.stack((y, -y)))
    seen, real = [], ExactGP.neg_log_marginal_likelihood

    def nll(gp_, mask=None):
        seen.append([p.detach()[0].clone() for p in gp_.kernel.parameters()])
        out, ok = real(gp_, mask)
        if len(seen) == 6:  # a passing trouble of GP 0
            out = torch.where(torch.arange(2) == 0, torch.nan, out)
        return out, ok
    monkeypatch.setattr(ExactGP, "neg_log_marginal_likelihood", nll)
    start1 = [p.detach()[1].clone() for p in gp.kernel.parameters()]
    out = fit(gp, steps=20, lr=0.05)
    assert out["frozen"].tolist() == [True, False]
    for p, good in zip(gp.kernel.parameters(), seen[4]):   # the parameters of the last good evaluation
        torch.testing.assert_close(p.detach()[0], good, atol=0, rtol=0)
    assert any((p.detach()[1] - s).abs().max() > 1e-3 for p, s in zip(gp.kernel.parameters(), start1))


def test_train_creates_tensors_on_the_gps_device():
    """Every tensor factory call in gp/train.py names a device (or copies one with *_like),
    so fitting works for GPs on an accelerator."""
    import ast
    import inspect
    import trl_dgpq.gp.train as train
    factories = {"zeros", "ones", "arange", "eye", "full", "empty", "tensor", "rand", "randn", "linspace"}
    bad = [node.lineno for node in ast.walk(ast.parse(inspect.getsource(train)))
           if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in factories
           and isinstance(node.func.value, ast.Name) and node.func.value.id == "torch"
           and not any(kw.arg == "device" for kw in node.keywords)]
    assert not bad, f"tensors created without device= on lines {bad}"


def test_manifold_kernel_trains_once_per_kernel_train_every_new_points():
    """sigma_tol2 tiny: every step at a new state adds a point and none overwrites Q̂, so the
    taken action's GP grows by one per step. kernel_train_every = kernel_min_points = 3:
    trainings after the 3rd and the 6th point only, i.e. 2 after 7 points."""
    cfg = with_overrides(DGPQConfig(), dict(gp="exact", kernel="manifold", sigma_tol2=1e-9, eps1=100.0,
                                            kernel_train_every=3, kernel_min_points=3, kernel_train_steps=1,
                                            lengthscale=0.1, gamma=0.5, v_max=10.0))
    ag = DGPQ(cfg, seeds=[0], state_dim=2, num_actions=2)
    for i in range(7):
        out = ag.learn(torch.tensor([[0.1 * i, 0.5]], dtype=D), torch.tensor([0]), torch.tensor([1.0], dtype=D),
                       torch.tensor([[0.1 * i, 0.6]], dtype=D), torch.tensor([False]))
        assert out["learn"].item() and not out["update"].item()
    assert ag.gp.size.tolist() == [[7, 0]]
    assert ag.kernel_fits.tolist() == [2]


@pytest.mark.parametrize("kernel", ["manifold", "rbf"])
def test_fitting_one_gp_leaves_the_others_bit_identical(kernel):
    """Per-GP hyperparameters do not leak: fitting GP 1 of 3 moves GP 1's kernel rows, noise
    and predictions, and leaves every row of GPs 0 and 2 - data, factor, kernel parameters,
    noise - and their predictions bit-identical."""
    x, y = step_data(40)
    k = (ManifoldKernel(3, 1, hidden=(10,), lengthscale=0.3) if kernel == "manifold"
         else RBFKernel(0.3, 1.0, batch_shape=(3,)))
    gp = ExactGP(k, 0.1, 1, batch_shape=(3,))
    gp.set_data(torch.stack((x, -x, x)), torch.stack((y, y, -y)))
    xq = torch.linspace(-1, 1, 9, dtype=D).expand(3, 9)[..., None]
    before = {name: t.clone() for name, t in gp.state_dict().items()}
    m0, v0 = gp.predict(xq)
    out = fit(gp, torch.tensor([False, True, False]), steps=20, lr=0.05)
    assert out["rows"].tolist() == [1] and not out["frozen"].any()
    after = gp.state_dict()
    assert all(t.shape[0] == 3 for t in after.values())  # every state tensor has one row per GP
    for name, t in before.items():
        assert torch.equal(after[name][[0, 2]], t[[0, 2]]), name
    moved = [name for name, t in before.items() if not torch.equal(after[name][1], t[1])]
    assert set(moved) >= {f"kernel.{n}" for n, _ in gp.kernel.named_parameters()} | {"likelihood.noise"}
    m1, v1 = gp.predict(xq)
    assert torch.equal(m1[[0, 2]], m0[[0, 2]]) and torch.equal(v1[[0, 2]], v0[[0, 2]])
    assert not torch.equal(m1[1], m0[1])


def test_kernel_training_settings_are_dgpqs_and_old_configs_still_load():
    """kernel_train_every & co. are DGPQConfig's own settings (same flat names, so the
    flags and presets keep working); a config recorded before the move holds them under
    gp, and from_dict moves them (DGPQConfig.upgrade)."""
    cfg = with_overrides(DGPQConfig(), dict(kernel="manifold", gp="exact", kernel_train_every=7, kernel_lr=0.05))
    assert (cfg.kernel_train_every, cfg.kernel_lr, cfg.kernel_min_points) == (7, 0.05, 5)
    for key in DGPQConfig.KERNEL_TRAINING:
        assert find_leaf(DGPQConfig, key).path == (key,)
    new = to_dict(cfg)
    assert not set(DGPQConfig.KERNEL_TRAINING) & set(new["gp"])
    old = {k: v for k, v in new.items() if k not in DGPQConfig.KERNEL_TRAINING}
    old["gp"] = dict(new["gp"], **{k: new[k] for k in DGPQConfig.KERNEL_TRAINING})
    assert from_dict(DGPQConfig, old) == cfg
    assert DGPQConfig.upgrade(new) is new
    with pytest.raises(ValueError, match="given twice"):
        from_dict(DGPQConfig, dict(old, kernel_lr=0.1))
    for bad, match in ((dict(kernel_train_every=0), "kernel_train_every"), (dict(kernel_lr=0.0), "kernel_lr"),
                       (dict(kernel_train_steps=0), "kernel_train_steps")):
        with pytest.raises(ValueError, match=match):
            with_overrides(DGPQConfig(), bad).resolve(4)


# ---------------------------------------------------------------- the feature map's initialisation, by hand
def _draws(n, count):
    """A known 'uniform' source: every draw different, so a weight read from the wrong place shows."""
    return (torch.arange(n * count, dtype=torch.float32).reshape(n, count) + 0.5) / (n * count)


def test_initial_weights_are_glorot_uniform_read_in_order_from_the_draws():
    """skip=True, hidden (3,), 2 inputs, 2 GPs: 15 draws per GP, read as weight0 (3, 2) with Glorot's
    scale sqrt(6 / (2 + 3)), then bias0 (3,) unscaled, then the skip map (2, 3) at 0.01 -- each
    2 u - 1, so in (-1, 1); float64 though the draws are float32."""
    asked = []
    k = ManifoldKernel(2, 2, hidden=(3,), uniform=lambda n, c: asked.append((n, c)) or _draws(n, c))
    assert asked == [(2, 15)]
    u = _draws(2, 15).double() * 2 - 1
    assert torch.equal(k.weight0, u[:, :6].reshape(2, 3, 2) * math.sqrt(6 / 5))
    assert torch.equal(k.bias0, u[:, 6:9])
    assert torch.equal(k.skip_weight, u[:, 9:].reshape(2, 2, 3) * 0.01)
    assert all(p.dtype == torch.float64 for p in k.parameters())
    assert [name for name, _ in k.named_parameters()] == ["raw_lengthscale", "raw_outputscale", "weight0",
                                                          "skip_weight", "bias0"]


def test_without_skip_each_layer_has_its_own_glorot_scale_and_no_output_map():
    k = ManifoldKernel(1, 2, hidden=(3, 4), skip=False, uniform=_draws)
    u = _draws(1, 6 + 3 + 12 + 4).double() * 2 - 1
    assert torch.equal(k.weight0, u[:, :6].reshape(1, 3, 2) * math.sqrt(6 / 5))
    assert torch.equal(k.bias0, u[:, 6:9])
    assert torch.equal(k.weight1, u[:, 9:21].reshape(1, 4, 3) * math.sqrt(6 / 7))
    assert torch.equal(k.bias1, u[:, 21:])
    assert not hasattr(k, "skip_weight") and k.depth == 2


def test_the_default_kernel_and_its_default_draws():
    """Defaults: one hidden layer of 10, tanh, skip, both scales 1, and draws from torch's generator
    seeded 0 (float64) -- the same kernel every time it is made without a stream."""
    k = ManifoldKernel(2, 3)
    assert (k.hidden, k.skip, k.act) == ((10,), True, torch.tanh)
    assert k.lengthscale.tolist() == [1.0, 1.0] and k.outputscale.tolist() == [1.0, 1.0]
    u = torch.rand(2, 30 + 10 + 30, generator=torch.Generator().manual_seed(0), dtype=torch.float64) * 2 - 1
    assert torch.equal(k.weight0, u[:, :30].reshape(2, 10, 3) * math.sqrt(6 / 13))
    assert torch.equal(k.skip_weight, u[:, 40:].reshape(2, 3, 10) * 0.01)
    assert k.raw_lengthscale.dtype == torch.float64


@pytest.mark.parametrize("kw, match", [
    (dict(batch_shape=()), r"^ManifoldKernel needs batch_shape \(N,\): one feature map per GP$"),
    (dict(hidden=()), r"^hidden must be a non-empty list of positive widths, got \(\)$"),
    (dict(hidden=(4, 0)), r"^hidden must be a non-empty list of positive widths, got \(4, 0\)$"),
    (dict(activation="relu"), r"^activation must be one of \['sigmoid', 'softplus', 'tanh'\], got 'relu'$")])
def test_bad_settings_are_refused_by_name(kw, match):
    with pytest.raises(ValueError, match=match):
        ManifoldKernel(**{"batch_shape": 2, "in_dim": 1, **kw})


def test_a_hidden_layer_of_one_is_allowed():
    assert ManifoldKernel(1, 1, hidden=(1,)).weight0.shape == (1, 1, 1)


def test_features_are_the_input_plus_the_output_map_of_the_hidden_layer_by_hand():
    """M(x) = x + W_out tanh(W_1 x + b_1) with skip; tanh(W_1 x + b_1) without; one GP, 1 input,
    one hidden unit, weights set by hand."""
    for skip, want in ((True, 0.5 + 2.0 * math.tanh(3.0 * 0.5 - 1.0)), (False, math.tanh(3.0 * 0.5 - 1.0))):
        k = ManifoldKernel(1, 1, hidden=(1,), skip=skip)
        with torch.no_grad():
            k.weight0.fill_(3.0), k.bias0.fill_(-1.0)
            if skip:
                k.skip_weight.fill_(2.0)
        assert k.features(torch.tensor([[[0.5]]], dtype=D)).item() == pytest.approx(want, rel=1e-15)


def test_a_float32_kernel_keeps_every_parameter_in_float32():
    k = ManifoldKernel(2, 1, dtype=torch.float32)
    assert {p.dtype for p in k.parameters()} == {torch.float32}


def test_the_kernel_says_what_it_is():
    assert repr(ManifoldKernel(2, 3, hidden=(4,), skip=False)).startswith(
        "ManifoldKernel(batch_shape=(2,), in_dim=3, hidden=(4,), skip=False")
