"""scripts/tune.py (trl_dgpq/study/): Optuna studies of an agent's settings, every trial a run
with the same budget; its objective, search spaces, seeds, pruning, resume and tuned presets."""
import json
import os
import re
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import optuna
import pandas as pd
import pytest

from trl_dgpq import presets
from trl_dgpq.agents import agent_class
from trl_dgpq.analysis.objective import Objective, objective, stage
from trl_dgpq.analysis.runs import Run, load_run
from trl_dgpq.analysis.runs import read_csv_exact
from trl_dgpq.collectors import runner
from trl_dgpq.collectors.experiment import TIMING_COLUMNS, RunConfig, parse_seeds, resolve_config, run_experiment
from trl_dgpq.commands import tune
from trl_dgpq.envs import domains
from trl_dgpq.study import KEEP, Study
from trl_dgpq.tuning import REPORTING_SEEDS, TUNING_SEEDS, IntRange, LogUniform, OfBudget, search_space, suggest

ROOT = Path(__file__).resolve().parent.parent
# one seed, 2 stages of 2 episodes (a second or two a trial), a checkpoint after every episode
TINY = ["--env", "square", "--agent", "dgpq", "--seeds", "1000-1000", "--episodes", "4", "--stages", "0.5,1",
        "--checkpoint-every", "1"]


def trials_of(out):
    return optuna.load_study(study_name=Path(out).name, storage=f"sqlite:///{Path(out) / 'study.db'}").trials


def frame(rows):
    """A hand-made episodes frame as ``load_run`` gives it (each seed's cumulative env_steps)."""
    df = pd.DataFrame(rows, columns=["seed", "episode", "steps", "cost_ratio"])  # liquidation's measure
    df["env_steps"] = df.groupby("seed")["steps"].cumsum()
    return df


# ---------------------------------------------------------------- the objective


def test_objective_steps_to_threshold_by_hand():
    """Square: steps to "mean steps <= 25 over 10 episodes", a seed that never meets it counting
    as the budget (1,000 env steps), IQM over 5 seeds = the mean of the middle three."""
    per_seed_steps = {0: [20] * 12,                 # met at episode 10: 200 steps
                      1: [30] * 12,                 # never: 1,000
                      2: [40] * 10 + [10] * 6,      # 40 - 3k <= 25 after k = 5 more: 400 + 50 = 450 steps
                      3: [25] * 12,                 # met at episode 10: 250
                      4: [100] * 10}                # never: 1,000
    df = frame([(s, e + 1, n, 0.0) for s, steps in per_seed_steps.items() for e, n in enumerate(steps)])
    run = Run(Path("."), df, {"run": {"env": "square", "env_steps": 1000, "episodes": 1000}})
    obj = objective("square")
    assert obj.direction == "minimize"
    assert obj.per_seed(run).tolist() == [200, 1000, 450, 250, 1000]
    assert obj.value(run) == pytest.approx((250 + 450 + 1000) / 3)


def test_objective_measure_ignores_the_threshold_when_asked():
    """--objective measure on the square: the same seeds as above scored by their mean steps
    over the last 10 episodes within the budget (fewer is better), not by when they met the
    threshold: 20, 30, (4 x 40 + 6 x 10) / 10 = 22, 25, 100; IQM = (22 + 25 + 30) / 3."""
    per_seed_steps = {0: [20] * 12, 1: [30] * 12, 2: [40] * 10 + [10] * 6, 3: [25] * 12, 4: [100] * 10}
    df = frame([(s, e + 1, n, 0.0) for s, steps in per_seed_steps.items() for e, n in enumerate(steps)])
    run = Run(Path("."), df, {"run": {"env": "square", "env_steps": 1000, "episodes": 1000}})
    obj = objective("square", "measure")
    assert obj.threshold is None and obj.direction == "minimize"
    assert obj.per_seed(run).tolist() == [20, 30, 22, 25, 100]
    assert obj.value(run) == pytest.approx((22 + 25 + 30) / 3)
    with pytest.raises(ValueError, match="objective must be"):
        objective("square", "threshold")


def test_a_study_keeps_its_objective_and_older_studies_read_as_report():
    from trl_dgpq.study import Study
    old = {"given": {}, "config": {}, "tune": {"trials": 3}}            # made before --objective existed
    assert Study.reopen_request(old, {}, {"trials": 5})["tune"]["objective"] == "report"
    with pytest.raises(ValueError, match="keeps its objective report"):
        Study.reopen_request(old, {}, {"objective": "measure"})
    measured = {**old, "tune": {"trials": 3, "objective": "measure"}}
    assert Study.reopen_request(measured, {}, {})["tune"]["objective"] == "measure"
    with pytest.raises(ValueError, match="keeps its objective measure"):
        Study.reopen_request(measured, {}, {"objective": "report"})


def test_a_study_keeps_the_column_its_trials_were_scored_on(tmp_path):
    """A study records the column it scores; reopened after its env's measure changed, it goes
    on scoring that column (at the budget, over its window), so new trials are on the old ones'
    scale. A study made before the record gets it on reopening."""
    from trl_dgpq.study import Study
    out = tmp_path / "study"
    study = Study.open(out, None, {"env": "liquidation", "agent": "dgpq", "episodes": "12"}, {"window": 4})
    url = f"sqlite:///{out / 'study.db'}"
    assert study.request["scored"] == "cost_ratio" == Study.stored_request(url, "study")["scored"]

    def stored_as(scored):
        request = {k: v for k, v in Study.stored_request(url, "study").items() if k != "scored"}
        optuna.load_study(study_name="study", storage=url).set_user_attr(
            "request", request if scored is None else {**request, "scored": scored})
    stored_as("ac_cost")
    old = Study.open(out, None, {}, {}).objective
    assert (old.column, old.threshold, old.window, old.direction) == ("ac_cost", None, 4, "minimize")
    assert old.name == "ac_cost at budget" and "when the study began" in old.text
    df = frame([(s, e, 5, 10 * s + e) for s in range(4) for e in range(1, 13)]).rename(columns={"cost_ratio": "ac_cost"})
    run = Run(Path("."), df, {"run": {"env": "liquidation", "env_steps": 50, "episodes": 50}})
    assert old.per_seed(run).tolist() == [8.5, 18.5, 28.5, 38.5]   # episodes 7-10 within the 50 steps
    stored_as(None)
    assert Study.open(out, None, {}, {}).request["scored"] == "cost_ratio" == Study.stored_request(url, "study")["scored"]


def test_objective_measure_at_budget_by_hand():
    """Liquidation (no threshold; less shortfall is better): each seed's mean over its last 10
    episodes ended within the budget (50 steps: episodes 1-10 of 5 steps), IQM over 4 seeds."""
    df = frame([(s, e, 5, 10 * s + e) for s in range(4) for e in range(1, 13)])
    run = Run(Path("."), df, {"run": {"env": "liquidation", "env_steps": 50, "episodes": 50}})
    obj = objective("liquidation")
    assert obj.direction == "minimize" and obj.threshold is None
    assert obj.per_seed(run).tolist() == [5.5, 15.5, 25.5, 35.5]
    assert obj.value(run) == pytest.approx((15.5 + 25.5) / 2)
    # over the last 4 episodes within the budget (7-10): seed s's mean is 10 s + 8.5
    late = objective("liquidation", "report", window=4)
    assert late.per_seed(run).tolist() == [8.5, 18.5, 28.5, 38.5] and "last 4 episodes" in late.text


