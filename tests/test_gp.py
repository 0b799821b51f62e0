import numpy as np
import pytest
import torch

from trl_dgpq.gp import ExactGP, GPNumericalError, ManifoldKernel, RBFKernel, SparseOnlineGP

LS, OS, NOISE = 0.3, 1.5, 0.1
D = torch.float64


def sklearn_gp(X, y, noise=NOISE, ls=LS, os_=OS):
    # (imported here: sklearn takes ~1 s to import, which every test process would pay at collection)
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel
    return GaussianProcessRegressor(ConstantKernel(os_, "fixed") * RBF(ls, "fixed"),
                                    alpha=noise, optimizer=None).fit(X, y)


def sklearn_predict(X, y, Xq, noise=NOISE, ls=LS, os_=OS):
    m, s = sklearn_gp(X, y, noise, ls, os_).predict(Xq, return_std=True)
    return m, s ** 2


def stream(batch, npts, seed=0, dim=2):
    g = torch.Generator().manual_seed(seed)
    X = torch.rand(npts, *batch, dim, generator=g, dtype=D)
    y = torch.sin(6 * X.sum(-1)) + 0.1 * torch.randn(npts, *batch, generator=g, dtype=D)
    masks = torch.rand(npts, *batch, generator=g) < 0.6
    Xq = torch.rand(*batch, 9, dim, generator=g, dtype=D)
    return X, y, masks, Xq


def per_gp_data(X, y, masks, idx):
    """The points GP ``idx`` actually received."""
    sel = masks[(slice(None), *idx)]
    return X[(slice(None), *idx)][sel].numpy(), y[(slice(None), *idx)][sel].numpy()


@pytest.mark.parametrize("batch", [(), (3, 4)])
def test_exact_matches_sklearn(batch):
    X, y, masks, Xq = stream(batch, 40)
    gp = ExactGP(RBFKernel(LS, OS), NOISE, dim=2, batch_shape=batch, capacity=16)  # forces growth
    for t in range(40):
        gp.add(X[t], y[t], mask=masks[t] if batch else None)
    mean, var = gp.predict(Xq)
    for idx in np.ndindex(*batch):
        Xi, yi = per_gp_data(X, y, masks if batch else torch.ones(40, dtype=bool), idx)
        ms, vs = sklearn_predict(Xi, yi, Xq[idx].numpy())
        np.testing.assert_allclose(mean[idx].numpy(), ms, atol=1e-8, rtol=0)
        np.testing.assert_allclose(var[idx].numpy(), vs, atol=1e-8, rtol=0)
        assert gp.size[idx] == len(yi)


def test_exact_set_data_equals_incremental():
    X, y, _, Xq = stream((2,), 25)
    a = ExactGP(RBFKernel(LS, OS), NOISE, 2, batch_shape=(2,))
    b = ExactGP(RBFKernel(LS, OS), NOISE, 2, batch_shape=(2,), capacity=4)
    for t in range(25):
        a.add(X[t], y[t])
    b.set_data(X.transpose(0, 1), y.T)
    for u, v in zip(a.predict(Xq), b.predict(Xq)):
        torch.testing.assert_close(u, v, atol=1e-10, rtol=0)
    b.refit()
    torch.testing.assert_close(a.predict(Xq)[0], b.predict(Xq)[0], atol=1e-10, rtol=0)


def test_predict_mask_reports_prior_for_unselected():
    X, y, _, Xq = stream((3,), 10)
    gp = ExactGP(RBFKernel(LS, OS), NOISE, 2, batch_shape=(3,))
    for t in range(10):
        gp.add(X[t], y[t])
    full_m, full_v = gp.predict(Xq)
    m, v = gp.predict(Xq, mask=torch.tensor([False, True, False]))
    torch.testing.assert_close(m[1], full_m[1])
    torch.testing.assert_close(v[1], full_v[1])
    assert (m[[0, 2]] == 0).all() and torch.allclose(v[[0, 2]], torch.full_like(v[[0, 2]], OS))


