"""train's command (commands/train.py) with the runner stubbed: what it hands the runner for a
new, a resumed and a lengthened run, each refusal in one line, what it prints at each end, and
its helpers (flags from the config dataclasses, lengths, --set, negative lists, the summary)
checked by hand."""
import argparse
import json
from types import SimpleNamespace

import pandas as pd
import pytest

from trl_dgpq.collectors import runner
from trl_dgpq.commands import train


class Folder:
    """A run folder as train uses one: its path, released once when a resume is refused."""

    def __init__(self, path):
        self.path, self.released = path, 0

    def release(self):
        self.released += 1


ROWS = pd.DataFrame({"seed": [0, 0, 0, 1, 1, 1], "episode": [1, 2, 3, 1, 2, 3], "steps": [10, 8, 4, 20, 6, 2],
                     "terminated": [True, True, False, True, False, False],
                     "wall_s": [0.5] * 6, "cpu_s": [0.25] * 6})


@pytest.fixture
def ran(monkeypatch):
    """The runner stubbed: ``calls`` records what train hands it, ``outcome`` what a run does."""
    calls, outcome = [], {}

    def create(out, name, overwrite=False):
        calls.append(("create", out, name, overwrite))
        return Folder(out or f"runs/{name}")

    def existing(path):
        calls.append(("existing", path))
        return Folder(path)

    def start(config, folder, progress=True):
        calls.append(("start", config, folder.path, progress))
        if "raise" in outcome:
            raise outcome["raise"](folder)
        return ROWS.copy()

    def resume(folder, config, progress=True):
        calls.append(("resume", config, folder.path, progress))
        return ROWS.copy()

    def resumable(folder, lengthen=False):
        calls.append(("resumable", folder.path, lengthen))
        if "refuse" in outcome:
            raise outcome["refuse"]
        return {"run": {"env": "square", "agent": "random", "seeds": [0, 1], "episodes": 3, "env_steps": None}}

    def lengthen(folder, config, **lengths):
        calls.append(("lengthen", folder.path, config["run"]["episodes"], lengths))
        return {"run": {**config["run"], **{k: int(v) for k, v in lengths.items()}}}

    monkeypatch.setattr(runner.RunFolder, "create", staticmethod(create))
    monkeypatch.setattr(runner.RunFolder, "existing", staticmethod(existing))
    monkeypatch.setattr(runner, "start", start)
    monkeypatch.setattr(runner, "resume", resume)
    monkeypatch.setattr(runner, "resumable_config", resumable)
    monkeypatch.setattr(runner, "lengthen", lengthen)
    monkeypatch.setattr(runner, "check_memory", lambda config: calls.append(("memory", config["run"]["seeds"])))
    monkeypatch.setattr(runner, "disk_note", lambda config: "checkpoints up to ~1 MB")
    return SimpleNamespace(calls=calls, outcome=outcome)


def refused(capsys, *argv) -> str:
    """The one line of a refusal (exit 2, nothing on stdout)."""
    with pytest.raises(SystemExit) as exc:
        train.main(list(argv))
    err = capsys.readouterr()
    assert exc.value.code == 2 and err.out == "" and err.err.count("\n") == 1, err
    return err.err


# ---------------------------------------------------------------- a new run


def test_a_new_run_is_resolved_created_started_and_summarised(ran, capsys):
    assert train.main(["--agent", "random", "--seeds", "0-1", "--episodes", "3", "--out", "o d", "--no-progress",
                       "--set", " env.noise = 0.02"]) == 0
    kinds = [c[0] for c in ran.calls]
    assert kinds == ["memory", "create", "start"]
    assert ran.calls[0] == ("memory", [0, 1])
    assert ran.calls[1] == ("create", "o d", "square-random-shaped", False)
    config = ran.calls[2][1]
    assert config["run"]["agent"] == "random" and config["run"]["episodes"] == 3 and config["env"]["noise"] == 0.02
    assert ran.calls[2][2:] == ("o d", False)                      # --no-progress: no bar
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "square/random/shaped: 2 seeds x 3 episodes -> o d; checkpoints up to ~1 MB"
    assert out[-1] == "wrote o d/episodes.csv; plot: python scripts/plot.py 'o d'"


