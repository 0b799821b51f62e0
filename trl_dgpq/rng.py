"""Per-seed random streams, batched.

A seed's draws must not depend on which other seeds share its batch, and looping
over one ``torch.Generator`` per seed costs a Python call per seed per draw. So
each (seed, stream) pair gets a counter-based generator: the ``i``-th number of a
draw is ``splitmix64(key(seed, stream) + counter * 2^20 + i)``, computed for all
seeds at once with int64 tensor ops. Draw ``t`` of seed ``s`` is the same whatever
else is in the batch, and whatever other streams (env noise, tie-breaking) drew.
"""
from __future__ import annotations

import hashlib
from typing import Sequence

import torch

# Each consumer draws from its own stream, so one consumer drawing more or less never
# shifts another's numbers. Ids 1-7 were numbered by hand and stay as they are (results
# depend on them): 5 is liquidation's price noise (PRICE_STREAM in envs/liquidation/env.py),
# 7 the square's reward noise (envs/square/env.py). A new consumer names its stream
# instead, ``stream_id("corridor.wind")``, in its own file: no table to edit.
TIE_STREAM = 1     # DGPQ: tie-breaking among equal Q̂ values
ENV_STREAM = 2     # environment noise (every env's ``self.rng``)
KERNEL_STREAM = 3  # initial weights of manifold kernels
POLICY_STREAM = 4  # random agent's actions
LEARNER_STREAM = 6  # neural learners (DDPG, DQN): initial weights, replay sampling, exploration


def stream_id(name: str) -> int:
    """A stream id from a name: 48 bits of its BLAKE2 hash above 2^48, never one of the
    numbered ids, and the same in every process and version."""
    return (1 << 48) | int.from_bytes(hashlib.blake2b(name.encode(), digest_size=6).digest(), "big")


def _signed(c: int) -> int:
    return c - (1 << 64) if c >= 1 << 63 else c


_GOLDEN, _MIX1, _MIX2 = (_signed(c) for c in (0x9E3779B97F4A7C15, 0xBF58476D1CE4E5B9, 0x94D049BB133111EB))


def _lsr(z: torch.Tensor, k: int) -> torch.Tensor:
    """Logical right shift of int64 (torch's >> is arithmetic)."""
    return (z >> k) & ((1 << (64 - k)) - 1)


def splitmix64(z: torch.Tensor) -> torch.Tensor:
    """The splitmix64 finaliser on int64 tensors (wrapping arithmetic)."""
    z = z + _GOLDEN
    z = (z ^ _lsr(z, 30)) * _MIX1
    z = (z ^ _lsr(z, 27)) * _MIX2
    return z ^ _lsr(z, 31)


class SeedStreams:
    """Independent uniform streams, one per seed, for one named purpose.

    >>> rng = SeedStreams([0, 3, 7], stream=1)
    >>> u = rng.uniform(4)      # (3, 4) in [0, 1); row i depends only on seeds[i]
    """

    MAX_PER_DRAW = 1 << 20
    BLOCK = 256  # draws generated at once (hashing is ~12 tensor ops; a buffer read is one)

    def __init__(self, seeds: Sequence[int], stream: int = 0, device=None):
        seeds = torch.as_tensor(list(seeds), dtype=torch.int64, device=device)
        if seeds.dim() != 1 or (seeds < 0).any():
            raise ValueError("seeds must be a list of non-negative integers")
        self.key = splitmix64(splitmix64(seeds) ^ splitmix64(torch.full_like(seeds, stream)))
        self.counter = 0  # draws made so far; every seed of a batch draws in lock-step
        self._buf, self._buf_start, self._buf_shape = None, 0, None

    def _draws(self, counter: torch.Tensor, n: int) -> torch.Tensor:
        """n uniforms of draw ``counter`` (int64, shape (S, ...) broadcast with the seeds'
        keys): ``(*counter.shape, n)``. The one place the numbers are made."""
        idx = torch.arange(n, dtype=torch.int64, device=self.key.device)
        key = self.key.view(-1, *([1] * (counter.dim() - 1)))
        z = splitmix64((key + counter * self.MAX_PER_DRAW)[..., None] + idx)
        return _lsr(z, 11).double() * 2.0 ** -53

    def _generate(self, first: int, draws: int, n: int) -> torch.Tensor:
        """Draws ``first .. first + draws - 1`` of n numbers each: (S, draws, n)."""
        ctr = torch.arange(first, first + draws, dtype=torch.int64, device=self.key.device)
        return self._draws(ctr[None, :], n)

    def uniform(self, *shape: int) -> torch.Tensor:
        """Uniform [0, 1) float64 of shape ``(S, *shape)``: draw number ``counter`` of each
        seed. Values do not depend on how draws are buffered."""
        n = 1
        for s in shape:
            n *= s
        if n > self.MAX_PER_DRAW:
            raise ValueError(f"at most {self.MAX_PER_DRAW} numbers per draw")
        i = self.counter - self._buf_start
        if self._buf is None or self._buf_shape != shape or i >= self._buf.shape[1]:
            self._buf = self._generate(self.counter, self.BLOCK, n)
            self._buf_start, self._buf_shape, i = self.counter, shape, 0
        self.counter += 1
        return self._buf[:, i].view(-1, *shape)

    def normal(self, *shape: int) -> torch.Tensor:
        """Standard normal float64 ``(S, *shape)`` (Box-Muller on one uniform draw of twice the size)."""
        u = self.uniform(2, *shape)
        return box_muller(u[:, 0], u[:, 1])

    def uniform_at(self, index: torch.Tensor, n: int) -> torch.Tensor:
        """Uniform [0, 1) ``(S, n)``: draw number ``index[i]`` of seed i, without moving the
        counter. For numbers keyed by something other than the step count (liquidation's
        price path of episode ``index[i]``), so they never depend on what came before."""
        if n > self.MAX_PER_DRAW:
            raise ValueError(f"at most {self.MAX_PER_DRAW} numbers per draw")
        return self._draws(index.to(torch.int64).view(-1), n)

    def seed_for_torch(self) -> list:
        """One 63-bit integer per seed, derived from its key: a seed for ``torch.manual_seed``
        where a library draws from torch's global generator."""
        return _lsr(splitmix64(self.key), 1).tolist()

    def state_dict(self) -> dict:
        return {"key": self.key.clone(), "counter": self.counter}

    def load_state_dict(self, state: dict) -> None:
        """Continue from a saved position; the key must be the same seeds' and stream's."""
        if not torch.equal(state["key"].to(self.key.device), self.key):
            raise ValueError("random-stream state belongs to other seeds or another stream")
        self.counter = int(state["counter"])
        self._buf, self._buf_start, self._buf_shape = None, 0, None  # values do not depend on buffering


def box_muller(u1: torch.Tensor, u2: torch.Tensor) -> torch.Tensor:
    """Standard normals from two uniforms in [0, 1) of the same shape."""
    return torch.sqrt(-2.0 * torch.log1p(-u1)) * torch.cos(2.0 * torch.pi * u2)
