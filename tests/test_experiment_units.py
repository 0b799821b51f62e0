"""collectors/experiment.py rule by rule, without a learning run: seeds in every form and each
refusal's words, which section a setting belongs to, a recorded config as the base, the memory
checks with the machine's numbers stubbed, and the flags' owners."""
from types import SimpleNamespace

import pytest
import torch

from trl_dgpq.collectors import experiment
from trl_dgpq.collectors.experiment import (RunConfig, describe, load_sections, parse_seeds, resolve_config,
                                            run_settings, split_overrides)
from trl_dgpq.envs.corridor.env import CorridorEnv
from trl_dgpq.envs.liquidation.env import LiquidationEnv
from trl_dgpq.agents.constant import ConstantAgent
from trl_dgpq.dgpq import DGPQ


@pytest.mark.parametrize("given, seeds", [
    ("3", [0, 1, 2]), (" 1 ", [0]), (2, [0, 1]), ("3-5", [3, 4, 5]), ("7 - 7", [7]), ("1,5,9", [1, 5, 9]),
    ("4, 2,", [4, 2]), ([3, 1], [3, 1]), ((0,), [0]), (range(2, 4), [2, 3]),
])
def test_seeds_are_a_count_a_range_or_a_list(given, seeds):
    assert parse_seeds(given) == seeds


@pytest.mark.parametrize("given, words", [
    ("0", "seeds count must be >= 1"),
    (0, "seeds count must be >= 1"),
    ("5-3", "seeds range '5-3' is empty"),
    ("1,1", "seeds [1, 1] repeat a seed"),
    ([], "seeds must be non-negative integers, got []"),
    ([1, -2], "seeds must be non-negative integers, got [1, -2]"),
    ([True], "seeds must be non-negative integers, got [True]"),
    ([1.0], "seeds must be non-negative integers, got [1.0]"),
    ("a-b", "seeds must be a count N, a range A-B or a comma list, got 'a-b'"),
    ("1,,2", "seeds must be a count N, a range A-B or a comma list, got '1,,2'"),
    ("-3", "seeds must be a count N, a range A-B or a comma list, got '-3'"),
    ("x", "seeds must be a count N, a range A-B or a comma list, got 'x'"),
    ("5-2", "seeds range '5-2' is empty"),
])
def test_bad_seeds_are_refused_in_words(given, words):
    with pytest.raises(ValueError) as err:
        parse_seeds(given)
    assert str(err.value) == words


def test_a_setting_goes_to_its_section_by_name_path_or_section():
    got = split_overrides({"episodes": 3, "slip": 0.2, "agent.action": "1", "run.seeds": "2", "env.length": 4},
                          CorridorEnv, ConstantAgent)
    assert got == {"run": {"episodes": 3, "seeds": "2"}, "env": {"slip": 0.2, "length": 4}, "agent": {"action": "1"}}
    assert split_overrides({}, CorridorEnv, ConstantAgent) == {"run": {}, "env": {}, "agent": {}}
    nested = split_overrides({"gp.noise_var": 0.1, "agent.gp": "sparse", "agent.gp.budget": 5}, CorridorEnv, DGPQ)
    assert nested["agent"] == {"noise_var": 0.1, "gp": "sparse", "budget": 5}


def test_an_unknown_or_ambiguous_setting_is_refused_in_words():
    with pytest.raises(ValueError) as err:
        split_overrides({"slipp": 1}, CorridorEnv, ConstantAgent)
    assert str(err.value) == "unknown setting 'slipp' for env CorridorEnv and agent ConstantAgent"
    with pytest.raises(ValueError) as err:
        split_overrides({"agent.slip": 1}, CorridorEnv, ConstantAgent)
    assert str(err.value) == "unknown setting 'agent.slip' for env CorridorEnv and agent ConstantAgent (did you mean 'slip'?)"
    with pytest.raises(ValueError) as err:
        split_overrides({"agent.nothing": 1}, CorridorEnv, ConstantAgent)
    assert str(err.value) == "unknown setting 'agent.nothing' for env CorridorEnv and agent ConstantAgent"


