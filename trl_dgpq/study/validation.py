"""Validation: the best trials and the base preset's run again on other seeds at the full budget,
and the trial a preset is written from."""
from __future__ import annotations

from pathlib import Path

from trl_dgpq.analysis.objective import stage
from trl_dgpq.analysis.runs import load_run
from trl_dgpq.collectors import runner
from trl_dgpq.collectors.experiment import resolve_config
from trl_dgpq.selection import check_selection_seeds

from .config import DEFAULT_VALIDATION_SEEDS


class Validation:
    """Validating trials (a mixin of ``Study``)."""

    def validate(self, k: int, seeds, log=print) -> dict:
        """Run the ``k`` best complete trials, and the first (the base preset's) if it completed,
        again at the full budget on ``seeds``, other tuning seeds than the study's: the best of
        30 trials on 5 seeds is partly the luckiest (on CartPole DGPQ's best trial beat the
        preset by 10 % on the tuning seeds and lost to it by half on 10 others). Each value is
        kept in the study (user attr ``validation``, by trial number), and a run stopped midway
        goes on from its checkpoint when asked again. Returns {trial number: value}."""
        from optuna.trial import TrialState
        from trl_dgpq.analysis.results import seeds_text
        seeds = self.validation_seeds(seeds)
        study = self.load()
        done = [t for t in study.get_trials(deepcopy=False) if t.state == TrialState.COMPLETE]
        if not done:
            raise ValueError("no trial has completed: there is nothing to validate")
        ranked = sorted(done, key=lambda t: t.value, reverse=self.objective.direction == "maximize")
        picked = ranked[:k] + [t for t in ranked[k:] if "first" in t.user_attrs]
        stored = study.user_attrs.get("validation", {})
        # values on other seeds do not compare with these: start over
        results = {int(n): v for n, v in stored.get("values", {}).items()} if stored.get("seeds") == seeds else {}
        for t in picked:
            if t.number not in results:
                path = self.out / "validation" / f"{t.number:04d}"
                config = resolve_config({**self.request["given"], "seeds": seeds_text(seeds),
                                         **{f"agent.{k}": v for k, v in t.user_attrs["settings"].items()}})
                self.run_to_end(path, config)
                results[t.number] = self.objective.value(stage(load_run(path), self.stages[-1]))
                self.tidy(path)
                study.set_user_attr("validation", dict(seeds=seeds, values={str(n): v for n, v in results.items()}))
            log(f"trial {t.number}: {self.objective.name} {results[t.number]:.6g} on the validation seeds "
                f"{seeds_text(seeds)} ({t.value:.6g} on the tuning seeds{', the base preset' if 'first' in t.user_attrs else ''})")
        return results

    def validation_seeds(self, seeds) -> list:
        """``seeds`` sorted, once checked: no reporting seed, none of the study's own (ValueError)."""
        seeds = sorted(set(seeds))
        check_selection_seeds(seeds, "validation seeds", DEFAULT_VALIDATION_SEEDS)
        own = self.config["run"]["seeds"]
        shared = sorted(set(seeds) & set(own))
        if shared:
            raise ValueError(f"validation seeds {shared} are the study's own tuning seeds: validate on others, e.g. "
                             f"--validation-seeds {max(own) + 1}-{max(own) + 10}")
        return seeds

    @staticmethod
    def run_to_end(path: Path, config: dict) -> None:
        """``config``'s run in ``path``: started, or resumed from its checkpoint, to its end."""
        recorded = runner.RunFolder(path).read_json(runner.CONFIG) if (path / runner.CONFIG).exists() else None
        if recorded is None or any(recorded[k] != config[k] for k in ("run", "env", "agent")):
            folder = runner.RunFolder.create(str(path), "", overwrite=True)  # held
            try:
                runner.start(config, folder, progress=False)
            finally:
                folder.release()
            return
        folder = runner.RunFolder.existing(path)
        if not folder.finished():
            folder.acquire()
            try:
                runner.resume(folder, runner.resumable_config(folder), progress=False)
            finally:
                folder.release()

    def best_trial(self, study):
        """The trial a preset is written from: the best on the validation seeds where trials were
        validated (with its value there), else the best on the tuning seeds (value None)."""
        validation = study.user_attrs.get("validation", {}).get("values", {})
        if not validation:
            return study.best_trial, None
        pick = (max if self.objective.direction == "maximize" else min)(validation, key=lambda n: validation[n])
        return study.trials[int(pick)], validation[pick]
