"""Gymnasium environments with discrete actions (``--env gym:ID``), through TorchRL's
``GymEnv``, batched over seeds.

One TorchRL ``GymEnv`` per seed: seed i's instance is reset with ``seed=i`` the first
time and then draws from its own ``np_random``, so seed i alone is seed i in any
batch. (TorchRL's ``SerialEnv`` seeds its members ``seed, seed + 1, ...`` from one
number, which ties a seed's stream to its place in the batch.)

Observations, as ``observations`` says: "unit" (the default, DGPQ's) maps them affinely
onto the unit box [0, 1]^d and clips them to it, so that DGPQ's lengthscale and L_Q mean
what they mean on the square. The bounds are ``obs_low``/``obs_high`` when given, else
``BOUNDS`` below (documented per env where gymnasium's are infinite or far wider than
what an episode visits), else the observation space's own; a dimension still unbounded
is squashed by (1 + tanh x) / 2 instead. "raw" passes gymnasium's own observations
through, as Stable-Baselines3 and the zoo feed their networks (the neural agents' gym
presets): the unit box's clipping and squashing cost DQN most of CartPole (issue 27).
A setting of the env rather than a TorchRL transform, so that it is recorded in
config.json with the env's other settings, chosen by presets, and the env's specs stay
built in one place. Actions are indices in [0, n). The step cap is gymnasium's
``max_episode_steps`` unless ``max_steps`` is set (gymnasium's own ``TimeLimit`` is
built with the same cap, so the two never disagree).

Exact resume for gymnasium's classic-control and toy-text envs, whose state is plain
Python: each seed's env (its wrappers' and the unwrapped env's attributes: physics
state, ``np_random``, step counters) goes into the state dict as plain data (numbers,
strings, tensors, lists and dicts: ``to_plain``; ``np_random`` as its bit generator's
state) and is copied back attribute by attribute -- never a pickle, so a checkpoint
from elsewhere cannot run code when it is loaded. Spaces and the env's spec do not
change as it runs and are not saved. Other envs (simulators holding state outside Python) run
and write checkpoints without it, and a resume from one is refused with a clear
error. An env's own cap (truncation before ``max_steps``) ends the episode as ours does.
"""
from __future__ import annotations

import functools
import importlib
import math
from dataclasses import dataclass, replace
from typing import Tuple

import gymnasium
import numpy as np
import torch
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import GymEnv

from trl_dgpq.config import check_config, setting
from trl_dgpq.rng import ENV_STREAM, SeedStreams

from ..base import SeedBatchedEnv

# the block-push id in gymnasium's "module:id" form (gymnasium imports the module, which registers it)
PUSH_GYM_ID = "trl_dgpq.envs.push.gym_adapter:trl_dgpq/BlockPush-v0"
# envs whose whole state is plain Python attributes, so saving them as plain data is exact
CHECKPOINTABLE = ("gymnasium.envs.classic_control", "gymnasium.envs.toy_text")

# (low, high) of the observation where gymnasium's bounds are infinite or much wider
# than reachable; a step out of them is clipped onto the box's face.
BOUNDS = {
    # x: the episode ends past +-2.4; velocities: beyond what a surviving pole reaches
    # (|x'| < 3, |theta'| < 3.5 in 10^5 random and trained steps); theta ends past +-12 deg.
    "CartPole-v1": ((-2.4, -3.0, -0.2095, -3.5), (2.4, 3.0, 0.2095, 3.5)),
    # MountainCar-v0 and Acrobot-v1: gymnasium's own bounds are finite and used as they are.
}


@dataclass
class GymConfig:
    """A gymnasium env with discrete actions (--env gym:ID)."""
    max_steps: int = setting(0, "step cap per episode (0: the env's registered max_episode_steps)",
                             within="[0, inf)")
    obs_low: Tuple[float, ...] = setting((), "lower observation bounds mapped to 0 (empty: documented or "
                                             "gymnasium's)")
    obs_high: Tuple[float, ...] = setting((), "upper observation bounds mapped to 1 (empty: documented or "
                                              "gymnasium's)")
    observations: str = setting("unit", "what the agent sees: 'unit' (mapped onto [0, 1]^d: DGPQ's lengthscale and "
                                        "L_Q) or 'raw' (gymnasium's own, as SB3 and the zoo)", choices=("unit", "raw"))

    def cross_check(self) -> None:
        if len(self.obs_low) != len(self.obs_high):
            raise ValueError(f"obs_low and obs_high need one bound per dimension each, got {len(self.obs_low)} "
                             f"and {len(self.obs_high)}")
        if self.obs_low and not all(math.isfinite(lo) and math.isfinite(hi) and lo < hi
                                    for lo, hi in zip(self.obs_low, self.obs_high)):
            raise ValueError(f"need finite obs_low < obs_high, got {list(self.obs_low)} and {list(self.obs_high)}")


