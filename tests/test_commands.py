"""The console entry point (``trl-dgpq`` / ``python -m trl_dgpq``) and train.py's guards."""
import json
import subprocess
import sys

import pytest

import trl_dgpq
from trl_dgpq.__main__ import main as entry
from trl_dgpq.commands import train


def test_the_entry_point_lists_and_dispatches_commands(capsys):
    assert entry([]) == 0 and "reproduce" in capsys.readouterr().out
    assert entry(["nope"]) == 2 and "unknown command 'nope'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as stop:
        entry(["train", "--help"])
    assert stop.value.code == 0 and "usage: trl-dgpq train" in capsys.readouterr().out
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
