"""The exact GP's small parts by hand: the jitter ladder, its errors naming the failing GPs, the
NLL's corner cases, growth and a grown GP's state, its settings (trl_dgpq/gp/exact.py, base.py)."""
import math

import pytest
import torch

from trl_dgpq.gp import ExactGP, GPNumericalError, RBFKernel
from trl_dgpq.gp.exact import cholesky_jitter, cholesky_ladder

D = torch.float64


def test_the_ladder_adds_the_first_rung_that_fixes_each_matrix_times_its_own_scale():
    """ones(2, 2) is singular: the first rung, 1e-10 times its scale 2, fixes it; the identity
    needs none; info 0 for both."""
    K = torch.stack((torch.ones(2, 2, dtype=D), torch.eye(2, dtype=D)))
    L, info = cholesky_ladder(K, torch.tensor([2.0, 5.0], dtype=D))
    assert info.tolist() == [0, 0]
    assert torch.equal(L[0], torch.linalg.cholesky(torch.ones(2, 2, dtype=D) + 2e-10 * torch.eye(2, dtype=D)))
    assert torch.equal(L[1], torch.eye(2, dtype=D))


def test_a_matrix_no_rung_fixes_is_named():
    """A negative first pivot (LAPACK's info 1) fails at every rung: the error names the matrix,
    and the top rung; a non-finite entry is refused before any factorisation."""
    K = torch.stack((torch.diag(torch.tensor([-1.0, 1.0], dtype=D)), torch.eye(2, dtype=D)))
    names = lambda bad: str(bad.tolist())   # noqa: E731
    with pytest.raises(GPNumericalError, match=r"^Cholesky failed even with jitter 0\.0001 in \[True, False\]$"):
        cholesky_jitter(K, torch.ones(2, dtype=D), names)
    assert cholesky_ladder(K, torch.ones(2, dtype=D))[1].tolist() == [1, 0]
    nan = torch.eye(2, dtype=D).repeat(3, 1, 1)
    nan[1, 0, 1] = math.nan
    with pytest.raises(GPNumericalError, match=r"^non-finite covariance in \[False, True, False\]$"):
        cholesky_jitter(nan, torch.ones(3, dtype=D), names)
    with pytest.raises(GPNumericalError, match=r"^non-finite covariance in GP$"):
        cholesky_jitter(nan, torch.ones(3, dtype=D))


def test_gps_are_named_by_their_batch_index():
    gp = ExactGP(RBFKernel(), 0.1, 1, batch_shape=(2, 4))
    assert gp._gp_names(torch.tensor([0, 5, 7])) == "ExactGP batch index (0, 0), (1, 1), (1, 3)"
    assert gp._gp_names(torch.arange(7)) == ("ExactGP batch index (0, 0), (0, 1), (0, 2), (0, 3), (1, 0) "
                                              "(+2 more)")
    assert ExactGP(RBFKernel(), 0.1, 1)._gp_names(torch.tensor([0])) == "ExactGP batch index ()"
    assert gp._gp_names(torch.arange(5)).endswith("(1, 0)")                 # five: all named
    assert gp._gp_names(torch.arange(6)).endswith("(1, 0) (+1 more)")


def test_the_nll_of_one_point_and_of_none_by_hand():
    """One point y under k(x, x) = s and noise w: NLL = y^2 / (2 (s + w)) + log(s + w) / 2 + log(2 pi) / 2;
    a GP holding nothing: 0, and ok; no GP selected: nothing."""
    s, w = 1.5, 0.1
    gp = ExactGP(RBFKernel(0.3, s), w, 1, batch_shape=(3,))
    assert [t.tolist() for t in gp.neg_log_marginal_likelihood()] == [[0.0, 0.0, 0.0], [True, True, True]]
    assert [t.dtype for t in gp.neg_log_marginal_likelihood()] == [D, torch.bool]
    gp.add(torch.tensor([[0.2], [0.4], [0.9]], dtype=D), torch.tensor([2.0, -1.0, 0.0], dtype=D),
           mask=torch.tensor([True, True, False]))
    nll, ok = gp.neg_log_marginal_likelihood()
    want = [y * y / (2 * (s + w)) + math.log(s + w) / 2 + math.log(2 * math.pi) / 2 for y in (2.0, -1.0)] + [0.0]
    assert nll.tolist() == pytest.approx(want, rel=1e-14) and ok.all()
    nll, ok = gp.neg_log_marginal_likelihood(torch.zeros(3, dtype=torch.bool))
    assert nll.shape == ok.shape == (0,)