def test_a_setting_two_sections_have_must_name_its_section():
    class Both:
        Config = RunConfig          # every run setting also an agent's
    with pytest.raises(ValueError) as err:
        split_overrides({"episodes": 3}, CorridorEnv, Both)
    assert str(err.value) == "setting 'episodes' is ambiguous: say run.episodes or agent.episodes"
    assert split_overrides({"run.episodes": 3}, CorridorEnv, Both)["run"] == {"episodes": 3}


def test_the_run_settings_are_picked_out_first():
    assert run_settings({"episodes": 3, "run.env": "corridor", "slip": 0.1, "run.gp.kind": "x", "gp.kind": "y",
                         "agent.episodes": 2}) == {"episodes": 3, "env": "corridor"}


def test_a_budget_alone_sets_the_episode_cap_and_a_preset_is_named():
    config = resolve_config(env="corridor", agent="constant", env_steps=30)
    assert config["run"]["episodes"] == 30 and config["run"]["preset"] == "default"
    assert resolve_config(env="corridor", agent="constant", env_steps=30, episodes=2)["run"]["episodes"] == 2
    assert resolve_config({"env": "corridor"}, agent="constant", slip=0.3)["env"]["slip"] == 0.3   # both forms


def test_a_recorded_config_keeps_its_settings_and_its_env_and_agent():
    base = resolve_config(env="corridor", agent="constant", length=5, action="1", seeds="3", episodes=4)
    again = resolve_config({"episodes": 9, "env_steps": 100}, base=base)
    assert again["env"] == base["env"] and again["agent"] == base["agent"] and again["run"]["episodes"] == 9
    assert again["run"]["seeds"] == [0, 1, 2] and again["run"]["env_steps"] == 100
    for other in ({"env": "square"}, {"agent": "random"}):
        with pytest.raises(ValueError) as err:
            resolve_config(other, base=base)
        assert str(err.value) == "a recorded config keeps its env and agent; start a new run to change them"


def test_an_agent_the_env_cannot_take_says_why():
    with pytest.raises(ValueError) as err:               # no preset of the pair: the agent says why
        resolve_config(env="corridor", agent="ddpg")
    assert str(err.value) == "ddpg needs a continuous (Bounded) action spec; this env's is Categorical"


def test_a_configs_sections_are_checked_and_made_into_objects():
    config = resolve_config(env="corridor", agent="constant", action="right", seeds="2")
    run, env_cfg, agent_cfg = load_sections({**config, "versions": {}, "git": "x", "lengthened": [],
                                             "model_knowledge": []})
    assert (run.env, run.seeds, env_cfg.length, agent_cfg.action) == ("corridor", (0, 1), 10, "right")
    for bad in ({k: v for k, v in config.items() if k != "agent"}, {**config, "extra": 1}):
        with pytest.raises(ValueError) as err:
            load_sections(bad)
        assert str(err.value) == f"a config needs sections ['run', 'env', 'agent'], got {sorted(bad)}"
    assert describe(config) == "corridor/constant/default"


def test_build_makes_the_configs_seeds_or_the_given_ones_on_the_device():
    config = resolve_config(env="corridor", agent="random", seeds="3-4")
    env, agent = experiment.build(config)
    assert env.seeds == [3, 4] and agent.rng.key.shape == (2,)
    env, agent = experiment.build(config, seeds=[7])
    assert env.seeds == [7] and agent.act(None).shape == (1,) and env.device == torch.device("cpu")


def test_use_threads_sets_torchs_and_a_config_without_them_leaves_them(monkeypatch):
    set_to = []
    monkeypatch.setattr(torch, "set_num_threads", set_to.append)
    experiment.use_threads({"run": {"threads": "3"}})
    experiment.use_threads({"run": {}})
    experiment.use_threads({"run": {"threads": 0}})
    assert set_to == [3]


