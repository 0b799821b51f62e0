"""Q̂'s storage (trl_dgpq/qhat.py) by hand: the bound of one pair, pruning at equality, growth
when only some rows are full, the version count, the memory a growth takes, the l2 distance
without cancellation, its state, and its refusals. Eq. 7's values: test_dgpq.py."""
import math

import pandas as pd
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


def test_a_pair_goes_to_the_first_free_slot_found_through_blocks_of_slots():
    """Blocks of 2 slots, capacity 5 (the last block of 1). Pairs at x = 0, 10, 20, 30, 40 with mu 9
    and L 1 fill slots 0-4; (25, mu 0) prunes those at 20 and 30 (0 + 1 x 5 <= 9), taking slot
    2; the next pair takes the hole left at slot 3 (block 1), the one after finds the storage full
    and goes to slot 5, after the doubling. A hole in the last, partial block is found too."""
    q = LipschitzQ(1, 1, 1, lipschitz=1.0, v_max=100.0, capacity=5, free_block=2)
    a = torch.zeros(1, dtype=torch.long)
    for k in range(5):
        q.insert(t([[10.0 * k]]), a, t([9.0]), YES)
    q.insert(t([[25.0]]), a, t([0.0]), YES)
    assert q.mu[0, 0].tolist() == [9.0, 9.0, 0.0, math.inf, 9.0]
    q.insert(t([[100.0]]), a, t([9.0]), YES)
    q.insert(t([[200.0]]), a, t([9.0]), YES)
    assert q.capacity == 10 and q.mu[0, 0, :7].tolist() == [9.0, 9.0, 0.0, 9.0, 9.0, 9.0, math.inf]
    assert q.s[0, 0, :6, 0].tolist() == [0.0, 10.0, 25.0, 100.0, 40.0, 200.0]
    r = LipschitzQ(1, 1, 1, lipschitz=1.0, v_max=100.0, capacity=5, free_block=2)
    for k in range(5):
        r.insert(t([[10.0 * k]]), a, t([9.0]), YES)
    r.insert(t([[38.0]]), a, t([0.0]), YES)     # prunes 30 (slot 3) and 40 (slot 4, the last block)
    r.insert(t([[300.0]]), a, t([9.0]), YES)
    assert r.capacity == 5 and r.mu[0, 0].tolist() == [9.0, 9.0, 9.0, 0.0, 9.0]


def test_free_block_must_be_positive():
    with pytest.raises(ValueError, match=r"^free_block must be >= 1, got 0$"):
        LipschitzQ(1, 1, 1, 1.0, 1.0, free_block=0)


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


# ---------------------------------------------------------------- the index (ChunkIndex)
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from trl_dgpq import qhat as qhat_module  # noqa: E402


def twins(S, A, dim, L, metric, chunk=2, fan=2, **kw):
    """A Q̂ that always scans and one that answers through an index of tiny chunks and groups from
    its first pair on, so that a few dozen pairs fill several groups."""
    scan = LipschitzQ(S, A, dim, L, 50.0, metric, index_min=10**9, free_block=2, **kw)
    index = LipschitzQ(S, A, dim, L, 50.0, metric, index_min=1, chunk=chunk, fan=fan, free_block=3, **kw)
    return scan, index


def check_index_against_scan(seed, metric, dim, chunk, fan, lipschitz, grid, inserts=50):
    """Eq. 7's values and the storage after every insert are the full scan's to the bit, over random
    inserts (states on a coarse grid too: ties, repeats, chunks of one point), masks, actions and
    queries, with rebuilds (every 1/16 of the width in inserts) and growth along the way."""
    g = torch.Generator().manual_seed(seed)
    S, A = 3, 2
    scan, index = twins(S, A, dim, lipschitz, metric, chunk, fan, capacity=4)
    for _ in range(inserts):
        x = torch.rand(S, dim, generator=g, dtype=D) * 4 - 2
        if grid:
            x = x.round()
        a = torch.randint(0, A, (S,), generator=g)
        mu = torch.rand(S, generator=g, dtype=D) * 6 - 3
        mask = torch.rand(S, generator=g) < 0.8
        scan.insert(x, a, mu, mask)
        index.insert(x, a, mu, mask)
        assert torch.equal(scan.mu, index.mu) and torch.equal(scan.s, index.s)
        check_first_free(scan, x, a, mu, mask)
        for q in (scan, index):
            check_free_counts(q)
        if index.index.built:
            check_chunk_copy(index)
        probe = torch.rand(S, dim, generator=g, dtype=D) * 5 - 2.5
        for at in (probe, x):
            assert torch.equal(scan(at), index(at))
    assert index.index.built > 0