def test_objective_worst_by_hand():
    """--objective worst over 4 stages of 12 episodes (3, 6, 9, 12), window 3: each seed's worst
    block of 3 episodes ending at 6, 9 and 12 (the first stage's block is not scored); seeds'
    episodes differ in length, and each seed is scored at its own episodes, not the fewest steps
    any seed ran. A run staged to its k-th end scores the worst so far (NaN before the second)."""
    costs = {0: [9, 9, 9, 2, 2, 2, 1, 1, 1, 1, 1, 4],       # blocks 4-6: 2, 7-9: 1, 10-12: 2 -> 2
             1: [5, 5, 5, 1, 1, 1, 3, 3, 3, 1, 1, 1],       # 1, 3, 1 -> 3
             2: [1, 1, 1, 1, 1, 1, 1, 1, 1, 7, 1, 1],       # 1, 1, 3 -> 3
             3: [0, 0, 0, 6, 6, 6, 5, 5, 5, 0, 0, 0]}       # 6, 5, 0 -> 6
    df = frame([(s, e + 1, 5 + 10 * s, c) for s, cs in costs.items() for e, c in enumerate(cs)])
    run = Run(Path("."), df, {"run": {"env": "liquidation", "env_steps": 0, "episodes": 12}})
    stages = [dict(episodes=e, env_steps=0) for e in (3, 6, 9, 12)]
    obj = objective("liquidation", "worst", window=3, stages=stages)
    assert obj.direction == "minimize" and obj.stages == ((6, 0), (9, 0), (12, 0))
    assert obj.per_seed(run).tolist() == [2, 3, 3, 6]
    assert obj.value(run) == pytest.approx(3)                  # IQM of 4: the middle two
    assert "6, 9, 12" in obj.text and "last 3 episodes" in obj.text
    assert obj.per_seed(stage(run, stages[2])).tolist() == [2, 3, 1, 6]
    first = obj.per_seed(stage(run, stages[0]))
    assert first.index.tolist() == [0, 1, 2, 3] and first.dtype == float and first.isna().all()
    # a run of 10 episodes has not reached the end at 12, though it holds a block ending at 10;
    # a seed with no episode in any block scored (seed 4: 3 episodes) is NaN, not left out
    ten = Run(Path("."), pd.concat([df[df["episode"] <= 10], frame([(4, e, 5, 9) for e in (1, 2, 3)])]),
              {"run": {"env": "liquidation", "env_steps": 0, "episodes": 10}})
    assert obj.per_seed(ten).fillna(-1).tolist() == [2, 3, 1, 6, -1]
    # a return (more is better) takes the lowest block
    df["return"] = -df["cost_ratio"]
    ret = Objective("worst return", "", "maximize", None, "return", 3, obj.stages)
    assert ret.per_seed(run).tolist() == [-2, -3, -3, -6]
    # a budget of env steps scores each end at its steps (each seed's last 3 episodes within them)
    steps = objective("liquidation", "worst", window=3, stages=[dict(episodes=12, env_steps=s) for s in (15, 30, 60)])
    ran = Run(Path("."), df, {"run": {"env": "liquidation", "env_steps": 60, "episodes": 12}})
    # (the first end, 15 steps, not scored) seed 0 (5 steps an episode): episodes 4-6, 10-12 -> 2;
    # seed 1 (15): 1-2, 2-4 -> 5; seed 2 (25): 1, 1-2 -> 1; seed 3 (35): none, 1 -> 0 (the ends it has)
    assert steps.per_seed(ran).tolist() == [2, 5, 1, 0] and "30 steps, 60 steps" in steps.text
    two = objective("liquidation", "worst", window=3, stages=stages[2:])
    assert two.name.startswith("worst ac_cost / U*") and two.text.endswith("(each seed's mean of its last 3 "
                                                                           "episodes before 12; the worst of these), IQM over seeds")
    with pytest.raises(ValueError, match="^objective 'worst' needs at least two stages"):
        objective("liquidation", "worst", window=3, stages=stages[:1])


def test_a_study_scores_the_measure_named_and_keeps_it(tmp_path, capsys):
    """--measure noise_free_cost_ratio on liquidation: its worst block by hand, not cost_ratio's;
    the square's threshold is not used where a measure is named; a measure the domain lacks is
    refused naming its measures; a study keeps its measure and records the column it scored."""
    df = frame([(s, e, 5, 9.0) for s in range(2) for e in range(1, 7)])
    df["noise_free_cost_ratio"] = [1, 1, 3, 1, 2, 2] + [1, 1, 1, 1, 4, 1]   # blocks 3-4, 5-6: 2, 2 | 1, 2.5
    run = Run(Path("."), df, {"run": {"env": "liquidation", "env_steps": 0, "episodes": 6}})
    stages = [dict(episodes=e, env_steps=0) for e in (2, 4, 6)]
    obj = objective("liquidation", "worst", window=2, stages=stages, measure="noise_free_cost_ratio")
    assert obj.column == "noise_free_cost_ratio" and obj.direction == "minimize"
    assert obj.per_seed(run).tolist() == [2.0, 2.5] and obj.name == "worst noise-free ac_cost / U*"
    assert objective("liquidation", measure="cost_ratio").column == "cost_ratio"
    square = objective("square", "report", measure="steps")      # named: at the budget, not steps to threshold
    assert square.threshold is None and square.column == "steps" and square.direction == "minimize"
    assert objective("square", "report").threshold is not None
    with pytest.raises(ValueError, match=r"^square has no measure 'cost_ratio': its measures are steps$"):
        objective("square", measure="cost_ratio")
    with pytest.raises(ValueError, match="its measures are cost_ratio, noise_free_cost_ratio$"):
        objective("liquidation", measure="ac_cost")
    # a domain without a MEASURE of its own: the return, more is better; naming it scores it at the budget
    pendulum = objective("gym:Pendulum-v1", "report", measure="return")
    assert (pendulum.column, pendulum.name, pendulum.direction) == ("return", "return per episode at budget", "maximize")
    assert objective("gym:CartPole-v1", "report", measure="return").threshold is None
    cartpole = objective("gym:CartPole-v1", "report")
    assert cartpole.threshold.value == 195 and cartpole.name == "steps to threshold" and cartpole.text == (
        "steps to threshold (mean return >= 195 over 10 episodes; a seed that never met it: the budget), IQM over seeds")
    with pytest.raises(ValueError, match=r"^gym has no measure 'steps': its measures are return$"):
        objective("gym:CartPole-v1", measure="steps")
    out = tmp_path / "study"
    from trl_dgpq.study import Study
    study = Study.open(out, None, {"env": "liquidation", "agent": "dgpq", "episodes": "12"},
                       {"measure": "noise_free_cost_ratio"})
    assert study.request["scored"] == "noise_free_cost_ratio" == study.objective.column
    with pytest.raises(ValueError, match="keeps its measure noise_free_cost_ratio"):
        Study.open(out, None, {}, {"measure": "cost_ratio"})
    with pytest.raises(SystemExit) as exc:
        tune.main([*TINY, "--out", str(tmp_path / "never"), "--measure", "cost_ratio"])
    assert exc.value.code == 2 and "square has no measure 'cost_ratio'" in capsys.readouterr().err


def test_a_worst_study_needs_two_stages(capsys):
    with pytest.raises(SystemExit) as exc:
        tune.main([*TINY, "--stages", "1", "--out", "unused", "--objective", "worst"])
    assert exc.value.code == 2 and "at least two stages" in capsys.readouterr().err


def test_a_study_keeps_its_window(tmp_path, capsys):
    out = str(tmp_path / "study")
    assert tune.main([*TINY, "--episodes", "2", "--out", out, "--trials", "1", "--objective", "measure",
                      "--window", "2"]) == 0
    assert "last 2 episodes" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exc:
        tune.main(["--out", out, "--trials", "2", "--window", "5"])
    assert exc.value.code == 2 and "keeps its window" in capsys.readouterr().err


def test_a_stage_of_a_run_is_the_shorter_run():
    """What a trial reports after a stage: its rows cut to the stage's budget are those of a run
    asked for that budget (a seed's last episode is the one that crossed it)."""
    config = resolve_config(env="square", agent="dgpq", seeds=[1000, 1001], env_steps=300)
    short = resolve_config(env="square", agent="dgpq", seeds=[1000, 1001], env_steps=120)
    long = Run(Path("."), with_env_steps(run_experiment(config, progress=False)), config)
    cut = stage(long, {"episodes": 120, "env_steps": 120})
    assert len(cut.df) < len(long.df) and cut.config["run"]["env_steps"] == 120
    pd.testing.assert_frame_equal(rows(cut.df), rows(with_env_steps(run_experiment(short, progress=False))))


def rows(df):
    """Episode rows in (seed, episode) order, without the timing columns."""
    df = df.sort_values(["seed", "episode"], kind="stable").reset_index(drop=True)
    return df.drop(columns=list(TIMING_COLUMNS))


def with_env_steps(df):
    df = df.sort_values(["seed", "episode"], kind="stable").reset_index(drop=True)
    df["env_steps"] = df.groupby("seed")["steps"].cumsum()
    return df


# ---------------------------------------------------------------- search spaces and seeds


@pytest.mark.parametrize("env, agent, budget", [("square", "dgpq", {"episodes": 4}),
                                                ("square", "dqn", {"env_steps": 10_000}),
                                                ("square", "dqn", {"episodes": 4}),
                                                ("liquidation", "ddpg", {"episodes": 4}),
                                                ("liquidation", "td3", {"episodes": 4})])
def test_suggestions_stay_in_their_ranges_and_make_valid_configs(env, agent, budget):
    space = search_space(agent_class(agent, env))
    steps = budget.get("env_steps", 0)
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=3))
    for _ in range(25):
        trial = study.ask()
        settings = suggest(trial, space, steps)
        for name, r in space.items():
            v = settings[name]
            if hasattr(r, "options"):
                assert v in r.options, (name, v)
            elif isinstance(r, OfBudget) and steps:
                assert r.low * steps - 1 <= v <= r.high * steps + 1 and isinstance(v, int), (name, v)
                assert trial.distributions[f"{name}_fraction"].low == r.low
            else:
                inner = r.otherwise if isinstance(r, OfBudget) else r
                assert inner.low <= v <= inner.high, (name, v)
                log = isinstance(inner, LogUniform) or (isinstance(inner, IntRange) and inner.log)
                assert trial.distributions[name].log == log, name
        config = resolve_config({"env": env, "agent": agent, **budget,
                                 **{f"agent.{k}": v for k, v in settings.items()}})
        flat = {**config["agent"], **config["agent"].get("gp", {})}
        assert {k: flat[k] for k in settings} == {k: list(v) if isinstance(v, tuple) else v
                                                  for k, v in settings.items()}
        study.tell(trial, 0.0)