@pytest.mark.parametrize("batch", [(), (3, 4)])
def test_sparse_with_room_equals_exact(batch):
    X, y, masks, Xq = stream(batch, 40, seed=1)
    k = RBFKernel(LS, OS)
    ex = ExactGP(k, NOISE, 2, batch_shape=batch)
    sp = SparseOnlineGP(k, NOISE, 2, batch_shape=batch, budget=50, novelty_tol=0.0)
    for t in range(40):
        mask = masks[t] if batch else None
        ex.add(X[t], y[t], mask)
        sp.add(X[t], y[t], mask)
    assert torch.equal(sp.size, ex.size)
    for u, v in zip(ex.predict(Xq), sp.predict(Xq)):
        torch.testing.assert_close(u, v, atol=1e-4, rtol=0)


def test_sparse_well_separated_points_agree_to_round_off():
    k = RBFKernel(0.05, 1.0)
    grid = torch.stack(torch.meshgrid(torch.linspace(0, 1, 6, dtype=D), torch.linspace(0, 1, 6, dtype=D),
                                      indexing="ij"), -1).reshape(-1, 2)
    y = torch.cos(5 * grid[:, 0])
    ex, sp = ExactGP(k, NOISE, 2), SparseOnlineGP(k, NOISE, 2, budget=40, novelty_tol=0.0)
    for xi, yi in zip(grid, y):
        ex.add(xi, yi)
        sp.add(xi, yi)
    xq = grid[None, :5] + 0.01
    for u, v in zip(ex.predict(xq[0]), sp.predict(xq[0])):
        torch.testing.assert_close(u, v, atol=1e-12, rtol=0)


def test_sparse_small_budget_stays_bounded_and_finite():
    X, y, masks, Xq = stream((4,), 300, seed=2)
    sp = SparseOnlineGP(RBFKernel(0.1, 1.0), 1e-4, 2, batch_shape=(4,), budget=8, novelty_tol=0.0)
    for t in range(300):
        sp.add(X[t], y[t], masks[t])
        assert (sp.size <= 8).all()
    m, v = sp.predict(Xq)
    assert torch.isfinite(m).all() and torch.isfinite(v).all() and (v >= 0).all()
    assert (sp.size == 8).all()
    # Unused slots stay exactly zero: the padding invariant the batching relies on.
    assert (sp.C[:, 8] == 0).all() and (sp.Q[:, :, 8] == 0).all() and (sp.alpha[:, 8] == 0).all()


def test_sparse_deleting_new_point_equals_projection():
    """Extending with x and deleting it again must equal the eta-corrected projection of x."""
    X, y, _, _ = stream((), 12, seed=3)
    k = RBFKernel(LS, OS)
    a = SparseOnlineGP(k, NOISE, 2, budget=10, novelty_tol=0.0)
    for t in range(10):
        a.add(X[t], y[t])
    b = SparseOnlineGP(k, NOISE, 2, budget=10, novelty_tol=0.0)
    b.load_state_dict(a.state_dict())
    x_new, y_new = X[10:11], y[10:11]
    a._add(a._state(), x_new, y_new, force_project=True)
    b._kl_argmin = lambda st: st["n"] - 1  # force deletion of the just-added vector
    b._add(b._state(), x_new, y_new)
    assert int(a.n) == int(b.n) == 10
    for name in ("alpha", "C", "Q", "BV"):
        torch.testing.assert_close(getattr(a, name), getattr(b, name), atol=1e-12, rtol=0)


