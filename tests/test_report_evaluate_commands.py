"""The report and evaluate commands (trl_dgpq/commands/report.py, evaluate.py) as a user meets
them, with the work they hand on stubbed: what each passes on, prints, refuses (in its words, one
line, exit 2) and returns."""
from pathlib import Path
from types import SimpleNamespace

import pandas as pd
import pytest

from trl_dgpq.analysis import published
from trl_dgpq.analysis import report as report_module
from trl_dgpq.collectors import evaluate as evaluate_module
from trl_dgpq.commands import evaluate, report, reproduce
from trl_dgpq.selection import SelectionSeedsError


@pytest.fixture
def reported(monkeypatch):
    calls = []

    def fake(runs, labels, out, budget, window, check):
        calls.append(dict(runs=runs, labels=labels, out=out, budget=budget, window=window, check=check))
        return [out / "compare.md", out / "compare-square.png"], "the table"
    monkeypatch.setattr(report, "report", fake)
    return calls


def test_report_hands_on_its_runs_labels_budget_window_and_seed_check(reported, capsys):
    assert report.main(["a", "b", "--labels", "A", "B", "--budget", "40", "--window", "3", "--out", "o"]) == 0
    assert reported == [dict(runs=["a", "b"], labels=["A", "B"], out=Path("o"), budget=40, window=3,
                             check=report_module.reportable)]
    assert capsys.readouterr().out == "the table\nwrote o/compare.md\nwrote o/compare-square.png\n"
    assert report.main(["a", "--unpublished"]) == 0
    assert reported[-1] == dict(runs=["a"], labels=None, out=Path("a"), budget=None, window=report_module.WINDOW,
                                check=None)


@pytest.mark.parametrize("argv, words", [
    (["a", "b", "--labels", "A"], "2 runs need 2 labels, got 1"),
    (["a", "--window", "0"], "--window and --budget must be positive"),
    (["a", "--budget", "0"], "--window and --budget must be positive"),
])
def test_report_refuses_in_one_line(reported, capsys, argv, words):
    assert report.main(argv) == 2 and not reported
    assert capsys.readouterr().err == f"report.py: error: {words}\n"


def test_report_takes_the_smallest_window_and_budget(reported):
    assert report.main(["a", "--window", "1", "--budget", "1"]) == 0
    assert (reported[0]["window"], reported[0]["budget"]) == (1, 1)


def test_report_names_unpublished_when_a_run_is_on_selection_seeds(monkeypatch, capsys):
    def refuse(*args, **kwargs):
        raise SelectionSeedsError("run a is on seeds 1000-1004, its preset's tuning seeds")
    monkeypatch.setattr(report, "report", refuse)
    assert report.main(["a"]) == 2
    assert capsys.readouterr().err == ("report.py: error: run a is on seeds 1000-1004, its preset's tuning seeds "
                                       "(--unpublished: a look at it that is not to be published)\n")


def test_report_on_one_publication_rebuilds_it(monkeypatch, capsys, reported):
    rebuilt = []
    monkeypatch.setattr(published, "is_published", lambda folder: folder == "pub")
    monkeypatch.setattr(reproduce, "rebuild", lambda folder: rebuilt.append(folder) or folder / "REPORT.md")
    assert report.main(["pub"]) == 0 and rebuilt == [Path("pub")] and not reported
    assert capsys.readouterr().out == f"wrote pub/REPORT.md and the rest from {Path('pub') / published.DATA}\n"
    assert report.main(["pub", "other"]) == 0 and len(reported) == 1 and rebuilt == [Path("pub")]


# ------------------------------------------------------------------ evaluate
@pytest.fixture
def evaluated(monkeypatch):
    calls = []
    rows = pd.DataFrame({"seed": [0, 0, 1, 1], "steps": [10.0, 20.0, 30.0, 40.0]})

    def fake(folder, episodes, progress, out):
        calls.append(dict(folder=folder, episodes=episodes, progress=progress, out=out))
        return rows
    monkeypatch.setattr(evaluate_module, "evaluate", fake)
    trained = SimpleNamespace(
        df=pd.DataFrame({"seed": [0, 0, 1, 1, 1], "steps": [1.0, 2.0, 8.0, 16.0, 32.0]}), env_id="gym:X",
        domain=SimpleNamespace(measure=lambda env_id: ("steps", f"steps of {env_id}"),
                               format_measure=lambda value, env_id: f"{value:.2f} ({env_id})"))
    import trl_dgpq.analysis
    monkeypatch.setattr(trl_dgpq.analysis, "load_run", lambda folder: trained)
    return calls


def test_evaluate_compares_with_each_seeds_last_training_episodes(evaluated, capsys):
    assert evaluate.main(["r", "--episodes", "2"]) == 0
    assert evaluated == [dict(folder=Path("r"), episodes=2, progress=True, out=None)]
    # training: seed 0's 2 episodes 1 and 2, seed 1's last 2 16 and 32: mean 12.75 (the last 4 rows of all: 14.5;
    # seeds of unequal lengths, the longer last); evaluation: 25
    assert capsys.readouterr().out == ("r: steps of gym:X, mean over 2 seeds x 2 evaluation episodes: 25.00 (gym:X) "
                                       "(mean over each seed's last 2 training episodes: 12.75 (gym:X)); wrote r/eval.csv\n")


def test_evaluate_writes_elsewhere_one_folder_a_run(evaluated, capsys):
    assert evaluate.main(["r", "--out", "o", "--no-progress", "--episodes", "1"]) == 0
    assert evaluated[-1] == dict(folder=Path("r"), episodes=1, progress=False, out=Path("o"))
    assert capsys.readouterr().out.endswith("wrote o/eval.csv\n")
    assert evaluate.main(["x/r1", "y/r2", "--out", "o"]) == 0
    assert [c["out"] for c in evaluated[-2:]] == [Path("o/r1"), Path("o/r2")]
    assert evaluated[-1]["episodes"] == 10


def test_evaluate_refuses_no_episodes_in_one_line(evaluated, capsys):
    assert evaluate.main(["r", "--episodes", "0"]) == 2 and not evaluated
    assert capsys.readouterr().err == "evaluate.py: error: --episodes must be positive, got 0\n"


def test_ctrl_c_says_which_runs_have_their_eval_csv(evaluated, monkeypatch, capsys):
    def second_stopped(folder, episodes, progress, out):
        if folder.name == "b":
            stop = KeyboardInterrupt()
            stop.path, stop.episodes = folder / "eval.partial.csv", 3
            raise stop
        return pd.DataFrame({"seed": [0], "steps": [1.0]})
    monkeypatch.setattr(evaluate_module, "evaluate", second_stopped)
    assert evaluate.main(["a", "b", "c"]) == 130
    assert capsys.readouterr().err == ("evaluate.py: interrupted while evaluating b: wrote eval.csv for a; no eval.csv "
                                       "written for b, c; the 3 episodes it finished are in b/eval.partial.csv\n")
    assert evaluate.main(["a", "c", "b"]) == 130
    assert capsys.readouterr().err.startswith("evaluate.py: interrupted while evaluating b: wrote eval.csv for a, c; "
                                              "no eval.csv written for b;")
    assert evaluate.main(["b"]) == 130
    assert capsys.readouterr().err == ("evaluate.py: interrupted while evaluating b: no eval.csv written for b; the 3 "
                                       "episodes it finished are in b/eval.partial.csv\n")