def check_first_free(q, x, a, mu, mask):
    """Each inserted pair sits in its row's first free slot: every slot before it holds a pair."""
    for seed in mask.nonzero()[:, 0].tolist():
        row_mu, row_s = q.mu[seed, a[seed]], q.s[seed, a[seed]]
        (at,) = ((row_mu == mu[seed]) & (row_s == x[seed]).all(-1)).nonzero()[:, 0].tolist()
        assert torch.isfinite(row_mu[:at]).all()


def check_free_counts(q):
    """The free slots counted per block of each row are the storage's, counted one slot at a time."""
    if q._free is None:
        return
    mu = q.mu.reshape(q.S * q.A, -1).tolist()
    B = q.free_block
    want = [[sum(math.isinf(m) for m in row[b:b + B]) for b in range(0, len(row), B)] for row in mu]
    assert q._free.tolist() == want


def check_chunk_copy(q):
    """The index's pairs in chunk order are the storage's pairs in its sorted slots, as inserts and
    pruning left them (padding: mu +inf)."""
    ix = q.index
    rows = q.S * q.A
    slots = ix.order.reshape(rows, -1).long()
    s, mu = q._rows()
    want_mu = mu.gather(1, slots.clamp_min(0)).masked_fill(slots < 0, torch.inf)
    assert torch.equal(ix.chunk_mu.reshape(rows, -1), want_mu)
    held = torch.isfinite(want_mu)
    want_s = s.gather(1, slots.clamp_min(0)[..., None].expand(-1, -1, q.dim))
    assert torch.equal(ix.chunk_s.reshape(rows, -1, q.dim)[held], want_s[held])


CASES = dict(seed=st.integers(0, 2**31 - 1), metric=st.sampled_from(sorted(("l1", "l2", "linf"))),
             dim=st.integers(1, 3), chunk=st.integers(1, 4), fan=st.integers(2, 3),
             lipschitz=st.sampled_from([0.3, 1.0, 7.0]), grid=st.booleans())


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(**CASES)
def test_the_index_gives_the_scans_values_and_prunes_the_same_pairs(**case):
    check_index_against_scan(**case)


@pytest.mark.slow
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(**CASES)
def test_the_index_gives_the_scans_values_over_many_cases(**case):
    check_index_against_scan(**case, inserts=120)


def test_the_index_is_exact_where_a_bound_meets_the_answer_by_rounding():
    """Values far from 0 (mu near 1e6, states near 1e3), where the bounds and the values round
    differently: the slack keeps every chunk that could hold the minimum."""
    g = torch.Generator().manual_seed(5)
    scan, index = twins(2, 1, 2, 3.0, "l2", chunk=3, fan=2)
    for _ in range(60):
        x = 1e3 + torch.rand(2, 2, generator=g, dtype=D) * 1e-6
        mu = 1e6 + torch.rand(2, generator=g, dtype=D) * 1e-9
        for q in (scan, index):
            q.insert(x, torch.zeros(2, dtype=torch.long), mu, torch.tensor([True, True]))
        assert torch.equal(scan(x + 1e-7), index(x + 1e-7))


def test_an_empty_row_beside_full_ones_reads_v_max_through_the_index():
    scan, index = twins(2, 2, 1, 1.0, "l1")
    for k in range(12):
        for q in (scan, index):
            q.insert(t([[float(k)], [0.0]]), torch.tensor([0, 0]), t([float(k), 0.0]), torch.tensor([True, False]))
    got = index(t([[3.5], [1.0]]))
    assert torch.equal(got, scan(t([[3.5], [1.0]])))
    assert got[0, 1] == 50.0 and got[1].eq(50.0).all()       # action 1 of seed 0, and seed 1: no pair