def test_a_pivot_at_the_floor_gets_the_jitter_relative_to_k_xx():
    """Two copies of one point without noise: the second pivot is 0, at most the floor
    1e-12 (k(x,x) + noise); the first rung adds 1e-10 k(x,x) to it, so the new diagonal entry of L
    is sqrt(1e-10 * 4) with k(x,x) = 4 (noise 1e-300: the likelihood refuses 0)."""
    gp = ExactGP(RBFKernel(0.5, 4.0), 1e-300, 1, capacity=4)
    x = torch.tensor([0.3], dtype=D)
    gp.add(x, torch.tensor(1.0, dtype=D))
    gp.add(x, torch.tensor(1.0, dtype=D))
    assert gp.L[0, 1, 1].item() == pytest.approx(math.sqrt(4e-10), rel=1e-6)


def test_a_gp_that_fails_every_rung_is_named_by_its_place_in_the_batch():
    """An update whose pivot stays below the floor at every rung (a NaN target variance) names
    the GP by its batch index among those updated."""
    gp = ExactGP(RBFKernel(0.5, 1.0), 0.1, 1, batch_shape=(2, 4))
    d2 = torch.tensor([1.0, math.nan], dtype=D)
    learn = torch.tensor([False, True, True])
    gp._rows_in_flight = torch.tensor([1, 4, 6])   # the update's rows among the batch's (2, 4)
    with pytest.raises(GPNumericalError, match=r"^Cholesky update failed even with jitter 0\.0001\*k\(x,x\) in "
                                               r"ExactGP batch index \(1, 2\)$"):
        gp._jitter(d2, torch.ones(2, dtype=D), torch.full((2,), 0.1, dtype=D), learn)


def test_capacity_defaults_to_1024_and_doubles_when_full():
    assert ExactGP(RBFKernel(), 0.1, 1).capacity == 1024
    gp = ExactGP(RBFKernel(), 0.1, 1, batch_shape=(2,), capacity=1)
    assert gp.growth_bytes() == 0
    gp.add(torch.tensor([[0.1], [0.2]], dtype=D), torch.zeros(2, dtype=D), mask=torch.tensor([True, False]))
    # at capacity 2, per GP: X 2 x 1, Y 2, z 2 and L 2 x 2 float64s, and n (int64): 88 bytes
    assert gp.growth_bytes() == 2 * (8 * (2 + 2 + 2 + 4) + 8) == 176
    gp.add(torch.tensor([[0.3], [0.4]], dtype=D), torch.zeros(2, dtype=D), mask=torch.tensor([True, False]))
    assert gp.capacity == 2 and gp.size.tolist() == [2, 0]
    assert sum(getattr(gp, k).numel() * getattr(gp, k).element_size() for k in ("X", "Y", "L", "z", "n")) == 176
    big = ExactGP(RBFKernel(), 0.1, 3, capacity=2, max_capacity=3)
    big.add(torch.zeros(3, dtype=D), torch.zeros((), dtype=D)), big.add(torch.ones(3, dtype=D), torch.zeros((), dtype=D))
    assert big.growth_bytes() == 8 * (3 * 3 + 3 + 3 + 9) + 8     # grows to max_capacity 3, not 4
    big.add(torch.full((3,), 2.0, dtype=D), torch.zeros((), dtype=D))
    assert big.capacity == 3 and big.size.tolist() == 3
    assert big.growth_bytes() == 0        # full at its maximum: the next add refuses, nothing grows
    for max_capacity, grown in ((None, 4), (5, 4), (3, 3)):     # twice 2, unless the maximum is less
        gp = ExactGP(RBFKernel(), 0.1, 1, capacity=2, max_capacity=max_capacity)
        gp.add(torch.zeros(1, dtype=D), torch.zeros((), dtype=D)), gp.add(torch.ones(1, dtype=D), torch.zeros((), dtype=D))
        assert gp.growth_bytes() == 8 * (grown + grown + grown + grown * grown) + 8, max_capacity


def test_a_new_gps_factor_is_the_identity_and_its_unused_rows_stay_so():
    """L over the whole capacity: the identity when empty, the points' factor in its corner and identity
    rows below it after adds, a reset and a growth (what a checkpoint holds, byte for byte)."""
    gp = ExactGP(RBFKernel(0.3, 1.0), 0.1, 1, batch_shape=(2,), capacity=3)
    assert torch.equal(gp.L, torch.eye(3, dtype=D).expand(2, 3, 3)) and gp.L.dtype == D
    gp.add(torch.tensor([[0.1], [0.2]], dtype=D), torch.zeros(2, dtype=D), mask=torch.tensor([True, False]))
    assert torch.equal(gp.L[0, 1:, 1:], torch.eye(2, dtype=D)) and torch.equal(gp.L[1], torch.eye(3, dtype=D))
    for t in range(3):
        gp.add(torch.tensor([[0.3 * t], [0.4]], dtype=D), torch.zeros(2, dtype=D), mask=torch.tensor([True, False]))
    assert gp.capacity == 6 and gp.size.tolist() == [4, 0]
    assert torch.equal(gp.L[0, 4:, 4:], torch.eye(2, dtype=D)) and torch.equal(gp.L[1], torch.eye(6, dtype=D))
    assert not gp.L[0, 4:, :4].any() and not gp.L[0, :4, 4:].any()
    gp.reset()
    assert torch.equal(gp.L, torch.eye(gp.capacity, dtype=D).expand(2, -1, -1))


