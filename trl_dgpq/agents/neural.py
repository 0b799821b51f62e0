"""What the neural-network agents (DDPG, DQN) share: S seeds' learners as one.

Every network holds one copy per seed, its parameters stacked along a leading seed
dimension (TorchRL's multi-agent machinery, ``MultiAgentNetBase`` with
``share_params=False``: a seed is an "agent" that sees only its own input), and one
vmapped forward, loss and backward serves all seeds. TorchRL's losses (``DQNLoss``,
``DDPGLoss``), target updaters and ``LazyTensorStorage`` work on the stacked
parameters and batches as they are. What would couple seeds is done here instead:

- losses are computed with ``reduction="none"`` and reduced per seed
  (``seed_mean``: each seed's mean, summed over seeds, so a seed's gradient is its
  own);
- gradient norms are clipped per seed (``clip_grad_norm_per_seed``);
- every random draw (exploration, replay indices) comes from the seed's own
  counter-based stream (``rng.SeedStreams``), never torch's global generator --
  TorchRL's ``EGreedyModule``, OU module and samplers draw from that one, so the
  thin equivalents below replace them;
- initial weights: each seed's networks are built under its own torch generator
  (the same weights the earlier one-learner-per-seed code drew);
- Adam is elementwise, so Adam on stacked parameters is per-seed Adam (tested).

Seeds in a batch move in lock-step: the collector only ever drops finished seeds,
so every active seed has taken the same number of steps, and one step counter
serves them all. A finished seed is frozen: its rows of every parameter, target
and optimiser state are put back after each update (``keep_rows``), so its saved
networks are the ones it finished with.
"""
from __future__ import annotations

import contextlib
import copy
from typing import Callable, Iterable, List, Sequence

import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import LazyTensorStorage
from torchrl.modules import MultiAgentNetBase

from ..rng import LEARNER_STREAM, SeedStreams, stream_id


def build_per_seed(build: Callable[[], nn.Module], seeds: Sequence[int]) -> List[nn.Module]:
    """``build()`` once per seed, each under a torch generator seeded from the seed's learner
    stream: seed i's initial weights never depend on the others."""
    nets = []
    for torch_seed in SeedStreams(seeds, LEARNER_STREAM).seed_for_torch():
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(torch_seed)
            nets.append(build())
    return nets


class SeedStack(MultiAgentNetBase):
    """One network per seed (``nets``, all of one architecture), run as one: inputs
    ``(..., S, features)``, several inputs concatenated on the last dim, output
    ``(..., S, out)``."""

    def __init__(self, nets: List[nn.Module]):
        self._pending = (nets[0], list(nets))  # (a tuple: nn.Module refuses modules before its __init__)
        super().__init__(n_agents=len(nets), centralized=False, share_params=False, agent_dim=-2,
                         vmap_randomness="error")
        del self._pending

    def _build_single_net(self, *, device=None):
        template, nets = self._pending
        if str(device) == "meta":  # the parameter-less shell the vmapped call runs in
            return copy.deepcopy(template).to("meta")
        return nets.pop(0)

    def _pre_forward_check(self, inputs):
        if inputs.shape[-2] != self.n_agents:
            raise ValueError(f"expected {self.n_agents} seeds at dim -2, got input of shape {tuple(inputs.shape)}")
        return inputs

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        """As ``MultiAgentNetBase.forward``, with each seed's rows contiguous (seed dim
        leading) on the way in and for the gradient on the way back: the backward's
        reductions over the minibatch (a bias's gradient) then take the same kernel path
        for every seed whatever S is. With the gradient laid out (B, S, out), as a loss
        hands it back, a 2-wide output's bias gradient differed in the last bit between
        S = 1, 8 and S = 2, 3."""
        x = self._pre_forward_check(torch.cat(inputs, -1) if len(inputs) > 1 else inputs[0])
        x = x.movedim(-2, 0).contiguous()
        out = self.vmap_func_module(self._empty_net, in_dims=(0, 0), out_dims=(0,),
                                    randomness=self.vmap_randomness)(self.params, x).movedim(0, -2)
        if out.requires_grad:  # the gradient coming back, seed-major too (a loss lays it out (B, S, ..))
            out.register_hook(lambda g: g.movedim(-2, 0).contiguous().movedim(0, -2))
        return out