def test_a_run_shows_a_progress_bar_and_overwrites_only_when_asked(ran, capsys):
    assert train.main(["--agent", "random", "--seeds", "1", "--episodes", "1", "--overwrite"]) == 0
    assert ran.calls[1] == ("create", None, "square-random-shaped", True) and ran.calls[2][3] is True
    assert capsys.readouterr().out.startswith("square/random/shaped: 1 seed x 1 episode -> runs/square-random-shaped; ")


def test_a_budget_of_env_steps_is_said_with_its_cap_when_it_binds(ran, capsys):
    assert train.main(["--agent", "random", "--seeds", "1", "--env-steps", "2000", "--episodes", "40"]) == 0
    assert "1 seed x 2,000 env steps (at most 40 episodes) -> " in capsys.readouterr().out


def test_a_recorded_config_is_the_base_and_flags_go_on_top(ran, tmp_path, capsys):
    recorded = tmp_path / "config.json"
    train.main(["--agent", "random", "--seeds", "1", "--episodes", "2", "--print-config"])
    recorded.write_text(capsys.readouterr().out)
    assert train.main(["--config", str(recorded), "--episodes", "5"]) == 0
    config = ran.calls[-1][1]
    assert config["run"]["agent"] == "random" and config["run"]["episodes"] == 5 and config["run"]["seeds"] == [0]


def test_print_config_prints_the_resolved_config_and_runs_nothing(ran, capsys):
    assert train.main(["--agent", "random", "--seeds", "2-3", "--print-config"]) == 0
    printed = capsys.readouterr().out
    assert json.loads(printed)["run"]["seeds"] == [2, 3] and printed.startswith('{\n  "run"') and ran.calls == []


def test_a_config_that_cannot_be_read_is_one_line(ran, tmp_path, capsys):
    line = refused(capsys, "--config", str(tmp_path / "nowhere.json"))
    assert line.startswith(f"train.py: error: cannot read --config {tmp_path / 'nowhere.json'}: ")
    (tmp_path / "bad.json").write_text("{")
    assert "cannot read --config" in refused(capsys, "--config", str(tmp_path / "bad.json"))
    assert ran.calls == []


def test_a_bad_setting_is_refused_before_any_work(ran, capsys):
    assert refused(capsys, "--episodes", "0").startswith("train.py: error: ")
    assert "--set wants KEY=VALUE, got 'noise'" in refused(capsys, "--set", "noise")
    assert "--set wants KEY=VALUE, got ' =1'" in refused(capsys, "--set", " =1")
    assert ran.calls == []


def test_many_seeds_run_with_yes_without_asking(ran, monkeypatch):
    monkeypatch.setattr("sys.stdin.isatty", lambda: False)      # (refused without --yes: test_commands')
    assert train.main(["--agent", "random", "--seeds", "0-256", "--episodes", "1", "--yes"]) == 0
    assert ran.calls[0] == ("memory", list(range(257)))


@pytest.mark.parametrize("n, yes, answer, ok", [(256, False, None, True), (257, True, None, True),
                                                 (257, False, "y", True), (257, False, " YES ", True),
                                                 (257, False, "n", False), (257, False, "", False)])
def test_confirm_many_asks_on_a_terminal_above_256(monkeypatch, n, yes, answer, ok):
    asked = []
    monkeypatch.setattr("sys.stdin.isatty", lambda: answer is not None)
    monkeypatch.setattr("builtins.input", lambda q: asked.append(q) or answer)
    if ok:
        train.confirm_many(n, yes)
    else:
        with pytest.raises(ValueError, match=r"^257 seeds in one run \(a range is A-B, e.g. --seeds 3-201\): not "
                                             r"confirmed; add --yes to run that many$"):
            train.confirm_many(n, yes)
    assert asked == ([f"{n} seeds in one run (a range is A-B, e.g. --seeds 3-201): go on? [y/N] "]
                     if answer is not None and n > 256 and not yes else [])