def test_sparse_deletion_removes_the_smallest_kl_score():
    """Over budget, the basis vector with the smallest alpha_j^2 / (Q_jj + C_jj) goes. The
    scores are read from a GP with room for all 11 points: the state before the deletion."""
    X, y, _, _ = stream((), 11, seed=4)
    k = RBFKernel(LS, OS)
    room = SparseOnlineGP(k, NOISE, 2, budget=11, novelty_tol=0.0)
    sp = SparseOnlineGP(k, NOISE, 2, budget=10, novelty_tol=0.0)
    for t in range(11):
        room.add(X[t], y[t])
        sp.add(X[t], y[t])
    assert int(room.n) == 11 and int(sp.n) == 10
    score = room.alpha[0, :11] ** 2 / (room.Q[0, :11, :11].diagonal() + room.C[0, :11, :11].diagonal())
    j = int(score.argmin())
    assert j != int(score.argmax())
    kept = {tuple(r) for r in sp.BV[0, :10].tolist()}
    assert kept == {tuple(r) for i, r in enumerate(X.tolist()) if i != j}


def test_novelty_tol_decides_which_points_extend_the_basis():
    """k = exp(-d^2 / (2 0.3^2)); after x0, a point 0.02 away has novelty 1 - k^2 = 0.00443,
    one at (0.9, 0.1) has novelty 1 - exp(-0.32/0.18)^2 = 0.971."""
    x0, near, far = (torch.tensor(v, dtype=D) for v in ([0.5, 0.5], [0.52, 0.5], [0.9, 0.1]))
    for tol, sizes in ((0.01, [1, 1, 2]), (0.001, [1, 2, 3])):
        sp = SparseOnlineGP(RBFKernel(0.3, 1.0), NOISE, 2, budget=10, novelty_tol=tol)
        got = []
        for x in (x0, near, far):
            sp.add(x, torch.tensor(1.0, dtype=D))
            got.append(int(sp.n))
        assert got == sizes, tol


@pytest.mark.parametrize("cls,kw", [(ExactGP, {}), (SparseOnlineGP, {"budget": 5})])
def test_duplicates_and_tiny_noise_stay_finite(cls, kw):
    gp = cls(RBFKernel(0.2, 1.0), 1e-12, 2, **kw)
    x = torch.tensor([0.3, 0.3], dtype=D)
    for i in range(20):
        gp.add(x, torch.tensor(1.0 + 1e-3 * i, dtype=D))
    m, v = gp.predict(x[None])
    assert torch.isfinite(m).all() and torch.isfinite(v).all() and (v >= 0).all()
    assert abs(m.item() - 1.0095) < 1e-5   # the mean of the 20 targets


def test_exact_zero_noise_duplicates_use_jitter():
    gp = ExactGP(RBFKernel(0.2, 1.0), 0.0, 1)
    for _ in range(3):
        gp.add(torch.tensor([0.5]), torch.tensor(2.0))
    m, v = gp.predict(torch.tensor([[0.5]]))
    assert torch.isfinite(m).all() and abs(m.item() - 2.0) < 1e-3


@pytest.mark.parametrize("cls", [ExactGP, SparseOnlineGP])
def test_bad_inputs_raise(cls):
    gp = cls(RBFKernel(), 0.1, 2, batch_shape=(3,))
    x, y = torch.zeros(3, 2), torch.zeros(3)
    with pytest.raises(ValueError, match="x must have shape"):
        gp.add(torch.zeros(3, 3), y)
    with pytest.raises(ValueError, match="y must have shape"):
        gp.add(x, torch.zeros(4))
    with pytest.raises(ValueError, match="NaN or inf"):
        gp.add(torch.tensor([[0.0, float("nan")]] * 3), y)
    with pytest.raises(ValueError, match="NaN or inf"):
        gp.add(x, torch.tensor([0.0, float("inf"), 0.0]))
    with pytest.raises(ValueError, match="mask"):
        gp.add(x, y, mask=torch.ones(3))
    with pytest.raises(ValueError, match="xq"):
        gp.predict(torch.zeros(3, 2))
    with pytest.raises(ValueError, match="noise_var"):
        cls(RBFKernel(), -0.1, 2)
    with pytest.raises(ValueError, match="lengthscale"):
        RBFKernel(lengthscale=0.0)
    assert (gp.size == 0).all()


