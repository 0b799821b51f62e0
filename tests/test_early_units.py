"""The early answer (trl_dgpq/commands/early.py) in this process: the help snapshot captured and
written, and ``answer``'s rules on a help file of the test's own."""
import json
import os

import pytest

import trl_dgpq.commands as commands
from trl_dgpq.commands import early

HELP = "usage: x\n\noptions:\n  -h, --help  show\n  --episodes EPISODES, --eps EPISODES\n                        n of 7919 cores\n  --seeds S   s\n  --seed S    one\n"


@pytest.fixture
def own_help(tmp_path, monkeypatch):
    path = tmp_path / "help.json"
    path.write_text(json.dumps({"train": {"trl-dgpq": HELP.replace("usage: x", "usage: trl-dgpq train"),
                                          "script": HELP}}))
    monkeypatch.setattr(early, "HELP_FILE", path)     # ENTRY: conftest's script_entry
    return path


@pytest.mark.parametrize("argv", [["-h"], ["--help"], ["--seeds", "3", "-h"]])
def test_help_is_printed_with_this_machines_cores(own_help, argv, capsys, monkeypatch):
    monkeypatch.setattr(os, "cpu_count", lambda: 3)
    assert early.answer("train", argv) == 0
    assert capsys.readouterr().out == HELP.replace("7919", "3")
    monkeypatch.setattr(os, "cpu_count", lambda: None)
    early.answer("train", argv)
    assert "n of 1 cores" in capsys.readouterr().out


def test_the_entry_points_help_when_run_as_trl_dgpq(own_help, capsys, monkeypatch):
    monkeypatch.setattr(commands, "ENTRY", "trl-dgpq")
    assert early.answer("train", ["--help"]) == 0 and capsys.readouterr().out.startswith("usage: trl-dgpq train")
    assert early.answer("train", ["--bogus"]) == 2
    assert capsys.readouterr().err == ("trl-dgpq train: error: unrecognized arguments: --bogus (see trl-dgpq train "
                                       "--help)\n")


def test_a_flag_no_option_begins_with_is_refused_with_a_guess(own_help, capsys):
    assert early.answer("train", ["--seedz=4", "--episodes", "2", "--nothing-like-it"]) == 2
    assert capsys.readouterr().err == ("train.py: error: unrecognized arguments: --seedz=4 --nothing-like-it; did you "
                                       "mean --seed? (see train.py --help)\n")


def test_one_guess_a_flag_close_enough_to_an_option(own_help, capsys):
    """--seedz is closest to --seed (--seeds is close too: one guess); --seedz=444 is read as --seedz;
    --epixodxx is not close enough (below 0.75) to --episodes; --hexp is to --help."""
    assert early.answer("train", ["--seedz=444", "--epixodxx", "--hexp"]) == 2
    assert capsys.readouterr().err == ("train.py: error: unrecognized arguments: --seedz=444 --epixodxx --hexp; "
                                       "did you mean --seed --help? (see train.py --help)\n")


def test_prefixes_values_and_what_follows_dashes_go_on(own_help, capsys):
    assert early.answer("train", ["--epi", "3", "--seeds=2", "-x"]) is None
    assert early.answer("train", ["--", "--bogus", "-h"]) is None
    assert capsys.readouterr() == ("", "")


def test_without_a_help_file_or_an_entry_the_command_answers(own_help, monkeypatch):
    assert early.answer("plot", ["--help"]) is None                       # not in the file
    own_help.write_text("not json")
    assert early.answer("train", ["--help"]) is None
    monkeypatch.setattr(early, "HELP_FILE", own_help.parent / "absent.json")
    assert early.answer("train", ["--bogus"]) is None


def test_options_are_the_long_flags_of_option_lines():
    assert early.options(HELP) == ["--episodes", "--eps", "--help", "--seed", "--seeds"]
    assert early.options("usage: x [--not-an-option]\n  text --neither\n") == []


def test_capture_prints_a_commands_help_at_100_columns_and_puts_everything_back(monkeypatch):
    monkeypatch.setattr(commands, "ENTRY", "before")
    monkeypatch.setenv("COLUMNS", "33")
    text = early.capture("report", "trl-dgpq", cores=5)
    # wrapped at 100 columns, not at COLUMNS' 33 (which leaves report's longest line at 90)
    assert text.startswith("usage: trl-dgpq report") and 90 < max(map(len, text.splitlines())) <= 100
    assert commands.ENTRY == "before" and os.environ["COLUMNS"] == "33"
    assert early.capture("report", None).startswith("usage: report.py")
    monkeypatch.delenv("COLUMNS")
    early.capture("report", None)
    assert "COLUMNS" not in os.environ
    assert "7919" in early.capture("sweep", None) and "(default: the cores, 5)" in early.capture("sweep", None, cores=5)


def test_main_writes_the_snapshot_sorted_and_says_where(tmp_path, monkeypatch, capsys):
    path = tmp_path / "help.json"
    monkeypatch.setattr(early, "HELP_FILE", path)
    monkeypatch.setattr(early, "snapshot", lambda: {"b": {"script": "2"}, "a": {"trl-dgpq": "1", "script": "0"}})
    assert early.main() == 0
    assert path.read_text() == '{\n "a": {\n  "script": "0",\n  "trl-dgpq": "1"\n },\n "b": {\n  "script": "2"\n }\n}\n'
    assert capsys.readouterr().out == f"wrote {path}\n"
