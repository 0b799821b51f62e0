"""What a study may search (``trl-dgpq tune``), declared beside each agent's config.

An agent's module holds one ``SEARCH_SPACE``: {setting name: range}, ranges on settings
its config already has, made of the classes below:

    SEARCH_SPACE = {"lr": LogUniform(1e-4, 1e-2), "hidden": Choice(((64, 64), (256, 256))),
                    "exploration_steps": OfBudget(0.05, 0.5, otherwise=IntRange(1_000, 20_000))}

Each range turns into one Optuna suggestion and back into the setting's value; nothing
here imports Optuna (agent modules import this one). Which seeds a study may tune on is
here too: never those reports are drawn from.
"""
from __future__ import annotations

import importlib
import math
from dataclasses import dataclass
from typing import Any, Tuple

from trl_dgpq.selection import REPORTING, check_selection_seeds

# Seeds reports are drawn from: configs/compare.toml (0-9, make compare), reproduce's scales
# (0..N-1, N <= 10), RunConfig's default (0-7). Tuning on them would report the seeds the settings
# were chosen on, so a study refuses them (trl_dgpq/selection.py holds the rule; tests/test_tune.py
# checks these files stay inside).
REPORTING_SEEDS = REPORTING
TUNING_SEEDS = range(1000, 1005)  # tune's default seeds
VALIDATION_SEEDS = range(1005, 1015)  # tune's default --validation-seeds


def check_tuning_seeds(seeds) -> None:
    """ValueError (one line) if any of ``seeds`` is a reporting seed."""
    check_selection_seeds(seeds, "tuning seeds", f"{TUNING_SEEDS.start}-{TUNING_SEEDS.stop - 1}")


@dataclass(frozen=True)
class Uniform:
    low: float
    high: float
    log = False

    def suggest(self, trial, name: str, budget: int):
        return trial.suggest_float(name, self.low, self.high, log=self.log)

    def contains(self, value, budget: int) -> bool:
        return isinstance(value, (int, float)) and self.low <= value <= self.high

    def params(self, name: str, value, budget: int) -> dict:
        """The Optuna parameters that ``suggest`` turns back into ``value``."""
        return {name: float(value)}


@dataclass(frozen=True)
class LogUniform(Uniform):
    log = True


@dataclass(frozen=True)
class IntRange:
    low: int
    high: int
    log: bool = False

    def suggest(self, trial, name: str, budget: int):
        return trial.suggest_int(name, self.low, self.high, log=self.log)

    def contains(self, value, budget: int) -> bool:
        return isinstance(value, int) and self.low <= value <= self.high

    def params(self, name: str, value, budget: int) -> dict:
        return {name: int(value)}


@dataclass(frozen=True)
class Choice:
    """One of ``options``; tuples (network widths) go to Optuna as text ("64,64") and come back."""
    options: Tuple[Any, ...]

    @staticmethod
    def label(option) -> Any:
        return ",".join(map(str, option)) if isinstance(option, tuple) else option

    def suggest(self, trial, name: str, budget: int):
        picked = trial.suggest_categorical(name, [self.label(o) for o in self.options])
        return next(o for o in self.options if self.label(o) == picked)

    @staticmethod
    def option(value):
        """``value`` as the options hold it: a config's widths come as a list."""
        return tuple(value) if isinstance(value, list) else value

    def contains(self, value, budget: int) -> bool:
        return self.option(value) in self.options

    def params(self, name: str, value, budget: int) -> dict:
        return {name: self.label(self.option(value))}


@dataclass(frozen=True)
class OfBudget:
    """A count of env steps as a fraction in [low, high] of a budget of env steps (the
    optuna parameter ``<name>_fraction``); a run budgeted in episodes has no such count, so
    there ``otherwise`` applies."""
    low: float
    high: float
    otherwise: Any

    def suggest(self, trial, name: str, budget: int):
        if not budget:
            return self.otherwise.suggest(trial, name, budget)
        return max(1, round(trial.suggest_float(f"{name}_fraction", self.low, self.high) * budget))

    def contains(self, value, budget: int) -> bool:
        if not budget:
            return self.otherwise.contains(value, budget)
        return max(1, math.floor(self.low * budget)) <= value <= math.ceil(self.high * budget)

    def params(self, name: str, value, budget: int) -> dict:
        if not budget:
            return self.otherwise.params(name, value, budget)
        return {f"{name}_fraction": min(max(value / budget, self.low), self.high)}


