"""What a study gives back: its best trial in one line, and the preset written from it, with its
provenance (refusing to replace another study's preset unless forced)."""
from __future__ import annotations

import time
from pathlib import Path
from typing import Optional, Tuple

from trl_dgpq import presets
from trl_dgpq.collectors.experiment import classes, split_overrides
from trl_dgpq.config import find_leaf
from trl_dgpq.presets import check_preset_name, preset_overrides, tuned_name, write_tuned

from .config import plain, shown
from .storage import portable


class Preset:
    """Results and preset writing (a mixin of ``Study``)."""

    def summary(self, trials: int) -> str:
        """One line: the best trial, its objective and settings, and how many trials have ended."""
        study = self.load()
        ended = self.ended(study.get_trials(deepcopy=False))
        done = sum(map(len, ended.values()))
        tally = (f"{done}/{trials} trials done ({len(ended['complete'])} complete, {len(ended['pruned'])} pruned, "
                 f"{len(ended['failed'])} failed)")
        if not ended["complete"]:
            return f"no trial has completed; {tally}"
        best = study.best_trial
        seeds = self.config["run"]["seeds"]
        better = "lower" if self.objective.direction == "minimize" else "higher"
        return (f"best: trial {best.number}, {self.objective.name} {best.value:.6g} ({better} is better, IQM over "
                f"{len(seeds)} seeds) with {shown(best.user_attrs['settings'])}; {tally}")

    def written(self, name: str) -> Optional[dict]:
        """Preset ``name`` of this study's env and agent as tuned.json holds it ({"preset",
        "provenance"}); None if there is none."""
        run = self.config["run"]
        return (presets.tuned_entries(run["env"]).get(run["agent"]) or {}).get(name)

    def replaces(self, name: str) -> Optional[str]:
        """What writing preset ``name`` would replace, in words, if another study wrote it (None: no
        preset of that name, or one this study wrote)."""
        run = self.config["run"]
        old = self.written(name)
        prov = (old or {}).get("provenance") or {}
        if old is None or prov.get("study_name") == self.name:
            return None
        return (f"preset {name!r} of {run['agent']} on {run['env']}, written by study {prov.get('study_name', '?')!r} "
                f"({prov.get('trials', '?')} trials on seeds {prov.get('seeds', '?')}, {prov.get('date', '?')})")

    def write_preset(self, name: Optional[str] = None, force: bool = False) -> Tuple[str, Path]:
        """The best trial as preset ``name`` of this env and agent (by default ``tuned``, or
        ``<preset>-tuned`` if the study ran on another than the env's default): the preset the
        study ran on, the settings given to it and the trial's over it, with where it came from.
        A preset another study wrote is replaced only with ``force`` (ValueError saying what it
        is otherwise). Returns the name and the file written."""
        from trl_dgpq.collectors.runner import provenance
        run = self.config["run"]
        name = name or tuned_name(run["env"], run["preset"])
        check_preset_name(run["env"], run["agent"], name)
        other = self.replaces(name)
        if other and not force:
            raise ValueError(f"this study would replace {other}: write it under another name (--write-preset NAME), "
                             "or add --force to replace it")
        study = self.load()
        ended = self.ended(study.get_trials(deepcopy=False))
        if not ended["complete"]:
            raise ValueError("no trial has completed: there is no best trial to write as a preset")
        best, validated = self.best_trial(study)
        _, base = preset_overrides(run["env"], run["agent"], run["preset"])
        given = split_overrides(self.given_agent_env(), *classes(run))
        sections = {s: {**base[s], **{k: self.value_of(s, k) for k in given[s]}} for s in ("env", "agent")}
        sections["agent"].update(best.user_attrs["settings"])
        record = dict(
            study=portable(self.url), study_name=self.name, trial=best.number, trials=sum(map(len, ended.values())),
            objective=self.objective.name, window=self.tune.window, direction=self.objective.direction,
            value=best.value,
            base_preset=run["preset"], budget=dict(episodes=run["episodes"], env_steps=run["env_steps"]),
            seeds=run["seeds"],
            **({"search": list(self.tune.search)} if self.tune.search else {}),
            **({"validation": dict(seeds=study.user_attrs["validation"]["seeds"], value=validated,
                                   trials=sorted(map(int, study.user_attrs["validation"]["values"])))}
               if validated is not None else {}))
        if self.unchanged(name, sections, record):   # its date and commit: when the study first wrote it
            return name, presets.tuned_file(run["env"])
        return name, write_tuned(run["env"], run["agent"], name, sections, dict(
            record, date=time.strftime("%Y-%m-%d %H:%M:%S"), commit=provenance()["git"]["commit"]))

    def unchanged(self, name: str, sections: dict, record: dict) -> bool:
        """Whether preset ``name`` holds ``sections`` and ``record`` already (as JSON reads them back),
        its date and commit apart: a finished study asked again writes the same preset, and
        rewriting it would stamp it with a later commit than the one its trials ran at."""
        old = self.written(name) or {}
        kept = {k: v for k, v in (old.get("provenance") or {}).items() if k not in ("date", "commit")}
        return bool(old) and plain(old.get("preset")) == plain(sections) and plain(kept) == plain(record)

    def value_of(self, section: str, key: str):
        """A given setting's value as the study's config resolved it."""
        cls = {"env": classes(self.config["run"])[0].Config, "agent": classes(self.config["run"])[1].Config}[section]
        node = self.config[section]
        for p in find_leaf(cls, key).path:
            node = node[p]
        return node
