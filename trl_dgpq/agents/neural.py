"""What the neural-network agents (DDPG, DQN) share: S seeds' learners as one.

Every network holds one copy per seed, its parameters stacked along a leading seed
dimension (``SeedStack``: each ``nn.Linear`` becomes one batched matrix product over
seeds), and every tensor is seed-major -- observations (S, obs), minibatches (S, B) --
so one forward, loss and backward serves all seeds. ``LazyTensorStorage`` holds the
replay memory. The losses, the target updates and the exploration noise are thin code
on these tensors; TorchRL's ``DQNLoss``, ``DDPGLoss``, ``HardUpdate`` and ``SoftUpdate``
are their reference in the tests (equal values on the same parameters and batch) but
not the running code: measured here at S = 4 on the course's DDPG (1 thread),
``DDPGLoss``'s forward took 1.7 ms for 0.2 ms of arithmetic -- its functional
parameter swapping and key routing for each of its five network calls -- and with it a
seed-batched step could not be made the 4x cheaper the neural baselines need.
What would couple seeds is done here instead:

- losses are computed per element and reduced per seed
  (``seed_mean``: each seed's mean, summed over seeds, so a seed's gradient is its
  own);
- gradient norms are clipped per seed (``clip_grad_norm_per_seed``);
- every random draw (exploration, replay indices) comes from the seed's own
  counter-based stream (``rng.SeedStreams``), never torch's global generator, which
  TorchRL's ``EGreedyModule``, OU module and samplers draw from;
- initial weights: each seed's networks are built under its own torch generator
  (the same weights the earlier one-learner-per-seed code drew);
- Adam is elementwise, so Adam on stacked parameters is per-seed Adam (tested). Each
  stack's parameters are views of one flat buffer (``FlatParams``) of whole cache lines,
  so torch's fused Adam, one pass per element, never meets its scalar tail, whose
  rounding differs from its vectors': a seed's result is the same in any batch.

Seeds in a batch move in lock-step: the collector only ever drops finished seeds,
so every active seed has taken the same number of steps, and one step counter
serves them all. A finished seed is frozen: the updates are computed for the active
seeds alone (``seed_rows``: a run's seeds finish apart, liquidation's learners with
up to half of the batched steps after the first seed finished, in the seed report's
runs), and its rows of every parameter, target and optimiser state, which Adam and the
target updates touch, are put back after each update (``keep_rows``), so its saved
networks are the ones it finished with.
"""
from __future__ import annotations

import contextlib
import copy
from typing import Callable, Iterable, List, Optional, Sequence, Tuple

import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import LazyTensorStorage

from ..rng import LEARNER_STREAM, SeedStreams, stream_id
from .base import learning_reward


def build_per_seed(build: Callable[[], nn.Module], seeds: Sequence[int]) -> List[nn.Module]:
    """``build()`` once per seed, each under a torch generator seeded from the seed's learner
    stream: seed i's initial weights never depend on the others."""
    nets = []
    for torch_seed in SeedStreams(seeds, LEARNER_STREAM).seed_for_torch():
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(torch_seed)
            nets.append(build())
    return nets


class SeedLinear(nn.Module):
    """S independent ``nn.Linear`` layers as one: weight (S, in, out) -- each seed's
    ``nn.Linear`` weight transposed, so the product needs no transposed operand (13%
    faster forward + backward at 64 x 256 x 256 here) -- and bias (S, out); input
    (S, ..., in) -> (S, ..., out), one ``baddbmm``."""

    rows: Optional[torch.Tensor] = None   # the seeds a forward is for (``seed_rows``); None: all

    def __init__(self, layers: List[nn.Linear]):
        super().__init__()
        self.weight = nn.Parameter(torch.stack([layer.weight.detach().T for layer in layers]).contiguous())
        self.bias = nn.Parameter(torch.stack([layer.bias.detach() for layer in layers]))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        weight, bias = self.weight, self.bias
        if self.rows is not None:   # their rows alone; backward adds their gradient into those rows
            weight, bias = weight.index_select(0, self.rows), bias.index_select(0, self.rows)
        S, _, out = weight.shape
        xs = x.reshape(S, -1, x.shape[-1])
        if S == 1:
            # torch's batched product of a single matrix takes another path (an mm) whose last bits
            # differ from the same matrix's in a batch of two or more (DDPG's output layer forward,
            # weight gradients of some widths): a seed alone is computed beside a copy of itself that
            # takes no gradient, so that its bits are the ones it gets in a batch (tested against
            # batches of two and three)
            pair = lambda t: torch.cat([t, t.detach()])  # noqa: E731
            return torch.baddbmm(pair(bias).unsqueeze(1), pair(xs), pair(weight))[:1].view(*x.shape[:-1], out)
        return torch.baddbmm(bias.unsqueeze(1), xs, weight).view(*x.shape[:-1], out)