def test_reset_mask_and_capacity_errors():
    gp = ExactGP(RBFKernel(), 0.1, 1, batch_shape=(2,), capacity=2, max_capacity=2)
    for _ in range(2):
        gp.add(torch.rand(2, 1), torch.rand(2))
    with pytest.raises(GPNumericalError, match="full"):
        gp.add(torch.rand(2, 1), torch.rand(2))
    gp.reset(torch.tensor([True, False]))
    assert gp.size.tolist() == [0, 2]
    m, v = gp.predict(torch.full((2, 1, 1), 0.5))
    assert m[0].item() == 0 and v[0].item() == pytest.approx(1.0)
    with pytest.raises(ValueError, match="budget"):
        SparseOnlineGP(RBFKernel(), 0.1, 1, budget=0)


@pytest.mark.parametrize("cls,kw,atol", [(ExactGP, {}, 1e-8), (SparseOnlineGP, {"budget": 50, "novelty_tol": 0.0}, 1e-4)])
def test_add_if_uncertain_matches_sklearn(cls, kw, atol):
    """Gate, variance before and posterior after, against sklearn fitted on the points the
    gate let in (the sparse GP with room and novelty_tol 0 is exact)."""
    X, y, _, _ = stream((), 30, seed=6)
    gp = cls(RBFKernel(LS, OS), NOISE, 2, **kw)
    tol, kept = 0.3, []
    for t in range(30):
        if kept:
            _, before = sklearn_predict(X[kept].numpy(), y[kept].numpy(), X[t:t + 1].numpy())
        else:
            before = np.array([OS])
        var1, mean2, var2, added = gp.add_if_uncertain(X[t], y[t], tol)
        assert abs(var1.item() - before[0]) < atol
        assert bool(added) == (before[0] > tol)
        if added:
            kept.append(t)
        m, v = sklearn_predict(X[kept].numpy(), y[kept].numpy(), X[t:t + 1].numpy())
        assert abs(mean2.item() - m[0]) < atol and abs(var2.item() - v[0]) < atol
    assert 5 < len(kept) < 30  # the gate both took and refused points


@pytest.mark.parametrize("cls,kw", [(ExactGP, {}), (SparseOnlineGP, {"budget": 6, "novelty_tol": 1e-3}),
                                    (SparseOnlineGP, {"budget": 50, "novelty_tol": 0.3})])
def test_add_if_uncertain_matches_predict(cls, kw):
    """The gated add reports exactly what predict sees before and after, and only
    adds where the variance exceeds the gate (projection and deletion paths included)."""
    X, y, masks, _ = stream((3, 2), 30, seed=5)
    a = cls(RBFKernel(LS, OS), NOISE, 2, batch_shape=(3, 2), **kw)
    b = cls(RBFKernel(LS, OS), NOISE, 2, batch_shape=(3, 2), **kw)
    tol = 0.5
    for t in range(30):
        x = X[t]
        _, before = b.predict(x[..., None, :])
        var1, mean2, var2, added = a.add_if_uncertain(x, y[t], tol, mask=masks[t])
        sel = masks[t]
        torch.testing.assert_close(var1[sel], before[..., 0][sel], atol=1e-10, rtol=0)
        assert (var1[~sel] == OS).all() and (mean2[~sel] == 0).all()  # unselected: prior
        expect = sel & (before[..., 0] > tol)
        assert torch.equal(added, expect)
        b.add(x, y[t], mask=expect)
        m_after, v_after = b.predict(x[..., None, :])
        torch.testing.assert_close(mean2[sel], m_after[..., 0][sel], atol=1e-9, rtol=0)
        torch.testing.assert_close(var2[sel], v_after[..., 0][sel], atol=1e-9, rtol=0)
        assert torch.equal(a.size, b.size)