def test_the_index_is_not_saved_and_a_loaded_q_answers_the_same():
    g = torch.Generator().manual_seed(2)
    _, index = twins(2, 2, 2, 2.0, "l1", chunk=2, fan=2)
    for _ in range(40):
        index.insert(torch.rand(2, 2, generator=g, dtype=D), torch.randint(0, 2, (2,), generator=g),
                     torch.rand(2, generator=g, dtype=D), torch.tensor([True, True]))
    probe = torch.rand(2, 2, generator=g, dtype=D)
    want = index(probe)
    state = index.state_dict()
    assert set(state) == {"s", "mu", "width", "version"}
    fresh = LipschitzQ(2, 2, 2, 2.0, 50.0, "l1", index_min=1, chunk=2, fan=2)
    fresh.load_state_dict(state)
    assert fresh.index.built == 0 and torch.equal(fresh(probe), want)


def test_an_index_build_allocates_what_growth_bytes_counts():
    """A build is due at the first query from ``index_min`` on: growth_bytes counts it then, and
    nothing once it is built. At 40 slots in chunks of 4, groups of 3: 10 chunks padded to 12, 4
    groups of them padded to 6, and a top of 2; the index keeps 4 bytes a sorted slot (chunks
    padded: 40) and a place a slot, dim + 1 float64s a sorted slot (the pairs in chunk order), and
    3 dim + 2 float64s a box (12 + 6 + 2), and makes the
    10 and 4 unpadded boxes first; beside it, a block's sort of 8 (6 dim + 8) bytes a slot."""
    q = LipschitzQ(2, 3, 2, 1.0, 50.0, index_min=40, chunk=4, fan=3, capacity=64)
    x = torch.arange(2 * 39 * 2, dtype=D).view(39, 2, 2)
    for k in range(39):
        q.insert(x[k], torch.tensor([0, 1]), t([float(k), -float(k)]), torch.tensor([True, True]))
    assert q.width == 39
    due = q.growth_bytes()     # the next insert reaches 40 slots and the query after it builds
    rows, w, dim = 6, 40, 2
    box = 8 * (3 * dim + 2)
    kept = rows * (4 * 40 + 4 * w + box * (12 + 6 + 2) + 8 * (dim + 1) * 40)
    assert due == kept + rows * box * (10 + 4) + rows * w * 8 * (6 * dim + 8)
    q.insert(x[0] + 100, torch.tensor([0, 0]), t([1e3, 1e3]), torch.tensor([True, True]))
    assert q.width == 40
    q(x[0])
    ix = q.index
    assert [b.packed.shape[1] for b in ix.levels] == [12, 6, 2]
    held = sum(v.numel() * v.element_size()
               for v in (ix.order, ix.place_of, ix.chunk_s, ix.chunk_mu, *(b.packed for b in ix.levels)))
    assert held == kept
    assert q.growth_bytes() == 0


def test_the_index_is_rebuilt_after_a_sixteenth_of_its_slots_in_inserts():
    """Built at 32 slots, it is used as built for one insert and rebuilt at the first use after the
    second (2 x 16 >= 32); growth_bytes counts a build from the step that may make one (one insert
    early: a step queries, then inserts)."""
    q = LipschitzQ(1, 1, 1, 1.0, 50.0, index_min=32, chunk=4, fan=2, capacity=64)
    for k in range(32):
        q.insert(t([[float(k)]]), torch.tensor([0]), t([0.0]), YES)
    q(t([[0.5]]))
    assert q.index.built == 32 and q.index.inserts == 0 and not q.index.due()
    assert q.growth_bytes() == 0
    q.insert(t([[40.0]]), torch.tensor([0]), t([0.0]), YES)
    q(t([[0.5]]))
    assert q.index.built == 32 and q.index.inserts == 1 and q.index.due() and q.growth_bytes() > 0
    q.insert(t([[41.0]]), torch.tensor([0]), t([0.0]), YES)
    assert q.index.built == 32        # pruning went through the index as built: its use is the next query
    q(t([[0.5]]))
    assert q.index.built == 34 and q.index.inserts == 0


