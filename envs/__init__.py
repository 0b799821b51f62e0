"""TorchRL environments, batched over seeds (``batch_size=[S]``); installed as
``trl_dgpq.envs``. A new env: one file with its class and ``Config`` dataclass,
one line in ``ENVS``, one entry in ``trl_dgpq/presets.py``."""
from .base import SeedBatchedEnv
from .liquidation import LiquidationConfig, LiquidationEnv
from .push import PushConfig, PushEnv
from .push_gym import register as _register_gym
from .square import SquareConfig, SquareEnv

ENVS = {"square": SquareEnv, "liquidation": LiquidationEnv, "push": PushEnv}
_register_gym()  # gymnasium id "trl_dgpq/BlockPush-v0"


def make_env(name: str, cfg, seeds, device="cpu") -> SeedBatchedEnv:
    if name not in ENVS:
        raise ValueError(f"unknown env {name!r}; choose from {sorted(ENVS)}")
    return ENVS[name](seeds, cfg, device=device)


__all__ = ["ENVS", "make_env", "SeedBatchedEnv", "SquareEnv", "SquareConfig", "LiquidationEnv",
           "LiquidationConfig", "PushEnv", "PushConfig"]