@functools.cache
def describe(gym_id: str):
    """(number of actions, observation low, high, registered max_episode_steps) of a
    gymnasium id, or a one-line ValueError for ids the suite cannot run."""
    module, _, name = gym_id.rpartition(":")  # "module:id": gymnasium.make imports the module that registers it
    try:
        if module:
            importlib.import_module(module)
        spec = gymnasium.spec(name)
    except ImportError as e:
        raise ValueError(f"gym:{gym_id}: cannot import {module}: {e}") from None
    except gymnasium.error.Error as e:
        hint = (f"; the block-push id is now gym:{PUSH_GYM_ID}" if name.startswith("trl_dgpq/") and not module
                else "")
        raise ValueError(f"unknown gymnasium id gym:{gym_id}: {e}{hint}") from None
    try:
        env = gymnasium.make(gym_id)
    except (gymnasium.error.Error, TypeError, ImportError) as e:  # e.g. a simulator that is not installed
        raise ValueError(f"gym:{gym_id} cannot be made: {e}") from None
    try:
        act, obs = env.action_space, env.observation_space
    finally:
        env.close()
    if not isinstance(act, gymnasium.spaces.Discrete):
        raise ValueError(f"gym:{gym_id} has {type(act).__name__} actions; the suite's agents (DGPQ, DQN) "
                         f"need discrete ones (gymnasium Discrete)")
    if act.start != 0:
        raise ValueError(f"gym:{gym_id}: discrete actions must start at 0, they start at {act.start}")
    if not (isinstance(obs, gymnasium.spaces.Box) and len(obs.shape) == 1):
        raise ValueError(f"gym:{gym_id} observations must be a flat Box, got {obs}")
    return int(act.n), obs.low.astype(np.float64), obs.high.astype(np.float64), spec.max_episode_steps