def seed_mean(loss: torch.Tensor) -> torch.Tensor:
    """Per-element losses ``(B, S, ...)`` -> the sum over seeds of each seed's mean. Each
    seed's elements are made contiguous first, so its mean is summed in the same order
    whatever the number of seeds (bitwise equal alone and in a batch)."""
    return loss.movedim(1, 0).contiguous().flatten(1).mean(-1).sum()


def clip_grad_norm_per_seed(params: Iterable[torch.Tensor], max_norm: float) -> torch.Tensor:
    """``clip_grad_norm_`` for each seed on its own rows of stacked parameters (S, ...):
    the same formula (2-norm of the per-tensor norms, scale max_norm / (norm + 1e-6) when
    above). Returns the per-seed norms before clipping."""
    grads = [p.grad for p in params if p.grad is not None]
    S = grads[0].shape[0]
    norms = torch.stack([g.reshape(S, -1).norm(dim=1) for g in grads], dim=1)  # (S, tensors), row per seed
    total = norms.norm(dim=1)
    scale = (max_norm / (total + 1e-6)).clamp(max=1.0)
    for g in grads:
        g.mul_(scale.view(S, *([1] * (g.dim() - 1))))
    return total


@contextlib.contextmanager
def keep_rows(tensors: Sequence[torch.Tensor], rows: torch.Tensor):
    """Whatever happens inside, seeds ``rows`` (bool (S,)) of every tensor with a leading
    seed dimension are as before (finished seeds stay frozen). Free when no row is kept."""
    if not bool(rows.any()):
        yield
        return
    S = rows.shape[0]
    tensors = [t for t in tensors if t.dim() > 0 and t.shape[0] == S]
    saved = [t[rows].clone() for t in tensors]
    yield
    with torch.no_grad():
        for t, s in zip(tensors, saved):
            t[rows] = s


def optimizer_tensors(optim: torch.optim.Optimizer) -> List[torch.Tensor]:
    return [v for state in optim.state.values() for v in state.values() if torch.is_tensor(v)]


class SeedReplay:
    """Replay memory with a seed dimension: TorchRL's ``LazyTensorStorage`` laid out
    (capacity, S); each seed draws its own minibatch indices from its own stream, and
    one gather returns the (B, S) minibatch. Seeds write in lock-step (one cursor).
    TorchRL's samplers are not used: they draw from torch's global generator over all
    rows at once."""

    def __init__(self, capacity: int, seeds: Sequence[int]):
        self.capacity, self.S = int(capacity), len(seeds)
        self.storage = LazyTensorStorage(self.capacity * self.S, ndim=2)
        self.rng = SeedStreams(seeds, stream_id("neural.replay"))
        self.seed_index = torch.arange(self.S)
        self.written = 0  # transitions written per seed

    def __len__(self) -> int:
        return min(self.written, self.capacity)

    def add(self, transition: TensorDict) -> None:
        """One transition per seed (batch (S,))."""
        self.storage.set(self.written % self.capacity, transition)
        self.written += 1

    def sample(self, batch_size: int) -> TensorDict:
        """(batch_size, S): uniform with replacement over each seed's stored transitions."""
        u = self.rng.uniform(batch_size)                                  # (S, B) float64
        rows = (u * len(self)).long().T                                   # (B, S)
        return self.storage.get((rows, self.seed_index.expand_as(rows)))

    def state_dict(self) -> dict:
        return {"storage": self.storage.state_dict(), "rng": self.rng.state_dict(), "written": self.written}

    def load_state_dict(self, state: dict) -> None:
        self.storage.load_state_dict(state["storage"])
        self.rng.load_state_dict(state["rng"])
        self.written = int(state["written"])


