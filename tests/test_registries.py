"""The registries and the commands' shared helpers by hand: agents' and envs' names, classes and
refusals word for word (trl_dgpq/agents/__init__.py, envs/__init__.py), the gymnasium family's
presets and words for an id without its own (envs/gym/__init__.py), and how a command names
itself, quotes a path, is run and ends (trl_dgpq/commands/__init__.py)."""
import sys
import types
from pathlib import Path

import pytest
import torch

import trl_dgpq.commands
from trl_dgpq.agents import AGENTS, agent_class, agent_names, check_agent_name
from trl_dgpq.envs import DOMAINS, domain, make_env, split_name

ENVS = "square, liquidation, push, gym:CartPole-v1"   # the start of the list of examples


def test_an_agent_is_found_by_its_name_and_an_unknown_one_refused_naming_every_agent():
    from trl_dgpq.agents.random import RandomAgent
    from trl_dgpq.dgpq import DGPQ
    assert agent_class("dgpq") is DGPQ and agent_class("random", "square") is RandomAgent
    names = agent_names()
    assert names[:len(AGENTS)] == list(AGENTS) and "oracle" in names and "twap" in names
    assert check_agent_name("td3") == "td3"
    for bad in ("nope", "DGPQ", 3, None):
        with pytest.raises(ValueError) as refused:
            check_agent_name(bad)
        assert str(refused.value) == f"agent must be one of {names}, got {bad!r}"
    with pytest.raises(ValueError) as refused:
        agent_class("nope", "square")
    assert str(refused.value) == f"agent must be one of {names}, got 'nope'"


def test_a_domains_own_agent_runs_only_on_that_domains_envs():
    twap = domain("liquidation").baseline("twap")
    assert agent_class("twap", "liquidation") is twap and agent_class("twap") is twap
    with pytest.raises(ValueError) as refused:
        agent_class("twap", "square")
    assert str(refused.value) == "twap is a baseline of the liquidation domain: use --env liquidation"


def test_an_env_name_splits_into_domain_and_id_and_an_unknown_one_is_refused_with_the_choices():
    assert split_name("gym:CartPole-v1") == ("gym", "CartPole-v1") and split_name("square") == ("square", None)
    assert split_name("gym:") == ("gym", "") and split_name("a:b:c") == ("a", "b:c")
    with pytest.raises(ValueError) as refused:
        split_name(3)
    assert str(refused.value) == "env must be text, got 3"
    assert domain("square").name == "square" and domain("gym:Acrobot-v1").name == "gym" and len(DOMAINS) == 6
    with pytest.raises(ValueError) as refused:
        domain("sqare")
    words = str(refused.value)
    assert words.startswith(f"unknown env 'sqare'; choose from {ENVS}, ") and "corridor" in words
    assert words.endswith(", f16 (gym:ID: any gymnasium id with discrete actions)")


def test_make_env_builds_the_named_env_for_the_seeds_on_the_device_given():
    from trl_dgpq.envs.square.env import SquareConfig
    env = make_env("square", SquareConfig(), [3, 4])
    assert type(env).__name__ == "SquareEnv" and env.seeds == [3, 4] and env.device == torch.device("cpu")
    with pytest.raises(RuntimeError):
        make_env("square", SquareConfig(), [0], device="nowhere")


def test_a_gymnasium_id_without_presets_runs_dqn_on_raw_observations_and_others_on_defaults():
    gym = domain("gym:CartPole-v1")
    presets = gym.module("presets")
    assert gym.presets("dqn", "Pong-v5") == presets.FALLBACK["dqn"] == {"default": {"env": presets.RAW}}
    assert gym.presets("dgpq", "Pong-v5") == {"default": {}} and gym.presets("random", None) == {"default": {}}
    assert gym.presets("dqn", "CartPole-v1") == presets.PRESETS["CartPole-v1"]["dqn"]
    terminated = gym.analysis().TERMINATED
    assert gym.terminated_means("Pong-v5") == "ended by gymnasium, not the step cap"
    for env_id, words in terminated.items():
        assert gym.terminated_means(env_id) == words
    assert gym.terminated_means() == "ended by gymnasium, not the step cap"


def test_a_command_names_itself_and_its_neighbours_as_it_was_run(monkeypatch):
    from trl_dgpq.commands import command, prog, quote
    assert prog("train") == "train.py" and command("plot") == "python scripts/plot.py"
    monkeypatch.setattr(trl_dgpq.commands, "ENTRY", "trl-dgpq")
    assert prog("train") == "trl-dgpq train" and command("plot") == "trl-dgpq plot"
    assert quote(Path("runs/a b")) == "'runs/a b'" and quote("plain/path") == "plain/path"
    assert quote("it's") == "'it'\"'\"'s'"


def fake_command(monkeypatch, main):
    module = types.ModuleType("trl_dgpq.commands.fake")
    module.main = main
    monkeypatch.setitem(sys.modules, "trl_dgpq.commands.fake", module)


def test_run_hands_the_command_its_arguments_or_the_processs(monkeypatch):
    from trl_dgpq.commands import run
    got = []
    fake_command(monkeypatch, lambda argv: got.append(argv) or 7)
    assert run("fake", ("--a", "1")) == 7 and got == [["--a", "1"]]
    monkeypatch.setattr(sys, "argv", ["fake.py", "--b", "2"])
    assert run("fake") == 7 and got[-1] == ["--b", "2"]
    assert run("train", ["--help"]) == 0                       # (answered by commands.early: test_commands)


def test_guarded_ends_a_bad_request_with_2_and_ctrl_c_with_130_in_one_line(capsys):
    from trl_dgpq.commands import guarded
    assert guarded("train", lambda: 5) == 5

    def fails(err):
        def body():
            raise err
        return body
    assert guarded("train", fails(ValueError("no such preset"))) == 2
    assert capsys.readouterr() == ("", "train.py: error: no such preset\n")
    assert guarded("plot", fails(FileNotFoundError(2, "No such file or directory", "x.csv"))) == 2
    assert capsys.readouterr().err == "plot.py: error: [Errno 2] No such file or directory: 'x.csv'\n"
    assert guarded("sweep", fails(KeyboardInterrupt())) == 130
    assert capsys.readouterr() == ("", "sweep.py: interrupted\n")
    with pytest.raises(RuntimeError):
        guarded("train", fails(RuntimeError("a bug")))      # a bug keeps its traceback