def test_the_memory_a_run_needs_is_refused_past_what_is_available(monkeypatch):
    config = resolve_config(env="corridor", agent="dgpq", seeds="4")
    need = experiment.memory_estimate(config)
    # DGPQ's state is per seed: twice the seeds, twice the bytes
    assert need > 0 and experiment.memory_estimate(resolve_config(env="corridor", agent="dgpq", seeds="8")) == 2 * need
    monkeypatch.setattr(experiment, "available_memory", lambda: need)
    experiment.check_memory(config)                                     # exactly enough
    monkeypatch.setattr(experiment, "available_memory", lambda: need - 1)
    with pytest.raises(ValueError) as err:
        experiment.check_memory(config)
    assert str(err.value) == (f"this run needs about {need / 2**30:.3g} GiB for its agents' state at the start, "
                              f"{(need - 1) / 2**30:.3g} GiB is available: fewer seeds, a smaller budget or capacity")
    monkeypatch.setattr(experiment, "available_memory", lambda: None)
    experiment.check_memory(config)                                     # unknown: not refused


def test_this_machines_memory_and_this_processs_are_read(monkeypatch):
    import io
    assert experiment.resident_bytes() > 2**20
    meminfo = "MemTotal:       24684144 kB\nMemFree:        19981276 kB\nMemAvailable:   22649748 kB\n"
    monkeypatch.setattr(experiment, "open", lambda path: io.StringIO(meminfo) if path == "/proc/meminfo"
                        else pytest.fail(path), raising=False)
    assert experiment.available_memory() == 22649748 * 1024
    monkeypatch.setattr(experiment, "open", lambda path: io.StringIO(meminfo.replace("MemAvailable", "Other")),
                        raising=False)
    assert experiment.available_memory() is None                     # an old kernel's file: unknown

    def unreadable(path):
        raise PermissionError(path)
    monkeypatch.setattr(experiment, "open", unreadable, raising=False)
    assert experiment.available_memory() is None


def test_the_memory_guard_names_what_a_growth_would_pass(monkeypatch):
    assert experiment.memory_guard(SimpleNamespace(), 1.0) is None           # storage that never grows
    growth = {"bytes": 0}
    check = experiment.memory_guard(SimpleNamespace(growth_bytes=lambda: growth["bytes"]), max_gib=1.0)
    monkeypatch.setattr(experiment, "available_memory", lambda: 2**30)
    monkeypatch.setattr(experiment, "resident_bytes", lambda: 2**29)
    check()                                                                # no growth
    growth["bytes"] = 2**29
    check()                                                                # 0.5 + 0.5 GiB: at the limit, not past
    growth["bytes"] = 2**29 + 1
    with pytest.raises(experiment.MemoryLimit) as err:
        check()
    assert str(err.value) == ("the agents' storage must grow by 0.5 GiB, past --max-memory 1 GiB (this process "
                              "holds 0.5); continue with fewer seeds per run, a smaller budget, the sparse GP (--gp "
                              "sparse), or more --max-memory")
    growth["bytes"] = 2**30 + 1
    with pytest.raises(experiment.MemoryLimit, match=r"grow by 1 GiB, past 1 GiB available and --max-memory 1 GiB"):
        check()
    unlimited = experiment.memory_guard(SimpleNamespace(growth_bytes=lambda: 2**30), max_gib=0.0)
    unlimited()                                                            # no limit of its own; 1 GiB available
    monkeypatch.setattr(experiment, "available_memory", lambda: None)
    experiment.memory_guard(SimpleNamespace(growth_bytes=lambda: 2**40), max_gib=0.0)()   # nothing known: go on
    assert issubclass(experiment.MemoryLimit, ValueError)


def test_every_flag_names_each_config_that_has_it():
    owners = experiment.cli_owners()
    assert {"SquareConfig", "LiquidationConfig"} <= {name for name, _ in owners["reward"]}
    assert [name for name, _ in owners["episodes"]] == ["RunConfig"]
    leaves = experiment.cli_leaves()
    # the first owner's leaf: the square's reward (default "shaped"), not the liquidation's ("shortfall")
    assert leaves["reward"].field.default == "shaped" and set(leaves) == set(owners)
    assert leaves["episodes"].field.default == 50


