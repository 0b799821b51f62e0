"""Shared machinery of the seed-batched environments.

A subclass describes one domain: its settings are a config dataclass (``Config``),
it builds its specs in the classmethod ``_specs(cfg, S, device)`` (so what an agent
needs to know of the env, ``EnvInfo``, comes from the config alone, with no env
built) and implements ``_initial(mask)`` (reset
the selected seeds' state, return the observation of all seeds) and
``_transition(action)`` (advance every seed, return observation, reward ``(S,)``
and terminated ``(S,)``, and optionally truncated ``(S,)`` where the env has a cap of
its own); ``_state_names`` lists the tensors that change as it
runs, so ``state_dict`` can save them. This base handles the per-seed random
streams, partial resets through the ``_reset`` mask, the step cap (truncation,
which is not termination), checking actions against the action spec and
building TensorDicts on ``self.device``.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Sequence, Tuple

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite
from torchrl.envs import EnvBase

from trl_dgpq.config import check_config
from trl_dgpq.rng import ENV_STREAM, SeedStreams, stream_id


@dataclass(frozen=True)
class EnvInfo:
    """What an agent may know of an env, from its class and config alone: the specs of
    one seed, the names of what each step's TensorDict holds beside the observation,
    and the names of discrete actions. Resolution, the memory estimate and the run each
    make it the same way, from the config (``describe``), never from a built env."""
    config: Any                       # the env's checked Config
    observation_spec: Composite       # one seed's (shape (1, ...))
    action_spec: Any
    action_names: Tuple[str, ...] = ()  # discrete actions' names, by index (empty: unnamed)
    action_hint: str = ""             # how to get the other kind of action, if the env can
    device: Any = "cpu"

    @property
    def observation_dim(self) -> int:
        return int(self.observation_spec["observation"].shape[-1])

    @property
    def keys(self) -> Tuple[str, ...]:
        """Entries of each step's TensorDict beside "observation" (readable by key)."""
        return tuple(k for k in self.observation_spec.keys() if k != "observation")

    def num_actions(self, who: str = "this agent") -> int:
        """Number of actions of a discrete (Categorical) action spec; a clear error otherwise."""
        spec = self.action_spec
        if not isinstance(spec, Categorical):
            raise ValueError(f"{who} needs discrete actions; this env's action spec is {type(spec).__name__}"
                             + (f" ({self.action_hint})" if self.action_hint else ""))
        return int(spec.space.n)

    def action_box(self, who: str = "this agent") -> Bounded:
        """The continuous (Bounded) action spec; a clear error otherwise."""
        spec = self.action_spec
        if not isinstance(spec, Bounded):
            raise ValueError(f"{who} needs a continuous (Bounded) action spec; this env's is {type(spec).__name__}"
                             + (f" ({self.action_hint})" if self.action_hint else ""))
        return spec

    def action_index(self, name: str) -> int:
        """Index of the discrete action called ``name``."""
        if not self.action_names:
            raise ValueError(f"this env does not name its actions: give an index instead of {name!r}")
        if name not in self.action_names:
            raise ValueError(f"this env has no action {name!r}; its actions are {list(self.action_names)}")
        return self.action_names.index(name)

    def state_box(self):
        """(low, high) of the observation, for covering numbers (Section 5)."""
        spec = self.observation_spec["observation"]
        if not isinstance(spec, Bounded):
            raise ValueError("this env's observations are unbounded, so Section 5 has no covering number from "
                             "them: use covering unit-square, or give sigma_tol2 and eps1")
        return spec.space.low[0].tolist(), spec.space.high[0].tolist()