@pytest.mark.parametrize("capacity", [0, 1.5, -1])
def test_a_capacity_that_is_not_a_positive_integer_is_refused(capacity):
    with pytest.raises(ValueError, match=rf"^capacity must be a positive integer, got {capacity}$"):
        ExactGP(RBFKernel(), 0.1, 1, capacity=capacity)


def test_a_full_gp_at_max_capacity_is_named():
    gp = ExactGP(RBFKernel(), 0.1, 1, batch_shape=(3,), capacity=1, max_capacity=1)
    gp.add(torch.tensor([[0.1], [0.2], [0.3]], dtype=D), torch.zeros(3, dtype=D),
           mask=torch.tensor([False, True, True]))
    with pytest.raises(GPNumericalError, match=r"^ExactGP batch index \(1,\), \(2,\) is full \(max_capacity=1 points\)$"):
        gp.add(torch.tensor([[0.5], [0.6], [0.7]], dtype=D), torch.zeros(3, dtype=D),
               mask=torch.tensor([False, True, False]))


def test_a_grown_gp_loads_into_a_fresh_one_with_its_capacity():
    """Saved after growing from 2 to 4 points of storage, a GP loads into a new one of capacity 2:
    the new one takes capacity 4 and predicts bit for bit as the saved one."""
    gp = ExactGP(RBFKernel(0.3, 1.0), 0.1, 2, batch_shape=(2,), capacity=2)   # 2 inputs: dim = capacity
    for t in range(3):
        gp.add(torch.tensor([[0.1 * t, 0.5], [0.2 * t + 0.05, 0.1]], dtype=D), torch.tensor([t, -t], dtype=D))
    assert gp.capacity == 4
    other = ExactGP(RBFKernel(0.3, 1.0), 0.1, 2, batch_shape=(2,), capacity=2)
    other.load_state_dict(gp.state_dict())
    assert other.capacity == 4 and other.X.shape == (2, 4, 2) and torch.equal(other.L, gp.L)
    xq = torch.tensor([[[0.15, 0.2]], [[0.33, 0.4]]], dtype=D)
    for a, b in zip(gp.predict(xq), other.predict(xq)):
        assert torch.equal(a, b)


def test_a_pivot_at_or_below_its_floor_gets_the_first_rung():
    """The floor is 1e-12 (k(x,x) + noise): with k(x,x) 1 and noise 3, a pivot of 1e-12 is under it and
    gets 1e-10 k(x,x); one exactly at it too; one of 1e-11 above it is kept."""
    gp = ExactGP(RBFKernel(), 3.0, 1)
    kxx, noise, learn = torch.ones(1, dtype=D), torch.full((1,), 3.0, dtype=D), torch.ones(1, dtype=torch.bool)
    floor = 1e-12 * (kxx + noise)
    for d2, want in ((torch.tensor([1e-12], dtype=D), 1e-12 + 1e-10), (floor.clone(), float(floor) + 1e-10),
                     (torch.tensor([1e-11], dtype=D), 1e-11)):
        assert gp._jitter(d2, kxx, noise, learn).item() == want


@pytest.mark.parametrize("kw, error, match", [
    (dict(dim=0), ValueError, r"^dim must be a positive integer, got 0$"),
    (dict(batch_shape=(2, 0)), ValueError, r"^batch_shape entries must be >= 1, got \(2, 0\)$"),
    (dict(kernel=torch.nn.Linear(1, 1)), TypeError, r"^kernel must be a trl_dgpq.gp.Kernel, got Linear$")])
def test_a_gp_that_cannot_be_made_is_refused_in_its_words(kw, error, match):
    with pytest.raises(error, match=match):
        ExactGP(**{"kernel": RBFKernel(), "noise_var": 0.1, "dim": 1, **kw})


def test_inputs_are_taken_as_tensors_and_a_non_finite_one_is_named():
    gp = ExactGP(RBFKernel(0.3, 1.0), 0.1, 1)
    gp.add([0.25], 1.0)                                   # a list and a float: as tensors
    assert gp.X[0, 0].tolist() == [0.25] and gp.Y[0, 0].item() == 1.0
    with pytest.raises(ValueError, match="^y contains NaN or inf$"):
        gp.add([0.5], math.inf)
