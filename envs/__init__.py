"""TorchRL environments, batched over seeds (``batch_size=[S]``)."""
from .square import PRESETS as SQUARE_PRESETS
from .square import SquareEnv

ENVS = {"square": (SquareEnv, SQUARE_PRESETS)}

__all__ = ["SquareEnv", "SQUARE_PRESETS", "ENVS"]
