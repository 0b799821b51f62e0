"""Q̂'s storage (trl_dgpq/qhat.py) by hand: the bound of one pair, pruning at equality, growth
when only some rows are full, the version count, the memory a growth takes, the l2 distance
without cancellation, its state, and its refusals. Eq. 7's values: test_dgpq.py."""
import math

import pytest
import torch

from trl_dgpq.qhat import LipschitzQ, distance

D = torch.float64


def t(v):
    return torch.tensor(v, dtype=D)


YES = torch.tensor([True])


def test_the_bound_of_one_pair_is_mu_plus_l_times_the_distance():
    q = LipschitzQ(2, 1, 2, lipschitz=2.0, v_max=100.0)
    got = q.bound(t([[0.0, 0.0], [1.0, 1.0]]), t([[3.0, 4.0], [1.0, 0.5]]), t([1.0, -1.0]))
    assert torch.equal(got, t([1.0 + 2.0 * 7.0, -1.0 + 2.0 * 0.5]))


def test_a_pair_whose_bound_meets_a_stored_mu_exactly_prunes_it():
    """(0, mu 5) then (1, mu 3) at L 2: 3 + 2 x 1 = 5 <= 5, so the first is redundant."""
    q = LipschitzQ(1, 1, 1, lipschitz=2.0, v_max=100.0)
    q.insert(t([[0.0]]), torch.tensor([0]), t([5.0]), YES)
    q.insert(t([[1.0]]), torch.tensor([0]), t([3.0]), YES)
    assert q.size().tolist() == [1] and q.mu[0, 0][q.valid[0, 0]].tolist() == [3.0]


def test_rows_fill_their_own_first_free_slot_and_grow_only_when_one_is_full():
    """Capacity 2, 3 seeds. Seed 0 holds 2 pairs (full), seed 1 one: an insert into seeds 1 and 2
    fits without growing; one into seeds 0 and 1 doubles the storage, each pair in its own row's
    first free slot."""
    q = LipschitzQ(3, 1, 1, lipschitz=1.0, v_max=100.0, capacity=2)
    a = torch.zeros(3, dtype=torch.long)
    x = t([[0.0], [0.0], [0.0]])
    q.insert(x, a, t([1.0, 1.0, 1.0]), torch.tensor([True, True, False]))
    q.insert(t([[5.0], [0.0], [0.0]]), a, t([2.0, 1.0, 1.0]), torch.tensor([True, False, False]))
    assert q.capacity == 2 and q.size().tolist() == [2, 1, 0]
    q.insert(t([[0.0], [9.0], [3.0]]), a, t([0.0, 3.0, 4.0]), torch.tensor([False, True, True]))
    assert q.capacity == 2 and q.size().tolist() == [2, 2, 1]
    assert q.mu[:, 0].tolist() == [[1.0, 2.0], [1.0, 3.0], [4.0, math.inf]]
    q.insert(t([[20.0], [30.0], [0.0]]), a, t([7.0, 8.0, 0.0]), torch.tensor([True, True, False]))
    assert q.capacity == 4 and q.size().tolist() == [3, 3, 1]
    assert q.mu[:2, 0, 2].tolist() == [7.0, 8.0] and q.s[:2, 0, 2, 0].tolist() == [20.0, 30.0]
    assert q.mu[:2, 0, :2].tolist() == [[1.0, 2.0], [1.0, 3.0]]


def test_version_counts_the_inserts_that_changed_something():
    q = LipschitzQ(2, 1, 1, lipschitz=1.0, v_max=1.0)
    assert q.version == 0
    for k in (1, 2, 3):
        q.insert(t([[0.0], [0.0]]), torch.tensor([0, 0]), t([0.5, 0.5]), torch.tensor([True, False]))
        assert q.version == k
    q.insert(t([[0.0], [0.0]]), torch.tensor([0, 0]), t([0.5, 0.5]), torch.tensor([False, False]))
    assert q.version == 3


