"""Kernel fitting's bookkeeping (trl_dgpq/gp/train.py) by hand: which GPs it trains, what it
returns for none, the noise trained or not, and trouble (a GP reported failing mid-fit or at its
end) kept to that GP, each checked against a fit where nothing failed. That fitting lowers the NLL
and agrees with scikit-learn: test_manifold.py."""
import logging

import pytest
import torch

from trl_dgpq.gp import ExactGP, ManifoldKernel, SparseOnlineGP, RBFKernel, fit

D = torch.float64


def gp_with(sizes, seed=0):
    """An exact GP per entry of ``sizes`` (a manifold kernel per GP), GP i holding sizes[i] points."""
    g = torch.Generator().manual_seed(seed)
    gp = ExactGP(ManifoldKernel(len(sizes), 1, hidden=(4,), lengthscale=0.5), 0.1, 1, batch_shape=(len(sizes),))
    for k in range(max(sizes)):
        gp.add(torch.rand(len(sizes), 1, generator=g, dtype=D), torch.randn(len(sizes), generator=g, dtype=D),
               torch.tensor([k < n for n in sizes]))
    return gp


def params(gp, i):
    """GP i's trained values: its rows of the kernel's parameters and its noise."""
    return [p.detach()[i].clone() for p in gp.kernel.parameters()] + [gp.likelihood.raw_noise.detach()[i].clone()]


def same(a, b):
    return all(torch.equal(x, y) for x, y in zip(a, b))


@pytest.mark.parametrize("mask", [[True, True, True, False], [1, 1, 1, 0]])
def test_fit_trains_the_masked_gps_holding_at_least_two_points(mask):
    """Of GPs holding 2, 1, 5 and 4 points, the mask (booleans, or 0/1) leaving out the last, the
    first and third are trained (a GP of 1 point is not: min_points is 2); one NLL per trained GP."""
    gp = gp_with([2, 1, 5, 4])
    before = [params(gp, i) for i in range(4)]
    out = fit(gp, mask, steps=3, lr=0.05)
    assert out["rows"].tolist() == [0, 2]
    assert out["nll_before"].shape == out["nll_after"].shape == out["frozen"].shape == (2,)
    assert [same(params(gp, i), before[i]) for i in range(4)] == [False, True, False, True]
    assert fit(gp, mask, steps=1, min_points=3)["rows"].tolist() == [2]


def test_fit_trains_the_noise_unless_asked_not_to():
    gp = gp_with([6])
    noise = gp.likelihood.raw_noise.detach().clone()
    fit(gp, steps=3, lr=0.05, train_noise=False)
    assert torch.equal(gp.likelihood.raw_noise.detach(), noise)
    fit(gp, steps=3, lr=0.05)
    assert not torch.equal(gp.likelihood.raw_noise.detach(), noise)


def test_fit_of_no_gp_returns_empty_float64_results():
    gp = gp_with([1, 1])
    out = fit(gp, steps=3)
    assert set(out) == {"rows", "nll_before", "nll_after", "frozen"}
    assert [t.numel() for t in out.values()] == [0, 0, 0, 0]
    assert out["nll_before"].dtype == out["nll_after"].dtype == D and out["frozen"].dtype == torch.bool
    assert out["nll_after"] is not out["nll_before"]


def test_fit_refuses_the_sparse_gp_saying_why():
    with pytest.raises(TypeError, match=r"^fitting needs the GP's data: use ExactGP \(the sparse GP keeps only "
                                        r"basis vectors\)$"):
        fit(SparseOnlineGP(RBFKernel(), 0.1, 1))


def failing(gp, monkeypatch, rule):
    """Report GP rows as failing where ``rule(call, nll, ok)`` says (call 1: the NLL before; 2 on:
    the steps; the last ones: the check after), recording each call's trained values."""
    real = gp.neg_log_marginal_likelihood
    seen = []

    def nll(mask=None):
        value, ok = real(mask)
        seen.append([params(gp, i) for i in range(gp.num_gps)])
        return rule(len(seen), value, ok)
    monkeypatch.setattr(gp, "neg_log_marginal_likelihood", nll)
    return seen


def test_a_gp_failing_mid_fit_keeps_its_last_good_values_and_the_others_train_on(monkeypatch, caplog):
    """GP 0 reported non-finite from the 4th call to the last step: it ends at its values of the 3rd (the last good
    ones) and is frozen; GP 1 ends exactly where a fit with nothing failing ends (the GPs share
    nothing); the warning names one GP."""
    calm = gp_with([5, 6])
    fit(calm, steps=8, lr=0.05)
    gp = gp_with([5, 6])

    def rule(call, value, ok):      # calls 2-9 are the 8 steps, 10 the check after them
        return (torch.where(torch.tensor([4 <= call <= 9, False]), torch.nan, value), ok)
    seen = failing(gp, monkeypatch, rule)
    with caplog.at_level(logging.WARNING, logger="trl_dgpq.gp.train"):
        out = fit(gp, steps=8, lr=0.05)
    assert out["frozen"].tolist() == [True, False]
    assert same(params(gp, 0), seen[2][0]) and not same(seen[2][0], seen[1][0])
    assert same(params(gp, 1), params(calm, 1))
    assert caplog.messages == ["kernel fit: 1 GP(s) hit a failed factorisation or non-finite NLL; "
                               "kept their last good parameters"]


