"""The ``trl-dgpq`` entry point (trl_dgpq/__main__.py) in this process: its usage text in full, help
and version, an unknown command in one line, and a command handed its arguments under its name."""
import sys

import pytest

import trl_dgpq
import trl_dgpq.commands
from trl_dgpq import __main__ as entry

USAGE = (f"usage: trl-dgpq COMMAND [--help] ...   (trl-dgpq {trl_dgpq.__version__})\n\ncommands:\n"
         "  train      train one experiment (many seeds, batched in one process)\n"
         "  sweep      many experiments on a pool of processes or a Ray cluster\n"
         "  evaluate   a trained run's agents on new episodes, exploration off (eval.csv)\n"
         "  plot       figures of one or more run folders\n"
         "  report     learners compared by environment steps, from run folders\n"
         "  reproduce  every experiment of the reproduction, then REPORT.md\n"
         "  tune       an agent's settings tuned by Optuna on one env, every trial the same budget\n"
         "\ntrl-dgpq COMMAND --help shows a command's options.")


@pytest.mark.parametrize("argv", [[], ["-h"], ["--help"], ["--help", "train"]])
def test_no_command_or_help_prints_the_usage(argv, capsys):
    assert entry.main(argv) == 0
    assert capsys.readouterr().out == USAGE + "\n"


def test_the_version(capsys):
    assert entry.main(["--version"]) == 0
    assert capsys.readouterr().out == f"trl-dgpq {trl_dgpq.__version__}\n"


def test_the_arguments_default_to_the_command_lines(monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["trl-dgpq", "--version"])
    assert entry.main() == 0 and capsys.readouterr().out.startswith("trl-dgpq ")


def test_an_unknown_command_is_one_line_and_exit_2(capsys):
    assert entry.main(["trian", "--help"]) == 2
    assert capsys.readouterr().err == ("trl-dgpq: unknown command 'trian'; one of train, sweep, evaluate, plot, report, "
                                       "reproduce, tune\n")


def test_a_command_gets_its_arguments_under_the_entry_points_name(monkeypatch):
    ran = []
    monkeypatch.setattr(trl_dgpq.commands, "run", lambda name, rest: ran.append((name, rest, trl_dgpq.commands.ENTRY)) or 7)
    assert entry.main(["report", "a", "--budget", "3"]) == 7
    assert ran == [("report", ["a", "--budget", "3"], "trl-dgpq")]
