"""The console entry point (``trl-dgpq`` / ``python -m trl_dgpq``) and train.py's guards."""
import json
import subprocess
import sys

import pytest

import trl_dgpq
from trl_dgpq.__main__ import main as entry
from trl_dgpq import presets
from trl_dgpq.commands import train


def test_the_entry_point_answers_help_from_the_snapshot(capsys):
    """(Usage, unknown commands and mistyped flags: test_entry_point and test_early_units.)"""
    assert entry(["train", "--help"]) == 0 and "usage: trl-dgpq train" in capsys.readouterr().out  # help.json's
    assert isinstance(trl_dgpq.__version__, str) and trl_dgpq.__version__[0].isdigit()


def test_python_dash_m_runs_from_any_folder(tmp_path):
    out = subprocess.run([sys.executable, "-m", "trl_dgpq", "--version"], cwd=tmp_path, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.startswith("trl-dgpq ")


def test_print_config_resolves_presets_and_flags_and_writes_nothing(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert train.main(["--env", "f16", "--preset", "lq10", "--eps1", "0.2", "--print-config"]) == 0
    config = json.loads(capsys.readouterr().out)
    assert config["agent"]["lipschitz"] == 10.0 and config["agent"]["eps1"] == 0.2   # preset, then the flag
    assert config["agent"]["state_scale"] == [10.0, 0.0, 20.0, 20.0, 5.0]
    assert list(tmp_path.iterdir()) == []


def test_a_very_large_seed_count_needs_a_yes(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr("sys.stdin.isatty", lambda: False)
    with pytest.raises(SystemExit) as stop:
        train.main(["--seeds", "3201", "--episodes", "1"])
    assert stop.value.code == 2 and "3201 seeds" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
    train.confirm_many(train.MANY_SEEDS, yes=False)       # the limit itself runs
    train.confirm_many(3201, yes=True)
    monkeypatch.setattr("sys.stdin.isatty", lambda: True)
    monkeypatch.setattr("builtins.input", lambda prompt: "y")
    train.confirm_many(3201, yes=False)                   # asked on a terminal, and confirmed


@pytest.mark.parametrize("command", ["plot", "report", "evaluate"])
def test_an_unwritable_or_missing_folder_is_one_line_not_a_traceback(command, tmp_path, capsys):
    from trl_dgpq.commands import evaluate, plot, report
    from tests.test_report import fake_run
    run = fake_run(tmp_path / "run", "square", {0: [30, 20]}, agent="dgpq")
    locked = tmp_path / "a-file"  # a folder under a file cannot be made, even by root
    locked.write_text("")
    main = {"plot": plot.main, "report": report.main, "evaluate": evaluate.main}[command]
    argv = {"plot": [str(run), "--out", str(locked / "figs")], "report": [str(run), "--out", str(locked / "r")],
            "evaluate": [str(run), "--no-progress"]}[command]  # evaluate: the run has no checkpoint
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "error:" in err and "Traceback" not in err


def test_sweep_into_an_unwritable_folder_is_one_line(tmp_path, capsys):
    from trl_dgpq.commands import sweep
    locked = tmp_path / "a-file"
    locked.write_text("")
    toml = tmp_path / "s.toml"
    toml.write_text('[defaults]\nseeds = 1\nepisodes = 1\n[[experiment]]\nname = "a"\nenv = "square"\n')
    assert sweep.main([str(toml), "--out", str(locked / "s")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "error:" in err


def test_a_budget_alone_is_enough_and_the_summary_says_what_terminated_means(tmp_path, capsys):
    from trl_dgpq.collectors.experiment import resolve_config
    assert resolve_config(env="corridor", env_steps=30)["run"]["episodes"] == 30   # a budget of 30 ends within 30
    assert resolve_config(env="corridor", env_steps=30, episodes=2)["run"]["episodes"] == 2
    assert resolve_config(env="corridor")["run"]["episodes"] == 50
    out = tmp_path / "run"
    assert train.main(["--env", "corridor", "--agent", "constant", "--seeds", "2", "--env-steps", "25",
                       "--out", str(out), "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "2 seeds x 25 env steps ->" in text and "terminated (reached the goal) in 100% of episodes" in text
    import pandas as pd
    df = pd.read_csv(out / "episodes.csv")
    assert (df.groupby("seed").steps.sum() >= 25).all() and (df.groupby("seed").steps.sum() < 25 + 50).all()


def test_the_progress_of_a_budget_counts_each_seeds_steps_up_to_it():
    import torch
    from trl_dgpq.collectors.online import OnlineCollector
    from trl_dgpq.envs.corridor.env import CorridorEnv
    c = OnlineCollector(CorridorEnv([0, 1]), None, episodes=5, progress=False, env_steps=10)
    c.env_steps_done = torch.tensor([4, 17])   # seed 1 ran past its budget to finish its episode
    assert c._progress() == 4 + 10
    c = OnlineCollector(CorridorEnv([0, 1]), None, episodes=5, progress=False)
    c.episode = torch.tensor([2, 3])
    assert c._progress() == 5


def test_counts_are_singular_for_one():
    from trl_dgpq.analysis import count
    assert [count(1, "seed"), count(2, "seed"), count(1000, "episode")] == ["1 seed", "2 seeds", "1,000 episodes"]


def test_the_readme_library_example_runs(capsys):
    from pathlib import Path
    text = (Path(__file__).resolve().parent.parent / "README.md").read_text()
    code = text.split("<!-- library-example -->\n```python\n", 1)[1].split("```", 1)[0]
    exec(compile(code, "README.md", "exec"), {})
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("tensor([") and len(out) == 4 and out[-1].endswith("dtype=torch.float64)")


def test_help_is_grouped_by_owner_and_presets_can_be_listed(capsys):
    with pytest.raises(SystemExit):
        train.main(["--help"])
    text = capsys.readouterr().out
    for section in ("run settings:", "DGPQ settings:", "DQN settings:", "F16 settings:", "Square settings:",
                    "settings of several envs or agents"):
        assert section in text, section
    dqn = text.split("DQN settings:")[1].split("settings:")[0]
    assert "--hidden" in dqn and "--lipschitz" not in dqn      # a flag is listed under its owner
    assert train.main(["--list-presets"]) == 0
    lines = capsys.readouterr().out.splitlines()
    start = lines.index("f16 dgpq")
    block = lines[start + 1:next(i for i in range(start + 1, len(lines)) if not lines[i].startswith("  "))]
    names = [line.split()[0] for line in block]
    assert block[0].split()[:2] == ["default", "(default)"]                                  # the default first
    tuned = presets.tuned_entries("f16").get("dgpq", {})                              # and what studies wrote
    assert set(names) == {"default", "flight", "flight-05", "flight-05-cost-shaped", "flight-05-shaped", "gamma99",
                          "gamma99-shaped", "lq10", *tuned}
    about = {line.split()[0]: line.split(None, 1)[1] for line in block}
    assert about["gamma99-shaped"].startswith("env.potential=lqr, env.potential_gamma=0.99, agent.gamma=0.99")
    assert about["gamma99-shaped"].endswith("; uses the model") and "uses the model" not in about["gamma99"]
    assert about["flight-05-tuned"].startswith("study f16-05-weights300: the best of 30 trials on seeds 1000-1004 "
                                               "validated on 1005-1014, by episode reward")
    square = lines[lines.index("square random") + 1:lines.index("square random") + 3]
    assert square == ["  shaped (default)             the defaults; uses the model",   # its default reward does
                      "  paper                        env.reward=paper"]


# ------------------------------------------------------------ --help and typos before the heavy imports
from trl_dgpq.commands import early  # noqa: E402


def test_the_help_snapshot_is_what_the_parsers_print():
    """help.json must follow every change of an option (regenerate: python scripts/docs_reference.py)."""
    assert json.loads(early.HELP_FILE.read_text()) == early.snapshot(), \
        "trl_dgpq/commands/help.json is out of date: run python scripts/docs_reference.py"


def test_help_and_a_typo_are_answered_without_importing_torch():
    """In a fresh process: --help prints the parser's own text, an unknown flag is one line and
    exit 2, and neither imports torch (seconds under load); a flag the command has goes on."""
    code = ("import sys; from trl_dgpq.commands.early import answer; "
            "rc = [answer('train', ['--help']), answer('tune', ['--env', 'square', '--bogus=3']), "
            "answer('train', ['--epis', '3', '--', '--not-a-flag'])]; "
            "print(rc, 'torch' in sys.modules, file=sys.stderr)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    lines = proc.stderr.strip().splitlines()
    assert lines[-1] == "[0, 2, None] False"
    assert lines[0] == "tune.py: error: unrecognized arguments: --bogus=3 (see tune.py --help)" and len(lines) == 2
    assert proc.stdout == early.capture("train", None).replace(str(early.CORES), "1")


def test_a_flag_given_as_flag_equals_value_goes_on_to_the_commands_parser(capsys):
    """``trl-dgpq train --seeds=0-4 --episodes=3``: argparse's --flag=value form names options
    train has, so the fast path lets it through to the parser (None), as it does a prefix with a
    value (--epis=3); only the part before "=" is matched, so a flag no option begins with is
    still refused, value and all."""
    assert early.answer("train", ["--seeds=0-4", "--episodes=3"]) is None
    assert early.answer("train", ["--epis=3", "--env", "square"]) is None
    assert capsys.readouterr().err == ""
    assert early.answer("train", ["--seeds=0-4", "--bogus=3"]) == 2
    assert capsys.readouterr().err == "train.py: error: unrecognized arguments: --bogus=3 (see train.py --help)\n"

def test_sweeps_help_shows_this_machines_cores(monkeypatch, capsys):
    monkeypatch.setattr("os.cpu_count", lambda: 48)
    assert early.answer("sweep", ["-h"]) == 0
    out = capsys.readouterr().out
    assert out == early.capture("sweep", None, cores=48) and "48" in out


# ------------------------------------------------------------ small things a new user met (issue 30)
def test_a_flag_that_means_something_else_per_config_shows_each_ones_help(capsys):
    with pytest.raises(SystemExit):
        train.main(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    reward = text.split("--reward REWARD Square: shaped")[1].split(" --")[0]   # the square's own help
    assert "; Liquidation: shortfall: minus each trade" in reward             # and liquidation's


def test_a_reward_domain_summary_gives_the_reward_and_evaluate_the_domains_format(tmp_path, capsys):
    import pandas as pd
    from trl_dgpq.envs import domain
    out = tmp_path / "f16"
    assert train.main(["--env", "f16", "--seeds", "2", "--episodes", "4", "--max-steps", "20", "--out", str(out),
                       "--no-progress"]) == 0
    text = capsys.readouterr().out
    df = pd.read_csv(out / "episodes.csv")
    first = df[df.episode <= 2]["return"].mean()
    last = df[df.episode >= 3]["return"].mean()
    assert f"episode reward, mean over seeds: first 2 episodes {first:.4g}, last 2 {last:.4g}" in text
    assert domain("liquidation").format_measure(1.23456) == "1.2346"
    assert domain("f16").format_measure(-134.44) == "-134.4"
    assert train.measure_line(df.assign(steps=1), domain("square"), None) == []   # steps: said already


def test_make_clean_keeps_the_runs():
    from pathlib import Path
    make = (Path(__file__).resolve().parent.parent / "Makefile").read_text()
    clean = make.split("\nclean:", 1)[1].split("\n\n")[0]
    assert "rm -rf" in clean and "runs" not in clean                # hours of runs are not build output


def test_plot_draws_runs_of_two_domains_on_the_generic_figures(tmp_path):
    """A real draw (test_plot_command has plot's rules with the figures stubbed): a square run and a
    CartPole run together get the steps and time figures."""
    from tests.test_report import fake_run
    from trl_dgpq.commands import plot
    square = fake_run(tmp_path / "sq", "square", {0: [5, 6]})
    gym = fake_run(tmp_path / "gym", "gym:CartPole-v1", {0: [10, 20]})
    assert plot.main([str(square), str(gym), "--out", str(tmp_path / "fig")]) == 0
    assert sorted(p.name for p in (tmp_path / "fig").glob("*.png")) == ["steps_per_episode.png", "time_per_step.png"]