class SeedBatchedEnv(EnvBase):
    """Base for envs with ``batch_size=[len(seeds)]``; seed i's trajectory depends
    only on seeds[i] and its own actions. ``cfg`` is the subclass's ``Config``
    (defaults when None); keyword arguments override its fields."""

    batch_locked = True
    Config = None                         # the env's settings dataclass (with a max_steps field)
    action_names: Tuple[str, ...] = ()    # names of discrete actions, by index
    action_hint: str = ""                 # how to get the other kind of action, for agents' errors
    _state_names: Tuple[str, ...] = ()    # tensors that change as the env runs
    _streams: Tuple[Tuple[str, int], ...] = ()  # more per-seed streams beside self.rng: (attribute, stream id)
    episode_info: Tuple[str, ...] = ()    # (S,) entries of each step's output holding running episode
                                          # totals; their values at the episode's end go in its CSV row

    def __init__(self, seeds: Sequence[int] = (0,), cfg=None, device="cpu", **overrides):
        self.cfg = cfg = self.checked_config(replace(cfg if cfg is not None else self.Config(), **overrides))
        seeds = [int(s) for s in seeds]
        if not seeds or min(seeds) < 0:
            raise ValueError("need at least one seed, each a non-negative integer")
        super().__init__(device=device, batch_size=torch.Size([len(seeds)]))
        self.seeds = seeds
        self.max_steps = int(cfg.max_steps)
        self._key_streams()
        self.t = torch.zeros(len(seeds), dtype=torch.long, device=self.device)
        specs = self._specs(cfg, len(seeds), self.device)
        self.observation_spec, self.action_spec, self.reward_spec = specs
        flag = Categorical(2, shape=(len(seeds), 1), dtype=torch.bool, device=self.device)
        self.full_done_spec = Composite(done=flag.clone(), terminated=flag.clone(), truncated=flag.clone(),
                                        shape=self.batch_size, device=self.device)

    @property
    def num_seeds(self) -> int:
        return len(self.seeds)

    @classmethod
    def checked_config(cls, cfg):
        """``cfg`` checked (and completed, where an env fills a value from elsewhere)."""
        return check_config(cfg)

    @classmethod
    def describe(cls, cfg=None, device="cpu") -> EnvInfo:
        """The ``EnvInfo`` of this env with settings ``cfg`` (default: the defaults)."""
        cfg = cls.checked_config(cfg if cfg is not None else cls.Config())
        observation, action, _ = cls._specs(cfg, 1, device)
        return EnvInfo(cfg, observation, action, tuple(cls.action_names), cls.action_hint, torch.device(device))

    @property
    def info(self) -> EnvInfo:
        return self.describe(self.cfg, self.device)

    # --------------------------------------------------------- subclass API
    @classmethod
    def _specs(cls, cfg, num_seeds: int, device) -> Tuple[Composite, Any, Any]:
        """(observation spec, action spec, reward spec) for ``num_seeds`` seeds."""
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
        out, reward, terminated, *own_cap = self._transition(self.check_action(tensordict.get("action")))
        self.t += 1
        truncated = ((self.t >= self.max_steps) | (own_cap[0] if own_cap else False)) & ~terminated
        out.update({"reward": reward[:, None], "terminated": terminated[:, None],
                    "truncated": truncated[:, None], "done": (terminated | truncated)[:, None]})
        return out

    def check_action(self, action: torch.Tensor) -> torch.Tensor:
        """The action as the spec wants it, or a ValueError saying what is wrong.
        Discrete: indices of shape (S,) in [0, n); integral floats are cast, nothing
        else is (a negative index would silently count from the end)."""
        spec = self.action_spec
        shape = tuple(spec.shape)
        if not torch.is_tensor(action):
            raise ValueError(f"action must be a tensor of shape {shape}, got {type(action).__name__}")
        if isinstance(spec, Categorical):
            n = spec.space.n
            if tuple(action.shape) != shape:
                hint = " (one-hot? pass .argmax(-1))" if tuple(action.shape) == shape + (n,) else ""
                raise ValueError(f"action must be indices of shape {shape} in [0, {n}), "
                                 f"got shape {tuple(action.shape)}{hint}")
            if action.dtype == torch.bool or action.is_complex():
                raise ValueError(f"action must be integer indices in [0, {n}), got dtype {action.dtype}")
            if action.is_floating_point():
                fractional = ~(torch.isfinite(action) & (action == action.round()))
                if fractional.any():
                    raise ValueError(f"action must be integer indices in [0, {n}), got non-integral "
                                     f"{action[fractional][:3].tolist()}")
                action = action.long()
            bad = (action < 0) | (action >= n)
            if bad.any():
                raise ValueError(f"action must be in [0, {n}), got {action[bad][:3].tolist()}")
            return action.long()
        if isinstance(spec, Bounded):
            if tuple(action.shape) != shape:
                raise ValueError(f"action must have shape {shape}, got {tuple(action.shape)}")
            low, high = spec.space.low, spec.space.high
            bad = ~(torch.isfinite(action) & (action >= low) & (action <= high))
            if bad.any():
                raise ValueError(f"action must be finite and in [{low.min().item()}, {high.max().item()}], "
                                 f"got {action[bad][:3].tolist()}")
            return action.to(spec.dtype)
        return action

    def _set_seed(self, seed: int | None) -> None:
        """Re-key the streams as seeds ``seed, seed + 1, ...`` (TorchRL's convention);
        the usual way is to pass ``seeds`` to the constructor."""
        if seed is not None:
            self.seeds = [int(seed) + i for i in range(self.num_seeds)]
            self._key_streams()

    evaluating = False  # for_evaluation() sets it: every stream keyed apart from training's

    def for_evaluation(self) -> "SeedBatchedEnv":
        """Re-key every random stream so that seed i's episodes are ones its training never
        met (the same for seed i in any batch); before the first reset. Returns self."""
        self.evaluating = True
        self._key_streams()
        return self

    def stream_key(self, stream: int) -> int:
        """The stream id this env draws ``stream`` from: itself in training, a named id apart
        from every training stream in evaluation."""
        return stream_id(f"evaluation/{stream}") if self.evaluating else stream

    def _key_streams(self) -> None:
        self.rng = SeedStreams(self.seeds, self.stream_key(ENV_STREAM), device=self.device)
        for name, stream in self._streams:
            setattr(self, name, SeedStreams(self.seeds, self.stream_key(stream), device=self.device))

    def _td(self, **tensors) -> TensorDict:
        return TensorDict(tensors, batch_size=self.batch_size, device=self.device)

    # ------------------------------------------------------------- state
    def state_dict(self, *args, **kwargs) -> dict:
        """Step counters, random streams and the subclass's ``_state_names`` tensors."""
        return {"t": self.t.clone(), "rng": self.rng.state_dict(),
                **{name: getattr(self, name).state_dict() for name, _ in self._streams},
                **{name: getattr(self, name).clone() for name in self._state_names}}

    def load_state_dict(self, state: dict, strict: bool = True) -> None:
        if state["t"].shape != self.t.shape:
            raise ValueError(f"env state is for {state['t'].shape[0]} seeds, this env has {self.num_seeds}")
        self.rng.load_state_dict(state["rng"])
        for name, _ in self._streams:
            if name in state:  # checkpoints from before the stream existed: it had drawn nothing
                getattr(self, name).load_state_dict(state[name])
        self.t.copy_(state["t"])
        for name in self._state_names:
            getattr(self, name).copy_(state[name])