def test_an_interrupted_run_says_how_to_continue_and_exits_with_its_signal(ran, capsys):
    ran.outcome["raise"] = lambda folder: runner.Interrupted(15, folder, 7)
    assert train.main(["--agent", "random", "--seeds", "0-2", "--episodes", "3", "--out", "a b"]) == 143
    err = capsys.readouterr().err
    assert err == ("interrupted by SIGTERM after 7 episodes summed over 3 seeds; checkpoint saved. Continue with: "
                   "python scripts/train.py --resume 'a b'\n")


def test_ctrl_c_before_the_run_started_is_one_line_and_130(monkeypatch, capsys):
    def stop(argv):
        raise KeyboardInterrupt
    monkeypatch.setattr(train, "_main", stop)
    assert train.main([]) == 130
    assert capsys.readouterr().err == "interrupted before the run started\n"


def test_a_value_error_of_the_run_is_one_line_and_2(ran, capsys):
    ran.outcome["raise"] = lambda folder: ValueError("the env refused")
    with pytest.raises(SystemExit) as exc:
        train.main(["--agent", "random", "--seeds", "1", "--episodes", "1"])
    assert exc.value.code == 2 and capsys.readouterr().err == "train.py: error: the env refused\n"


def test_the_arguments_are_the_processs_past_its_name_by_default(ran, capsys, monkeypatch):
    monkeypatch.setattr("sys.argv", ["train.py", "--agent", "random", "--seeds", "1", "--episodes", "2",
                                     "--print-config"])
    assert train.main() == 0
    assert json.loads(capsys.readouterr().out)["run"]["episodes"] == 2


def test_list_presets_prints_every_table_and_runs_nothing(ran, capsys, monkeypatch):
    monkeypatch.setattr(train, "list_presets", lambda: "the list")
    assert train.main(["--list-presets"]) == 0
    assert capsys.readouterr().out == "the list\n" and ran.calls == []


# ---------------------------------------------------------------- resume


def test_resume_continues_the_run_as_configured(ran, capsys):
    assert train.main(["--resume", "runs/x", "--no-progress"]) == 0
    assert ran.calls[:2] == [("existing", "runs/x"), ("resumable", "runs/x", False)]
    assert ran.calls[2][0] == "resume" and ran.calls[2][2:] == ("runs/x", False)
    assert ran.calls[2][1]["run"]["agent"] == "random"                     # the run's recorded config
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "resuming runs/x" and out[-1] == "wrote runs/x/episodes.csv; plot: python scripts/plot.py runs/x"


def test_resume_with_a_length_lengthens_the_run(ran, capsys):
    assert train.main(["--resume", "runs/x", "--episodes", "9", "--set", "run.env_steps=500"]) == 0
    assert ran.calls[1] == ("resumable", "runs/x", True)
    assert ran.calls[2] == ("lengthen", "runs/x", 3, {"episodes": "9", "env_steps": "500"})
    assert ran.calls[3][0] == "resume" and ran.calls[3][3] is True
    assert ran.calls[3][1]["run"]["episodes"] == 9 and ran.calls[3][1]["run"]["env_steps"] == 500   # the longer one
    assert capsys.readouterr().out.splitlines()[0] == "resuming runs/x (500 env steps (at most 9 episodes) per seed)"


@pytest.mark.parametrize("extra", [["--seeds", "3"], ["--out", "y"], ["--overwrite"], ["--config", "c.json"],
                                   ["--set", "env.noise=0.1"], ["--episodes", "9", "--gamma", "0.5"]])
def test_resume_refuses_anything_but_a_longer_length(ran, capsys, extra):
    line = refused(capsys, "--resume", "runs/x", *extra)
    assert line == ("train.py: error: --resume continues a run as it was configured: give no settings other than a "
                    "longer --episodes or --env-steps, and no --config, --out or --overwrite with it\n")
    assert ran.calls == []


