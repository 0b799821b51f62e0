"""The optimistic Lipschitz envelope Q̂ of DGPQ (GWH14, Eq. 7), batched over seeds.

For each seed and action a, Q̂ stores pairs (s_i, mu_i) and answers
    Q̂_a(s) = min(V_max, min_i [mu_i + L_Q * d(s, s_i)]).
An empty Q̂_a is V_max everywhere. Storage is ``capacity`` slots per seed and
action, laid out ``(S, A, capacity, ...)``; an unused slot holds mu = +inf.
Inserting into a full row doubles the capacity (documented growth, a copy,
amortised O(1)).

A large Q̂ (``index_min`` slots a row or more: by default ``INDEX_SLOTS`` over all rows) answers
through ``ChunkIndex``: its pairs sorted in Z-order into chunks of ``CHUNK``, kept in that order
beside the storage, with a bounding box and the least and largest mu of each, so that Eq. 7's
minimum and the pruning of an insert scan only the chunks whose bound can matter. Those chunks'
pairs go through the same arithmetic as a full scan, so the values are the same bit for bit; the
index is derived from the storage, never saved, and rebuilt when stale.
"""
from __future__ import annotations

import math
from typing import Optional

import torch

METRICS = {"l1": 1.0, "l2": 2.0, "linf": math.inf}


def distance(x: torch.Tensor, s: torch.Tensor, metric: str) -> torch.Tensor:
    """d(x_b, s_bj): x ``(B, d)``, s ``(B, n, d)`` -> ``(B, n)``. ``cdist`` is ~10x faster
    than ``(x - s).abs().sum(-1)``, whose reduction runs over a tiny last dim."""
    return torch.cdist(x[:, None, :], s, p=METRICS[metric],
                       compute_mode="donot_use_mm_for_euclid_dist")[:, 0]


def values(x: torch.Tensor, s: torch.Tensor, mu: torch.Tensor, lipschitz: float, metric: str) -> torch.Tensor:
    """mu_j + L d(x_b, s_bj), (B, n): Eq. 7's terms and pruning's test, one arithmetic for the scan
    and the index (so that the index's values are the scan's to the bit)."""
    return torch.add(mu, distance(x, s, metric), alpha=lipschitz)