@pytest.mark.parametrize("chunk, fan", [(0, 2), (1, 1)])
def test_a_bad_index_shape_is_refused(chunk, fan):
    with pytest.raises(ValueError, match=f"at least 1 pair and its groups at least 2 boxes, got chunk {chunk} and fan {fan}$"):
        LipschitzQ(1, 1, 1, 1.0, 1.0, chunk=chunk, fan=fan)
    LipschitzQ(1, 1, 1, 1.0, 1.0, chunk=1, fan=2)


def test_dgpq_through_the_index_runs_as_through_the_scan(monkeypatch, tmp_path):
    """DGPQ on the square for 3 seeds x 12 episodes with the index from Q̂'s first pair on (chunks of
    2, groups of 2) writes the same episodes as with the scan: the index only answers faster."""
    from tests.test_run import csv, run
    out = {}
    for name, (index_min, chunk, fan) in {"scan": (10**9, 32, 32), "index": (1, 2, 2)}.items():
        for attr, value in (("INDEX_SLOTS", index_min), ("CHUNK", chunk), ("FAN", fan)):
            monkeypatch.setattr(qhat_module, attr, value)
        assert run("--env", "square", "--agent", "dgpq", "--seeds", "0-2", "--episodes", 12,
                   "--out", tmp_path / name) == 0
        out[name] = csv(tmp_path / name)
    assert out["scan"]["qhat_size"].max() > 20
    pd.testing.assert_frame_equal(out["scan"], out["index"])


def test_bench_qhat_index_times_both_ways_and_finds_the_same_values(tmp_path, capsys):
    """``bench.py qhat-index`` on a small synthetic Q̂: the scan and the index answer alike, and the
    share of slots the index opened is a share (in (0, 1]) that its JSON keeps."""
    import json
    import runpy
    from pathlib import Path
    bench = runpy.run_path(str(Path(__file__).resolve().parents[1] / "scripts" / "bench.py"), run_name="bench")
    out = tmp_path / "b.json"
    bench["main"](["qhat-index", "--widths", "3000", "--seeds", "2", "--queries", "4", "--repeats", "1",
                   "--out", str(out)])
    (r,) = json.loads(out.read_text())["results"]
    assert r["same_values"] and r["width"] == 3000 and r["rows"] == 6 and 0 < r["scanned_share"] <= 1
    assert "values the same: True" in capsys.readouterr().out


def test_the_z_order_key_interleaves_each_rows_quantised_coordinates():
    """By hand: 16 bits a coordinate up to 3 dims (62 // dim, at most 16), 1 from 32 dims on; each
    row quantised over its own used pairs' box; unused slots last (the largest int64)."""
    from trl_dgpq.qhat import _zorder
    s = t([[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0], [7.0, 7.0]],
           [[10.0, 10.0], [30.0, 10.0], [10.0, 20.0], [30.0, 20.0], [0.0, 0.0]]])
    used = torch.tensor([[True, True, True, True, False]] * 2)
    x_bits = sum(1 << (2 * b) for b in range(16))
    want = [0, x_bits, x_bits << 1, (x_bits << 1) | x_bits, torch.iinfo(torch.long).max]
    assert _zorder(s, used).tolist() == [want, want]
    assert _zorder(t([[[0.0], [1.0]]]), torch.tensor([[True, True]])).tolist() == [[0, 2 ** 16 - 1]]
    wide = torch.stack((torch.zeros(40, dtype=D), torch.ones(40, dtype=D)))[None]
    assert _zorder(wide, torch.tensor([[True, True]])).tolist() == [[0, 2 ** 40 - 1]]