def test_a_refused_resume_frees_the_folder_at_once(ran, capsys, monkeypatch):
    folders = []
    monkeypatch.setattr(runner.RunFolder, "existing", staticmethod(lambda path: folders.append(Folder(path))
                                                                   or folders[-1]))
    ran.outcome["refuse"] = ValueError("the run's code changed")
    assert refused(capsys, "--resume", "runs/x") == "train.py: error: the run's code changed\n"
    assert [f.released for f in folders] == [1]
    ran.outcome["refuse"] = KeyboardInterrupt()
    assert train.main(["--resume", "runs/x"]) == 130
    assert [f.released for f in folders] == [1, 1]


# ---------------------------------------------------------------- helpers by hand


def test_section_names_are_the_config_less_its_suffix_and_run_in_lower_case():
    assert [train.section_name(n) for n in ("DGPQConfig", "RunConfig", "SquareEnvConfig", "Run")] == [
        "DGPQ", "run", "SquareEnv", "run"]


def test_lengths_are_said_in_episodes_or_env_steps():
    assert train.length({"episodes": 1}) == "1 episode"
    assert train.length({"episodes": 50, "env_steps": None}) == "50 episodes"
    assert train.length({"episodes": 40, "env_steps": 2000}) == "2,000 env steps (at most 40 episodes)"
    assert train.length({"episodes": 2000, "env_steps": 2000}) == "2,000 env steps"
    assert train.length({"episodes": 5000, "env_steps": 2000}) == "2,000 env steps"


def test_given_settings_are_the_flags_given_and_each_set_not_the_process_flags():
    p = train.make_parser()
    args = p.parse_args(["--out", "o", "--episodes", "3", "--set", "a.b=1", "--set", "c= x=y ", "--no-progress",
                         "--yes", "--gamma", "0.5"])
    assert train.given_settings(args, p) == {"episodes": "3", "gamma": "0.5", "a.b": "1", "c": " x=y "}
    assert train.given_settings(args, p, process=("set",)) == {
        "out": "o", "episodes": "3", "gamma": "0.5", "overwrite": False, "no_progress": True, "print_config": False,
        "yes": True, "list_presets": False, "a.b": "1", "c": " x=y "}


@pytest.mark.parametrize("argv, joined", [
    (["--goal", "-1e-2,-0.5,"], ["--goal=-1e-2,-0.5,"]),     # (-0.3,0.2 and --lam -1: test_run's)
    (["--goal", "-.5, 2"], ["--goal=-.5, 2"]),
    (["--goal", "-1E-2,3E+1"], ["--goal=-1E-2,3E+1"]),
    (["--x", "-2.5"], ["--x", "-2.5"]),                                       # one negative number passes as is
    (["--goal=1,2", "-0.3,0.2"], ["--goal=1,2", "-0.3,0.2"]),                  # the flag has its value
    (["-x", "-0.3,0.2"], ["-x", "-0.3,0.2"]),                                  # not a long flag
    (["-0.3,0.2"], ["-0.3,0.2"]),                                              # no flag before it
    (["--goal", "-0.3,a"], ["--goal", "-0.3,a"]),
    (["--goal", "0.3,-0.2"], ["--goal", "0.3,-0.2"]),                          # argparse reads it already
])
def test_a_comma_list_of_numbers_starting_negative_is_joined_to_its_flag(argv, joined):
    assert train.attach_negative_lists(argv) == joined