def test_jitter_ladder_keeps_each_matrix_at_the_jitter_that_fixed_it():
    """One matrix needs the smallest rung, the other a larger one: both must factorise."""
    from trl_dgpq.gp.exact import cholesky_jitter
    A = torch.ones(2, 2, dtype=D)                                   # singular: smallest rung fixes it
    B = torch.tensor([[1.0, 1.0 + 5e-6], [1.0 + 5e-6, 1.0]], dtype=D)  # eigenvalue -5e-6: needs 1e-4
    L = cholesky_jitter(torch.stack((A, B)), torch.ones(2, dtype=D))
    assert torch.isfinite(L).all()
    rebuilt = L @ L.mT
    assert (rebuilt - torch.stack((A, B))).abs().max() < 2e-4
    assert (rebuilt[0] - A).abs().max() < 1e-8                      # A kept its tiny jitter


# ------------------------------------------------ kernels, likelihood, NLL
def test_one_kernel_call_signature_batch_shapes_and_select():
    """A kernel with batch_shape (N,) on x1 (N, n, d), x2 (N, m, d) gives (N, n, m), row i
    being GP i's own kernel; select(rows) is that kernel on those rows, bit for bit, and
    its gradients reach only those rows. A shared kernel (batch_shape ()) broadcasts and
    select returns it."""
    g = torch.Generator().manual_seed(0)
    x1, x2 = torch.rand(4, 5, 2, generator=g, dtype=D), torch.rand(4, 3, 2, generator=g, dtype=D)
    rows = torch.tensor([3, 1])
    per = RBFKernel(batch_shape=(4,))
    with torch.no_grad():
        per.raw_lengthscale.copy_(torch.tensor([0.2, 0.5, 1.0, 0.3], dtype=D).log())
        per.raw_outputscale.copy_(torch.tensor([1.0, 2.0, 0.5, 1.5], dtype=D).log())
    K = per(x1, x2)
    assert per.batch_shape == (4,) and K.shape == (4, 5, 3) and per.diag(x1).shape == (4, 5)
    for i in range(4):
        alone = RBFKernel()
        with torch.no_grad():
            alone.raw_lengthscale.copy_(per.raw_lengthscale[i])
            alone.raw_outputscale.copy_(per.raw_outputscale[i])
        assert torch.equal(K[i], alone(x1[i], x2[i])) and torch.equal(per.diag(x1)[i], alone.diag(x1[i]))
    for kernel in (per, ManifoldKernel(4, 2, hidden=(6,), lengthscale=0.4)):
        sub = kernel.select(rows)
        assert sub.batch_shape == (2,)
        assert torch.equal(sub(x1[rows], x2[rows]), kernel(x1, x2)[rows])
        assert torch.equal(sub.diag(x1[rows]), kernel.diag(x1)[rows])
        kernel.zero_grad()
        kernel.select(rows)(x1[rows], x2[rows]).sum().backward()
        for name, p in kernel.named_parameters():
            touched = p.grad.reshape(4, -1).abs().sum(1) > 0
            assert touched.tolist() == [False, True, False, True], name
    shared = RBFKernel(LS, OS)
    assert shared.batch_shape == () and shared.select(rows) is shared
    assert shared(x1, x2).shape == (4, 5, 3) and shared(x1[0], x2[0]).shape == (5, 3)


