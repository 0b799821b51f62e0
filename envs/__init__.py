"""TorchRL environments, batched over seeds (``batch_size=[S]``); installed as
``trl_dgpq.envs``. A new env: one file with its class and ``Config`` dataclass,
one line in ``ENVS``, one entry in ``trl_dgpq/presets.py``. Any gymnasium id with
discrete actions is an env too, named ``gym:ID`` (``envs/gym.py``)."""
from .base import SeedBatchedEnv
from .gym import PREFIX as GYM_PREFIX
from .gym import GymConfig, GymSeedEnv, gym_env
from .liquidation import LiquidationConfig, LiquidationEnv
from .push import PushConfig, PushEnv
from .push_gym import register as _register_gym
from .square import SquareConfig, SquareEnv

ENVS = {"square": SquareEnv, "liquidation": LiquidationEnv, "push": PushEnv}
GYM_ENVS = ("gym:CartPole-v1", "gym:MountainCar-v0", "gym:Acrobot-v1")  # with presets and documented bounds
_register_gym()  # gymnasium id "trl_dgpq/BlockPush-v0"


def env_class(name: str) -> type:
    """The env class of a registered name or of ``gym:ID``; ValueError (one line) otherwise."""
    if name in ENVS:
        return ENVS[name]
    if isinstance(name, str) and name.startswith(GYM_PREFIX) and len(name) > len(GYM_PREFIX):
        return gym_env(name[len(GYM_PREFIX):])
    raise ValueError(f"unknown env {name!r}; choose from {sorted(ENVS)} or gym:ID (a gymnasium id with "
                     f"discrete actions, e.g. {', '.join(GYM_ENVS)})")


def check_env_name(name) -> str:
    """``name`` if it names an env the suite can run (the setting's parser)."""
    if not isinstance(name, str):
        raise ValueError(f"env must be text, got {name!r}")
    env_class(name)
    return name


def env_configs() -> list:
    """Every env config class (for the command line's flags)."""
    return [cls.Config for cls in ENVS.values()] + [GymConfig]


def make_env(name: str, cfg, seeds, device="cpu") -> SeedBatchedEnv:
    return env_class(name)(seeds, cfg, device=device)


__all__ = ["ENVS", "GYM_ENVS", "env_class", "check_env_name", "env_configs", "make_env", "SeedBatchedEnv",
           "SquareEnv", "SquareConfig", "LiquidationEnv", "LiquidationConfig", "PushEnv", "PushConfig",
           "GymSeedEnv", "GymConfig"]