class GymSeedEnv(SeedBatchedEnv):
    """TorchRL env, ``batch_size=[len(seeds)]``, over one gymnasium id (``gym_env(id)``
    makes the class); observations float64 ``(S, d)``, in the unit box or raw."""

    Config = GymConfig
    gym_id: str = ""

    @classmethod
    def checked_config(cls, cfg: GymConfig) -> GymConfig:
        """Checked, with max_steps filled from gymnasium's registration when 0."""
        check_config(cfg)
        _, low, _, registered = describe(cls.gym_id)
        if not cfg.max_steps:
            if not registered:
                raise ValueError(f"gym:{cls.gym_id} has no registered max_episode_steps: set max_steps")
            cfg = replace(cfg, max_steps=registered)
        if cfg.obs_low and len(cfg.obs_low) != len(low):
            raise ValueError(f"gym:{cls.gym_id} observations have {len(low)} dimensions; "
                             f"obs_low/obs_high have {len(cfg.obs_low)}")
        return cfg

    @classmethod
    def bounds(cls, cfg: GymConfig):
        """(low, high) float64 tensors of the raw observations mapped onto the unit box."""
        _, low, high, _ = describe(cls.gym_id)
        if cfg.obs_low:
            low, high = np.asarray(cfg.obs_low, float), np.asarray(cfg.obs_high, float)
        elif cls.gym_id in BOUNDS:
            low, high = (np.asarray(b, float) for b in BOUNDS[cls.gym_id])
        return torch.tensor(low), torch.tensor(high)

    def __init__(self, seeds=(0,), cfg: GymConfig | None = None, device="cpu", **overrides):
        super().__init__(seeds, cfg, device, **overrides)  # checks and completes the config (checked_config)
        self.low, self.high = self.bounds(self.cfg)
        self.squash = ~(torch.isfinite(self.low) & torch.isfinite(self.high))
        # x -> (x - offset) / span on bounded dimensions, fixed for the env's life
        self.offset = torch.where(self.squash, 0.0, self.low)
        self.span = torch.where(self.squash, 1.0, self.high - self.low)
        self.envs = []
        try:
            for _ in self.seeds:
                self.envs.append(GymEnv(self.gym_id, categorical_action_encoding=True,
                                        max_episode_steps=self.max_steps))
        except Exception:
            self.close(raise_if_closed=False)
            raise
        self.started = torch.zeros(self.num_seeds, dtype=torch.bool)
        self.raw = torch.zeros(self.num_seeds, self.low.numel(), dtype=torch.float64)  # gymnasium's observations
        # what GymEnv._step converted a step's observation and reward to (_transition steps gymnasium itself)
        self.obs_dtype = self.envs[0].observation_spec["observation"].dtype
        self.reward_dtype = self.envs[0].reward_spec.dtype

    @classmethod
    def _specs(cls, cfg, S, device):
        n, low, high, _ = describe(cls.gym_id)
        d = len(low)
        if cfg.observations == "unit":
            spec = Bounded(0.0, 1.0, shape=(S, d), dtype=torch.float64, device=device)
        elif np.isfinite(low).all() and np.isfinite(high).all():
            spec = Bounded(torch.tensor(low).expand(S, d), torch.tensor(high).expand(S, d), shape=(S, d),
                           dtype=torch.float64, device=device)
        else:
            spec = Unbounded(shape=(S, d), dtype=torch.float64, device=device)
        observation = Composite(observation=spec, shape=(S,), device=device)
        return (observation, Categorical(n, shape=(S,), device=device),
                Unbounded(shape=(S, 1), dtype=torch.float64, device=device))

    def first_seed(self, seed: int) -> int:
        """The seed of gymnasium's first reset: the seed itself in training; in evaluation a
        32-bit number keyed by (seed, "evaluation"), so its episodes are new ones."""
        if not self.evaluating:
            return seed
        return int(SeedStreams([seed], self.stream_key(ENV_STREAM)).uniform(1)[0, 0] * 2**32)

    def to_unit_box(self, raw: torch.Tensor) -> torch.Tensor:
        """Raw gymnasium observations (..., d) -> [0, 1]^d."""
        raw = raw.to(torch.float64)
        affine = (raw - self.offset) / self.span
        return torch.where(self.squash, 0.5 * (1 + torch.tanh(raw)), affine).clamp(0.0, 1.0)

    def observed(self) -> torch.Tensor:
        """What the agent sees of ``self.raw``: in the unit box, or gymnasium's own."""
        obs = self.raw if self.cfg.observations == "raw" else self.to_unit_box(self.raw)
        return obs.to(self.device, copy=True)

    def _initial(self, mask):
        for i in mask.nonzero()[:, 0].tolist():
            # the first reset seeds this instance's np_random; later ones continue it
            kwargs = {} if self.started[i] else {"seed": self.first_seed(self.seeds[i])}
            self.raw[i] = self.envs[i].reset(**kwargs).get("observation")
            self.started[i] = True
        return self._td(observation=self.observed())

    def _transition(self, action):
        S = self.num_seeds
        reward = torch.zeros(S, dtype=torch.float64)
        terminated = torch.zeros(S, dtype=torch.bool)
        truncated = torch.zeros(S, dtype=torch.bool)  # an env's own cap (gymnasium's TimeLimit is ours)
        for i, (env, a) in enumerate(zip(self.envs, action.tolist())):
            # gymnasium's own step, with GymEnv._step's conversions (observation and reward
            # to their specs' dtypes): our step already checked the action, and GymEnv's
            # TensorDict in and out cost ~10x CartPole's physics (a third of DQN's seed-step)
            obs, r, term, trunc, _ = env._env.step(a)
            self.raw[i] = torch.as_tensor(np.ascontiguousarray(obs), dtype=self.obs_dtype)  # (a flipped view too)
            reward[i] = torch.as_tensor(r, dtype=self.reward_dtype).item()
            terminated[i], truncated[i] = bool(term), bool(trunc)
        return self._td(observation=self.observed()), reward, terminated, truncated

    # ------------------------------------------------------------- state
    def state_dict(self, *args, **kwargs) -> dict:
        gym = None
        if self.checkpointable:
            gym = [[to_plain(_attributes(layer)) for layer in _layers(env._env)] for env in self.envs]
        return {**super().state_dict(), "started": self.started.clone(), "raw": self.raw.clone(), "gym": gym}

    def load_state_dict(self, state: dict, strict: bool = True) -> None:
        if state["gym"] is None:
            raise ValueError(f"gym:{self.gym_id} cannot continue from a checkpoint: only gymnasium's "
                             f"{' and '.join(m.split('.')[-1] for m in CHECKPOINTABLE)} envs keep all their "
                             f"state in Python attributes; start the run again")
        super().load_state_dict(state, strict)
        self.started.copy_(state["started"])
        self.raw.copy_(state["raw"])
        for env, data in zip(self.envs, state["gym"]):
            layers = _layers(env._env)
            if not isinstance(data, list) or len(data) != len(layers):
                raise ValueError(f"gym:{self.gym_id}: the checkpoint's env state is not this env's "
                                 f"({len(layers)} layers of plain data)")
            for layer, saved in zip(layers, data):
                vars(layer).update(from_plain(saved))

    @property
    def checkpointable(self) -> bool:
        """Whether a seed's whole state is in its layers' attributes (saved as plain data in checkpoints)."""
        return type(self.envs[0]._env.unwrapped).__module__.startswith(CHECKPOINTABLE)

    def close(self, *, raise_if_closed: bool = True) -> None:
        for env in getattr(self, "envs", ()):
            env.close(raise_if_closed=False)
        super().close(raise_if_closed=raise_if_closed)