def test_per_gp_kernel_hyperparameters_reach_their_own_gp():
    """Each GP of a (3, 2) batch with its own lengthscale and outputscale (an RBF kernel
    with batch_shape (6,)) matches sklearn with its own values, through masked (gathered)
    adds, gated adds and masked and full predictions."""
    X, y, masks, Xq = stream((3, 2), 30, seed=7)
    ls, os_ = torch.linspace(0.15, 0.6, 6, dtype=D), torch.linspace(0.5, 2.0, 6, dtype=D)
    kernel = RBFKernel(batch_shape=(6,))
    with torch.no_grad():
        kernel.raw_lengthscale.copy_(ls.log())
        kernel.raw_outputscale.copy_(os_.log())
    ls, os_ = kernel.lengthscale.detach(), kernel.outputscale.detach()
    gp = ExactGP(kernel, NOISE, 2, batch_shape=(3, 2))
    for t in range(30):
        if t % 2:
            gp.add(X[t], y[t], mask=masks[t])
        else:
            gp.add_if_uncertain(X[t], y[t], -1.0, mask=masks[t])  # gate below any variance: adds
    some = torch.tensor([[True, False], [False, True], [True, True]])
    for mask in (None, some):
        mean, var = gp.predict(Xq, mask=mask)
        for flat, idx in enumerate(np.ndindex(3, 2)):
            if mask is not None and not mask[idx]:
                assert (mean[idx] == 0).all() and torch.allclose(var[idx], os_[flat].expand(9))
                continue
            Xi, yi = per_gp_data(X, y, masks, idx)
            ms, vs = sklearn_predict(Xi, yi, Xq[idx].numpy(), ls=ls[flat].item(), os_=os_[flat].item())
            np.testing.assert_allclose(mean[idx].numpy(), ms, atol=1e-8, rtol=0)
            np.testing.assert_allclose(var[idx].numpy(), vs, atol=1e-8, rtol=0)


def test_kernel_batch_shape_must_fit_the_gp_batch():
    with pytest.raises(ValueError, match="batch_shape"):
        ExactGP(ManifoldKernel(5, 2), NOISE, 2, batch_shape=(2, 3))
    with pytest.raises(ValueError, match="batch_shape"):
        RBFKernel(batch_shape=(2, 3))
    with pytest.raises(TypeError, match="Kernel"):
        ExactGP(torch.nn.Linear(2, 2), NOISE, 2)
    assert ExactGP(ManifoldKernel(6, 2), NOISE, 2, batch_shape=(2, 3)).kernel.batch_shape == (6,)


def test_neg_log_marginal_likelihood_matches_sklearn():
    """Per selected GP, for GPs holding different numbers of points (padded together); float64
    throughout (the n/2 log(2 pi) term was float32 once, off by ~5e-7)."""
    X, y, masks, _ = stream((3,), 25, seed=8)
    gp = ExactGP(RBFKernel(LS, OS), NOISE, 2, batch_shape=(3,))
    for t in range(25):
        gp.add(X[t], y[t], mask=masks[t])
    assert len(set(gp.size.tolist())) == 3
    nll, ok = gp.neg_log_marginal_likelihood(torch.tensor([True, False, True]))
    assert nll.shape == (2,) and ok.all()
    for j, i in enumerate((0, 2)):
        Xi, yi = per_gp_data(X, y, masks, (i,))
        assert abs(nll[j].item() + sklearn_gp(Xi, yi).log_marginal_likelihood_value_) < 1e-9
    full, _ = gp.neg_log_marginal_likelihood()
    torch.testing.assert_close(full[[0, 2]], nll, atol=1e-12, rtol=0)  # padded to another size: round-off


@pytest.mark.parametrize("cls,kw", [(ExactGP, {}), (SparseOnlineGP, {"budget": 8})])
def test_likelihood_and_state_dict_round_trip(cls, kw):
    """The noise is the likelihood's (exactly the value given), and the GP's state_dict -
    data, kernel and likelihood - is plain tensors that rebuild the GP bit for bit."""
    X, y, masks, Xq = stream((2,), 20, seed=9)
    gp = cls(ManifoldKernel(2, 2, lengthscale=0.3), NOISE, 2, batch_shape=(2,), **kw)
    assert gp.likelihood.noise.tolist() == [NOISE, NOISE]
    assert torch.equal(gp.likelihood.raw_noise.detach(), gp.likelihood.noise.log())
    for t in range(20):
        gp.add(X[t], y[t], mask=masks[t])
    state = gp.state_dict()
    assert {"kernel.raw_lengthscale", "kernel.weight0", "likelihood.noise", "likelihood.raw_noise"} <= set(state)
    assert all(type(v) is torch.Tensor for v in state.values())
    other = cls(ManifoldKernel(2, 2, lengthscale=0.3, uniform=lambda n, c: torch.rand(n, c, dtype=D)), 0.5, 2,
                batch_shape=(2,), **kw)
    other.load_state_dict(state)
    for a, b in zip(gp.predict(Xq), other.predict(Xq)):
        assert torch.equal(a, b)
    assert torch.equal(other.likelihood.noise, gp.likelihood.noise)