def test_pruning_through_the_index_uses_l_and_prunes_at_equality():
    """After a build: a pair in the tail (slot past the build) that a new pair bounds only with L = 1
    is kept at L = 7; a built pair met exactly (the same state and mu again) is pruned, as the scan
    prunes it."""
    scan, _ = twins(1, 1, 1, 7.0, "l1", capacity=64)
    index = LipschitzQ(1, 1, 1, 7.0, 50.0, "l1", index_min=40, chunk=2, fan=2, capacity=64)   # built at 40
    for k in range(40):
        for q in (scan, index):
            q.insert(t([[float(10 + k)]]), torch.tensor([0]), t([float(k)]), YES)
    index(t([[0.0]]))
    built = index.index.built
    assert built == 40 and index.index.inserts == 0      # (1, 5) goes past it, in the tail
    for x, mu in ((1.0, 5.0), (0.0, 0.0), (13.0, 3.0)):
        for q in (scan, index):
            q.insert(t([[x]]), torch.tensor([0]), t([mu]), YES)
        assert torch.equal(scan.mu, index.mu) and torch.equal(scan.s, index.s)
    assert index.index.built == built       # no rebuild: (1, 5) stayed in the tail
    assert index.size().item() == 42        # (13, 3) replaced itself; (1, 5) kept beside (0, 0)


def test_a_pair_in_the_tail_met_exactly_is_pruned_as_the_scan_prunes_it():
    """Built at 40 slots; (100, 5) goes into the tail (slot 40), then again: the first is pruned
    (the scan's test is <=) and the second takes its slot, with no rebuild between (2 inserts of
    40 / 16)."""
    scan, _ = twins(1, 1, 1, 7.0, "l1", capacity=64)
    index = LipschitzQ(1, 1, 1, 7.0, 50.0, "l1", index_min=40, chunk=2, fan=2, capacity=64)
    for k in range(40):
        for q in (scan, index):
            q.insert(t([[float(10 + k)]]), torch.tensor([0]), t([float(k)]), YES)
    index(t([[0.0]]))
    for _ in range(2):
        for q in (scan, index):
            q.insert(t([[100.0]]), torch.tensor([0]), t([5.0]), YES)
    assert index.index.built == 40 and index.width == 41     # the second took the first's slot
    assert torch.equal(scan.mu, index.mu) and index.size().item() == 41


def test_build_bytes_merges_no_level_of_exactly_fan_boxes():
    """12 slots in chunks of 4 are 3 chunks, a top of exactly ``fan`` = 3 boxes: nothing merged, no
    padding. One row of 1-D pairs keeps 4 bytes a sorted slot and a place (12 each), 2 float64s a
    sorted slot, 5 a box (3); beside it, a sort of 8 (6 + 8) bytes a slot."""
    kept = 4 * 12 + 4 * 12 + 8 * 2 * 12 + 8 * 5 * 3
    q = LipschitzQ(1, 1, 1, 1.0, 50.0, index_min=12, chunk=4, fan=3, capacity=16)
    assert q.index.build_bytes(1, 12, 1) == kept + 12 * 8 * 14
    for k in range(12):                     # 1 apart, mu 0: none bounds another
        q.insert(t([[float(k)]]), torch.tensor([0]), t([0.0]), YES)
    q(t([[0.5]]))
    ix = q.index
    assert ix.built == 12 and [b.packed.shape[1] for b in ix.levels] == [3]
    assert kept == sum(v.numel() * v.element_size()
                       for v in (ix.order, ix.place_of, ix.chunk_s, ix.chunk_mu, *(b.packed for b in ix.levels)))


def test_growth_bytes_counts_no_build_two_slots_short_of_index_min():
    q = LipschitzQ(1, 1, 1, 1.0, 50.0, index_min=40, chunk=4, fan=3, capacity=64)
    for k in range(38):
        q.insert(t([[float(k)]]), torch.tensor([0]), t([float(k)]), YES)
    assert q.width == 38 and q.growth_bytes() == 0
    q.insert(t([[99.0]]), torch.tensor([0]), t([99.0]), YES)
    assert isinstance(q.growth_bytes(), int) and q.growth_bytes() > 0


def test_a_build_in_blocks_of_rows_gives_the_scans_values(monkeypatch):
    """A build sorts ``BUILD_SLOTS`` slots at a time, a block of rows each: made small here, every block
    is one row, as in a large Q̂'s build; the values stay the scan's to the bit."""
    import trl_dgpq.qhat
    monkeypatch.setattr(trl_dgpq.qhat, "BUILD_SLOTS", 8)
    for metric in ("l1", "l2"):
        check_index_against_scan(seed=3, metric=metric, dim=2, chunk=2, fan=2, lipschitz=1.0, grid=False)