class LipschitzQ:
    """Q̂ for S seeds and A actions over ``dim``-dimensional states."""

    def __init__(self, num_seeds: int, num_actions: int, dim: int, lipschitz: float, v_max: float,
                 metric: str = "l1", capacity: int = 64, dtype=torch.float64, device=None,
                 index_min: Optional[int] = None, chunk: Optional[int] = None, fan: Optional[int] = None,
                 free_block: Optional[int] = None):
        if metric not in METRICS:
            raise ValueError(f"metric must be one of {sorted(METRICS)}, got {metric!r}")
        if not (lipschitz > 0 and math.isfinite(lipschitz)):
            raise ValueError(f"lipschitz must be finite and > 0, got {lipschitz}")
        if not math.isfinite(v_max):
            raise ValueError(f"v_max must be finite, got {v_max}")
        self.S, self.A, self.dim = num_seeds, num_actions, dim
        self.lipschitz, self.v_max, self.metric = float(lipschitz), float(v_max), metric
        kw = dict(dtype=dtype, device=device)
        self.s = torch.zeros(num_seeds, num_actions, capacity, dim, **kw)
        # Unused slots hold mu = +inf: Eq. 7 needs no mask (mu + L d is +inf there).
        self.mu = torch.full((num_seeds, num_actions, capacity), torch.inf, **kw)
        self.width = 0  # slots [0, width) may be used in some row; the rest are unused
        self.version = 0  # bumped by every change, for callers that memoise values
        # From this width on, queries and pruning go through the index (exact: the same values); by
        # default from INDEX_SLOTS slots in all rows (its own work per query is nearly fixed).
        self.index_min = -(-INDEX_SLOTS // (num_seeds * num_actions)) if index_min is None else index_min
        self._index_shape = (CHUNK if chunk is None else chunk, FAN if fan is None else fan)
        self.index = ChunkIndex(self.lipschitz, metric, *self._index_shape)
        self.free_block = FREE_BLOCK if free_block is None else free_block
        if self.free_block < 1:
            raise ValueError(f"free_block must be >= 1, got {self.free_block}")
        self._free = None   # free slots per block of ``free_block`` slots of each row; derived, rebuilt on use
        self._last = None   # (states, values) of the last query through the index (``_hint``)

    @property
    def capacity(self) -> int:
        return self.mu.shape[-1]

    @property
    def valid(self) -> torch.Tensor:
        """Which slots hold a pair, (S, A, capacity)."""
        return torch.isfinite(self.mu)

    def size(self) -> torch.Tensor:
        """Stored pairs per seed, (S,)."""
        return torch.isfinite(self.mu[..., :self.width]).flatten(1).sum(1)

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        """Q̂_a(x) for every action: x ``(S, dim)`` -> ``(S, A)``."""
        if self.width == 0:
            return x.new_full((self.S, self.A), self.v_max)
        xs = x[:, None, :].expand(self.S, self.A, self.dim).reshape(self.S * self.A, self.dim)
        if self.width >= self.index_min:
            q = self.index.envelope(xs, *self._rows(), self.width, self._hint(xs))
            self._last = (xs.clone(), q)   # (xs may be a view of the caller's tensor)
            return q.view(self.S, self.A).clamp_max(self.v_max)
        # One cdist over the (S*A) rows of stored states; the reduction then runs over
        # the contiguous last dim. cdist copies a sliced (strided) input, so a mostly
        # used storage (over 3/4) is passed whole: unused slots have mu = +inf and drop
        # out. Below that, the copy of [:width] is cheaper than the scan: measured at
        # S = 64, A = 4, scanning a just-doubled storage cost 3-5x the sliced [:width],
        # and the threshold of 1/2 this replaces made time per step jump at each doubling.
        w = self.capacity if 4 * self.width > 3 * self.capacity else self.width
        s, mu = self._rows()
        return values(xs, s[:, :w], mu[:, :w], self.lipschitz, self.metric).amin(-1).view(self.S, self.A) \
            .clamp_max(self.v_max)

    # Q̂ only falls (an insert adds a pair and prunes pairs it bounds everywhere) and is L-Lipschitz, so
    # the last answer, at the last query's states, bounds this one: Q̂(x) <= Q̂_last(x') + L d(x, x').
    # A step's query lies a step away from the last one, so the bound is near the answer and the index
    # opens fewer boxes than the reps' bound alone lets it.
    def _hint(self, xs: torch.Tensor) -> Optional[torch.Tensor]:
        if self._last is None:
            return None
        x_last, q_last = self._last
        return values(xs, x_last[:, None, :], q_last[:, None], self.lipschitz, self.metric)[:, 0]

    def bound(self, x: torch.Tensor, s: torch.Tensor, mu: torch.Tensor) -> torch.Tensor:
        """mu + L d(x, s) for one pair per seed: x, s ``(S, dim)``, mu ``(S,)``."""
        return values(x, s[:, None, :], mu[:, None], self.lipschitz, self.metric)[:, 0]

    def insert(self, x: torch.Tensor, a: torch.Tensor, mu: torch.Tensor, mask: torch.Tensor) -> None:
        """Insert (x, mu) into Q̂_a for the seeds in ``mask`` and prune, per action, every
        stored pair it makes redundant (mu + L d(x, s_j) <= mu_j)."""
        rows = mask.nonzero().squeeze(-1)
        if rows.numel() == 0:
            return
        self.version += 1
        x, a, mu = x[rows].to(self.s.dtype), a[rows], mu[rows].to(self.mu.dtype)   # as stored (the index copies them)
        w, r = self.width, rows * self.A + a
        self._free_blocks()   # counted from the storage before pruning changes it
        if w >= self.index_min:
            self._count_free(*self.index.prune(x, r, mu, *self._rows(), w))
        elif w:
            s_a, mu_a = self.s[:, :, :w][rows, a], self.mu[:, :, :w][rows, a]
            redundant = values(x, s_a, mu[:, None], self.lipschitz, self.metric) <= mu_a
            self.mu[:, :, :w][rows, a] = mu_a.masked_fill(redundant, torch.inf)
            k, j = (redundant & torch.isfinite(mu_a)).nonzero(as_tuple=True)
            self._count_free(r[k], j)
        if w == self.capacity and self._free[r].sum(-1).eq(0).any():
            self._grow()
            self._free_blocks()
        slot = self._first_free(r)
        self.s[rows, a, slot] = x
        self.mu[rows, a, slot] = mu
        self._count_free(r, slot, -(~torch.isinf(mu)).long())   # an infinite mu leaves its slot free
        self.index.inserted(r, slot, x, mu)
        self.width = max(w, int(slot.max()) + 1)

    # Finding a row's first free slot by scanning it cost O(width) an insert, most of an insert at
    # 10^5 slots; a count of free slots per block of each row finds the block, then one block is read.
    def _free_blocks(self) -> torch.Tensor:
        """Free slots in each block of ``free_block`` slots of each row, (S * A, blocks) int64;
        the last block counts only the slots within the capacity."""
        if self._free is None:
            B, rows = self.free_block, self.S * self.A
            free = torch.isinf(self._rows()[1])
            free = torch.cat((free, free.new_zeros(rows, -self.capacity % B)), 1)
            self._free = free.view(rows, -1, B).sum(-1)
        return self._free

    def _count_free(self, r: torch.Tensor, slot: torch.Tensor, change: Optional[torch.Tensor] = None) -> None:
        """Add ``change`` (default 1: slots emptied) to the free count of slot ``slot``'s block of row ``r``."""
        at = r * self._free.shape[1] + torch.div(slot, self.free_block, rounding_mode="floor")
        self._free.view(-1).index_add_(0, at, torch.ones_like(at) if change is None else change)

    def _first_free(self, r: torch.Tensor) -> torch.Tensor:
        """The first free slot of each row ``r`` (each has one): the first block with a free slot,
        then the first free slot in it."""
        B = self.free_block
        block = (self._free[r] > 0).int().argmax(-1)
        slots = (block[:, None] * B + torch.arange(B, device=r.device)).clamp_max(self.capacity - 1)
        return block * B + torch.isinf(_take(self._rows()[1], r[:, None], slots)).int().argmax(-1)

    def _rows(self):
        """The storage as (S * A) rows: states (rows, capacity, dim) and mu (rows, capacity)."""
        return self.s.view(self.S * self.A, self.capacity, self.dim), self.mu.view(self.S * self.A, self.capacity)

    def growth_bytes(self) -> int:
        """Bytes the next step may allocate: doubling a full storage copies it into one twice its
        size, and a build of the index (``ChunkIndex.build_bytes``) when one is due (0 otherwise)."""
        grow = 0
        if self.width == self.capacity:
            grow = 2 * (self.s.numel() * self.s.element_size() + self.mu.numel() * self.mu.element_size())
        if self.width + 1 < self.index_min or not self.index.due():
            return grow
        return grow + self.index.build_bytes(self.S * self.A, self.width + 1, self.dim)

    def _grow(self) -> None:
        pad = lambda t, fill: torch.cat((t, torch.full_like(t, fill)), 2)  # noqa: E731
        self.s, self.mu = pad(self.s, 0), pad(self.mu, torch.inf)
        self._free = None

    def state_dict(self) -> dict:
        """Every field, including grown storage, ``width`` and ``version``."""
        return {"s": self.s.clone(), "mu": self.mu.clone(), "width": self.width, "version": self.version}

    def load_state_dict(self, state: dict) -> None:
        s, mu = state["s"], state["mu"]
        if s.shape[:2] != (self.S, self.A) or s.shape[-1] != self.dim or mu.shape != s.shape[:-1]:
            raise ValueError(f"Q̂ state has shape {tuple(s.shape)}, expected ({self.S}, {self.A}, capacity, {self.dim})")
        self.s = s.to(dtype=self.s.dtype, device=self.s.device).clone()
        self.mu = mu.to(dtype=self.mu.dtype, device=self.mu.device).clone()
        self.width, self.version = int(state["width"]), int(state["version"])
        self._free = self._last = None
        self.index = ChunkIndex(self.lipschitz, self.metric, *self._index_shape)   # derived: rebuilt on use


FREE_BLOCK = 256    # slots per block of the free-slot counts: an insert reads blocks/row counts and one block
INDEX_SLOTS = 2 ** 19   # slots (rows x width) from which the index answers: below, a scan costs less
                        # (bench.py qhat-index; docs/agents/dgpq.md)
CHUNK = 32      # pairs per chunk: its bound is checked in place of its pairs
FAN = 32        # chunks per group: a group's bound is checked in place of its chunks'
STALE = 16      # rebuilt once the inserts since the last build reach 1/STALE of its slots
TOL = 1e-9      # relative slack on the bounds: a chunk is skipped only well clear of rounding
BUILD_SLOTS = 2 ** 20   # slots sorted at once by a build (its temporaries: ~40 bytes a slot and coordinate)


def _zorder(s: torch.Tensor, used: torch.Tensor) -> torch.Tensor:
    """Each slot's Morton (Z-order) key over its row's used pairs' bounding box, (rows, w) int64;
    unused slots last. Slots near in the key are near in space, so a run of them makes a tight box."""
    dim = s.shape[-1]
    bits = max(1, min(16, 62 // dim))
    top = 2 ** bits - 1
    lo = s.masked_fill(~used[..., None], torch.inf).amin(1, keepdim=True)
    hi = s.masked_fill(~used[..., None], -torch.inf).amax(1, keepdim=True)
    q = ((s - lo) / (hi - lo).clamp_min(1e-300) * top).nan_to_num(0.0).clamp(0, top).long()
    key = torch.zeros(s.shape[:-1], dtype=torch.long, device=s.device)
    for b in range(bits):
        for j in range(dim):
            key |= ((q[..., j] >> b) & 1) << (b * dim + j)
    return key.masked_fill(~used, torch.iinfo(torch.long).max)


def _take(t: torch.Tensor, rows: torch.Tensor, at: torch.Tensor) -> torch.Tensor:
    """``t[rows, at]`` for a (rows, n, ...) tensor, ``rows`` broadcast to ``at``: one ``index_select``
    on the flat tensor (advanced indexing by two tensors costs several times more)."""
    flat = (rows * t.shape[1] + at).reshape(-1)
    return t.reshape(-1, *t.shape[2:]).index_select(0, flat).view(*at.shape, *t.shape[2:])


class _Boxes:
    """Of n groups of pairs per row: their bounding boxes (lo, hi: (rows, n, dim)), mu ranges (least,
    most: (rows, n)) and the state of a pair with the least mu (rep), packed in one tensor (rows, n,
    3 dim + 2) so that one ``index_select`` takes them all. An empty group's box is (+inf, -inf), its
    range (+inf, -inf), its rep 0."""

    def __init__(self, packed: torch.Tensor):
        self.packed = packed
        dim = (packed.shape[-1] - 2) // 3
        self.lo, self.hi, self.rep = packed[..., :dim], packed[..., dim:2 * dim], packed[..., 2 * dim + 2:]
        self.least, self.most = packed[..., 2 * dim], packed[..., 2 * dim + 1]

    @classmethod
    def of(cls, lo, hi, least, most, rep) -> "_Boxes":
        return cls(torch.cat((lo, hi, least[..., None], most[..., None], rep), -1))

    @classmethod
    def around(cls, pts: torch.Tensor, m: torch.Tensor, used: torch.Tensor) -> "_Boxes":
        """The boxes of pairs ``pts`` (rows, n, k, dim) with mu ``m`` (rows, n, k), ``used`` where
        they hold a pair (unused: mu +inf)."""
        least, at = m.min(-1)
        rep = pts.gather(-2, at[..., None, None].expand(*at.shape, 1, pts.shape[-1]))[..., 0, :]
        return cls.of(pts.masked_fill(~used[..., None], torch.inf).amin(-2),
                      pts.masked_fill(~used[..., None], -torch.inf).amax(-2),
                      least, m.masked_fill(~used, -torch.inf).amax(-1), rep.masked_fill(~used.any(-1)[..., None], 0.0))

    def merged(self, fan: int) -> "_Boxes":
        """The boxes of each ``fan`` consecutive groups; this one is padded with empty groups to a
        whole number of them."""
        rows, n, width = self.packed.shape
        dim = (width - 2) // 3
        inf = torch.inf
        empty = self.packed.new_tensor([inf] * dim + [-inf] * dim + [inf, -inf] + [0.0] * dim)
        self.__init__(torch.cat((self.packed, empty.expand(rows, -n % fan, width)), 1))
        g = self.packed.shape[1] // fan
        view = lambda t: t.reshape(rows, g, fan, *t.shape[2:])  # noqa: E731
        least, at = view(self.least).min(2)
        rep = view(self.rep).gather(2, at[..., None, None].expand(rows, g, 1, dim))[:, :, 0]
        return _Boxes.of(view(self.lo).amin(2), view(self.hi).amax(2), least, view(self.most).amax(2), rep)

    def take(self, rows, at) -> "_Boxes":
        return _Boxes(_take(self.packed, rows, at))

    def near(self, x: torch.Tensor, norm) -> torch.Tensor:
        """d(x, each box), +inf for an empty one: x (k, dim) against boxes (k, n, dim)."""
        return norm((self.lo - x[:, None]).clamp_min(0) + (x[:, None] - self.hi).clamp_min(0))

    def rep_values(self, x: torch.Tensor, norm, lipschitz: float) -> torch.Tensor:
        """least + L d(x, rep): the value at x of a pair Q̂ holds or held (+inf for an empty box).
        A pair leaves Q̂ only when another bounds it everywhere, so each is an upper bound on Eq. 7."""
        return self.least + lipschitz * norm((self.rep - x[:, None]).abs())


class ChunkIndex:
    """An exact index over Q̂'s rows for Eq. 7's minimum and an insert's pruning.

    At a build, each row's pairs in slots [0, built) are sorted in Z-order and cut into chunks of
    ``CHUNK``, and the chunks merged ``FAN`` at a time level over level, each box with the bounding
    box of its pairs' states, the least and the largest of their mu and the state of the least (its
    rep); slots from ``built`` on (the tail) are scanned. For x, a box's pairs are all at least
    ``least + L d(x, box)``, and its rep's value ``least + L d(x, rep)`` bounds Eq. 7 from above; from
    the top, only the boxes whose lower bound reaches the smallest upper bound found are opened, and
    the chunks' pairs go through the scan's arithmetic (``values``), so the minimum is the scan's to
    the bit. Pruning opens the boxes whose largest mu an insert can reach. The chunks' pairs are
    copied in chunk order (``chunk_s``, ``chunk_mu``), so that opening one reads a block; inserts and
    pruning write both copies. An insert into a built slot widens its boxes at every level; pruning
    leaves them wide (still bounds); after ``built / STALE`` inserts the index is built again.
    """

    def __init__(self, lipschitz: float, metric: str, chunk: int = CHUNK, fan: int = FAN):
        if chunk < 1 or fan < 2:
            raise ValueError(f"the index's chunks hold at least 1 pair and its groups at least 2 boxes, "
                             f"got chunk {chunk} and fan {fan}")
        self.lipschitz, self.metric, self.chunk, self.fan = lipschitz, metric, chunk, fan
        self.built = 0      # slots [0, built) are in chunks; 0: not built
        self.inserts = 0    # inserts since the build

    def _norm(self, gaps: torch.Tensor) -> torch.Tensor:
        if self.metric == "l1":
            return gaps.sum(-1)
        if self.metric == "l2":
            return gaps.square().sum(-1).sqrt()
        return gaps.amax(-1)

    # ---------------------------------------------------------------- build
    def _refresh(self, s: torch.Tensor, mu: torch.Tensor, w: int) -> None:
        if self.built == 0 or self.inserts * STALE >= self.built:
            self._build(s, mu, w)

    def _build(self, s: torch.Tensor, mu: torch.Tensor, w: int) -> None:
        """Sort each row's slots [0, w) in Z-order, chunk them and bound the chunks and groups; rows
        a block at a time, so that what the sort needs beside the index stays near ``BUILD_SLOTS``."""
        rows, dim = s.shape[0], s.shape[-1]
        chunks = -(-w // self.chunk)
        order = torch.full((rows, chunks * self.chunk), -1, dtype=torch.int32, device=s.device)
        self.place_of = torch.empty(rows, w, dtype=torch.int32, device=s.device)   # slot -> chunk * CHUNK + k
        place = torch.arange(w, device=s.device, dtype=torch.int32)
        packed = s.new_empty(rows, chunks, 3 * dim + 2)
        # the pairs again in chunk order: opening a chunk reads one contiguous block (a gather of
        # its slots from the storage cost more than the scan it saved)
        self.chunk_s = s.new_empty(rows, chunks, self.chunk, dim)
        self.chunk_mu = mu.new_empty(rows, chunks, self.chunk)
        step = max(1, BUILD_SLOTS // max(w, 1))
        for a in range(0, rows, step):
            b = min(rows, a + step)
            sorted_ = _zorder(s[a:b, :w], torch.isfinite(mu[a:b, :w])).argsort(dim=1, stable=True)
            order[a:b, :w] = sorted_
            self.place_of[a:b].scatter_(1, sorted_, place.expand(b - a, w))
            pairs = self._pairs(s, mu, torch.arange(a, b, device=s.device)[:, None, None],
                                order[a:b].view(b - a, chunks, self.chunk))
            self.chunk_s[a:b], self.chunk_mu[a:b] = pairs[:2]
            packed[a:b] = _Boxes.around(*pairs).packed
        self.order = order.view(rows, chunks, self.chunk)
        # levels[0]: the chunks; each next level merges ``fan`` boxes of the one below, up to a few a row
        self.levels = [_Boxes(packed)]
        while self.levels[-1].packed.shape[1] > self.fan:
            self.levels.append(self.levels[-1].merged(self.fan))
        self.built, self.inserts = w, 0

    def due(self) -> bool:
        """Whether the next step (a query, then an insert) may build the index."""
        return self.built == 0 or (self.inserts + 1) * STALE >= self.built

    def build_bytes(self, rows: int, width: int, dim: int) -> int:
        """Bytes a build at ``width`` allocates: the index it keeps (a sorted slot and a place per
        slot, 4 bytes each; the pairs' states and mu in chunk order, dim + 1 float64s per sorted slot;
        3 dim + 2 float64s per box of every level, each level below the top padded to whole groups of
        ``fan``, its unpadded copy made first) and at most one block's sort beside it (~8 (6 dim + 8)
        bytes a slot)."""
        n = chunks = -(-width // self.chunk)
        boxes = 0
        while n > self.fan:
            padded = n + (-n % self.fan)
            boxes, n = boxes + n + padded, padded // self.fan
        kept = rows * (4 * chunks * self.chunk + 4 * width + 8 * (3 * dim + 2) * (boxes + n)
                       + 8 * (dim + 1) * chunks * self.chunk)
        return kept + min(rows * width, max(BUILD_SLOTS, width)) * 8 * (6 * dim + 8)

    @staticmethod
    def _pairs(s, mu, rows, slots):
        """States and mu of ``slots`` (-1: padding, mu +inf) of ``rows``, and which hold a pair."""
        m = _take(mu, rows, slots.clamp_min(0)).masked_fill(slots < 0, torch.inf)
        return _take(s, rows, slots.clamp_min(0)), m, torch.isfinite(m)

    def _open(self, level: int, r: torch.Tensor, at: torch.Tensor):
        """The boxes of level ``level - 1`` under boxes ``at`` of rows ``r`` at ``level``: (k, fan)
        numbers and their boxes."""
        below = at[:, None] * self.fan + torch.arange(self.fan, device=at.device)
        return below, self.levels[level - 1].take(r[:, None], below)

    def _top(self, rows: torch.Tensor):
        """Every box of the top level of ``rows``: (k, n) numbers and the boxes."""
        top = self.levels[-1]
        at = torch.arange(top.packed.shape[1], device=rows.device).expand(len(rows), -1)
        return at, (top if len(rows) == top.packed.shape[0] else top.take(rows[:, None], at))

    # ---------------------------------------------------------------- queries
    def envelope(self, x: torch.Tensor, s: torch.Tensor, mu: torch.Tensor, w: int,
                 hint: Optional[torch.Tensor] = None) -> torch.Tensor:
        """min_j mu_j + L d(x_r, s_rj) of each row r (+inf for a row with no pair): x (rows, dim).
        ``hint`` (rows,), if given, is at least each row's minimum (up to rounding; NaN: none): it
        only narrows which boxes are opened."""
        self._refresh(s, mu, w)
        L, rows = self.lipschitz, s.shape[0]
        tail = (values(x, s[:, self.built:w], mu[:, self.built:w], L, self.metric).amin(-1)
                if w > self.built else x.new_full((rows,), torch.inf))
        upper = tail if hint is None else torch.fmin(tail, hint)   # (fmin: a NaN hint, after a NaN query, is none)
        r = torch.arange(rows, device=s.device)
        at, boxes = self._top(r)
        for level in range(len(self.levels) - 1, -1, -1):    # from the top: open what may hold the minimum
            upper = upper.scatter_reduce(0, r, boxes.rep_values(x[r], self._norm, L).amin(1), "amin")
            k, j = self._reach(boxes.least, boxes.near(x[r], self._norm), upper[r, None]).nonzero(as_tuple=True)
            r, at = r[k], at[k, j]
            if level:
                at, boxes = self._open(level, r, at)
        pts, m = _take(self.chunk_s, r, at), _take(self.chunk_mu, r, at)
        return tail.scatter_reduce(0, r, values(x[r], pts, m, L, self.metric).amin(1), "amin")

    def _reach(self, least, near, upper):
        """Which boxes' lower bound (least + L d(x, box)) reaches ``upper``, with slack for rounding
        (empty boxes never)."""
        lower = least + self.lipschitz * near
        slack = TOL * (least.abs() + self.lipschitz * near + upper.abs())
        return (lower <= upper + slack) & torch.isfinite(lower)

    def _prunable(self, boxes: _Boxes, x, new_mu):
        """Which boxes may hold a pair that (x, new_mu) makes redundant: new_mu + L d(x, box) reaches
        their largest mu (with slack for rounding)."""
        near = boxes.near(x, self._norm)
        reach = new_mu[:, None] + self.lipschitz * near
        slack = TOL * (new_mu.abs()[:, None] + self.lipschitz * near + boxes.most.abs())
        return (reach <= boxes.most + slack) & torch.isfinite(boxes.most)

    def prune(self, x: torch.Tensor, rows: torch.Tensor, new_mu: torch.Tensor, s: torch.Tensor,
              mu: torch.Tensor, w: int):
        """Set to +inf each pair of ``rows`` that (x, new_mu) makes redundant (new_mu + L d(x, s_j)
        <= mu_j), as the full scan would: x (k, dim), rows and new_mu (k,), one insert per row.
        Returns the emptied slots: their rows and slots, (n,) each."""
        self._refresh(s, mu, w)
        L = self.lipschitz
        tail_rows = tail_slots = rows[:0]
        if w > self.built:
            st, mt = s[rows, self.built:w], mu[rows, self.built:w]
            redundant = values(x, st, new_mu[:, None], L, self.metric) <= mt
            mu[rows, self.built:w] = mt.masked_fill(redundant, torch.inf)
            k, j = (redundant & torch.isfinite(mt)).nonzero(as_tuple=True)
            tail_rows, tail_slots = rows[k], j + self.built
        i = torch.arange(len(rows), device=x.device)
        at, boxes = self._top(rows)
        for level in range(len(self.levels) - 1, -1, -1):    # from the top: open what may hold a redundant pair
            k, j = self._prunable(boxes, x[i], new_mu[i]).nonzero(as_tuple=True)
            i, at = i[k], at[k, j]
            if level:
                at, boxes = self._open(level, rows[i], at)
        r = rows[i]
        pts, m = _take(self.chunk_s, r, at), _take(self.chunk_mu, r, at)
        redundant = (values(x[i], pts, new_mu[i, None], L, self.metric) <= m) & torch.isfinite(m)
        slots = _take(self.order, r, at)
        r, slots = r[:, None].expand_as(slots)[redundant], slots[redundant].long()
        mu[r, slots] = torch.inf
        self.chunk_mu.view(-1)[self._places(rows[i], at)[redundant]] = torch.inf     # the copy too
        return torch.cat((tail_rows, r)), torch.cat((tail_slots, slots))

    def _places(self, r: torch.Tensor, at: torch.Tensor) -> torch.Tensor:
        """Flat positions in ``chunk_mu`` of the pairs of chunks ``at`` of rows ``r``: (k, chunk)."""
        first = (r * self.chunk_mu.shape[1] + at) * self.chunk
        return first[:, None] + torch.arange(self.chunk, device=r.device)

    def inserted(self, rows: torch.Tensor, slots: torch.Tensor, x: torch.Tensor, mu: torch.Tensor) -> None:
        """Pairs (x, mu) written into ``slots`` of ``rows``: a built slot's boxes, at every level, take them in."""
        if self.built == 0:
            return
        self.inserts += 1
        inside = slots < self.built
        r, place = rows[inside], self.place_of[rows[inside], slots[inside]].long()
        x, mu = x[inside], mu[inside]
        c = place // self.chunk
        flat = r * self.chunk_mu[0].numel() + place
        self.chunk_s.view(-1, x.shape[-1])[flat], self.chunk_mu.view(-1)[flat] = x, mu
        for level, boxes in enumerate(self.levels):
            at = c // self.fan ** level
            boxes.lo[r, at] = torch.minimum(boxes.lo[r, at], x)
            boxes.hi[r, at] = torch.maximum(boxes.hi[r, at], x)
            lower = mu < boxes.least[r, at]       # the new pair is the rep where its mu is the least
            boxes.rep[r[lower], at[lower]] = x[lower]
            boxes.least[r, at] = torch.minimum(boxes.least[r, at], mu)
            boxes.most[r, at] = torch.maximum(boxes.most[r, at], mu)