def test_a_saved_sparse_gp_holds_only_its_used_slots_and_loads_back_bitwise(tmp_path):
    """A checkpoint of sparse GPs keeps the slots up to the largest count (4 here, of 21); loaded
    into a fresh GP, every buffer equals the original's, zeros beyond included, and the two
    go on identically (the next add and prediction)."""
    g = torch.Generator().manual_seed(3)
    a = SparseOnlineGP(RBFKernel(0.3, 1.0), NOISE, 2, batch_shape=(3,), budget=20, novelty_tol=0.0)
    for i in range(4):       # GP 0 gets 4 points, GP 1 gets 2, GP 2 none
        a.add(torch.rand(3, 2, generator=g, dtype=torch.float64), torch.rand(3, generator=g, dtype=torch.float64),
              mask=torch.tensor([True, i < 2, False]))
    state = a.state_dict()
    assert state["CQ"].shape == (3, 4, 8) and state["BV"].shape == (3, 4, 2) and state["alpha"].shape == (3, 4)
    torch.save(state, tmp_path / "gp.pt")
    assert (tmp_path / "gp.pt").stat().st_size < 8000    # a clone, not the whole (3, 21, 42) storage: 21 kB
    b = SparseOnlineGP(RBFKernel(0.3, 1.0), NOISE, 2, batch_shape=(3,), budget=20, novelty_tol=0.0)
    b.load_state_dict(torch.load(tmp_path / "gp.pt", weights_only=True))
    for name in ("CQ", "BV", "alpha", "n"):
        assert torch.equal(getattr(a, name), getattr(b, name)), name
    x, y = torch.rand(3, 2, generator=g, dtype=torch.float64), torch.rand(3, generator=g, dtype=torch.float64)
    a.add(x, y)
    b.add(x, y)
    xq = torch.rand(3, 5, 2, generator=g, dtype=torch.float64)
    for u, v in zip(a.predict(xq), b.predict(xq)):
        assert torch.equal(u, v)
    with pytest.raises(RuntimeError, match="size mismatch"):   # a GP of another budget is refused by name
        SparseOnlineGP(RBFKernel(0.3, 1.0), NOISE, 2, batch_shape=(3,), budget=2).load_state_dict(state)


def test_sq_dist_of_near_points_far_from_the_origin_keeps_its_digits():
    """30 points 1e-3 apart near (1e4, 1e4): the difference form gives each squared distance to
    1e-12 relative (|a|^2 + |b|^2 - 2ab, cdist's shortcut for many points, loses them)."""
    from trl_dgpq.gp.kernels import sq_dist
    x1 = torch.tensor([[1e4, 1e4]], dtype=torch.float64)
    x2 = x1 + torch.tensor([[1e-3 * (k + 1), 0.0] for k in range(30)], dtype=torch.float64)
    expect = torch.tensor([[(1e-3 * (k + 1)) ** 2 for k in range(30)]], dtype=torch.float64)
    torch.testing.assert_close(sq_dist(x1, x2), expect, rtol=1e-9, atol=0)


