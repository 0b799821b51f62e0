"""The block-pushing env through the gymnasium API, for code outside TorchRL.

A thin adapter: one seed of ``PushEnv`` (the same physics, rewards and random
streams), with numpy observations and ``Discrete(4)`` actions. Registered as
``trl_dgpq/BlockPush-v0`` by this module, which gymnasium imports itself when the id
names it (gymnasium's "module:id" form; importing ``trl_dgpq`` registers nothing)::

    import gymnasium as gym
    env = gym.make(GYM_ID, max_steps=50)   # GYM_ID below; any PushConfig setting
    obs, info = env.reset(seed=3)           # seed 3 = seed 3 of a batched run

``reset(seed=s)`` re-keys the env's random stream to seed s (as ``--seeds s`` does);
without a seed, the stream goes on. ``info`` holds ``success``, ``fell_off`` and
``distance`` (block to goal). Stepping before ``reset()`` or after the episode ended
raises. There is no rendering (``render_mode`` must be None).
The env truncates at ``max_steps`` itself, so it is registered without a TimeLimit.
"""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from tensordict import TensorDict

from .env import MOVES, OBS_HIGH, OBS_LOW, PushEnv

ENV_ID = "trl_dgpq/BlockPush-v0"
GYM_ID = f"{__name__}:{ENV_ID}"  # for gym.make: gymnasium imports this module, which registers ENV_ID


class GymPushEnv(gym.Env):
    metadata = {"render_modes": []}

    def __init__(self, seed: int = 0, render_mode: str | None = None, **settings):
        if render_mode is not None:
            raise ValueError(f"trl_dgpq/BlockPush-v0 does not render (pybullet runs headless), got "
                             f"render_mode={render_mode!r}")
        self.render_mode = None
        self.env = PushEnv([seed], **settings)
        self.observation_space = spaces.Box(np.array(OBS_LOW), np.array(OBS_HIGH), dtype=np.float64)
        self.action_space = spaces.Discrete(len(MOVES))
        self._running = False

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self.env._set_seed(seed)
        out = self.env.reset()
        self._running = True
        return out.get("observation")[0].numpy(), self._info(out)

    def step(self, action):
        if not self._running:
            raise RuntimeError("call reset() before step(), and again after an episode ends")
        if isinstance(action, (bool, np.bool_)) or not self.action_space.contains(action):
            raise ValueError(f"action must be an integer in [0, {self.action_space.n}), got {action!r}")
        td = TensorDict({"action": torch.tensor([int(action)])}, batch_size=[1])
        nxt = self.env.step(td).get("next")
        terminated, truncated = bool(nxt.get("terminated")[0]), bool(nxt.get("truncated")[0])
        self._running = not (terminated or truncated)
        return (nxt.get("observation")[0].numpy(), float(nxt.get("reward")[0]), terminated, truncated,
                self._info(nxt))

    @staticmethod
    def _info(td) -> dict:
        return {"success": bool(td.get("success")[0]), "fell_off": bool(td.get("fell_off")[0]),
                "distance": float(td.get("distance")[0])}

    def close(self):
        self.env.close()


if ENV_ID not in gym.registry:
    gym.register(ENV_ID, entry_point=GymPushEnv, max_episode_steps=None)