def test_a_gp_in_trouble_at_the_end_goes_back_to_its_last_good_values(monkeypatch, caplog):
    """GP 0 fails mid-fit as above; GP 1's factorisation is reported failed (its NLL finite) at the
    check after the steps: it goes back to its values when the last step began, both end frozen, GP
    0 stays at its last good values, and the second warning names one GP."""
    gp = gp_with([5, 6])
    steps = 6

    def rule(call, value, ok):
        value = torch.where(torch.tensor([4 <= call <= steps + 1, False]), torch.nan, value)   # GP 0: mid-fit
        return value, ok & torch.tensor([True, call != steps + 2])                               # GP 1: at the end
    seen = failing(gp, monkeypatch, rule)
    with caplog.at_level(logging.WARNING, logger="trl_dgpq.gp.train"):
        out = fit(gp, steps=steps, lr=0.05)
    assert out["frozen"].tolist() == [True, True]
    assert same(params(gp, 1), seen[steps][1]) and not same(seen[steps][1], seen[steps + 1][1])
    assert same(params(gp, 0), seen[2][0])
    assert caplog.messages[-1] == "kernel fit: 1 GP(s) ended in trouble; kept their last good parameters"
    assert torch.isfinite(out["nll_after"]).all()


def test_a_second_gp_failing_later_leaves_the_first_frozen(monkeypatch):
    """GP 0 fails from the 4th call, GP 1 from the 6th (both mid-fit): each ends at its own last good
    values, both frozen (a later failure does not thaw an earlier one)."""
    gp = gp_with([5, 6])

    def rule(call, value, ok):
        return torch.where(torch.tensor([4 <= call <= 9, 6 <= call <= 9]), torch.nan, value), ok
    seen = failing(gp, monkeypatch, rule)
    out = fit(gp, steps=8, lr=0.05)
    assert out["frozen"].tolist() == [True, True]
    assert same(params(gp, 0), seen[2][0]) and same(params(gp, 1), seen[4][1])


def test_a_shared_kernel_refits_a_gp_of_one_point_it_did_not_train():
    """A shared RBF kernel trained on GP 0 (5 points) changes GP 1 (1 point, below min_points): its
    posterior mean at 0.3 is the one-point GP's by hand, k(0.3, x1) y1 / (k(x1, x1) + s^2), with the
    new lengthscale and outputscale."""
    g = torch.Generator().manual_seed(3)
    gp = ExactGP(RBFKernel(1.0, 1.0), 0.1, 1, batch_shape=(2,))
    for k in range(5):
        gp.add(torch.rand(2, 1, generator=g, dtype=D), torch.randn(2, generator=g, dtype=D), torch.tensor([True, k == 0]))
    fit(gp, steps=20, lr=0.1)
    ls, os_ = gp.kernel.lengthscale.item(), gp.kernel.outputscale.item()
    assert abs(ls - 1.0) > 0.05
    x1, y1, s2 = gp.X[1, 0, 0].item(), gp.Y[1, 0].item(), gp.likelihood.noise[1].item()
    k = lambda a, b: os_ * torch.exp(torch.tensor(-0.5 * (a - b) ** 2 / ls ** 2, dtype=D))  # noqa: E731
    mean, _ = gp.predict(torch.tensor([[[0.3]], [[0.3]]], dtype=D))
    torch.testing.assert_close(mean[1, 0], k(0.3, x1) * y1 / (k(x1, x1) + s2), rtol=1e-9, atol=0)


def test_a_refit_that_fails_puts_every_trained_gp_back_and_says_so(monkeypatch, caplog):
    """If the re-factorisation after the steps fails (guarded against above, never expected), every
    trained GP goes back to its values when the last step began and the GPs are refitted with
    them; the warning carries the error."""
    from trl_dgpq.gp.base import GPNumericalError
    gp = gp_with([5, 6])
    seen = failing(gp, monkeypatch, lambda call, value, ok: (value, ok))
    real, calls = gp.refit, []

    def refit(changed):
        calls.append(changed.clone())
        if len(calls) == 1:
            raise GPNumericalError("boom")
        return real(changed)
    monkeypatch.setattr(gp, "refit", refit)
    with caplog.at_level(logging.WARNING, logger="trl_dgpq.gp.train"):
        fit(gp, steps=4, lr=0.05)
    assert [c.tolist() for c in calls] == [[True, True], [True, True]]
    assert same(params(gp, 0), seen[4][0]) and same(params(gp, 1), seen[4][1])
    assert caplog.messages == ["kernel fit: re-factorisation failed (boom); restored the previous parameters"]