def test_growth_bytes_is_the_doubled_storage_once_full():
    """S 2, A 3, capacity 4, dim 2, float64: s 2x3x4x2 x 8 = 384 bytes, mu 2x3x4 x 8 = 192; a
    doubling allocates twice their sum, 1,152, and nothing while there is room."""
    q = LipschitzQ(2, 3, 2, lipschitz=1.0, v_max=1.0, capacity=4)
    for k in range(4):
        assert q.growth_bytes() == 0
        q.insert(t([[float(k), 0.0], [0.0, 0.0]]), torch.tensor([0, 0]), t([0.0, 0.0]), torch.tensor([True, False]))
    assert q.width == 4 and q.growth_bytes() == 1152


def test_l2_distance_of_near_points_far_from_the_origin_does_not_cancel():
    """30 stored points 1e-3 apart near 1e4 (cdist's matrix-product shortcut for the Euclidean
    distance would lose them to cancellation): each distance to 1e-12."""
    x = t([[1e4, 1e4]])
    s = x[:, None, :] + t([[[1e-3 * (k + 1), 0.0] for k in range(30)]])
    d = distance(x, s, "l2")
    assert torch.allclose(d, t([[1e-3 * (k + 1) for k in range(30)]]), rtol=0, atol=1e-12)


def test_state_round_trips_and_a_wrong_shape_is_refused():
    """S 2, A 3, dim 1 (A, capacity and dim all differ): the state restores every field,
    converting a float32 state to the storage's float64; a state of other seeds, dims, or mu not
    matching s is refused in one line."""
    q = LipschitzQ(2, 3, 1, lipschitz=1.0, v_max=9.0, capacity=2)
    for k in range(3):
        q.insert(t([[float(k)], [1.0]]), torch.tensor([1, 2]), t([float(k), 2.0]), torch.tensor([True, k == 0]))
    state = q.state_dict()
    assert set(state) == {"s", "mu", "width", "version"} and state["width"] == 3 and state["version"] == 3
    r = LipschitzQ(2, 3, 1, lipschitz=1.0, v_max=9.0)
    r.load_state_dict({**state, "s": state["s"].float(), "mu": state["mu"].float()})
    assert r.s.dtype == D and r.mu.dtype == D and torch.equal(r.s, q.s) and torch.equal(r.mu, q.mu)
    assert (r.width, r.version, r.capacity) == (3, 3, 4)
    xs = t([[0.5], [1.5]])
    assert torch.equal(r(xs), q(xs))
    for bad in ({**state, "s": state["s"][:1], "mu": state["mu"][:1]},
                {**state, "s": torch.cat([state["s"]] * 2, -1)},
                {**state, "mu": state["mu"][..., :2]}):
        with pytest.raises(ValueError, match=r"^Q̂ state has shape \(.*\), expected \(2, 3, capacity, 1\)$"):
            r.load_state_dict(bad)


@pytest.mark.parametrize("kw, message", [
    (dict(metric="l3"), r"^metric must be one of \['l1', 'l2', 'linf'\], got 'l3'$"),
    (dict(lipschitz=0.0), r"^lipschitz must be finite and > 0, got 0.0$"),
    (dict(lipschitz=math.inf), r"^lipschitz must be finite and > 0, got inf$"),
    (dict(v_max=math.nan), r"^v_max must be finite, got nan$")])
def test_bad_settings_are_refused_by_name(kw, message):
    with pytest.raises(ValueError, match=message):
        LipschitzQ(1, 1, 1, **{**dict(lipschitz=1.0, v_max=1.0), **kw})


def test_one_full_row_among_others_with_room_grows_the_storage():
    """Capacity 2: seed 0 full, seed 1 empty; one insert into both doubles the storage (seed 0's
    row has no free slot, whatever seed 1's has), seed 0's pair in its slot 2, seed 1's in slot 0."""
    q = LipschitzQ(2, 1, 1, lipschitz=1.0, v_max=100.0, capacity=2)
    a, first = torch.zeros(2, dtype=torch.long), torch.tensor([True, False])
    q.insert(t([[0.0], [0.0]]), a, t([1.0, 0.0]), first)
    q.insert(t([[9.0], [0.0]]), a, t([2.0, 0.0]), first)
    q.insert(t([[20.0], [5.0]]), a, t([3.0, 4.0]), torch.tensor([True, True]))
    assert q.capacity == 4 and q.mu[:, 0].tolist() == [[1.0, 2.0, 3.0, math.inf], [4.0, math.inf, math.inf, math.inf]]
