"""Gymnasium envs with discrete actions, ``gym:<id>`` (any id; presets and thresholds for a few)."""
from __future__ import annotations

from typing import Optional

from ..domain import Domain


class GymDomain(Domain):
    """A family: every method that depends on the env takes its gymnasium id."""

    takes_id = True

    def env_class(self, env_id: Optional[str] = None) -> type:
        return self.module("env").gym_env(env_id)

    def examples(self):
        return tuple(f"{self.name}:{i}" for i in self.module("presets").PRESETS)

    def presets(self, agent: str, env_id: Optional[str] = None) -> dict:
        """An id without presets of its own runs any agent with the defaults (DQN on raw observations)."""
        presets = self.module("presets")
        return presets.PRESETS.get(env_id, {}).get(agent, presets.FALLBACK.get(agent, {presets.DEFAULT: {}}))

    def preset_tables(self):
        for env_id, agents in self.module("presets").PRESETS.items():
            for agent, table in agents.items():
                yield f"{self.name}:{env_id}", agent, table

    def threshold(self, env_id: Optional[str] = None):
        return self.analysis().THRESHOLDS.get(env_id)

    def terminated_means(self, env_id: Optional[str] = None) -> str:
        return self.analysis().TERMINATED.get(env_id, "ended by gymnasium, not the step cap")


DOMAIN = GymDomain(__name__, example=dict(max_steps=12))
