"""Shared machinery of the seed-batched environments.

A subclass describes one domain: it builds its specs in ``_make_specs`` and
implements ``_initial(mask)`` (reset the selected seeds' state, return the
observation of all seeds) and ``_transition(action)`` (advance every seed, return
observation, reward ``(S,)`` and terminated ``(S,)``). This base handles the
per-seed random streams, partial resets through the ``_reset`` mask, the step
cap (truncation, which is not termination) and building TensorDicts on
``self.device``.
"""
from __future__ import annotations

from typing import Sequence

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Categorical, Composite
from torchrl.envs import EnvBase

from trl_dgpq.rng import SeedStreams

ENV_STREAM = 2  # random-stream id of environment noise (the agent uses others)


class SeedBatchedEnv(EnvBase):
    """Base for envs with ``batch_size=[len(seeds)]``; seed i's trajectory depends
    only on seeds[i] and its own actions."""

    batch_locked = True

    def __init__(self, seeds: Sequence[int] = (0,), max_steps: int = 200, device="cpu"):
        seeds = [int(s) for s in seeds]
        if not seeds:
            raise ValueError("need at least one seed")
        if int(max_steps) != max_steps or max_steps < 1:
            raise ValueError(f"max_steps must be a positive integer, got {max_steps}")
        super().__init__(device=device, batch_size=torch.Size([len(seeds)]))
        self.seeds = seeds
        self.max_steps = int(max_steps)
        self.rng = SeedStreams(seeds, ENV_STREAM, device=self.device)
        self.t = torch.zeros(len(seeds), dtype=torch.long, device=self.device)
        self._make_specs()
        flag = Categorical(2, shape=(len(seeds), 1), dtype=torch.bool, device=self.device)
        self.full_done_spec = Composite(done=flag.clone(), terminated=flag.clone(), truncated=flag.clone(),
                                        shape=self.batch_size, device=self.device)

    @property
    def num_seeds(self) -> int:
        return len(self.seeds)

    # --------------------------------------------------------- subclass API
    def _make_specs(self) -> None:
        raise NotImplementedError

    def _initial(self, mask: torch.Tensor) -> TensorDict:
        raise NotImplementedError

    def _transition(self, action: torch.Tensor):
        raise NotImplementedError

    # ------------------------------------------------------------- EnvBase
    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDict:
        S = self.num_seeds
        mask = None if tensordict is None else tensordict.get("_reset", None)
        mask = torch.ones(S, dtype=torch.bool, device=self.device) if mask is None else mask.reshape(S)
        self.t[mask] = 0
        out = self._initial(mask)
        false = torch.zeros(S, 1, dtype=torch.bool, device=self.device)
        out.update({"done": false, "terminated": false.clone(), "truncated": false.clone()})
        return out

    def _step(self, tensordict: TensorDictBase) -> TensorDict:
        out, reward, terminated = self._transition(tensordict.get("action"))
        self.t += 1
        truncated = (self.t >= self.max_steps) & ~terminated
        out.update({"reward": reward[:, None], "terminated": terminated[:, None],
                    "truncated": truncated[:, None], "done": (terminated | truncated)[:, None]})
        return out

    def _set_seed(self, seed: int | None) -> None:
        """Re-key the streams as seeds ``seed, seed + 1, ...`` (TorchRL's convention);
        the usual way is to pass ``seeds`` to the constructor."""
        if seed is not None:
            self.seeds = [int(seed) + i for i in range(self.num_seeds)]
            self.rng = SeedStreams(self.seeds, ENV_STREAM, device=self.device)

    def _td(self, **tensors) -> TensorDict:
        return TensorDict(tensors, batch_size=self.batch_size, device=self.device)
