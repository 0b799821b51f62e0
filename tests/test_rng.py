"""The per-seed streams (trl_dgpq/rng.py) against a pure-Python oracle written here from the
algorithm, not from the module: every published number depends on these exact draws."""
import hashlib
import math

import pytest
import torch

from trl_dgpq.rng import ENV_STREAM, LEARNER_STREAM, TIE_STREAM, SeedStreams, _signed, box_muller, splitmix64, stream_id

M64 = (1 << 64) - 1


def sm64(z: int) -> int:
    """splitmix64's output for state z (Vigna's splitmix64.c: state += golden, then the mix)."""
    z = (z + 0x9E3779B97F4A7C15) & M64
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & M64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & M64
    return z ^ (z >> 31)


def oracle(seed: int, stream: int, draw: int, n: int) -> list:
    """The n uniforms of draw ``draw``: the top 53 bits of sm64(key + draw * 2^20 + i), key =
    sm64(sm64(seed) ^ sm64(stream))."""
    key = sm64(sm64(seed) ^ sm64(stream & M64))
    return [(sm64((key + draw * (1 << 20) + i) & M64) >> 11) * 2.0 ** -53 for i in range(n)]


def test_splitmix64_on_tensors_is_the_published_sequence():
    """Seeded at 0, splitmix64's first outputs are 0xe220a8397b1dcdaf and 0x6e789e6aa1b965f4;
    wrapping int64 arithmetic gives the same bits as unsigned, for any input."""
    assert (sm64(0), sm64(0x9E3779B97F4A7C15)) == (0xE220A8397B1DCDAF, 0x6E789E6AA1B965F4)
    zs = [0, 1, 2 ** 31, 2 ** 62 + 12345, 2 ** 63 - 1, -1, -(2 ** 63), -987654321]
    got = splitmix64(torch.tensor(zs, dtype=torch.int64)).tolist()
    assert [g & M64 for g in got] == [sm64(z & M64) for z in zs]


@pytest.mark.parametrize("stream", [TIE_STREAM, ENV_STREAM, LEARNER_STREAM, stream_id("td3.explore")])
def test_uniform_draws_are_the_oracles_in_order_whatever_their_shape(stream):
    """Seeds 0, 3 and 2**40: draws 0-299 (past the 256-draw buffer) of 3 numbers each, then a draw
    of shape (2, 2) (4 numbers of draw 300), each the oracle's."""
    seeds = [0, 3, 2 ** 40]
    rng = SeedStreams(seeds, stream)
    for draw in range(300):
        u = rng.uniform(3)
        assert u.dtype == torch.float64 and u.shape == (3, 3)
        if draw in (0, 1, 255, 256, 299):
            assert u.tolist() == [oracle(s, stream, draw, 3) for s in seeds]
    square = rng.uniform(2, 2)
    assert square.shape == (3, 2, 2) and square.reshape(3, 4).tolist() == [oracle(s, stream, 300, 4) for s in seeds]
    assert rng.counter == 301


def test_a_draw_of_another_shape_mid_buffer_is_still_the_counters_draw():
    rng = SeedStreams([7], 9)
    rng.uniform(1)
    assert rng.uniform(5)[0].tolist() == oracle(7, 9, 1, 5)
    assert rng.uniform(1)[0].tolist() == oracle(7, 9, 2, 1)


def test_normal_is_box_muller_on_one_uniform_draw_of_twice_the_size():
    """normal(3): draw 0 of 6 uniforms, the first 3 as u1, the last 3 as u2:
    sqrt(-2 ln(1 - u1)) cos(2 pi u2)."""
    got = SeedStreams([4], 11).normal(3)[0].tolist()
    u = oracle(4, 11, 0, 6)
    expect = [math.sqrt(-2.0 * math.log1p(-u1)) * math.cos(2.0 * math.pi * u2) for u1, u2 in zip(u[:3], u[3:])]
    assert got == pytest.approx(expect, rel=1e-15, abs=1e-15)
    assert box_muller(torch.tensor([0.0]), torch.tensor([0.25])).item() == pytest.approx(0.0, abs=1e-15)