def test_reporting_seeds_cover_every_report_and_tuning_seeds_avoid_them():
    """REPORTING_SEEDS holds the seeds of every sweep file in configs/ (make compare, the tuned
    comparison), of every reproduction scale and train's default; the tuning default is outside
    them."""
    given = []
    for path in sorted((ROOT / "configs").glob("*.toml")):
        sweep = tomllib.loads(path.read_text())
        given += [sweep.get("defaults", {}).get("seeds", 1)] + [e["seeds"] for e in sweep["experiment"] if "seeds" in e]
    for d in domains():  # reproduce: counts per scale, the domain's and an experiment's own
        analysis = d.analysis()
        own = [e[2] for e in getattr(analysis, "REPRODUCE", []) if len(e) > 2]
        for scales in [getattr(analysis, "SCALES", {}), *own]:
            given += [seeds for seeds, *_ in scales.values()]   # (seeds, episodes[, env steps])
    used = {s for g in given for s in parse_seeds(g)} | set(RunConfig().seeds)
    assert used <= set(REPORTING_SEEDS)
    assert not set(TUNING_SEEDS) & set(REPORTING_SEEDS)


# ---------------------------------------------------------------- studies


# behind slow: whole studies (~3 s); trials run until the study is full is test_study_parts'
# test_work_runs_trials_until_the_study_is_full
@pytest.mark.slow
def test_a_larger_trials_adds_trials_and_a_full_study_only_reports(tmp_path, capsys):
    out = str(tmp_path / "study")
    args = [*TINY, "--episodes", "2", "--out", out]
    assert tune.main([*args, "--trials", "2"]) == 0
    first = [(t.params, t.value) for t in trials_of(out)]
    assert tune.main([*args, "--trials", "3"]) == 0
    trials = trials_of(out)
    assert len(trials) == 3 and all(t.state == optuna.trial.TrialState.COMPLETE for t in trials)
    assert [(t.params, t.value) for t in trials[:2]] == first
    for t in trials:  # an ended trial keeps its rows and config, no checkpoint
        assert sorted(p.name for p in (tmp_path / "study" / "trials" / f"{t.number:04d}").iterdir()) == sorted(KEEP)
    capsys.readouterr()
    assert tune.main(["--out", out, "--trials", "3"]) == 0  # full: the summary, no trial
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(trials_of(out)) == 3
    best = min(trials, key=lambda t: t.value)
    assert lines[-1].startswith(f"best: trial {best.number}, steps to threshold {best.value:.6g} ")
    assert lines[-1].endswith("3/3 trials done (3 complete, 0 pruned, 0 failed)")