# floats in a 64-byte cache line: torch's fused Adam on CPU splits its work at whole lines and
# runs whole vectors (8 floats on this CPU, 16 with AVX-512) in each, so a buffer of whole lines
# never meets the scalar tail, whose rounding differs: unpadded, a seed's result would depend on
# how many seeds share the buffer (tests/test_seed_adam.py)
LINE = 16


class FlatParams:
    """The parameters of ``module`` made views of one buffer ``data``, each a contiguous block
    (S, ...) starting on a cache line, the buffer padded with zeros to whole lines; their
    gradients views of one buffer ``grad`` laid out alike, which backward adds into (a
    defined gradient is accumulated in place, never replaced). ``param`` is the buffer as
    one parameter for the optimiser, so Adam and the target updates are one pass each over
    every seed's parameters. Padding stays zero: its gradient is zero, so Adam never moves it."""

    def __init__(self, module: nn.Module, grad: bool = True):
        named = list(module.named_parameters())
        self.spans, end = [], 0
        for _, p in named:
            self.spans.append((end, p.shape))
            end += -(-p.numel() // LINE) * LINE
        like = dict(dtype=named[0][1].dtype, device=named[0][1].device)  # the parameters' own, never cast
        self.data = torch.zeros(end, **like)
        self.grad = torch.zeros(end, **like) if grad else None
        self.placed = []  # (module holding it, its name, the parameter, its gradient view, where its data is)
        for (name, p), (offset, shape) in zip(named, self.spans):
            path, _, leaf = name.rpartition(".")
            owner = module.get_submodule(path)
            shared = nn.Parameter(self.view(self.data, offset, shape), requires_grad=p.requires_grad)
            shared.detach().copy_(p.detach())
            if grad:
                shared.grad = self.view(self.grad, offset, shape)
            setattr(owner, leaf, shared)
            self.placed.append((owner, leaf, shared, shared.grad, shared.data_ptr()))
        self.param = nn.Parameter(self.data, requires_grad=grad)
        self.param.grad = self.grad

    def places(self, seeds: torch.Tensor) -> torch.Tensor:
        """Where in the buffer the elements of ``seeds`` (indices) lie: every parameter's rows of them."""
        out = []
        for offset, shape in self.spans:
            per = shape[1:].numel()
            out.append((offset + seeds[:, None] * per + torch.arange(per)).flatten())
        return torch.cat(out)

    @staticmethod
    def view(buffer: torch.Tensor, offset: int, shape: torch.Size) -> torch.Tensor:
        return buffer[offset:offset + shape.numel()].view(shape)

    def check(self) -> None:
        """Refuse to go on once a parameter or its gradient is no longer a view of the buffers
        (``Module.zero_grad()``, ``.to()``, ``.double()`` or ``load_state_dict(assign=True)``
        replace them): Adam would step a buffer nothing reads, and learning would stop silently."""
        for owner, leaf, p, grad, where in self.placed:  # (~1 us a parameter: it runs at every step)
            if owner._parameters[leaf] is not p or p.grad is not grad or p.data_ptr() != where:
                raise RuntimeError("a stacked network's parameters or gradients were replaced (by Module.zero_grad, "
                                   ".to(), a dtype cast or load_state_dict(assign=True)): they are views of its flat "
                                   "buffers, which its optimiser steps; zero gradients with the optimiser's zero_grad")

    def pack(self, tensors: Sequence[torch.Tensor]) -> torch.Tensor:
        """Tensors shaped as the parameters, in their order, as one buffer (padding zero)."""
        out = torch.zeros_like(self.data)
        for (offset, shape), t in zip(self.spans, tensors):
            self.view(out, offset, shape).copy_(t)
        return out


class SeedAdam(torch.optim.Adam):
    """Adam on a stack's flat buffer, fused: one pass per element (3.8x faster than the
    foreach Adam's passes on 10 x 67,344 floats here). ``zero_grad`` zeroes the buffer the
    layers' gradients are views of (it must stay theirs: ``set_to_none`` is ignored). Each
    ``step`` first checks that they still are (``FlatParams.check``).

    A checkpoint of an earlier version (torch's Adam per layer tensor) is packed into the
    buffer on load; a run resumed from it goes on with the fused arithmetic, so its later
    episodes are neither version's bit for bit (equal in distribution: docs/agents/neural.md)."""

    def __init__(self, stack: "SeedStack", lr: float):
        super().__init__([stack.flat.param], lr=lr, fused=True)
        self.flat = stack.flat

    def zero_grad(self, set_to_none: bool = True) -> None:
        self.flat.grad.zero_()

    def step(self, closure=None):
        self.flat.check()
        return super().step(closure)

    def load_state_dict(self, state_dict: dict) -> None:
        group = state_dict["param_groups"][0]
        if len(group["params"]) != 1:  # an earlier version's Adam: a state per layer tensor, packed as ours
            if len(group["params"]) != len(self.flat.spans):
                raise ValueError(f"the optimiser state holds {len(group['params'])} tensors, the network "
                                 f"{len(self.flat.spans)}: it is another network's")
            if state_dict["state"] and set(state_dict["state"]) != set(group["params"]):
                raise ValueError("the optimiser state covers some of the network's tensors, not all: it cannot "
                                 "be packed into one buffer")
            per = [state_dict["state"][i] for i in group["params"]] if state_dict["state"] else []
            state = {0: {"step": per[0]["step"].clone(),
                         **{k: self.flat.pack([s[k] for s in per]) for k in ("exp_avg", "exp_avg_sq")}}} if per else {}
            state_dict = {"state": state, "param_groups": [{**group, "params": [0], "foreach": None, "fused": True}]}
        super().load_state_dict(state_dict)

    def seed_tensors(self) -> List[torch.Tensor]:
        """Adam's moments as views shaped as the parameters (S, ...), for ``keep_rows``."""
        return [self.flat.view(state[k], offset, shape) for state in self.state.values()
                for k in ("exp_avg", "exp_avg_sq") for offset, shape in self.flat.spans]


class SeedStack(nn.Module):
    """One network per seed (``nets``, all of one architecture), run as one: inputs
    (S, ..., features) give (S, ..., out). The architecture's ``nn.Linear`` layers become
    ``SeedLinear``; parameter-free layers (activations) and the architecture's own
    ``forward`` are kept.

    Why not TorchRL's ``MultiAgentMLP(share_params=False)``: it runs each call through
    ``torch.vmap`` of a functional call that swaps the stacked parameters into an empty
    network; measured here (S = 4, batch 128, the course's 8-24-48-1 actor, 1 thread),
    forward + backward took 780 us that way and 250 us as batched matrix products,
    forward alone 300 us and 43 us."""

    rows: Optional[torch.Tensor] = None   # as SeedLinear's

    def __init__(self, nets: List[nn.Module]):
        super().__init__()
        self.net = copy.deepcopy(nets[0])
        for name, module in nets[0].named_modules():
            if isinstance(module, nn.Linear):
                self.net.set_submodule(name, SeedLinear([net.get_submodule(name) for net in nets]))
            elif name and any(True for _ in module.parameters(recurse=False)):
                raise TypeError(f"SeedStack stacks nn.Linear layers only, not {type(module).__name__}")
        self.num_seeds = len(nets)
        self.flat = FlatParams(self.net)

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        seeds = self.num_seeds if self.rows is None else len(self.rows)
        if inputs[0].shape[0] != seeds:
            raise ValueError(f"expected {seeds} seeds at dim 0, got input of shape {tuple(inputs[0].shape)}")
        return self.net(*inputs)


@contextlib.contextmanager
def seed_rows(nets: nn.Module, rows: Optional[torch.Tensor]):
    """Inside, every stack in ``nets`` computes for seeds ``rows`` (long indices) alone: inputs
    (len(rows), ...), outputs likewise, and backward adds gradients into those rows only. Each
    seed's arithmetic is the same as in the whole batch (a seed's result never depends on its
    batch), so an update of the active seeds alone gives them the bits the whole batch's would,
    for the work of fewer seeds. None: all seeds, the plain path."""
    if rows is None:
        yield
        return
    modules = [m for m in nets.modules() if isinstance(m, (SeedStack, SeedLinear))]
    for m in modules:
        m.rows = rows
    try:
        yield
    finally:
        for m in modules:
            m.rows = None


def seed_mean(loss: torch.Tensor) -> torch.Tensor:
    """Per-element losses ``(S, B, ...)`` -> the sum over seeds of each seed's mean. Each
    seed's elements are contiguous, so its mean is summed in the same order whatever the
    number of seeds (bitwise equal alone and in a batch)."""
    return loss.contiguous().flatten(1).mean(-1).sum()


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
def keep_rows(buffers: Callable[[], Sequence[Tuple[torch.Tensor, FlatParams]]], rows: torch.Tensor):
    """Whatever happens inside, seeds ``rows`` (bool (S,)) of every flat buffer ``buffers()``
    lists, each with the layout it has (a stack's parameters, its target's, Adam's moments of
    them), are as before (finished seeds stay frozen): one gather and one scatter a buffer.
    Free when no row is kept."""
    if not bool(rows.any()):
        yield
        return
    seeds, places, saved = rows.nonzero()[:, 0], {}, []
    for t, flat in buffers():
        if id(flat) not in places:   # a layout's positions of those seeds' elements, found once
            places[id(flat)] = flat.places(seeds)
        saved.append((t, places[id(flat)], t[places[id(flat)]]))
    yield
    with torch.no_grad():
        for t, at, s in saved:
            t.index_copy_(0, at, s)


class Target(nn.Module):
    """A target network: a copy of ``net`` that follows it by copies (DQN) or soft
    updates (DDPG), never by gradients."""

    def __init__(self, net: nn.Module):
        super().__init__()
        self.net = copy.deepcopy(net)
        stacks = [(m, o) for m, o in zip(self.net.modules(), net.modules()) if isinstance(m, SeedStack)]
        if sum(p.numel() for m, _ in stacks for p in m.parameters()) != sum(p.numel() for p in net.parameters()):
            raise TypeError("a Target follows networks whose parameters are all in SeedStacks")
        for stack, _ in stacks:  # a deep copy's parameters are copies, no longer views of its buffer
            stack.flat = FlatParams(stack.net, grad=False)
        self.net.requires_grad_(False)
        # (plain lists, not submodules: the online net is saved once, as itself)
        self._pairs = ([m.flat.data for m, _ in stacks], [o.flat.data for _, o in stacks])

    def forward(self, *inputs):
        return self.net(*inputs)

    @torch.no_grad()
    def copy_(self) -> None:
        torch._foreach_copy_(*self._pairs)

    @torch.no_grad()
    def soft_update_(self, tau: float) -> None:
        """target <- target + tau (online - target), as TorchRL's ``SoftUpdate``."""
        torch._foreach_lerp_(*self._pairs, tau)


class SeedReplay:
    """Replay memory with a seed dimension: TorchRL's ``LazyTensorStorage`` laid out
    (capacity, S); each seed draws its own minibatch indices from its own stream, and
    one gather returns the (S, B) minibatch. Seeds write in lock-step (one cursor).
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
        """(S, batch_size): uniform with replacement over each seed's stored transitions."""
        rows = (self.rng.uniform(batch_size) * len(self)).long()         # (S, B)
        return self.storage.get((rows, self.seed_index[:, None].expand_as(rows)))

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
    A subclass builds its networks (``nets``, targets included) and ``optimizers`` and
    defines ``act``, ``update(batch)`` (one gradient step for the seeds of ``batch``: all, or
    the active ones while others have finished, ``updating``; a tensor of every seed's it draws
    itself it takes through ``of_updating``) and
    ``wants_update()``; ``before_updates()`` if it has per-step bookkeeping."""

    optimizers: List[SeedAdam]
    nets: nn.ModuleDict

    def __init__(self, seeds: Sequence[int], buffer_size: int):
        self.seeds = list(seeds)
        S = len(self.seeds)
        self.replay = SeedReplay(buffer_size, self.seeds)
        self.steps = 0                                    # env steps of every active seed
        self.updates = torch.zeros(S, dtype=torch.long)   # gradient steps per seed
        self.new_episode = torch.ones(S, dtype=torch.bool)
        self.updating: Optional[torch.Tensor] = None   # during an update: the seeds it is for (None: all)

    def stored(self, td) -> TensorDict:
        """The transition (S,) to store: observation, action, reward, next observation, flags."""
        nxt = td.get("next")
        return as_float32(TensorDict({
            "observation": td.get("observation"), "action": td.get("action"),
            "next": {"observation": nxt.get("observation"), "reward": learning_reward(td, self.cfg.gamma),
                     "done": nxt.get("done"), "terminated": nxt.get("terminated")}}, batch_size=td.batch_size))

    def learned_buffers(self) -> List[Tuple[torch.Tensor, FlatParams]]:
        """Everything an update changes, as flat buffers with their layouts: every stack's parameters
        (the networks' and the targets'), the optimisers' moments (their step count is one scalar)."""
        stacks = [m for m in self.nets.modules() if isinstance(m, SeedStack)]
        if sum(p.numel() for m in stacks for p in m.parameters()) != sum(p.numel() for p in self.nets.parameters()):
            raise TypeError("a network has parameters outside its SeedStacks: a finished seed's would not be kept")
        return [(m.flat.data, m.flat) for m in stacks] + [
            (state[k], o.flat) for o in self.optimizers for state in o.state.values() for k in ("exp_avg", "exp_avg_sq")]

    def observe(self, td, active=None) -> None:
        S = len(self.seeds)
        active = torch.ones(S, dtype=torch.bool) if active is None else active
        self.replay.add(self.stored(td))
        self.steps += 1
        n = self.wants_update()
        # finished seeds take no part: the updates are computed for the active ones alone (a run's
        # seeds finish apart, liquidation's up to half its steps before the last), and whatever
        # touches every row (Adam, the targets) is undone on the finished ones
        self.updating = None if bool(active.all()) else active.nonzero()[:, 0]
        try:
            with keep_rows(self.learned_buffers, ~active):
                self.before_updates()
                for _ in range(n):
                    batch = self.replay.sample(self.batch_size)   # every seed draws, active or not: its stream's place
                    with seed_rows(self.nets, self.updating):
                        self.update(self.of_updating(batch))
        finally:   # as seed_rows' rows: never left set past the updates, even by an error in one
            self.updating = None
        self.updates += n * active
        self.new_episode = td.get("next").get("done").reshape(S).clone()

    def of_updating(self, t):
        """The rows (S, ...) of ``t`` the update in progress is for: the active seeds' (``updating``)."""
        return t if self.updating is None else t[self.updating]

    def wants_update(self) -> int:
        """Gradient steps to take after this env step (0: none)."""
        raise NotImplementedError

    def update(self, batch: TensorDict) -> None:
        raise NotImplementedError

    def before_updates(self) -> None:
        """Per env step bookkeeping after the step is counted, before its updates (DQN's
        target copies, which SB3 makes in the rollout, before the rollout's training)."""

    def episode_stats(self) -> dict:
        return {"updates": self.updates.clone()}

    def state_dict(self) -> dict:
        return {"nets": self.nets.state_dict(), "optimizers": [o.state_dict() for o in self.optimizers],
                "replay": self.replay.state_dict(), "steps": self.steps, "updates": self.updates.clone(),
                "new_episode": self.new_episode.clone()}

    def load_state_dict(self, state: dict) -> None:
        if "learners" in state:
            raise ValueError("this checkpoint holds one learner per seed (an earlier version); it cannot be resumed "
                             "by the seed-batched learners: start the run again")
        if state["updates"].shape != self.updates.shape:
            raise ValueError(f"{type(self).__name__.lower()} state is for {state['updates'].shape[0]} seeds, "
                             f"not {len(self.seeds)}")
        self.nets.load_state_dict(state["nets"])
        for o, s in zip(self.optimizers, state["optimizers"]):
            o.load_state_dict(s)
        self.replay.load_state_dict(state["replay"])
        self.steps = int(state["steps"])
        self.updates.copy_(state["updates"])
        self.new_episode.copy_(state["new_episode"])