def test_each_setting_flag_says_its_default_and_choices_in_its_configs_group(monkeypatch):
    leaf = lambda help, default, type=float, choices=None: SimpleNamespace(  # noqa: E731
        help=help, default=default, type=type, choices=choices)
    p = argparse.ArgumentParser()
    settings = {"lr": [("DQNConfig", leaf("learning rate", 0.1))],
                "kind": [("RunConfig", leaf("which", "a", str, ("a", "b")))],
                "gamma": [("DQNConfig", leaf("discount", 0.9)), ("DDPGConfig", leaf("discount", 0.99))],
                "reward": [("AEnvConfig", leaf("reward kind", "x", str, ("x", "y"))),
                           ("BEnvConfig", leaf("the other reward", "z", str))],
                "quiet": [("RunConfig", leaf("say less", False, bool))]}
    monkeypatch.setattr(train, "describe_default", lambda lf: repr(lf.default))
    train.add_setting_flags(p, settings)
    groups = {g.title: g for g in p._action_groups}
    assert set(groups) >= {"DQN settings", "run settings", "settings of several envs or agents (each one's default)"}
    actions = {a.dest: a for a in p._actions}
    assert actions["lr"].help == "learning rate [0.1]" and actions["lr"].metavar == "LR"
    assert actions["lr"].option_strings == ["--lr"] and actions["lr"].default is None
    assert actions["kind"].help == "which ['a'] {a, b}"
    assert actions["gamma"].help == "discount [DQN: 0.9; DDPG: 0.99]"
    assert actions["reward"].help == "AEnv: reward kind ['x'] {x, y}; BEnv: the other reward ['z']"
    assert isinstance(actions["quiet"], argparse.BooleanOptionalAction) and actions["quiet"].default is None
    assert groups["run settings"].description.startswith("defaults in brackets are the dataclasses'; a preset may")
    assert groups["DQN settings"].description is None
    assert [a.dest for a in groups["settings of several envs or agents (each one's default)"]._group_actions] == [
        "gamma", "reward"]
    assert p.parse_args(["--no-quiet", "--lr", "3"]).quiet is False and p.parse_args([]).quiet is None


def test_several_configs_with_choices_show_each_ones():
    leaf = lambda default, choices: SimpleNamespace(help="h", default=default, type=str, choices=choices)  # noqa: E731
    p = argparse.ArgumentParser()
    train.add_setting_flags(p, {"k": [("AConfig", leaf("a", ("a", "b"))), ("BConfig", leaf("c", None))]})
    assert next(a for a in p._actions if a.dest == "k").help == "h [A: a {a, b}; B: c]"


def test_about_a_preset_names_its_settings_its_study_and_whether_it_uses_the_model():
    # the square's shaped reward uses the model even as the defaults; its paper reward does not
    assert train.about_preset("square", "random", "shaped", {"env": {}, "agent": {}}) == "the defaults; uses the model"
    assert train.about_preset("square", "random", "paper", {"env": {}, "agent": {}}) == "the defaults"
    text = train.about_preset("square", "random", "paper", {"env": {"a": 1}, "agent": {"lr": 0.5, "h": [2, 3]}})
    assert text == "env.a=1, agent.lr=0.5, agent.h=2,3"
    long = train.about_preset("square", "random", "paper", {"env": {"a": "y" * 200}, "agent": {}}, width=20)
    assert long == "env.a=" + "y" * 11 + "..." and len(long) == 20
    exact = train.about_preset("square", "random", "paper", {"env": {"a": "y" * 14}, "agent": {}}, width=20)
    assert exact == "env.a=" + "y" * 14                                  # 20 characters: it fits
    marked = train.about_preset("square", "random", "shaped", {"env": {"a": "y" * 200}, "agent": {}}, width=40)
    assert marked == "env.a=" + "y" * 15 + "...; uses the model" and len(marked) == 40
    study = {"provenance": {"study_name": "s1", "trials": 30, "seeds": [1000, 1001, 1002], "objective": "steps",
                            "validation": {"seeds": [1005, 1006]}}}
    assert train.about_preset("square", "random", "paper", {}, study) == (
        "study s1: the best of 30 trials on seeds 1000-1002 validated on 1005-1006, by steps")
    assert train.about_preset("square", "random", "paper", {}, {}) == (
        "study ?: the best of ? trials on seeds ?, by ?")


def test_list_presets_gives_each_env_and_agent_its_presets_the_default_first():
    lines = train.list_presets().splitlines()
    at = lines.index("square dgpq")
    names = []
    for line in lines[at + 1:]:
        if not line.startswith("  "):
            break
        names.append(line.split()[0])
    assert names[0] == "shaped" and lines[at + 1].startswith("  shaped (default)   ")
    assert names[1:] == sorted(names[1:]) and "report" in names
    assert all(len(line) <= 2 + 28 + 1 + 110 for line in lines)