@pytest.mark.slow  # real processes killed mid-trial, ~8 s
def test_a_study_continues_after_its_process_is_killed(tmp_path):
    """kill -9 in the middle of trial 0 (once its run folder has a checkpoint): the next run fails
    it, runs its parameters again from that checkpoint, and ends with the rows of a run that was
    never stopped."""
    out = tmp_path / "study"
    args = [*TINY, "--trials", "2", "--out", str(out)]
    proc = subprocess.Popen([sys.executable, str(ROOT / "scripts" / "tune.py"), *args],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    checkpoint = out / "trials" / "0000" / "checkpoint.pt"
    deadline = time.time() + 120
    while not checkpoint.exists() and proc.poll() is None and time.time() < deadline:
        time.sleep(0.02)
    proc.kill()
    proc.wait()
    assert checkpoint.exists()
    assert tune.main(args) == 0
    killed, *rest = trials_of(out)
    assert killed.state == optuna.trial.TrialState.FAIL and "is gone" in killed.user_attrs["retried"]
    retry = next(t for t in rest if t.user_attrs.get("retry_of") == 0)
    assert retry.state == optuna.trial.TrialState.COMPLETE and retry.params == killed.params
    assert retry.user_attrs["resumed"]["episodes_done"] >= 1  # from the checkpoint, not from scratch
    assert sum(t.state == optuna.trial.TrialState.COMPLETE for t in rest) == 2
    folder = out / "trials" / f"{retry.number:04d}"
    assert not (out / "trials" / "0000").exists() and sorted(p.name for p in folder.iterdir()) == sorted(KEEP)
    config = {k: v for k, v in json.loads((folder / "config.json").read_text()).items() if k in ("run", "env", "agent")}
    pd.testing.assert_frame_equal(rows(read_csv_exact(folder / "episodes.csv")),
                                  rows(run_experiment(config, progress=False)))


def test_ctrl_c_hands_the_trial_on_and_says_how_to_continue(tmp_path, capsys, stop_run_after):
    out = str(tmp_path / "study")
    args = [*TINY, "--trials", "1", "--out", out]
    stop_run_after(1, "signal")  # SIGINT once the first episode's row is on disk
    assert tune.main(args) == 130
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.endswith(f"continue with: python scripts/tune.py --out {out} --trials 1")
    capsys.readouterr()
    assert tune.main(["--out", out, "--trials", "1"]) == 0
    stopped, retry = trials_of(out)
    assert f"trial {retry.number} (the retry of trial 0, its run continued): " in capsys.readouterr().out
    assert stopped.user_attrs["retried"] == "interrupted by SIGINT"
    assert retry.state == optuna.trial.TrialState.COMPLETE and retry.user_attrs["resumed"]["episodes_done"] >= 1


def test_median_pruner_stops_a_trial_below_the_median(tmp_path, monkeypatch):
    """Values crafted per trial (trial 2 far worse at every stage): after two trials have ended,
    the pruner stops trial 2 after its first stage, whose rows are all it ran."""
    crafted = {0: 10.0, 1: 12.0, 2: 1000.0}
    monkeypatch.setattr(Objective, "value", lambda self, run: crafted[int(run.path.name)])
    out = tmp_path / "study"
    assert tune.main([*TINY, "--episodes", "2", "--prune-after", "2", "--trials", "3", "--out", str(out)]) == 0
    states = [t.state.name for t in trials_of(out)]
    assert states == ["COMPLETE", "COMPLETE", "PRUNED"]
    pruned = trials_of(out)[2]
    assert pruned.intermediate_values == {1: 1000.0}
    folder = out / "trials" / "0002"
    assert load_run(folder).df.episode.max() == 1 and sorted(p.name for p in folder.iterdir()) == sorted(KEEP)


@pytest.mark.usefixtures("own_tuned_file")   # presets written to tmp_path/tuned.json
def test_each_base_preset_keeps_its_own_tuned_preset():
    """The square's default is "shaped": a study on it writes "tuned", one on "noisy" writes
    "noisy-tuned", and neither replaces the other."""
    assert presets.tuned_name("square", "shaped") == "tuned" and presets.tuned_name("square", "noisy") == "noisy-tuned"
    presets.write_tuned("square", "dqn", "tuned", {"env": {}, "agent": {"lr": 0.002}}, {})
    presets.write_tuned("square", "dqn", "noisy-tuned", {"env": {"reward_noise": 0.1}, "agent": {"lr": 0.004}}, {})
    presets.write_tuned("square", "dgpq", "tuned", {"env": {}, "agent": {"lipschitz": 0.5}}, {})
    assert resolve_config(env="square", agent="dqn", preset="tuned")["agent"]["lr"] == 0.002
    assert resolve_config(env="square", agent="dqn", preset="noisy-tuned")["agent"]["lr"] == 0.004
    assert resolve_config(env="square", agent="dgpq", preset="tuned")["agent"]["lipschitz"] == 0.5
    assert "shaped" in presets.preset_table("square", "dqn")  # the domain's own presets stay


@pytest.mark.usefixtures("own_tuned_file")   # presets written to tmp_path/tuned.json
def test_the_best_trial_round_trips_as_the_tuned_preset(tmp_path):
    """--write-preset: the base preset the study ran on (its env section too), the settings given
    to it, the best trial's over them; resolve_config(preset="tuned") gives them back."""
    out = tmp_path / "study"
    study = Study.open(out, None, {"env": "square", "agent": "dqn", "preset": "noisy", "episodes": "4",
                                   "gamma": "0.8"}, {"first": "sampled", "window": 7})
    best = {"lr": 0.003, "hidden": [128, 128], "eps_end": 0.07, "exploration_steps": 900}
    for value, settings in [(50.0, {"lr": 0.0002}), (20.0, best)]:
        study.load().add_trial(optuna.trial.create_trial(value=value, user_attrs={"settings": settings}))
    study.write_preset()
    with pytest.raises(ValueError, match="unknown preset 'tuned'"):  # the base preset is not the default
        resolve_config(env="square", agent="dqn", preset="tuned")
    config = resolve_config(env="square", agent="dqn", preset="noisy-tuned")
    assert {k: config["agent"][k] for k in best} == best
    assert config["agent"]["gamma"] == 0.8 and config["env"]["reward_noise"] == 0.1  # given, and the base's env
    assert config["agent"]["buffer_size"] == presets.SMALL_DQN["buffer_size"]        # the base preset's agent
    provenance = json.loads((tmp_path / "tuned.json").read_text())["square"]["dqn"]["noisy-tuned"]["provenance"]
    assert provenance["trial"] == 1 and provenance["value"] == 20.0 and provenance["seeds"] == list(TUNING_SEEDS)
    assert provenance["base_preset"] == "noisy" and provenance["study"] == f"sqlite:///{out.resolve() / 'study.db'}"
    assert {"date", "commit", "budget", "trials", "objective"} <= set(provenance) and provenance["window"] == 7


@pytest.mark.usefixtures("own_tuned_file")   # presets written to tmp_path/tuned.json
def test_a_study_writes_its_preset_under_the_name_given_and_never_over_a_hand_set_one(tmp_path, capsys):
    """--write-preset NAME: the preset goes in under NAME (the default 'tuned' untouched); a name
    of the domain's own presets.py, or not a plain name, is refused in one line before writing."""
    out = tmp_path / "study"
    study = Study.open(out, None, {"env": "square", "agent": "dqn", "episodes": "4"}, {})
    study.load().add_trial(optuna.trial.create_trial(value=7.0, user_attrs={"settings": {"lr": 0.004}}))
    assert study.write_preset("late") == ("late", tmp_path / "tuned.json")
    assert resolve_config(env="square", agent="dqn", preset="late")["agent"]["lr"] == 0.004
    assert set(json.loads((tmp_path / "tuned.json").read_text())["square"]["dqn"]) == {"late"}
    for bad, says in [("shaped", "is a preset of dqn on square"), ("a b", "a preset name is"), ("_x", "a preset name is"), ("../x", "a preset name is")]:
        with pytest.raises(SystemExit) as exc:
            tune.main(["--out", str(out), "--trials", "1", "--write-preset", bad])
        assert exc.value.code == 2 and says in capsys.readouterr().err
    assert set(json.loads((tmp_path / "tuned.json").read_text())["square"]["dqn"]) == {"late"}
    assert tune.main(["--out", str(out), "--trials", "1", "--write-preset"]) == 0
    assert "wrote preset 'tuned'" in capsys.readouterr().out
    assert set(json.loads((tmp_path / "tuned.json").read_text())["square"]["dqn"]) == {"late", "tuned"}
    presets.check_preset_name("square", "dqn", "Late_2.b-c")                 # capitals, digits, _ . - are fine
    with pytest.raises(ValueError, match="is a preset of dqn on gym:CartPole-v1"):  # the id's own presets
        presets.check_preset_name("gym:CartPole-v1", "dqn", "zoo")


# ---------------------------------------------------------------- --search: ranges for another scale
def test_a_search_range_is_name_low_high_log_uniform():
    from trl_dgpq.tuning import parse_range, with_ranges
    assert parse_range(" eps1=0.1:3") == ("eps1", LogUniform(0.1, 3.0))
    for bad, says in [("eps1", "NAME=LOW:HIGH"), ("eps1=0.1", "NAME=LOW:HIGH"), ("=1:2", "NAME=LOW:HIGH"),
                      ("eps1=a:3", "NAME=LOW:HIGH"), ("eps1=3:1", "0 < LOW < HIGH"), ("eps1=0:1", "0 < LOW < HIGH"),
                      ("eps1=2:2", "0 < LOW < HIGH"), ("eps1=lr=1:2", "NAME=LOW:HIGH")]:   # one value; a name with "="
        with pytest.raises(ValueError, match=says):
            parse_range(bad)
    space = {"eps1": LogUniform(1e-4, 0.1), "lipschitz": LogUniform(0.1, 100.0)}
    assert with_ranges(space, ["eps1=0.5:2"]) == {"eps1": LogUniform(0.5, 2.0), "lipschitz": LogUniform(0.1, 100.0)}
    with pytest.raises(ValueError, match=r"gamma is not in the agent's search space \(eps1, lipschitz\)"):
        with_ranges(space, ["gamma=0.5:0.9"])


@pytest.mark.usefixtures("own_tuned_file")   # presets written to tmp_path/tuned.json
# behind slow: whole studies (~3 s): the space given by flag is test_study_parts'
# test_the_space_is_the_agents_less_what_the_command_line_gives's
@pytest.mark.slow
def test_a_study_searches_the_ranges_given_and_keeps_them(tmp_path, capsys):
    out = str(tmp_path / "study")
    args = [*TINY, "--episodes", "2", "--out", out, "--search", "lengthscale=5:6,eps1=0.5:0.6"]
    assert tune.main([*args, "--trials", "2"]) == 0
    for t in trials_of(out):
        assert 5 <= t.params["lengthscale"] <= 6 and 0.5 <= t.params["eps1"] <= 0.6
        assert 0.1 <= t.params["lipschitz"] <= 100.0                        # the agent's own range
    with pytest.raises(SystemExit) as exc:                                   # another range: another study
        tune.main(["--out", out, "--trials", "3", "--search", "lengthscale=1:2"])
    assert exc.value.code == 2 and "keeps its search" in capsys.readouterr().err
    assert tune.main(["--out", out, "--trials", "2", "--write-preset"]) == 0
    provenance = json.loads((tmp_path / "tuned.json").read_text())["square"]["dgpq"]["tuned"]["provenance"]
    assert provenance["search"] == ["lengthscale=5:6", "eps1=0.5:0.6"]


def test_per_dimension_weights_are_searched_as_factors_on_the_base_preset():
    from trl_dgpq.tuning import Factors, with_ranges
    space = {"eps1": LogUniform(1e-4, 0.1)}
    got = with_ranges(space, ["state_scale=0.25:4"], {"state_scale": [400, 0, 240]})
    assert got == {"eps1": LogUniform(1e-4, 0.1), "state_scale": Factors(0.25, 4.0, (400.0, 0.0, 240.0))}
    r = got["state_scale"]
    trial = optuna.trial.FixedTrial({"state_scale_0": 0.5, "state_scale_2": 4.0})   # no parameter for the zero
    assert r.suggest(trial, "state_scale", 0) == (200.0, 0.0, 960.0)
    assert r.params("state_scale", [200.0, 0.0, 960.0], 0) == {"state_scale_0": 0.5, "state_scale_2": 4.0}
    assert r.contains((100.0, 0.0, 60.0), 0) and r.contains((1600.0, 0.0, 960.0), 0)          # the range's ends
    for outside in [(99.0, 0.0, 240.0), (400.0, 0.0, 961.0), (400.0, 1.0, 240.0), (400.0, 240.0), (0.0, 0.0, 240.0),
                    0.5]:
        assert not r.contains(outside, 0), outside
    with pytest.raises(ValueError, match=r"the base preset has no state_scale weights to scale; give them \(e.g. "
                                         r"--state-scale \.\.\.\)"):
        with_ranges(space, ["state_scale=0.25:4"], {"state_scale": ()})
    with pytest.raises(ValueError, match="lipschitz is not in the agent's search space .eps1. nor per-dimension"):
        with_ranges(space, ["lipschitz=1:4"], {"lipschitz": 5.0})                          # a scalar: not weights


# behind slow: whole studies (~4 s); weights as factors are test_study_parts'
# test_weights_given_on_the_command_line_are_the_base_their_factors_scale and
# test_per_dimension_weights_are_searched_as_factors_on_the_base_preset
@pytest.mark.slow
def test_a_study_searches_each_weight_of_the_metric(tmp_path, capsys):
    """--search state_scale=LOW:HIGH on weights given on the command line: the first trial runs them
    (every factor 1), the others scale each nonzero one by its own factor; a zero stays zero."""
    out = str(tmp_path / "study")
    assert tune.main([*TINY, "--episodes", "2", "--stages", "1", "--out", out, "--trials", "3", "--state-scale", "2,0",
                      "--search", "state_scale=0.5:4"]) == 0
    trials = trials_of(out)
    assert [sorted(t.params) for t in trials] == [["eps1", "lengthscale", "lipschitz", "noise_var", "sigma_tol2",
                                                   "state_scale_0"]] * 3
    assert trials[0].params["state_scale_0"] == 1.0
    assert trials[1].distributions["state_scale_0"] == optuna.distributions.FloatDistribution(0.5, 4.0, log=True)
    for t in trials:
        weights = t.user_attrs["settings"]["state_scale"]
        assert weights == [pytest.approx(2 * t.params["state_scale_0"]), 0.0] and 1 <= weights[0] <= 8
        config = json.loads((Path(out) / "trials" / f"{t.number:04d}" / "config.json").read_text())
        assert config["agent"]["state_scale"] == weights
    assert len({t.params["state_scale_0"] for t in trials}) == 3
    shown = re.findall(r"state_scale=(\S+)\n", capsys.readouterr().out)                 # each weight to 4 digits
    assert shown[0] == "2,0" and len(shown) == 3 and all(re.fullmatch(r"\d\.\d{1,3},0", w) for w in shown[1:])


def test_a_search_range_outside_the_space_is_refused_before_any_trial(tmp_path, capsys):
    out = tmp_path / "study"
    with pytest.raises(SystemExit) as exc:
        tune.main([*TINY, "--out", str(out), "--trials", "1", "--search", "gamma=0.5:0.9"])
    assert exc.value.code == 2 and "gamma is not in the agent's search space" in capsys.readouterr().err
    assert not out.exists()


def test_the_first_trial_runs_the_base_presets_own_values_inside_their_ranges(tmp_path):
    """Square DQN's default preset, shaped, is SMALL_DQN (lr 1e-3, (64, 64), target every 100, eps_end 0.05, batch 64,
    buffer 10,000, 1 update every step): trial 0 runs those; its 2,000 exploration steps are
    five budgets of 400, outside the range (at most half the budget), so TPE draws that one.
    --first sampled draws them all."""
    args = ["--env", "square", "--agent", "dqn", "--seeds", "1000-1000", "--env-steps", "400", "--stages", "1"]
    assert tune.main([*args, "--out", str(tmp_path / "preset"), "--trials", "1"]) == 0
    (first,) = trials_of(tmp_path / "preset")
    settings = first.user_attrs["settings"]
    assert {k: settings[k] for k in settings if k != "exploration_steps"} == dict(
        lr=1e-3, hidden=[64, 64], target_update_interval=100, eps_end=0.05, batch_size=64, buffer_size=10_000,
        train_freq=1, gradient_steps=1)
    assert 20 <= settings["exploration_steps"] <= 200 and first.user_attrs["first"] == "preset shaped"
    config = json.loads((tmp_path / "preset" / "trials" / "0000" / "config.json").read_text())
    assert config["agent"]["lr"] == 1e-3 and config["agent"]["exploration_steps"] == settings["exploration_steps"]
    assert tune.main([*args, "--out", str(tmp_path / "sampled"), "--trials", "1", "--first", "sampled"]) == 0
    (drawn,) = trials_of(tmp_path / "sampled")
    assert drawn.user_attrs["settings"]["lr"] != 1e-3 and "first" not in drawn.user_attrs


def test_first_params_turn_back_into_the_values_by_each_ranges_suggest():
    """Each range's params, fed to Optuna as a fixed trial, suggest the value back; a value outside
    its range (or a setting not given) gives no param."""
    from trl_dgpq.tuning import Choice, Uniform, first_params
    space = {"a": LogUniform(0.1, 10.0), "b": Uniform(0.0, 1.0), "n": IntRange(10, 1_000, log=True),
             "h": Choice(((64, 64), (256, 256))), "x": OfBudget(0.05, 0.5, otherwise=IntRange(500, 20_000)),
             "far": LogUniform(1.0, 2.0), "missing": Uniform(0.0, 1.0)}
    values = {"a": 0.3, "b": 0.25, "n": 77, "h": (256, 256), "x": 1_500, "far": 5.0}
    params = first_params(space, values, 10_000)
    assert params == {"a": 0.3, "b": 0.25, "n": 77, "h": "256,256", "x_fraction": 0.15}
    study = optuna.create_study()
    study.enqueue_trial(params)
    trial = study.ask()
    got = suggest(trial, space, 10_000)
    assert {k: got[k] for k in values if k != "far"} == {k: v for k, v in values.items() if k != "far"}
    assert 1.0 <= got["far"] <= 2.0
    assert first_params(space, {"x": 1_500}, 0) == {"x": 1_500}   # a budget in episodes: its own count
    assert first_params(space, {"x": 100}, 0) == {}                # ... outside IntRange(500, 20,000)
    assert first_params(space, {"x": 400}, 4_000) == {"x_fraction": 0.1}  # a tenth of the budget, not the count
    x = OfBudget(0.05, 0.5, otherwise=IntRange(500, 20_000))             # 200 to 2,000 of 4,000, ends inside
    assert [x.contains(v, 4_000) for v in (199, 200, 2_000, 2_001)] == [False, True, True, False]
    assert x.contains(1, 10) and not x.contains(0, 10)                   # at least one step of a tiny budget
    # the ends of each range are inside; a config's widths come as a list
    ends = {"a": 10.0, "b": 0.0, "n": 10, "h": [64, 64]}
    assert first_params(space, ends, 0) == {"a": 10.0, "b": 0.0, "n": 10, "h": "64,64"}
    assert first_params(space, {"a": 0.1, "b": 1.0, "n": 1_000}, 0) == {"a": 0.1, "b": 1.0, "n": 1_000}


# behind slow: whole studies (~4 s): in units, test_study_validation's
# test_the_k_best_trials_and_the_base_presets_run_again_on_the_validation_seeds
@pytest.mark.slow
def test_validate_runs_the_best_trials_and_the_first_again_on_other_seeds(tmp_path, capsys):
    """--validate 1: the best trial and trial 0 (the base preset's) rerun at the full budget on
    the validation seeds; each value is the IQM (two seeds: their mean) of each seed's mean
    steps per episode over its last 10 episodes within the budget (a run in episodes: the
    fewest steps a seed ran), by hand from the run's own rows. Asked again,
    nothing reruns; overlapping the tuning seeds is refused."""
    out = tmp_path / "study"
    args = ["--env", "square", "--agent", "dgpq", "--seeds", "1000-1000", "--episodes", "3", "--stages", "1",
            "--objective", "measure", "--out", str(out)]
    assert tune.main([*args, "--trials", "3"]) == 0
    trials = trials_of(out)
    best = min(trials, key=lambda t: t.value)
    capsys.readouterr()
    assert tune.main(["--out", str(out), "--validate", "1", "--validation-seeds", "1005-1006"]) == 0
    printed = capsys.readouterr().out
    stored = optuna.load_study(study_name="study", storage=f"sqlite:///{out / 'study.db'}").user_attrs["validation"]
    assert stored["seeds"] == [1005, 1006] and set(stored["values"]) == {str(best.number), "0"}
    for number, value in stored["values"].items():
        folder = out / "validation" / f"{int(number):04d}"
        config = json.loads((folder / "config.json").read_text())
        assert config["run"]["seeds"] == [1005, 1006] and config["run"]["episodes"] == 3
        trial = trials[int(number)]
        assert {k: config["agent"]["gp"].get(k, config["agent"].get(k)) for k in trial.user_attrs["settings"]} == \
            trial.user_attrs["settings"]
        rows = pd.read_csv(folder / "episodes.csv")
        rows["env_steps"] = rows.groupby("seed")["steps"].cumsum()
        budget = rows.groupby("seed")["env_steps"].max().min()   # in episodes: the fewest steps a seed ran
        kept = rows[rows["env_steps"] <= budget]
        assert value == pytest.approx(kept.groupby("seed")["steps"].mean().mean())
        assert f"trial {number}: " in printed
    assert sorted(p.name for p in (out / "validation" / "0000").iterdir()) == sorted(KEEP)
    before = (out / "validation" / "0000" / "episodes.csv").stat().st_mtime_ns
    assert tune.main(["--out", str(out), "--validate", "1", "--validation-seeds", "1005-1006"]) == 0
    assert (out / "validation" / "0000" / "episodes.csv").stat().st_mtime_ns == before
    assert tune.main(["--out", str(out), "--validate", "1", "--validation-seeds", "1007-1007"]) == 0
    again = optuna.load_study(study_name="study", storage=f"sqlite:///{out / 'study.db'}").user_attrs["validation"]
    assert again["seeds"] == [1007] and set(again["values"]) == set(stored["values"])  # other seeds: run again
    assert json.loads((out / "validation" / "0000" / "config.json").read_text())["run"]["seeds"] == [1007]


@pytest.mark.usefixtures("own_tuned_file")   # presets written to tmp_path/tuned.json
def test_a_validated_study_writes_the_best_trial_on_the_validation_seeds(tmp_path):
    """Trial 0 is best on the tuning seeds (10 < 20), trial 1 on the validation seeds (30 < 40):
    the preset is trial 1's, and its provenance says so."""
    study = Study.open(tmp_path / "study", None, {"env": "square", "agent": "dqn", "episodes": "4"},
                       {"first": "sampled"})
    for value, lr in [(10.0, 0.0002), (20.0, 0.003)]:
        study.load().add_trial(optuna.trial.create_trial(value=value, user_attrs={"settings": {"lr": lr}}))
    study.write_preset()
    entry = json.loads((tmp_path / "tuned.json").read_text())["square"]["dqn"]["tuned"]
    assert entry["preset"]["agent"]["lr"] == 0.0002 and "validation" not in entry["provenance"]
    study.load().set_user_attr("validation", {"seeds": [1005, 1006], "values": {"0": 40.0, "1": 30.0}})
    study.write_preset()
    entry = json.loads((tmp_path / "tuned.json").read_text())["square"]["dqn"]["tuned"]
    assert entry["preset"]["agent"]["lr"] == 0.003 and entry["provenance"]["trial"] == 1
    assert entry["provenance"]["value"] == 20.0
    assert entry["provenance"]["validation"] == {"seeds": [1005, 1006], "value": 30.0, "trials": [0, 1]}


@pytest.mark.usefixtures("own_tuned_file")   # presets written to tmp_path/tuned.json
def test_a_finished_study_asked_again_keeps_its_preset_as_first_written(tmp_path, monkeypatch):
    """Writing the same preset again (a finished study's command run once more) leaves the entry as it
    was, its date and commit those of the first writing, not of the later checkout; a new best
    trial rewrites it, with a new date. The date and commit are stubbed so the two differ."""
    from trl_dgpq.collectors import runner
    commits = iter(["a" * 40, "b" * 40, "c" * 40])
    monkeypatch.setattr(runner, "provenance", lambda: {"git": {"commit": next(commits)}})
    study = Study.open(tmp_path / "study", None, {"env": "square", "agent": "dqn", "episodes": "4"}, {})
    study.load().add_trial(optuna.trial.create_trial(value=10.0, user_attrs={"settings": {"lr": 0.0002}}))
    entry = lambda: json.loads((tmp_path / "tuned.json").read_text())["square"]["dqn"]["tuned"]  # noqa: E731
    assert study.write_preset() == ("tuned", tmp_path / "tuned.json")
    first = entry()
    prov = first["provenance"]
    assert prov["commit"] == "a" * 40 and re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d", prov["date"])
    assert prov["budget"] == {"episodes": 4, "env_steps": 0} and prov["study_name"] == "study"
    assert prov["objective"] == study.objective.name and prov["value"] == 10.0 and "search" not in prov
    assert study.write_preset() == ("tuned", tmp_path / "tuned.json")
    assert entry() == first                                                   # kept whole: commit a
    edited = json.loads((tmp_path / "tuned.json").read_text())                # a hand edit of its values
    edited["square"]["dqn"]["tuned"]["preset"]["agent"]["lr"] = 0.5
    (tmp_path / "tuned.json").write_text(json.dumps(edited))
    study.write_preset()
    assert entry()["preset"] == first["preset"] and entry()["provenance"]["commit"] == "b" * 40
    study.load().add_trial(optuna.trial.create_trial(value=5.0, user_attrs={"settings": {"lr": 0.001}}))
    study.write_preset()
    assert entry()["preset"]["agent"]["lr"] == 0.001 and entry()["provenance"]["commit"] == "c" * 40
    assert entry()["provenance"]["trial"] == first["provenance"]["trial"] + 1
    other = Study.open(tmp_path / "other", None, {"env": "square", "agent": "dqn", "episodes": "4"}, {})
    other.load().add_trial(optuna.trial.create_trial(value=1.0, user_attrs={"settings": {"lr": 0.01}}))
    with pytest.raises(ValueError, match="this study would replace preset 'tuned'"):
        other.write_preset()                                                  # not forced by default


@pytest.mark.usefixtures("own_tuned_file")   # presets written to tmp_path/tuned.json
def test_a_study_never_replaces_another_studys_preset_unless_forced(tmp_path, capsys):
    """A 1-trial study writing 'tuned' over a preset another study wrote is refused, naming what it
    would replace; --force replaces it and says what went; the same study may rewrite its own."""
    first = Study.open(tmp_path / "first", None, {"env": "square", "agent": "dqn", "episodes": "4"}, {})
    first.load().add_trial(optuna.trial.create_trial(value=7.0, user_attrs={"settings": {"lr": 0.004}}))
    first.write_preset()
    first.write_preset()                                                    # its own: rewritten quietly
    other = tmp_path / "other"
    second = Study.open(other, None, {"env": "square", "agent": "dqn", "episodes": "4"}, {})
    second.load().add_trial(optuna.trial.create_trial(value=5.0, user_attrs={"settings": {"lr": 0.001}}))
    with pytest.raises(SystemExit) as exc:
        tune.main(["--out", str(other), "--trials", "1", "--write-preset"])
    err = capsys.readouterr().err
    prov = json.loads((tmp_path / "tuned.json").read_text())["square"]["dqn"]["tuned"]["provenance"]
    assert exc.value.code == 2 and ("would replace preset 'tuned' of dqn on square, written by study 'first' "
                                    f"({prov['trials']} trials on seeds {prov['seeds']}, {prov['date']})") in err
    assert err.strip().endswith(": write it under another name (--write-preset NAME), or add --force to replace it")
    # a provenance without its counts (written by hand): each said unknown
    data = json.loads((tmp_path / "tuned.json").read_text())
    data["square"]["dqn"]["tuned"]["provenance"] = {"study_name": "by-hand"}
    (tmp_path / "tuned.json").write_text(json.dumps(data))
    assert second.replaces("tuned") == ("preset 'tuned' of dqn on square, written by study 'by-hand' "
                                        "(? trials on seeds ?, ?)")
    data["square"]["dqn"]["tuned"]["provenance"] = {}
    (tmp_path / "tuned.json").write_text(json.dumps(data))
    assert second.replaces("tuned").startswith("preset 'tuned' of dqn on square, written by study '?' (")
    data["square"]["dqn"]["tuned"]["provenance"] = prov
    (tmp_path / "tuned.json").write_text(json.dumps(data))
    assert resolve_config(env="square", agent="dqn", preset="tuned")["agent"]["lr"] == 0.004      # untouched
    assert tune.main(["--out", str(other), "--trials", "1", "--write-preset", "--force"]) == 0
    assert "replaced preset 'tuned' of dqn on square, written by study 'first'" in capsys.readouterr().out
    assert resolve_config(env="square", agent="dqn", preset="tuned")["agent"]["lr"] == 0.001


def test_a_presets_provenance_records_its_study_relative_to_the_checkout():
    from trl_dgpq.study import portable
    root = Path(__file__).resolve().parent.parent
    assert portable(f"sqlite:///{root / 'runs/tune/x/study.db'}") == "sqlite:///runs/tune/x/study.db"
    assert portable("sqlite:////elsewhere/study.db") == "sqlite:////elsewhere/study.db"
    assert portable("postgresql://host/db") == "postgresql://host/db"


# ---------------------------------------------------------------- directions, validation, retries, hosts, signals
F16 = {"env": "f16", "agent": "dgpq", "episodes": "4"}


def f16_study(tmp_path, objective):
    """An F-16 study scored by ``objective`` ('measure': the episode reward, more is better;
    'report': steps to the threshold, fewer is better) holding four hand-made complete trials:
    trial 0 the base preset's (lipschitz 1, value 5), then lipschitz 2, 3, 4 valued 9, 7, 3."""
    study = Study.open(tmp_path / "study", None, F16, {"objective": objective, "first": "sampled"})
    for number, (value, lipschitz) in enumerate([(5.0, 1.0), (9.0, 2.0), (7.0, 3.0), (3.0, 4.0)]):
        first = {"first": "preset default"} if number == 0 else {}
        study.load().add_trial(optuna.trial.create_trial(value=value, user_attrs={"settings": {"lipschitz": lipschitz},
                                                                                  **first}))
    return study


@pytest.mark.parametrize("objective, direction, better, best, lipschitz, validated", [
    ("measure", "maximize", "higher", 1, 2.0, (2, 3.0)),     # 9 is the highest; on validation 8 > 6 > 4
    ("report", "minimize", "lower", 3, 4.0, (1, 2.0))])      # 3 is the lowest; on validation 4 < 6 < 8
@pytest.mark.usefixtures("own_tuned_file")   # presets written to tmp_path/tuned.json
def test_a_maximised_objective_calls_the_highest_trial_best(tmp_path, objective, direction, better,
                                                             best, lipschitz, validated):
    """F-16's measure is the episode reward: a study on it maximises (Optuna's direction), its
    summary and --write-preset take the trial of the highest value (9, trial 1), and among
    validated trials the highest there (8, trial 2); the same trials scored by steps to the
    threshold take the lowest (3, trial 3; validated: 4, trial 1). A study that minimised a
    return would write its worst trial."""
    study = f16_study(tmp_path, objective)
    assert study.load().direction == optuna.study.StudyDirection[direction.upper()]
    value = {1: 9, 3: 3}[best]
    assert re.match(rf"best: trial {best}, \D+ {value} \({better} is better, IQM over 5 seeds\) with "
                    rf"lipschitz={lipschitz:g}; 4/4 trials done", study.summary(4)), study.summary(4)
    name, path = study.write_preset()
    entry = json.loads(path.read_text())["f16"]["dgpq"][name]
    assert entry["preset"]["agent"]["lipschitz"] == lipschitz and entry["provenance"]["trial"] == best
    assert entry["provenance"]["value"] == value and entry["provenance"]["direction"] == direction
    study.load().set_user_attr("validation", {"seeds": [1005, 1006], "values": {"1": 4.0, "2": 8.0, "3": 6.0}})
    study.write_preset()
    entry = json.loads(path.read_text())["f16"]["dgpq"][name]
    assert (entry["provenance"]["trial"], entry["preset"]["agent"]["lipschitz"]) == validated


@pytest.mark.parametrize("agent, flag, value, where, searched", [
    ("dqn", "lr", "0.0005", ("lr",), {"hidden", "target_update_interval", "eps_end", "exploration_steps",
                                      "batch_size", "buffer_size", "train_freq", "gradient_steps"}),
    ("dgpq", "lengthscale", "0.5", ("gp", "lengthscale"), {"lipschitz", "sigma_tol2", "eps1", "noise_var"})])
def test_a_setting_given_on_tunes_command_line_is_kept_not_searched(tmp_path, monkeypatch, agent, flag, value, where,
                                                                     searched):
    """``tune --lr 0.0005`` (DQN) or ``--lengthscale 0.5`` (DGPQ's, under gp): the setting leaves
    the search space; neither the base preset's trial nor a TPE-drawn one draws it, and each
    trial's run config keeps the value given. (Runs stubbed: the config reaching the run is
    caught.)"""
    study = Study.open(tmp_path / "study", None, {"env": "square", "agent": agent, "episodes": "4", flag: value}, {})
    assert set(study.space) == searched
    configs = []

    def caught(self, trial, path, config):
        configs.append(config)
        raise LookupError("no run")
    monkeypatch.setattr(Study, "open_run", caught)
    optuna_study = study.load()
    for _ in range(2):                            # the base preset's trial, then one TPE draws
        trial = optuna_study.ask()
        with pytest.raises(LookupError):
            study.run_stages(trial)
        optuna_study.tell(trial, 1.0)
        assert set(trial.user_attrs["settings"]) == searched and not any(p.startswith(flag) for p in trial.params)
    first, drawn = trials_of(tmp_path / "study")
    assert "first" in first.user_attrs and "first" not in drawn.user_attrs
    for config in configs:
        node = config["agent"]
        for p in where:
            node = node[p]
        assert node == float(value)


def test_a_trial_stopped_before_drawing_its_settings_is_retried_with_the_same_ones(tmp_path, monkeypatch):
    """SIGTERM while the base preset's trial is asked for (before it drew a setting): next_trial
    raises Stopped once the trial is marked with its process, fails it as retried and enqueues its
    fixed values again (the preset's, not fresh draws), still marked first, as retry_of the trial
    whose folder holds its run (trial 0's: a retry of a retry goes on from it too). The retry
    then draws SMALL_DQN's values, so its run goes on from that folder instead of starting over."""
    from trl_dgpq.study import HOST, Stopped, stop_on_signals
    out = tmp_path / "study"
    study = Study.open(out, None, {"env": "square", "agent": "dqn", "episodes": "4"}, {})
    (out / "trials" / "0000").mkdir(parents=True)           # trial 0 ran, then its process died
    ask = optuna.study.Study.ask

    def ask_then_signal(self, *args, **kwargs):
        trial = ask(self, *args, **kwargs)
        os.kill(os.getpid(), signal.SIGTERM)
        return trial
    preset = dict(lr=1e-3, hidden=(64, 64), target_update_interval=100, eps_end=0.05, exploration_steps=2_000,
                  batch_size=64, buffer_size=10_000, train_freq=1, gradient_steps=1)
    for number in (0, 1):                                    # trial 0, then its retry, each stopped when asked for
        monkeypatch.setattr(optuna.study.Study, "ask", ask_then_signal)
        with stop_on_signals() as stop, pytest.raises(Stopped) as exc:
            study.next_trial(5, stop)
        monkeypatch.setattr(optuna.study.Study, "ask", ask)
        assert exc.value.signum == signal.SIGTERM
        *_, stopped, retry = trials_of(out)
        assert stopped.number == number and stopped.state == optuna.trial.TrialState.FAIL and not stopped.params
        assert stopped.user_attrs["retried"] == "interrupted by SIGTERM"
        assert (stopped.user_attrs["host"], stopped.user_attrs["pid"]) == (HOST, os.getpid())
        assert retry.state == optuna.trial.TrialState.WAITING
        assert retry.user_attrs == {"retry_of": 0, "first": "preset shaped"}
    trial = study.load().ask()
    assert trial.number == 2 and suggest(trial, study.space, 0) == preset


def test_dead_trial_detection_judges_only_this_machines_trials(tmp_path, monkeypatch):
    """With a shared --storage, a running trial marked by another host is that host's to judge:
    its pid means nothing here. Every pid reads as gone: this host's trial is failed and
    re-queued, the other host's stays running, as does an unmarked one asked for just now."""
    from trl_dgpq.study import HOST
    study = Study.open(tmp_path / "study", None, {"env": "square", "agent": "dqn", "episodes": "4"},
                       {"first": "sampled"})
    optuna_study = study.load()
    here, there, unmarked = optuna_study.ask(), optuna_study.ask(), optuna_study.ask()
    for trial, host in ((here, HOST), (there, HOST + "-elsewhere")):
        trial.set_user_attr("host", host)
        trial.set_user_attr("pid", 4321)
    monkeypatch.setattr(runner, "_alive", lambda pid: False)
    study.recover(study.load())
    states = {t.number: (t.state.name, t.user_attrs.get("retried"), t.user_attrs.get("retry_of"))
              for t in trials_of(tmp_path / "study")}
    assert states == {here.number: ("FAIL", "process 4321 is gone", None), there.number: ("RUNNING", None, None),
                      unmarked.number: ("RUNNING", None, None), 3: ("WAITING", None, here.number)}


@pytest.mark.usefixtures("own_tuned_file")   # presets written to tmp_path/tuned.json
def test_a_presets_provenance_counts_every_ended_trial(tmp_path):
    """"trials" in --write-preset's provenance is what the study's --trials counts: complete (2),
    pruned (1) and failed in their own code (1), not a trial failed only to hand it to a retry: 4."""
    from optuna.trial import TrialState, create_trial
    study = Study.open(tmp_path / "study", None, {"env": "square", "agent": "dqn", "episodes": "4"},
                       {"first": "sampled"})
    for trial in [create_trial(value=7.0, user_attrs={"settings": {"lr": 0.004}}),
                  create_trial(state=TrialState.PRUNED, user_attrs={"settings": {"lr": 0.002}}),
                  create_trial(state=TrialState.FAIL, user_attrs={"settings": {"lr": 0.003}, "error": "ValueError: x"}),
                  create_trial(state=TrialState.FAIL, user_attrs={"retried": "process 1 is gone"}),
                  create_trial(value=9.0, user_attrs={"settings": {"lr": 0.001}})]:
        study.load().add_trial(trial)
    _, path = study.write_preset()
    provenance = json.loads(path.read_text())["square"]["dqn"]["tuned"]["provenance"]
    assert provenance["trials"] == 4 and provenance["trial"] == 0
    assert study.summary(4).endswith("4/4 trials done (2 complete, 1 pruned, 1 failed)")


def test_a_study_keeps_its_pruner(tmp_path, capsys):
    """--prune-after is the MedianPruner's n_startup_trials: continuing a study with another would
    change its pruner mid-study, so it is refused in one line before any trial; the same value,
    or none, continues it."""
    out = tmp_path / "study"
    Study.open(out, None, {"env": "square", "agent": "dgpq", "episodes": "4"}, {"prune_after": 3})
    with pytest.raises(SystemExit) as exc:
        tune.main(["--out", str(out), "--trials", "2", "--prune-after", "5"])
    assert exc.value.code == 2
    assert capsys.readouterr().err == "tune.py: error: the study keeps its prune_after 3: continue it without " \
                                      "--prune-after\n"
    assert [t.state.name for t in trials_of(out)] == ["WAITING"]                     # nothing ran
    stored = Study.stored_request(f"sqlite:///{out / 'study.db'}", "study")
    assert Study.reopen_request(stored, {}, {"prune_after": 3, "trials": 9})["tune"]["prune_after"] == 3
    assert Study.open(out, None, {}, {}).tune.prune_after == 3


def test_a_signal_inside_a_held_section_stops_once_the_section_ends():
    """tune's records of a trial are written whole: a SIGTERM that arrives inside ``held`` lets the
    section run to its end and then raises Stopped(SIGTERM); a second signal meanwhile (Ctrl-C)
    is ignored, not swallowing the first. Outside a held section a signal stops at once. The
    handlers before are restored after."""
    from trl_dgpq.study import Stopped, held, stop_on_signals
    leaked = []
    guard = signal.signal(signal.SIGTERM, lambda signum, frame: leaked.append(signum))
    try:
        mine, interrupt = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
        ran = []
        with stop_on_signals() as stop:
            with pytest.raises(Stopped) as exc:
                with held(stop):
                    os.kill(os.getpid(), signal.SIGTERM)
                    time.sleep(0.05)                # the handler runs here: it must not raise
                    ran.append("after SIGTERM")
                    os.kill(os.getpid(), signal.SIGINT)
                    time.sleep(0.05)
                    ran.append("after SIGINT")
            assert exc.value.signum == signal.SIGTERM and ran == ["after SIGTERM", "after SIGINT"]
            assert stop["held"] is False
        with stop_on_signals():
            with pytest.raises(Stopped) as exc:
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(5)                       # interrupted by the handler's Stopped
                ran.append("never")
            assert exc.value.signum == signal.SIGINT and ran[-1] == "after SIGINT"
        assert signal.getsignal(signal.SIGTERM) is mine and signal.getsignal(signal.SIGINT) is interrupt
        assert leaked == []
    finally:
        signal.signal(signal.SIGTERM, guard)


def test_a_signal_while_a_trial_is_recorded_lets_the_record_finish(tmp_path, monkeypatch):
    """SIGINT arriving inside study.tell (the held section that records an ended trial): the trial
    is stored complete with its value and its folder tidied before Stopped(SIGINT) is raised, so no
    finished trial is lost or run twice."""
    from trl_dgpq.study import Stopped, stop_on_signals
    out = tmp_path / "study"
    study = Study.open(out, None, {"env": "square", "agent": "dqn", "episodes": "2"}, {})
    tell, logged = optuna.study.Study.tell, []

    def tell_then_signal(self, *args, **kwargs):
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)                                   # the handler has run: it must not raise here
        return tell(self, *args, **kwargs)
    with stop_on_signals() as stop:
        trial = study.next_trial(3, stop)
        monkeypatch.setattr(optuna.study.Study, "tell", tell_then_signal)
        with pytest.raises(Stopped) as exc:
            study.run(trial, stop, logged.append)
    assert exc.value.signum == signal.SIGINT
    (done,) = trials_of(out)
    assert done.state == optuna.trial.TrialState.COMPLETE and done.value is not None
    assert logged and logged[-1].startswith("trial 0: ")
    assert (out / "trials" / "0000" / "episodes.csv").is_file()            # its rows kept, and tidied:
    assert not any((out / "trials" / "0000").glob("**/checkpoint*"))      # the record was written whole


