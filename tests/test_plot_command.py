"""plot's command (commands/plot.py) with the runs and figures stubbed: which runs it plots, what it
refuses in one line, the legend's labels, and which figures a set of runs gets."""
import os
from argparse import Namespace
from pathlib import Path
from types import SimpleNamespace

import pytest

import trl_dgpq.analysis.figures as figures
from trl_dgpq.commands import plot


def run(path, agent="dgpq", preset=None, config=True, domain="square", figures_of_its_own=None, env_id=None):
    """A loaded run as analysis.runs gives it: without its config, no domain either."""
    analysis = SimpleNamespace(figures=figures_of_its_own) if figures_of_its_own else SimpleNamespace()
    return SimpleNamespace(path=Path(path), agent=agent, preset=preset, config={"run": {}} if config else None,
                           env_id=env_id or domain,
                           domain=SimpleNamespace(name=domain, analysis=lambda: analysis,
                                                  measure=lambda env_id: (f"steps of {env_id}", "steps per episode"))
                           if config else None)


def test_labels_are_agent_and_preset_else_the_folders_name():
    runs = [run("r/a", "dgpq", "late"), run("r/b", "dqn"), run("r/c", config=False)]
    assert plot.default_labels(runs) == ["dgpq late", "dqn default", "c"]
    twins = [run("r/x", "dqn", "tuned"), run("r/y", "dqn", "tuned"), run("r/z", "dqn")]
    assert plot.default_labels(twins) == ["x", "y", "dqn default"]


@pytest.fixture
def drawn(monkeypatch, tmp_path):
    """main with load_run and draw stubbed: each load recorded, and each draw with its runs, labels,
    folder, --block and --last."""
    monkeypatch.chdir(tmp_path)
    calls = []
    monkeypatch.setattr(plot, "load_run", lambda r, need_config: calls.append(("load", r, need_config)) or r)
    monkeypatch.setattr(plot, "draw", lambda runs, labels, out, args: calls.append(
        ("draw", runs, labels, out, args.block, args.last)) or 0)
    return calls


def finished(*names):
    for name in names:
        Path(name).mkdir(parents=True, exist_ok=True)
        Path(name, "episodes.csv").write_text("")


def test_the_runs_given_are_loaded_without_needing_a_config_and_drawn_into_the_first(drawn):
    finished("runs/a", "b")
    assert plot.main(["runs/a", "b", "--labels", "one", "two"]) == 0
    assert drawn == [("load", "runs/a", False), ("load", "b", False),
                     ("draw", ["runs/a", "b"], ["one", "two"], Path("runs/a"), None, None)]
    drawn.clear()
    assert plot.main(["runs/a", "--out", "figs"]) == 0
    assert drawn[-1] == ("draw", ["runs/a"], None, Path("figs"), None, None)
    assert plot.main(["runs/a", "--block", "1", "--last", "20"]) == 0       # --block 1: the least
    assert drawn[-1] == ("draw", ["runs/a"], None, Path("runs/a"), 1, 20)


def test_without_a_run_the_newest_under_runs_is_plotted(drawn):
    finished("runs/old", "runs/new", "runs/older")
    for age, name in ((300, "old"), (0, "new"), (600, "older")):
        t = 1_700_000_000 - age
        os.utime(Path("runs", name, "episodes.csv"), (t, t))
    assert plot.main([]) == 0 and drawn[-1][1] == ["runs/new"]


@pytest.mark.parametrize("argv, words", [
    ([], "no run folder given and none found under runs/"),
    (["--block", "0", "a"], "--block must be >= 1 (episodes per plotted mean), got 0"),
    (["my run"], "my run/episodes.csv not found (run python scripts/train.py --out 'my run' first)"),
    (["a", "--labels", "x", "y"], "give one label per run (1 runs, 2 labels)"),
])
def test_what_is_refused_in_one_line(drawn, capsys, argv, words):
    finished("a")
    assert plot.main(argv) == 2 and capsys.readouterr().err == f"plot.py: error: {words}\n" and not drawn


def test_a_sweeps_folder_names_its_finished_experiments(drawn, capsys):
    Path("sw").mkdir()
    Path("sw/sweep.json").write_text("{}")
    assert plot.main(["sw"]) == 2
    assert capsys.readouterr().err == ("plot.py: error: sw is a sweep's folder and none of its experiments has finished "
                                       "yet\n")
    finished("sw/b x", "sw/a")
    assert plot.main(["sw"]) == 2
    assert capsys.readouterr().err == "plot.py: error: sw is a sweep's folder: plot its experiments, e.g. python " \
                                      "scripts/plot.py sw/a 'sw/b x'\n"
    finished("sw/c")
    assert plot.main(["sw"]) == 2                                       # three: all named, no "..."
    assert capsys.readouterr().err.endswith("e.g. python scripts/plot.py sw/a 'sw/b x' sw/c\n")
    finished("sw/d")
    assert plot.main(["sw"]) == 2
    assert capsys.readouterr().err.endswith("e.g. python scripts/plot.py sw/a 'sw/b x' sw/c ...\n")