def test_run_experiment_gives_a_row_per_episode_and_its_step_time(monkeypatch):
    closed = []
    config = resolve_config(env="corridor", agent="constant", action="right", slip=0.0, length=3, seeds="2",
                            episodes=2)
    real = experiment.build

    def build(config, seeds=None):
        env, agent = real(config, seeds)
        env.close = lambda raise_if_closed: closed.append(raise_if_closed)
        return env, agent
    monkeypatch.setattr(experiment, "build", build)
    df = experiment.run_experiment(config, progress=False)
    assert len(df) == 4 and (df.steps == 2).all() and len(df.attrs["step_seconds"]) == 4 and closed == [False]
    assert sorted(experiment.run_experiment(config, progress=False, seeds=[5]).seed.unique()) == [5]


def test_a_domains_own_agent_is_refused_on_another_domains_env():
    with pytest.raises(ValueError) as err:
        experiment.classes({"env": "square", "agent": "twap"})
    assert str(err.value) == "twap is a baseline of the liquidation domain: use --env liquidation"
    assert experiment.classes({"env": "liquidation", "agent": "twap"})[0] is LiquidationEnv


def test_a_hint_names_the_last_part_of_a_dotted_setting():
    with pytest.raises(ValueError) as err:
        split_overrides({"agent.foo.slip": 1}, CorridorEnv, ConstantAgent)
    assert str(err.value).endswith("(did you mean 'slip'?)")


def test_the_memory_estimate_is_of_the_configs_env():
    few = resolve_config(env="liquidation", agent="dgpq", action_levels=5, seeds="2")
    many = resolve_config(env="liquidation", agent="dgpq", action_levels=21, seeds="2")
    assert experiment.memory_estimate(many) > experiment.memory_estimate(few) > 0


class Lines:
    """A file of the given text, for ``open`` of the one path allowed."""
    def __init__(self, path, text):
        self.path, self.text = path, text

    def __call__(self, path, *args):
        if path != self.path:
            raise OSError(f"no {path}")
        import io
        return io.StringIO(self.text)


def test_available_memory_is_meminfos_line_in_bytes(monkeypatch):
    monkeypatch.setattr(experiment, "open", Lines("/proc/meminfo", "MemTotal: 100 kB\nMemFree: 2 kB\n"
                                                                    "MemAvailable:    3 kB\n"), raising=False)
    assert experiment.available_memory() == 3 * 1024
    monkeypatch.setattr(experiment, "open", Lines("/proc/meminfo", "MemTotal: 100 kB\n"), raising=False)
    assert experiment.available_memory() is None
    monkeypatch.setattr(experiment, "open", Lines("/elsewhere", ""), raising=False)
    assert experiment.available_memory() is None


def test_resident_bytes_are_statms_second_field_in_pages(monkeypatch):
    import os
    monkeypatch.setattr(experiment, "open", Lines("/proc/self/statm", "10 20 30 40"), raising=False)
    assert experiment.resident_bytes() == 20 * os.sysconf("SC_PAGE_SIZE")
    for broken in (Lines("/elsewhere", ""), Lines("/proc/self/statm", "10"), Lines("/proc/self/statm", "a b")):
        monkeypatch.setattr(experiment, "open", broken, raising=False)
        assert experiment.resident_bytes() == 0


def test_quiet_torchrl_leaves_its_warnings_only():
    import logging
    logging.getLogger("torchrl").setLevel(logging.DEBUG)
    experiment.quiet_torchrl()
    assert logging.getLogger("torchrl").level == logging.WARNING


def test_run_experiment_keeps_a_budget_a_step_cap_and_no_progress_bar(capfd):
    config = resolve_config(env="corridor", agent="constant", action="right", slip=0.0, length=3, seeds="2",
                            episodes=5, env_steps=4)
    capfd.readouterr()
    df = experiment.run_experiment(config, progress=False)
    assert len(df) == 4 and capfd.readouterr().err == ""               # two 2-step episodes a seed: 4 steps
    assert len(experiment.run_experiment(config, progress=False, max_total_steps=2)) == 2