def test_validate_keeps_each_value_in_the_study_and_refuses_a_study_without_a_complete_trial(tmp_path, monkeypatch):
    """Asked again on the same seeds, validate reads each trial's value from the study (user attr
    ``validation``) and runs nothing; on other seeds it starts over. A study whose trials have all
    failed or been pruned: one line, nothing to validate. Runs and scores stubbed as above."""
    study = f16_study(tmp_path, "measure")
    ran = []
    monkeypatch.setattr(Study, "run_to_end", staticmethod(lambda path, config: ran.append(int(path.name))))
    monkeypatch.setattr("trl_dgpq.study.validation.load_run", lambda path: path)
    monkeypatch.setattr("trl_dgpq.study.validation.stage", lambda run, lengths: run)
    monkeypatch.setattr(Objective, "value", lambda self, run: 10.0 + int(run.name))
    lines = []
    assert study.validate(1, [1005, 1006], log=lines.append) == {1: 11.0, 0: 10.0} and ran == [1, 0]
    assert [line.split("(")[1] for line in lines] == ["9 on the tuning seeds)", "5 on the tuning seeds, the base preset)"]
    assert study.load().user_attrs["validation"] == {"seeds": [1005, 1006], "values": {"1": 11.0, "0": 10.0}}
    assert study.validate(1, [1006, 1005], log=lambda line: None) == {1: 11.0, 0: 10.0} and ran == [1, 0]
    assert study.validate(1, [1007], log=lambda line: None) == {1: 11.0, 0: 10.0} and ran == [1, 0, 1, 0]
    assert study.load().user_attrs["validation"]["seeds"] == [1007]
    empty = Study.open(tmp_path / "empty", None, F16, {"objective": "measure", "first": "sampled"})
    empty.load().add_trial(optuna.trial.create_trial(state=optuna.trial.TrialState.FAIL))
    with pytest.raises(ValueError, match=r"^no trial has completed: there is nothing to validate$"):
        empty.validate(1, [1005])
    with pytest.raises(ValueError, match=r"^validation seeds \[5, 6\] are reporting seeds: .* use e\.g\. 1005-1014$"):
        study.validation_seeds([6, 5])
    assert study.config["run"]["seeds"] == [1000, 1001, 1002, 1003, 1004]
    with pytest.raises(ValueError, match=r"^validation seeds \[1003\] are the study's own tuning seeds: validate on "
                                         r"others, e\.g\. --validation-seeds 1005-1014$"):
        study.validation_seeds([1003, 1005])