def test_an_empty_q_reads_v_max_and_one_pair_bounds_its_own_action_only():
    """No pair: v_max for every seed and action. One pair (0, mu 1) for action 0 of seed 0 at L 2: at 0.5
    it reads 1 + 2 x 0.5 = 2, and 1 + 2 x 60 = 121 is above v_max 100; action 1 and seed 1 read v_max."""
    q = LipschitzQ(2, 2, 1, lipschitz=2.0, v_max=100.0)
    assert torch.equal(q(t([[0.0], [3.0]])), t([[100.0, 100.0], [100.0, 100.0]]))
    q.insert(t([[0.0], [0.0]]), torch.tensor([0, 0]), t([1.0, 1.0]), torch.tensor([True, False]))
    assert torch.equal(q(t([[0.5], [0.5]])), t([[2.0, 100.0], [100.0, 100.0]]))
    assert torch.equal(q(t([[60.0], [0.5]])), t([[100.0, 100.0], [100.0, 100.0]]))


def test_the_index_answers_from_a_number_of_slots_over_all_rows():
    """By default the index takes over from 2^19 slots over all rows (its own work per query is
    nearly fixed, the scan's grows with every slot): 20 seeds x 3 actions from 8,739 slots a row
    (524,288 / 60 = 8,738.1), 4 x 2 from 65,536, one seed with 3 actions from 174,763."""
    assert qhat_module.INDEX_SLOTS == 524288
    for (S, A), width in {(20, 3): 8739, (4, 2): 65536, (1, 3): 174763}.items():
        assert LipschitzQ(S, A, 1, 1.0, 1.0).index_min == width
    assert LipschitzQ(20, 3, 1, 1.0, 1.0, index_min=7).index_min == 7


def test_float32_pairs_go_into_float64_storage_through_the_index_too():
    """Inserts in float32 into a float64 Q̂ are stored as the scan stores them, built index or not."""
    scan, index = twins(1, 1, 1, 1.0, "l1")
    for k in range(12):
        for q in (scan, index):
            q.insert(torch.tensor([[float(k)]], dtype=torch.float32), torch.tensor([0]),
                     torch.tensor([0.5 * k], dtype=torch.float32), YES)
            q(t([[0.25]]))
    assert index.index.built and torch.equal(scan.mu, index.mu) and torch.equal(scan(t([[3.3]])), index(t([[3.3]])))


def test_the_last_answer_through_the_index_bounds_the_next_query():
    """After a query at x through the index, the hint at x' is that answer plus L d(x, x') (by hand,
    l1, L 2); a load forgets it (another Q̂'s answers bound nothing)."""
    q = LipschitzQ(1, 2, 2, 2.0, 50.0, "l1", index_min=1, chunk=2, fan=2)
    for k in range(6):
        q.insert(t([[float(k), 0.0]]), torch.tensor([k % 2]), t([float(k)]), YES)
    assert q._hint(t([[0.0, 0.0], [0.0, 0.0]])) is None
    got = q(t([[2.0, 1.0]]))          # action 0 holds x 0, 2, 4 (mu 0, 2, 4): min 2 + 2 x 1 = 4;
    assert got.tolist() == [[4.0, 5.0]]   # action 1 holds x 1, 3, 5 (mu 1, 3, 5): min 1 + 2 x 2 = 5
    hint = q._hint(t([[2.5, 0.0], [2.5, 0.0]]))
    assert hint.tolist() == [4.0 + 2.0 * 1.5, 5.0 + 2.0 * 1.5]
    q.load_state_dict(q.state_dict())
    assert q._hint(t([[2.5, 0.0], [2.5, 0.0]])) is None