def test_the_summary_gives_the_median_steps_termination_and_time_per_seed_step(capsys):
    config = {"run": {"env": "square", "agent": "random"}}
    train.summarise(ROWS, config)
    out = capsys.readouterr().out.splitlines()
    # episode 1's steps 10 and 20; episodes 3+: 4 and 2; 3 of 6 terminated; 3 s over 50 seed-steps
    assert out[0] == ("steps per episode, median over seeds: episode 1: 15, episodes 3+: 3; terminated (reached the "
                      "goal) in 50% of episodes; 60000 us per seed-step")


def test_a_run_of_two_episodes_has_no_later_median(capsys):
    train.summarise(ROWS[ROWS.episode < 3], {"run": {"env": "square", "agent": "random"}})
    assert capsys.readouterr().out.startswith("steps per episode, median over seeds: episode 1: 15; terminated")


def test_the_measure_line_compares_the_first_and_last_tenth_of_a_runs_episodes():
    d = SimpleNamespace(measure=lambda env_id: ("return", "return") if env_id == "x" else pytest.fail(env_id),
                        format_measure=lambda v, env_id: f"{v:.2f}" if env_id == "x" else pytest.fail(env_id))
    df = pd.DataFrame({"seed": [0] * 30 + [1] * 30, "episode": list(range(30, 0, -1)) * 2,
                       "return": list(range(30, 0, -1)) + [2 * e for e in range(30, 0, -1)]})
    # 10 episodes each end: seed 0 1..10 -> 5.5, seed 1 2..20 -> 11; the last 21..30 -> 25.5 and 51
    assert train.measure_line(df, d, "x") == ["return, mean over seeds: first 10 episodes 8.25, last 10 38.25"]
    short = df[df.episode <= 5]        # 5 episodes: 2 each end
    assert train.measure_line(short, d, "x") == ["return, mean over seeds: first 2 episodes 2.25, last 2 6.75"]
    one = df[df.episode == 1]
    assert train.measure_line(one, d, "x") == ["return, mean over seeds: first 1 episodes 1.50, last 1 1.50"]
    steps = SimpleNamespace(measure=lambda env_id: ("steps", "steps"))
    assert train.measure_line(df, steps, "x") == []


def test_a_gym_runs_summary_says_what_its_ids_termination_means_and_its_return_early_and_late(capsys):
    df = ROWS.assign(**{"return": [1.0, 2.0, 3.0, 5.0, 6.0, 7.0]})
    train.summarise(df, {"run": {"env": "gym:CartPole-v1", "agent": "dqn"}})
    out = capsys.readouterr().out.splitlines()
    assert "terminated (the pole fell or the cart left the track) in 50% of episodes" in out[0]
    # 3 episodes: 1 at each end; seed 0: 1 then 3, seed 1: 5 then 7
    assert out[1:] == ["return per episode, mean over seeds: first 1 episodes 3, last 1 5"]


def test_a_domain_with_a_summary_of_its_own_prints_it_instead(capsys):
    df = ROWS.assign(ac_cost=[1.0, 2.0, 3.0, 4.0, 5.0, 9.0], implementation_shortfall=[0.0] * 6)
    train.summarise(df, {"run": {"env": "liquidation", "agent": "twap"}})
    out = capsys.readouterr().out.splitlines()
    assert out[1:] == ["last 3 episodes: mean ac_cost $4, mean implementation shortfall $0"]


def test_the_summary_asks_the_domain_about_the_runs_own_env_id(capsys, monkeypatch):
    asked = []
    stub = SimpleNamespace(terminated_means=lambda env_id: asked.append(env_id) or "ended",
                           analysis=lambda: SimpleNamespace(),
                           measure=lambda env_id: asked.append(env_id) or ("steps", "steps"))
    monkeypatch.setattr(train, "domain", lambda env: stub if env == "gym:Acrobot-v1" else pytest.fail(env))
    train.summarise(ROWS, {"run": {"env": "gym:Acrobot-v1", "agent": "dqn"}})
    assert asked == ["Acrobot-v1", "Acrobot-v1"] and "terminated (ended) in 50%" in capsys.readouterr().out