def test_a_failure_while_drawing_is_one_line(monkeypatch, tmp_path, capsys):
    monkeypatch.chdir(tmp_path)
    finished("a")
    monkeypatch.setattr(plot, "load_run", lambda r, need_config: (_ for _ in ()).throw(ValueError("a/episodes.csv is cut")))
    assert plot.main(["a"]) == 2 and capsys.readouterr().err == "plot.py: error: a/episodes.csv is cut\n"


# ------------------------------------------------------------------ draw
@pytest.fixture
def figured(monkeypatch):
    made = []
    monkeypatch.setattr(figures, "episode_figures", lambda runs, labels, out, logy_steps: made.append(
        ("episodes", labels, out, logy_steps)) or [out / "steps_per_episode.png", out / "time_per_step.png"])
    monkeypatch.setattr(figures, "evaluation_figure", lambda runs, labels, out, column, ylabel: made.append(
        ("evaluation", column, ylabel)) or None)
    return made


def args(**kw):
    return Namespace(**{"linear": False, "block": None, "last": None, **kw})


def test_runs_of_a_domain_without_figures_get_the_generic_ones(figured, tmp_path, capsys):
    out = tmp_path / "new" / "figs"
    assert plot.draw([run("r/a", "dgpq", "late"), run("r/b")], None, out, args()) == 0
    assert out.is_dir() and figured == [("episodes", ["dgpq late", "dgpq default"], out, True),
                                        ("evaluation", "steps of square", "steps per episode")]
    assert capsys.readouterr().out == f"wrote {out}/steps_per_episode.png\nwrote {out}/time_per_step.png\n"
    plot.draw([run("r/a")], ["mine"], out, args(linear=True))
    assert figured[-2] == ("episodes", ["mine"], out, False)


def test_a_domains_own_figures_get_last_and_a_block_only_when_given(figured, tmp_path, capsys):
    own = []

    def f16_figures(drawn_runs, labels, out, last, **kw):
        own.append((drawn_runs is runs, labels, last, kw))
        return [out / "f16_reward.png"]
    runs = [run("r/a", domain="f16", figures_of_its_own=f16_figures), run("r/b", domain="f16")]
    plot.draw(runs, ["a", "b"], tmp_path, args(last=20))
    plot.draw(runs, ["a", "b"], tmp_path, args(block=5))
    assert own == [(True, ["a", "b"], 20, {}), (True, ["a", "b"], None, {"block": 5})]
    assert [m[0] for m in figured] == ["evaluation", "evaluation"]
    assert capsys.readouterr().out == f"wrote {tmp_path}/f16_reward.png\n" * 2


def test_an_evaluated_run_adds_its_figure_and_a_run_without_config_is_scored_by_return(figured, tmp_path, capsys,
                                                                                        monkeypatch):
    monkeypatch.setattr(figures, "evaluation_figure", lambda runs, labels, out, column, ylabel: figured.append(
        ("evaluation", column, ylabel)) or out / "eval_returns.png")
    plot.draw([run("r/bare", config=False)], None, tmp_path, args())
    assert figured[-1] == ("evaluation", "return", "return per episode")
    assert capsys.readouterr().out.endswith(f"wrote {tmp_path}/eval_returns.png\n")


def test_runs_of_several_domains_share_the_generic_figures_with_a_note(figured, tmp_path, capsys):
    own = []
    runs = [run("r/a", domain="square", figures_of_its_own=lambda *a, **k: own.append(1) or []),
            run("r/b", domain="gym", env_id="gym:CartPole-v1"), run("r/c", config=False)]
    plot.draw(runs, None, tmp_path, args())
    assert not own and figured[0][0] == "episodes"
    assert capsys.readouterr().err == ("note: runs of 2 domains (gym, square) share only the generic figures (steps and "
                                       "time per episode); plot each domain's runs apart for its own figures\n")
    plot.draw([run("r/a", figures_of_its_own=lambda *a, **k: own.append(1) or []), runs[2]], None, tmp_path, args())
    assert not own and capsys.readouterr().err == ""        # a run without its domain: generic, no note


def test_a_folder_that_cannot_be_made_is_named(figured, tmp_path):
    (tmp_path / "file").write_text("")
    with pytest.raises(ValueError) as err:
        plot.draw([run("r/a")], None, tmp_path / "file" / "figs", args())
    assert str(err.value).startswith(f"cannot create the folder for the figures, {tmp_path}/file/figs: ")
    assert str(err.value).endswith("(give --out a folder you can write)") and "Errno" not in str(err.value)