def _layers(env) -> list:
    """A gymnasium env's wrappers, outside in, then the unwrapped env."""
    out = [env]
    while isinstance(env, gymnasium.Wrapper):
        env = env.env
        out.append(env)
    return out


def _attributes(layer) -> dict:
    """A layer's own state: its attributes, without a wrapper's link to the layer inside
    and without what never changes as it runs (its spaces and spec)."""
    inner = isinstance(layer, gymnasium.Wrapper)
    return {k: v for k, v in vars(layer).items()
            if not (inner and k == "env") and not isinstance(v, STATIC)}


STATIC = (gymnasium.spaces.Space, gymnasium.envs.registration.EnvSpec)
BIT_GENERATORS = ("PCG64", "PCG64DXSM", "MT19937", "Philox", "SFC64")


def to_plain(v):
    """``v`` as plain data a ``weights_only`` checkpoint holds: numbers, strings, None,
    tensors, lists and tagged dicts (``from_plain`` inverts it exactly)."""
    if isinstance(v, np.generic):  # before float: np.float64 is a float
        return {"np": v.item(), "dtype": v.dtype.str}
    if v is None or isinstance(v, (bool, int, float, str)):
        return v
    if isinstance(v, np.ndarray):
        if v.dtype.kind in "biuf":
            return {"ndarray": torch.from_numpy(v.copy()), "dtype": v.dtype.str}
        return {"ndarray_list": v.tolist(), "dtype": v.dtype.str, "shape": list(v.shape)}
    if isinstance(v, np.random.Generator):
        return {"generator": v.bit_generator.state}
    if isinstance(v, tuple):
        return {"tuple": [to_plain(x) for x in v]}
    if isinstance(v, list):
        return [to_plain(x) for x in v]
    if isinstance(v, dict):
        return {"items": [[to_plain(k), to_plain(x)] for k, x in v.items()]}
    raise ValueError(f"cannot save a {type(v).__name__} as plain data")


def from_plain(d):
    """The value ``to_plain`` gave ``d`` for; ValueError for anything it cannot have written."""
    if d is None or isinstance(d, (bool, int, float, str)):
        return d
    if isinstance(d, list):
        return [from_plain(x) for x in d]
    if isinstance(d, dict) and len(d) >= 1:
        if "np" in d:
            return np.dtype(d["dtype"]).type(d["np"])
        if "ndarray" in d and isinstance(d["ndarray"], torch.Tensor):
            return d["ndarray"].numpy().astype(np.dtype(d["dtype"]), copy=True)
        if "ndarray_list" in d:
            return np.array(d["ndarray_list"], dtype=np.dtype(d["dtype"])).reshape(d["shape"])
        if "generator" in d:
            name = d["generator"].get("bit_generator")
            if name not in BIT_GENERATORS:
                raise ValueError(f"unknown bit generator {name!r} in a checkpoint")
            g = np.random.Generator(getattr(np.random, name)())
            g.bit_generator.state = d["generator"]
            return g
        if "tuple" in d:
            return tuple(from_plain(x) for x in d["tuple"])
        if "items" in d:
            return {from_plain(k): from_plain(x) for k, x in d["items"]}
    raise ValueError(f"not plain data this code wrote: a {type(d).__name__} in a gym env's checkpoint state")


@functools.cache
def gym_env(gym_id: str) -> type:
    """The env class of gymnasium id ``gym_id`` (refused here if the suite cannot run it)."""
    describe(gym_id)
    return type(f"Gym[{gym_id}]", (GymSeedEnv,), {"gym_id": gym_id, "__module__": __name__})


Env = GymSeedEnv  # the family's base; ``gym_env(id)`` makes each id's class