def test_rbf_defaults_dtype_repr_and_refusals():
    k = RBFKernel()
    assert (k.lengthscale.item(), k.outputscale.item()) == (1.0, 1.0) and k.raw_lengthscale.dtype == torch.float64
    assert RBFKernel(dtype=torch.float32).raw_outputscale.dtype == torch.float32
    assert repr(RBFKernel(0.5, 2.0)) == "RBFKernel(lengthscale=0.5, outputscale=2)"
    assert repr(RBFKernel(batch_shape=(3,))) == "RBFKernel(batch_shape=(3,))"
    with pytest.raises(ValueError, match=r"^lengthscale must be a finite positive number, got 0.0$"):
        RBFKernel(lengthscale=0.0)
    with pytest.raises(ValueError, match=r"^outputscale must be a finite positive number, got -1.0$"):
        RBFKernel(outputscale=-1.0)
    with pytest.raises(ValueError, match=r"^rows must be 1-D flat GP indices, got shape \(2, 1\)$"):
        RBFKernel(batch_shape=(3,)).select(torch.tensor([[0], [1]]))


def test_the_factory_builds_what_the_config_says():
    """make_gp hands the sparse GP its budget and novelty threshold, the exact GP its capacity;
    make_kernel the RBF its scales, the manifold kernel its scales, skip and each seed's own
    kernel stream (draws laid out GP-major within a seed)."""
    from trl_dgpq.gp import GPConfig, make_gp, make_kernel
    from trl_dgpq.rng import KERNEL_STREAM, SeedStreams
    sparse = make_gp(GPConfig(budget=7, novelty_tol=0.5), 2, (3,), RBFKernel())
    assert isinstance(sparse, SparseOnlineGP) and (sparse.budget, sparse.novelty_tol) == (7, 0.5)
    exact = make_gp(GPConfig(backend="exact", capacity=5), 2, (3,), RBFKernel())
    assert isinstance(exact, ExactGP) and exact.capacity == 5
    rbf = make_kernel(GPConfig(lengthscale=0.3, outputscale=2.0), 2, [0], 1)
    assert type(rbf) is RBFKernel and rbf.batch_shape == () and rbf.lengthscale.item() == pytest.approx(0.3) and rbf.outputscale.item() == pytest.approx(2.0)
    cfg = GPConfig(backend="exact", kernel="manifold", lengthscale=0.3, outputscale=2.0, kernel_hidden=(4,))
    got = make_kernel(cfg, 2, [5, 9], 2)
    assert got.skip and got.lengthscale[0].item() == pytest.approx(0.3) and got.outputscale[0].item() == pytest.approx(2.0)
    streams = SeedStreams([5, 9], stream=KERNEL_STREAM)
    expect = ManifoldKernel(4, 2, (4,), 0.3, 2.0, skip=True,
                            uniform=lambda n, count: streams.uniform(2 * count).reshape(n, count))
    assert all(torch.equal(a, b) for a, b in zip(got.parameters(), expect.parameters()))
    assert not make_kernel(GPConfig(backend="exact", kernel="manifold", kernel_skip=False), 2, [5], 1).skip


def test_bytes_per_gp_by_hand():
    """Sparse, budget 100, 2-D: m = 101 slots, basis m x 2 + alpha m + C and Q m x m, float64:
    8 (202 + 101 + 20,402) = 165,640. Exact, capacity 64: 8 x 64 (2 + 2 + 64) = 34,816."""
    from trl_dgpq.gp import GPConfig
    assert GPConfig(budget=100).bytes_per_gp(2) == 165_640
    assert GPConfig(backend="exact", capacity=64).bytes_per_gp(2) == 34_816
    with pytest.raises(ValueError, match=r"^kernel 'manifold' trains on the GP's data, which only gp 'exact' keeps: "
                                         r"use --gp exact$"):
        GPConfig(kernel="manifold").cross_check()


def test_likelihood_repr():
    from trl_dgpq.gp.likelihood import GaussianLikelihood
    assert repr(GaussianLikelihood(0.1, (3,))) == "GaussianLikelihood(batch_shape=(3,))"
