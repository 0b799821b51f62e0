"""Which seeds may be reported on: the rule that seeds which chose anything are never reported.

A study (``trl-dgpq tune``) chooses a preset on its tuning seeds and, with ``--validate``, on
its validation seeds; both are kept in the preset's provenance (``envs/<domain>/tuned.json``).
A number measured on those seeds would be measured where the settings were picked for it.
So the seeds are split once and for all:

- ``REPORTING`` (0-99): what reports, ``make compare`` and the reproduction run on. Studies
  and validations never touch them (``check_selection_seeds``; tune's defaults are
  1000-1004 for trials and 1005-1014 for validation).
- every other seed: for studies and validations only. A run on them is never reported, and a
  run on a preset's own tuning or validation seeds even less (``check_reportable``).
- ``EXPLORED`` (0-9): the seeds development ran while it hand-set presets and chose what the
  claims measure (their windows, their lengths: the research logs' ``--seeds 0-9``). They chose
  things too, so the published reproduction (``check_reportable(..., publication=True)``) is
  never on them: it reports on ``FIRST_REPORTING`` (10) upward, seeds no development run used.
  A user's own ``report`` of a run on the default seeds 0-7 is not refused for that.

A preset a study wrote on top of another study's preset (its ``base_preset``) was chosen on
that study's seeds too: they count as well.
"""
from __future__ import annotations

from typing import Iterable, Optional

REPORTING = range(0, 100)
EXPLORED = range(0, 10)     # seeds development looked at while choosing hand-set presets and claims
FIRST_REPORTING = 10        # the reproduction's seeds begin here: past EXPLORED
EXAMPLE_TUNING = "1000-1004"       # tune's default --seeds
EXAMPLE_VALIDATION = "1005-1014"   # tune's default --validation-seeds


class SelectionSeedsError(ValueError):
    """A run that may not be reported: on seeds its preset was chosen on, or outside 0-99."""


def seeds_text(seeds: Iterable[int]) -> str:
    """Sorted seeds, runs of consecutive ones as A-B: "1000-1004, 2000, 2002"."""
    seeds = sorted(set(seeds))
    parts, start = [], None
    for i, s in enumerate(seeds):
        if start is None:
            start = s
        if i + 1 == len(seeds) or seeds[i + 1] != s + 1:
            parts.append(str(s) if s == start else f"{start}-{s}")
            start = None
    return ", ".join(parts)


def _reporting_text() -> str:
    return f"{REPORTING.start}-{REPORTING.stop - 1}"


def selection_seeds(env: str, agent: str, preset: Optional[str]) -> dict:
    """{"tuning": [...], "validation": [...]}: the seeds preset ``preset`` of ``agent`` on ``env``
    was chosen on, from its provenance in its domain's tuned.json (and those of the study presets
    it was built on, ``base_preset``); both empty for a hand-set preset (a domain's presets.py)."""
    from trl_dgpq.presets import tuned_entries
    entries = tuned_entries(env).get(agent) or {}
    tuning, validation, seen = set(), set(), set()
    name = preset
    while name is not None and name in entries and name not in seen:
        seen.add(name)
        provenance = entries[name].get("provenance") or {}
        tuning.update(as_seeds(provenance.get("seeds")))
        validation.update(as_seeds((provenance.get("validation") or {}).get("seeds")))
        name = provenance.get("base_preset")
    return {"tuning": sorted(tuning), "validation": sorted(validation)}


def as_seeds(seeds) -> list:
    """Seeds as a list of ints, from a list or from text as --seeds reads it ("1000-1004", "0,2,5")."""
    if seeds is None:
        return []
    if isinstance(seeds, (str, int)):
        from trl_dgpq.collectors.experiment import parse_seeds
        return [int(s) for s in parse_seeds(str(seeds))]
    return [int(s) for s in seeds]


def check_reportable(config: dict, name: Optional[str] = None, publication: bool = False) -> None:
    """SelectionSeedsError (one line) unless the run of ``config`` (a resolved config: its
    "run" has env, agent, preset and seeds) may be reported on: none of its seeds chose its
    preset (tuning or validation) and all lie in the reporting seeds 0-99. ``name``: the
    experiment or run folder the message names. ``publication``: the published reproduction, which
    the seeds development explored (EXPLORED) may not hold either."""
    run = config["run"]
    seeds = set(as_seeds(run.get("seeds")))
    if not seeds:
        raise SelectionSeedsError(f"{name or 'a run'}: its config names no seeds, so nothing says it may be reported on")
    env, agent, preset = run.get("env"), run.get("agent"), run.get("preset")
    what = f"{agent} on {env}, preset {preset!r}"
    who = f"{name} ({what})" if name else what
    chosen = selection_seeds(env, agent, preset)
    roles = [f"{seeds_text(shared)} ({role})" for role in ("tuning", "validation")
             if (shared := seeds & set(chosen[role]))]
    if roles:
        raise SelectionSeedsError(
            f"{who}: seeds {' and '.join(roles)} chose that preset, and seeds that chose a preset are never "
            f"reported on (reporting seeds are {_reporting_text()})")
    looked = seeds & set(EXPLORED) if publication else set()
    if looked:
        raise SelectionSeedsError(
            f"{who}: {'seed' if len(looked) == 1 else 'seeds'} {seeds_text(looked)} "
            f"{'was' if len(looked) == 1 else 'were'} explored while the hand-set "
            f"presets and the claims were chosen, so nothing is published on them: use seeds from {FIRST_REPORTING} "
            f"up (reporting seeds are {_reporting_text()}, less {EXPLORED.start}-{EXPLORED.stop - 1})")
    outside = seeds - set(REPORTING)
    if outside:
        raise SelectionSeedsError(
            f"{who}: {'seed' if len(outside) == 1 else 'seeds'} {seeds_text(outside)} outside the reporting seeds: "
            f"reporting seeds are {_reporting_text()} (the others are for studies and validations)")


def check_selection_seeds(seeds: Iterable[int], what: str, example: str = EXAMPLE_TUNING) -> None:
    """ValueError (one line) if any of ``seeds`` (a study's ``what``: "tuning seeds",
    "validation seeds") is a reporting seed."""
    shared = sorted(set(seeds) & set(REPORTING))
    if shared:
        listed = shared if len(shared) <= 6 else f"[{shared[0]}, {shared[1]}, {shared[2]}, ..., {shared[-1]}] " \
                                                 f"({len(shared)})"
        raise ValueError(f"{what} {listed} are reporting seeds: studies and validations never touch the reporting "
                         f"seeds {_reporting_text()} (reports and make compare use them); use e.g. {example}")