def test_uniform_at_reads_any_draw_of_each_seed_without_moving_the_counter():
    """Draws 7 and 3000 (an int32 index: 3000 x 2^20 overflows 32 bits), then the counter's draw
    0; a draw of 2^20 numbers is the most allowed (also for ``uniform``, shown with a limit of 8)."""
    rng = SeedStreams([1, 2], 5)
    got = rng.uniform_at(torch.tensor([7, 3000], dtype=torch.int32), 4)
    assert got.tolist() == [oracle(1, 5, 7, 4), oracle(2, 5, 3000, 4)] and rng.counter == 0
    assert rng.uniform_at(torch.tensor([0, 0]), 2 ** 20).shape == (2, 2 ** 20)
    small = SeedStreams([1], 5)
    small.MAX_PER_DRAW = 8
    assert small.uniform(8).shape == (1, 8)
    with pytest.raises(ValueError, match=r"^at most 8 numbers per draw$"):
        small.uniform(9)
    assert rng.uniform(2).tolist() == [oracle(1, 5, 0, 2), oracle(2, 5, 0, 2)]
    with pytest.raises(ValueError, match=r"^at most 1048576 numbers per draw$"):
        rng.uniform_at(torch.tensor([0, 0]), 2 ** 20 + 1)
    with pytest.raises(ValueError, match=r"^at most 1048576 numbers per draw$"):
        rng.uniform(2 ** 10, 2 ** 10 + 1)


def test_seed_for_torch_is_the_keys_next_output_in_63_bits():
    seeds = [0, 9]
    got = SeedStreams(seeds, LEARNER_STREAM).seed_for_torch()
    assert got == [sm64(sm64(sm64(s) ^ sm64(LEARNER_STREAM))) >> 1 for s in seeds]
    assert all(0 <= g < 2 ** 63 for g in got)


def test_a_stream_id_is_48_bits_of_the_names_blake2_hash_above_2_48():
    """A named stream's id is part of every result drawn from it: the same in every process and
    version (corridor.wind's recorded when stream_id was written), above the numbered ids."""
    assert stream_id("td3.explore") == (1 << 48) | int(hashlib.blake2b(b"td3.explore", digest_size=6).hexdigest(), 16)
    assert stream_id("corridor.wind") == 545550430812439
    assert stream_id("a") != stream_id("b") and min(stream_id("a"), stream_id("b")) >= 2 ** 48


def test_a_seed_alone_draws_what_it_draws_in_a_batch_across_a_buffer_refill():
    alone, batch = SeedStreams([3], stream=2), SeedStreams([0, 3, 7], stream=2)
    for _ in range(SeedStreams.BLOCK + 5):
        assert torch.equal(alone.uniform(4)[0], batch.uniform(4)[1])


def test_the_default_stream_is_0_and_the_signed_constants_wrap():
    assert SeedStreams([1]).uniform(2).tolist() == [oracle(1, 0, 0, 2)]
    assert [_signed(c) for c in (0, 5, 2 ** 63 - 1, 2 ** 63, 0x9E3779B97F4A7C15, 2 ** 64 - 1)] == [
        0, 5, 2 ** 63 - 1, -(2 ** 63), 0x9E3779B97F4A7C15 - 2 ** 64, -1]


def test_state_continues_the_stream_and_refuses_another_seeds_or_streams():
    rng = SeedStreams([3, 4], 2)
    for _ in range(5):
        rng.uniform(2)
    state = rng.state_dict()
    assert state["counter"] == 5
    again = SeedStreams([3, 4], 2)
    again.uniform(7)                                  # a buffer of another shape, dropped on load
    again.load_state_dict(state)
    assert again.counter == 5 and again.uniform(2).tolist() == [oracle(3, 2, 5, 2), oracle(4, 2, 5, 2)]
    for other in (SeedStreams([3, 5], 2), SeedStreams([3, 4], 1)):
        with pytest.raises(ValueError, match=r"^random-stream state belongs to other seeds or another stream$"):
            other.load_state_dict(state)


@pytest.mark.parametrize("seeds", [[-1], [[0, 1]]])
def test_seeds_must_be_a_list_of_non_negative_integers(seeds):
    with pytest.raises(ValueError, match=r"^seeds must be a list of non-negative integers$"):
        SeedStreams(seeds)