@dataclass(frozen=True)
class Factors:
    """Per-dimension weights (``state_scale``): each nonzero weight of ``base`` (the base preset's)
    times its own factor in [low, high], log-uniform (the optuna parameters ``<name>_<i>``); a
    zero weight stays zero (that dimension stays out of the metric)."""
    low: float
    high: float
    base: Tuple[float, ...]

    def suggest(self, trial, name: str, budget: int):
        return tuple(b * trial.suggest_float(f"{name}_{i}", self.low, self.high, log=True) if b else 0.0
                     for i, b in enumerate(self.base))

    def factors(self, value) -> dict:
        """{i: value[i] / base[i]} over the nonzero weights; None if ``value`` has another shape or
        other zeros than ``base``."""
        value = tuple(value) if isinstance(value, (list, tuple)) else ()
        if len(value) != len(self.base) or any((v == 0) != (b == 0) for v, b in zip(value, self.base)):
            return None
        return {i: v / b for i, (v, b) in enumerate(zip(value, self.base)) if b}

    def contains(self, value, budget: int) -> bool:
        f = self.factors(value)
        return f is not None and all(self.low <= x <= self.high for x in f.values())

    def params(self, name: str, value, budget: int) -> dict:
        return {f"{name}_{i}": x for i, x in self.factors(value).items()}


def search_space(agent_cls) -> dict:
    """The ``SEARCH_SPACE`` beside ``agent_cls``'s config (ValueError if none, or if it names a
    setting the config does not have)."""
    from .config import find_leaf
    module = importlib.import_module(agent_cls.Config.__module__)
    space = getattr(module, "SEARCH_SPACE", None)
    if not space:
        raise ValueError(f"{agent_cls.__name__} has nothing to tune: declare SEARCH_SPACE beside its config in "
                         f"{module.__name__}")
    unknown = [k for k in space if find_leaf(agent_cls.Config, k) is None]
    if unknown:
        raise ValueError(f"SEARCH_SPACE of {module.__name__} names {unknown}, not settings of "
                         f"{agent_cls.Config.__name__}")
    return space


def parse_range(text: str) -> Tuple[str, LogUniform]:
    """``"lengthscale=1:30"`` -> ("lengthscale", LogUniform(1, 30)); ValueError (one line) otherwise."""
    name, eq, rest = str(text).partition("=")
    low, colon, high = rest.partition(":")
    try:
        lo, hi = float(low), float(high)
    except ValueError:
        lo = hi = None
    if not (eq and colon and name.strip()) or lo is None:
        raise ValueError(f"a search range is NAME=LOW:HIGH, e.g. lengthscale=1:30, got {text!r}")
    if not 0 < lo < hi:
        raise ValueError(f"search range {text!r}: need 0 < LOW < HIGH (it is searched log-uniformly)")
    return name.strip(), LogUniform(lo, hi)


def with_ranges(space: dict, ranges, values=None) -> dict:
    """``space`` with the entries named in ``ranges`` ("NAME=LOW:HIGH" each) replaced. A name the
    space does not search is refused, naming those it does, unless ``values`` ({setting: the
    base preset's value}) holds per-dimension weights for it (a tuple, e.g. state_scale): those
    are searched as ``Factors`` of LOW to HIGH on the base's weights."""
    out, values = dict(space), values or {}
    for text in ranges:
        name, r = parse_range(text)
        base = values.get(name)
        if name in space:
            out[name] = r
        elif isinstance(base, (list, tuple)) and any(base):
            out[name] = Factors(r.low, r.high, tuple(float(b) for b in base))
        elif isinstance(base, (list, tuple)):
            raise ValueError(f"search range {text!r}: the base preset has no {name} weights to scale; give them "
                             f"(e.g. --{name.replace('_', '-')} ...) and search factors on them")
        else:
            raise ValueError(f"search range {text!r}: {name} is not in the agent's search space "
                             f"({', '.join(space)}) nor per-dimension weights of the base preset")
    return out


def first_params(space: dict, values: dict, budget: int) -> dict:
    """The Optuna parameters of a trial that runs ``values`` ({setting: value}, e.g. the base
    preset's) for every setting of ``space`` whose value lies inside its range; the others are
    left to the sampler."""
    out = {}
    for name, r in space.items():
        if name in values and r.contains(values[name], budget):
            out.update(r.params(name, values[name], budget))
    return out


def suggest(trial, space: dict, budget: int) -> dict:
    """{setting: value} drawn by ``trial`` from ``space``; ``budget``: env steps per seed (0 if
    the run is budgeted in episodes)."""
    return {name: r.suggest(trial, name, budget) for name, r in space.items()}