# behind slow: a study run to its end (~4 s): in units, test_study_validation's
# test_an_unfinished_run_is_resumed_from_its_folder and test_a_run_with_other_settings_is_started_over
@pytest.mark.slow
def test_a_validation_run_goes_on_from_its_checkpoint_and_starts_over_for_other_settings(tmp_path, stop_run_after):
    """``run_to_end``: a run stopped after its first batch of rows goes on from its checkpoint (its
    first rows are the ones written before the stop, wall times and all; the rows end as an
    uninterrupted run's); a finished run with the same config is left as it is; one whose env or
    agent settings differ starts over under the new config."""
    config = resolve_config(env="square", agent="dgpq", seeds=[1005, 1006], episodes=3, checkpoint_every=1)
    path = tmp_path / "v"
    stop_run_after(1)
    with pytest.raises(runner.Interrupted):
        Study.run_to_end(path, config)
    first = pd.read_csv(path / "episodes.csv")
    assert 0 < len(first) < 6
    Study.run_to_end(path, config)
    rows = pd.read_csv(path / "episodes.csv")
    assert len(rows) == 6 and runner.RunFolder(path).finished()
    pd.testing.assert_frame_equal(rows.iloc[:len(first)], first)       # kept, not run again
    whole = tmp_path / "whole"
    Study.run_to_end(whole, config)
    columns = [c for c in rows.columns if c not in TIMING_COLUMNS]
    pd.testing.assert_frame_equal(pd.read_csv(whole / "episodes.csv")[columns], rows[columns])
    before = (path / "episodes.csv").stat().st_mtime_ns
    Study.run_to_end(path, config)
    assert (path / "episodes.csv").stat().st_mtime_ns == before
    paper = dict(env="square", agent="dgpq", seeds=[1005, 1006], episodes=3, checkpoint_every=1, **{"env.reward": "paper"})
    for other in (resolve_config(**paper), resolve_config(**paper, eps1=0.2)):   # the env differs, then the agent alone
        assert [other[k] == json.loads((path / "config.json").read_text())[k] for k in ("run", "env", "agent")] == \
            ([True, False, True] if other["agent"]["eps1"] != 0.2 else [True, True, False])
        Study.run_to_end(path, other)
        recorded = json.loads((path / "config.json").read_text())
        assert all(recorded[k] == other[k] for k in ("run", "env", "agent")) and len(pd.read_csv(path / "episodes.csv")) == 6


