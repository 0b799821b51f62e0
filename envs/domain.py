"""What the suite knows about a domain, loaded only when the domain is used.

A domain is one folder ``envs/<name>/`` whose ``__init__.py`` holds one line,
``DOMAIN = Domain(__name__, ...)``, and nothing heavier; beside it:

    env.py        the env class ``Env`` (a ``SeedBatchedEnv``) and its ``Config``
    presets.py    ``PRESETS = {agent: {preset: {"env": {...}, "agent": {...}}}}`` and ``DEFAULT``,
                  the default preset's name (every agent the domain supports has it)
    baselines.py  (optional) the domain's own scripted agents, named in ``Domain(baselines=...)``
    analysis.py   (optional) ``MEASURE``, ``THRESHOLD``, ``TERMINATED`` and ``figures()``: see
                  ``trl_dgpq.analysis``

An env name is the domain's name (``square``) or, for a domain over a family of
envs, ``<domain>:<id>`` (``gym:CartPole-v1``); ``Domain`` subclasses that take an
id override the methods that depend on it.
"""
from __future__ import annotations

import importlib
from types import ModuleType
from typing import Dict, Iterator, Optional, Tuple


class Domain:
    """A domain's package and the names of its baselines (agents of its own)."""

    takes_id = False  # env names are "<domain>:<id>"

    def __init__(self, package: str, baselines: Optional[Dict[str, str]] = None, example: Optional[dict] = None):
        self.package = package
        self.name = package.rsplit(".", 1)[-1]
        self.baseline_paths = dict(baselines or {})  # agent name -> "module:Class", module relative to the package
        # env settings of a small, quick instance of the first of examples(): the contract tests
        # (tests/test_domains.py) run every domain with it, and fail for a domain without one
        self.example = example

    def module(self, part: str, optional: bool = False) -> Optional[ModuleType]:
        """``envs/<name>/<part>.py``, imported on first use (None if optional and absent)."""
        name = f"{self.package}.{part}"
        try:
            return importlib.import_module(name)
        except ModuleNotFoundError as err:
            if optional and err.name == name:
                return None
            raise

    def check_id(self, env_id: Optional[str]) -> None:
        name = self.name if env_id is None else f"{self.name}:{env_id}"
        if self.takes_id and not env_id:
            raise ValueError(f"unknown env {name!r}: {self.name} needs an id, {self.name}:ID")
        if not self.takes_id and env_id is not None:
            raise ValueError(f"unknown env {name!r}: {self.name} takes no id")

    # ------------------------------------------------------------ the env
    def env_class(self, env_id: Optional[str] = None) -> type:
        """The env class (``env_id`` as ``envs.domain()`` checked it)."""
        return self.module("env").Env

    def config_class(self) -> type:
        """The env's settings dataclass (the same for every id)."""
        return self.module("env").Env.Config

    def examples(self) -> Tuple[str, ...]:
        """Env names to show in help texts."""
        return (self.name,)

    # ------------------------------------------------------------ presets
    def presets(self, agent: str, env_id: Optional[str] = None) -> Optional[dict]:
        """{preset name: {"env": ..., "agent": ...}} of ``agent`` here (None: it has none)."""
        return self.module("presets").PRESETS.get(agent)

    def default_preset(self, env_id: Optional[str] = None) -> str:
        return self.module("presets").DEFAULT

    def preset_tables(self) -> Iterator[Tuple[str, str, dict]]:
        """(env name, agent, {preset: entry}) of every table of presets here."""
        for agent, table in self.module("presets").PRESETS.items():
            yield self.name, agent, table

    # ------------------------------------------------------------ agents and analysis
    def baseline(self, agent: str) -> type:
        module, _, cls = self.baseline_paths[agent].partition(":")
        return getattr(self.module(module), cls)

    def analysis(self) -> Optional[ModuleType]:
        return self.module("analysis", optional=True)

    def measure(self, env_id: Optional[str] = None, column: str = "") -> Tuple[str, str]:
        """(CSV column, label) of what curves of this domain show (default: the return); with
        ``column``, that one of its ``OTHER_MEASURES`` (same direction; ValueError naming them if it
        has no such one)."""
        default = getattr(self.analysis(), "MEASURE", ("return", "return per episode"))
        if not column or column == default[0]:
            return default
        others = dict(getattr(self.analysis(), "OTHER_MEASURES", {}))
        if column not in others:
            raise ValueError(f"{self.name} has no measure {column!r}: its measures are "
                             f"{', '.join([default[0], *others])}")
        return column, others[column]

    def format_measure(self, value: float, env_id: Optional[str] = None) -> str:
        """``value`` of ``measure`` as the domain writes it (``MEASURE_FORMAT``; default 4 digits)."""
        return getattr(self.analysis(), "MEASURE_FORMAT", "{:.4g}").format(value)

    def lower_is_better(self, env_id: Optional[str] = None) -> bool:
        """Whether less of ``measure`` is better (``MEASURE_LOWER_IS_BETTER``; default: more is)."""
        return bool(getattr(self.analysis(), "MEASURE_LOWER_IS_BETTER", False))

    def agent_side_settings(self, env_id: Optional[str] = None) -> Tuple[str, ...]:
        """Env settings that change what an agent sees or chooses among, not the task
        (``AGENT_SIDE_SETTINGS``: liquidation's action grid, gym's observation map): runs that
        differ only in them are runs of one task, and a report puts them in one table."""
        return tuple(getattr(self.analysis(), "AGENT_SIDE_SETTINGS", ()))

    def model_knowledge(self, config: dict) -> list:
        """What of the env's model a run of ``config`` (a resolved config: its "run", "env" and
        "agent" sections) uses: the texts of the domain's ``MODEL_KNOWLEDGE`` entries it matches,
        each keyed "section.setting=value" (e.g. "env.reward=impact"). Empty: model-free."""
        found = []
        for key, text in getattr(self.analysis(), "MODEL_KNOWLEDGE", {}).items():
            path, _, value = key.partition("=")
            section, _, setting = path.partition(".")
            if str(config.get(section, {}).get(setting)) == value:
                found.append(text)
        return found

    def threshold(self, env_id: Optional[str] = None):
        """The ``trl_dgpq.analysis.Threshold`` a learner must meet here (None: not defined)."""
        return getattr(self.analysis(), "THRESHOLD", None)

    def terminated_means(self, env_id: Optional[str] = None) -> str:
        """What an episode's ``terminated`` says here (``TERMINATED`` in its analysis.py)."""
        return getattr(self.analysis(), "TERMINATED", "ended by the env, not the step cap")