def as_float32(td: TensorDict) -> TensorDict:
    """The transition as the networks take it: floating entries float32, flags as they are."""
    return td.apply(lambda t: t.to(torch.float32) if t.is_floating_point() else t)


class SeedBatchedLearner:
    """Agent base for S seeds learning as one: the step counter, the replay memory, the
    transition as stored, per-seed update counts, and freezing finished seeds.
    A subclass builds its networks, ``loss`` and ``optimizers`` and defines ``act`` and
    ``update(batch)`` (one gradient step for all seeds) and ``wants_update()``."""

    optimizers: List[torch.optim.Optimizer]
    loss: nn.Module

    def __init__(self, seeds: Sequence[int], buffer_size: int):
        self.seeds = list(seeds)
        S = len(self.seeds)
        self.replay = SeedReplay(buffer_size, self.seeds)
        self.steps = 0                                    # env steps of every active seed
        self.updates = torch.zeros(S, dtype=torch.long)   # gradient steps per seed
        self.new_episode = torch.ones(S, dtype=torch.bool)

    def stored(self, td) -> TensorDict:
        """The transition (S,) to store: observation, action, reward, next observation, flags."""
        nxt = td.get("next")
        return as_float32(TensorDict({
            "observation": td.get("observation"), "action": td.get("action"),
            "next": {"observation": nxt.get("observation"), "reward": nxt.get("reward"),
                     "done": nxt.get("done"), "terminated": nxt.get("terminated")}}, batch_size=td.batch_size))

    def learned_tensors(self) -> List[torch.Tensor]:
        """Everything an update changes: the loss module's parameters and targets, the optimisers' state."""
        return list(self.loss.state_dict(keep_vars=True).values()) + [
            t for o in self.optimizers for t in optimizer_tensors(o)]

    def observe(self, td, active=None) -> None:
        S = len(self.seeds)
        active = torch.ones(S, dtype=torch.bool) if active is None else active
        self.replay.add(self.stored(td))
        self.steps += 1
        n = self.wants_update()
        with keep_rows(self.learned_tensors(), ~active):
            for _ in range(n):
                self.update(self.replay.sample(self.batch_size))
            self.after_step()
        self.updates += n * active
        self.new_episode = td.get("next").get("done").reshape(S).clone()

    def wants_update(self) -> int:
        """Gradient steps to take after this env step (0: none)."""
        raise NotImplementedError

    def update(self, batch: TensorDict) -> None:
        raise NotImplementedError

    def after_step(self) -> None:
        """Per env step bookkeeping after the updates (target copies)."""

    def episode_stats(self) -> dict:
        return {"updates": self.updates.clone()}

    def state_dict(self) -> dict:
        return {"loss": self.loss.state_dict(), "optimizers": [o.state_dict() for o in self.optimizers],
                "replay": self.replay.state_dict(), "steps": self.steps, "updates": self.updates.clone(),
                "new_episode": self.new_episode.clone()}

    def load_state_dict(self, state: dict) -> None:
        if "learners" in state:
            raise ValueError("this checkpoint holds one learner per seed (an earlier version); it cannot be resumed "
                             "by the seed-batched learners: start the run again")
        if state["updates"].shape != self.updates.shape:
            raise ValueError(f"{type(self).__name__.lower()} state is for {state['updates'].shape[0]} seeds, "
                             f"not {len(self.seeds)}")
        self.loss.load_state_dict(state["loss"])
        for o, s in zip(self.optimizers, state["optimizers"]):
            o.load_state_dict(s)
        self.replay.load_state_dict(state["replay"])
        self.steps = int(state["steps"])
        self.updates.copy_(state["updates"])
        self.new_episode.copy_(state["new_episode"])