def test_a_retry_stopped_after_taking_over_its_folder_is_retried_from_that_folder(tmp_path):
    """Trial 0 ran in trials/0000 and was stopped: its retry (trial 1, ``retry_of`` 0) renames that
    folder to trials/0001 when it starts. Stopped in turn, its own retry must go on from 0001, the
    folder it now has, not from 0000, which is gone (it would start over, losing the run)."""
    study = Study.open(tmp_path / "study", None, {"env": "square", "agent": "dqn", "episodes": "4"}, {"first": "sampled"})
    optuna_study = study.load()
    first = optuna_study.ask()
    study.folder(0).mkdir(parents=True)
    study.retry(optuna_study, first, "process 1 is gone")
    second = optuna_study.ask()
    assert second.number == 1 and second.user_attrs["retry_of"] == 0
    os.replace(study.folder(0), study.folder(1))              # what run_stages does as the retry starts
    study.retry(optuna_study, second, "process 2 is gone")
    third = optuna_study.ask()
    assert third.user_attrs["retry_of"] == 1
    # a retry stopped before it took the folder over hands on the folder it was given
    study.retry(optuna_study, third, "process 3 is gone")
    assert optuna_study.ask().user_attrs["retry_of"] == 1


def test_a_count_of_env_steps_is_a_fraction_of_the_budget_and_at_least_one():
    """OfBudget: the fraction drawn times the budget, rounded, never below one step (0.01 x 50 rounds
    to 0: 1); a run budgeted in episodes (budget 0) draws from its fallback range instead."""
    from trl_dgpq.tuning import IntRange, OfBudget
    space = OfBudget(0.005, 0.5, otherwise=IntRange(10, 20))
    assert space.suggest(optuna.trial.FixedTrial({"n_fraction": 0.01}), "n", 50) == 1
    assert space.suggest(optuna.trial.FixedTrial({"n_fraction": 0.05}), "n", 50) == 2       # 2.5 rounds to even
    assert space.suggest(optuna.trial.FixedTrial({"n_fraction": 0.25}), "n", 1000) == 250
    assert space.suggest(optuna.trial.FixedTrial({"n": 12}), "n", 0) == 12


@pytest.mark.usefixtures("own_tuned_file")   # presets written to tmp_path/tuned.json
def test_a_preset_records_the_search_ranges_its_study_was_given(tmp_path):
    study = Study.open(tmp_path / "study", None, {"env": "square", "agent": "dqn", "episodes": "4"},
                       {"search": "lr=0.0001:0.01,batch_size=32:64"})
    study.load().add_trial(optuna.trial.create_trial(value=10.0, user_attrs={"settings": {"lr": 0.0002}}))
    study.write_preset()
    prov = json.loads((tmp_path / "tuned.json").read_text())["square"]["dqn"]["tuned"]["provenance"]
    assert prov["search"] == ["lr=0.0001:0.01", "batch_size=32:64"]
