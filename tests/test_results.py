"""results.csv: one row per experiment, the form results/ keeps in the repository (issue 29).
The committed files and the next run's have the same columns, and every committed row's
command resolves to its env, agent and preset."""
import csv
import json
import re
from pathlib import Path

import numpy as np
import pytest

from tests.test_report import fake_run
from trl_dgpq.analysis import load_run, results
from trl_dgpq.collectors.experiment import resolve_config
from trl_dgpq.commands import report, reproduce, train

ROOT = Path(__file__).resolve().parent.parent


def config_of(command: str, capsys) -> dict:
    """What train.py resolves ``command`` to (its own parser, --print-config)."""
    words = command.split()
    assert words[:2] == ["python", "scripts/train.py"], command
    capsys.readouterr()
    assert train.main(words[2:] + ["--print-config"]) == 0
    return json.loads(capsys.readouterr().out)


@pytest.mark.parametrize("settings", [
    dict(env="liquidation", agent="dgpq", preset="shortfall", seeds=[2000, 2001, 2002, 2003], episodes=50,
         sigma_tol2=0.0005, state_scale=(0, 0, 0, 0, 0, 0, 1, 2.5)),
    dict(env="square", agent="dqn", seeds=[0, 3, 4], episodes=7, env_steps=300, reward="paper", gamma=0.9),
    dict(env="f16", agent="dgpq", preset="flight", seeds=[1], episodes=3, lipschitz=7.5, decision_steps=2),
])
def test_a_rows_command_resolves_to_the_runs_config(settings, capsys):
    """The command is train.py with the preset and a --set per changed setting: resolved by
    train's own parser it gives the run's config back, every section."""
    config = resolve_config(**settings)
    again = config_of(results.train_command(config), capsys)
    for section in ("run", "env", "agent"):
        assert again[section] == config[section], section


def test_a_rows_command_keeps_every_digit_of_a_float(capsys):
    """A tuned learning rate such as 0.00039329768981208975 goes into the command whole (Python's
    shortest repr, every digit): written to 6 significant digits (0.000393298) the command would
    re-run another setting. Resolved by train's parser it gives the same float back."""
    lr = 0.00039329768981208975
    assert results.cli_value(lr) == "0.00039329768981208975"
    assert results.cli_value([lr, 2.0]) == "0.00039329768981208975,2.0"
    config = resolve_config(env="square", agent="dqn", seeds=[0], episodes=3, lr=lr)
    command = results.train_command(config)
    assert "agent.lr=0.00039329768981208975" in command.split()
    assert config_of(command, capsys)["agent"]["lr"] == lr

def test_a_row_is_the_domains_measure_over_each_seeds_last_episodes(tmp_path):
    """Square, last 2 episodes per seed: seed means 15, 25, 35, 100 -> median 30, IQM (the
    middle two of four) 30; 1 ms per step as the fake run's wall times say."""
    steps = {0: [50, 10, 20], 1: [20, 30], 2: [90, 30, 40], 3: [100, 100]}
    run = load_run(fake_run(tmp_path / "r", "square", steps, agent="dgpq"))
    run.config["run"].update(seeds=[0], episodes=3, env_steps=0)   # a sweep job's config: seed 0 only
    row = results.row("exp", run, last=2, command="python scripts/train.py --env square")
    assert tuple(row) == results.COLUMNS
    assert row["measure"] == "steps" and row["median"] == 30 and row["iqm"] == pytest.approx(30)
    assert row["iqm_low"] <= row["iqm"] <= row["iqm_high"]
    assert row["seeds"] == "0-3" and row["last"] == 2 and row["us_per_seed_step"] == pytest.approx(1000)
    assert results.seeds_text([0, 2, 5]) == "0,2,5" and results.seeds_text([7]) == "7-7"


def test_a_rows_commit_is_its_jobs_not_its_experiment_folders(tmp_path):
    """A sweep experiment's own config records the commit it was laid out or merged at; the rows
    were made by its jobs, at theirs: the row names those, in full, each once, in job order."""
    run = load_run(fake_run(tmp_path / "r", "square", {0: [40, 20], 1: [30, 30]}, agent="dgpq"))
    run.config.update(git={"commit": "f" * 40, "dirty": False},
                      jobs=[dict(seeds=[0], commit="b" * 40, dirty=False), dict(seeds=[1], commit="a" * 40, dirty=True),
                            dict(seeds=[2], commit="b" * 40, dirty=False)])
    assert results.row("exp", run, command="x")["commit"] == f"{'b' * 40} {'a' * 40}-dirty"


def test_report_writes_results_with_the_columns_the_repository_keeps(tmp_path):
    run = fake_run(tmp_path / "r", "square", {0: [40, 20, 10], 1: [30, 30, 30]}, agent="dgpq")
    assert report.main([str(run), "--out", str(tmp_path / "out")]) == 0
    with open(tmp_path / "out" / "results.csv") as f:
        rows = list(csv.DictReader(f))
    assert tuple(rows[0]) == results.COLUMNS and len(rows) == 1
    assert float(rows[0]["median"]) == pytest.approx(np.median([np.mean([40, 20, 10]), 30]))


def committed():
    return sorted((ROOT / "results").rglob("results.csv")) if (ROOT / "results").is_dir() else []


@pytest.mark.parametrize("path", committed() or [None])
def test_every_committed_row_has_the_columns_and_a_command_that_resolves(path, capsys):
    if path is None:
        pytest.skip("no results/ committed yet")
    with open(path) as f:
        rows = list(csv.DictReader(f))
    assert rows and tuple(rows[0]) == results.COLUMNS, path
    for r in rows:
        config = config_of(r["command"], capsys)
        assert (config["run"]["env"], config["run"]["agent"], config["run"]["preset"]) == (r["env"], r["agent"],
                                                                                          r["preset"]), r
        commits = r["commit"].split()
        assert commits and all(re.fullmatch(r"[0-9a-f]{40}(-dirty)?", c) for c in commits), r["commit"]
        report_md = path.parent / "REPORT.md"
        if report_md.is_file():   # the commits REPORT.md names as those that made its rows
            made = re.search(r"Runs made at commits ([^.]*)\.", report_md.read_text()).group(1)
            assert all(c[:7] + ("-dirty" if c.endswith("-dirty") else "") in made.split(", ") for c in commits), \
                (r["experiment"], r["commit"])