def test_a_hint_narrows_what_the_index_opens_and_not_its_answer(monkeypatch):
    """64 pairs at x = 0..63 with mu 5 + |x - 48| / 96 (L 1: none bounds another), in chunks of 2,
    groups of 2. At 10.5 the minimum is pair 11's, 5 + 37 / 96 + 0.5; each box's rep (its least mu)
    is its pair nearest 48, far from 10.5, so the reps' bound opens more boxes on the way down than
    a hint at the minimum does; an infinite hint is none. The answer is the same."""
    q = LipschitzQ(1, 1, 1, 1.0, 50.0, "l1", index_min=1, chunk=2, fan=2)
    for k in range(64):
        q.insert(t([[float(k)]]), torch.zeros(1, dtype=torch.long), t([5.0 + abs(k - 48) / 96]), YES)
    x = t([[10.5]])
    s, mu = q._rows()
    q.index._refresh(s, mu, q.width)
    opened = []
    real = qhat_module.ChunkIndex._open
    monkeypatch.setattr(qhat_module.ChunkIndex, "_open", lambda self, level, r, at: (
        opened.append(at.numel()), real(self, level, r, at))[1])
    answers, boxes = [], []
    least = 5.0 + 37 / 96 + 0.5
    for hint in (None, t([math.inf]), t([least])):
        opened.clear()
        answers.append(q.index.envelope(x, s, mu, q.width, hint))
        boxes.append(sum(opened))
    assert [a.tolist() for a in answers] == [[least]] * 3
    assert boxes[1] == boxes[0] and boxes[2] < boxes[0]


def test_a_query_through_the_index_is_narrowed_by_the_last_answer(monkeypatch):
    """The same 64 pairs: a first query at 10.5 opens the boxes the reps' bound lets through; the
    same query again starts from the last answer (its distance 0) and opens fewer; both answer alike."""
    q = LipschitzQ(1, 1, 1, 1.0, 50.0, "l1", index_min=1, chunk=2, fan=2)
    for k in range(64):
        q.insert(t([[float(k)]]), torch.zeros(1, dtype=torch.long), t([5.0 + abs(k - 48) / 96]), YES)
    opened = []
    real = qhat_module.ChunkIndex._open
    monkeypatch.setattr(qhat_module.ChunkIndex, "_open", lambda self, level, r, at: (
        opened.append(at.numel()), real(self, level, r, at))[1])
    first = q(t([[10.5]]))
    boxes = sum(opened)
    opened.clear()
    assert torch.equal(q(t([[10.5]])), first) and sum(opened) < boxes


def test_a_nan_query_does_not_narrow_the_next_one():
    """A query at a NaN state leaves a NaN last answer: the next query through the index is the
    scan's all the same (a NaN hint narrows nothing)."""
    scan, index = twins(1, 2, 1, 1.0, "l1")
    for k in range(16):
        for q in (scan, index):
            q.insert(t([[k / 4]]), torch.tensor([k % 2]), t([float(k % 5)]), YES)
    index(t([[math.nan]]))
    assert index._hint(t([[0.8], [0.8]])).isnan().all()
    assert torch.equal(index(t([[0.8]])), scan(t([[0.8]])))


def test_an_infinite_mu_leaves_its_slot_free_and_a_loaded_state_brings_its_own_counts():
    """A pair inserted with mu +inf holds no slot: the next pair takes it, as the scan of the row
    did. A Q̂ whose counts were built loads another Q̂'s state (holes elsewhere): the counts are
    that state's and the next pair goes to its first free slot."""
    a = torch.zeros(1, dtype=torch.long)
    q = LipschitzQ(1, 1, 1, lipschitz=1.0, v_max=100.0, capacity=4, free_block=2)
    q.insert(t([[0.0]]), a, t([math.inf]), YES)
    q.insert(t([[5.0]]), a, t([1.0]), YES)
    assert q.mu[0, 0].tolist() == [1.0, math.inf, math.inf, math.inf]
    check_free_counts(q)
    other = LipschitzQ(1, 1, 1, lipschitz=1.0, v_max=100.0, capacity=4, free_block=2)
    for k in range(4):
        other.insert(t([[10.0 * k]]), a, t([9.0]), YES)
    other.insert(t([[25.0]]), a, t([0.0]), YES)     # prunes 20 and 30 (slots 2, 3), takes slot 2
    assert other.mu[0, 0].tolist() == [9.0, 9.0, 0.0, math.inf]
    q.load_state_dict(other.state_dict())
    q.insert(t([[100.0]]), a, t([9.0]), YES)
    assert q.mu[0, 0].tolist() == [9.0, 9.0, 0.0, 9.0] and q.capacity == 4
    check_free_counts(q)
