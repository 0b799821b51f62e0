"""collectors/sweep.py's small parts by hand, without a worker process: a job's name, a running
job's time left (and the clock's and minutes_left's boundaries test_sweep leaves out), a job's outcome from its status, the exit code's lines, the jobs described, the
seed slices of a plan, a sweep file's refusals word for word and its defaults, and an experiment's
rows merged from its jobs. (Real sweeps, signals, planned seed-steps, the clock, the makespan and
the time-left guide: test_sweep.)"""
import signal
from pathlib import Path

import pandas as pd
import pytest

from trl_dgpq.collectors import runner, sweep
from trl_dgpq.collectors.experiment import resolve_config


def job(seeds, experiment="e", index=0, folder="f", **run):
    config = {"run": {"env": "square", "episodes": 10, "seeds": seeds, **run}, "env": {"max_steps": 50}}
    return sweep.Job(experiment, index, seeds, folder, config)


def test_a_jobs_name_spans_consecutive_seeds_and_lists_the_others():
    assert job([3, 4, 5]).name == "e job 0 (seeds 3-5)"
    assert job([3, 5], index=2).name == "e job 2 (seeds 3,5)"
    assert job([7]).name == "e job 0 (seeds 7)"
    assert job([5, 4]).name == "e job 0 (seeds 5,4)"
    assert job([3, 4]).name == "e job 0 (seeds 3-4)"


def test_a_running_jobs_time_left_is_its_estimate_less_what_it_ran_at_least_a_quarter_of_that():
    assert sweep.running_left(100.0, 30.0) == 70.0
    assert sweep.running_left(100.0, 80.0) == 20.0                                    # 0.25 x 80 = 20: equal
    assert sweep.running_left(100.0, 90.0) == 22.5
    assert sweep.running_left(100.0, 200.0) == 50.0
    assert sweep.clock(120.0) == "2.0 h" and sweep.clock(119.96) == "120 min"           # (the rest: test_sweep)
    assert sweep.clock(10.0) == "10 min" and sweep.clock(600.0) == "10.0 h"
    assert sweep.minutes_left(2.0, ["a"], ["b"], {"a": 0.5, "b": 1.0}.get) == 4.0          # costs below 1


def test_a_jobs_outcome_from_its_status_and_how_its_process_ended(tmp_path):
    j = job([0], folder=str(tmp_path / "j"))
    (tmp_path / "j").mkdir()
    status = tmp_path / "j" / runner.STATUS

    def write(state, reason=None):
        status.write_text(pd.Series({"status": state, "reason": reason}).to_json())
    assert sweep.outcome(j, 1) == dict(status="failed", reason="exit code 1, status None")
    assert sweep.outcome(j, None, "it broke") == dict(status="failed", reason="it broke")
    assert sweep.outcome(j, -signal.SIGKILL) == dict(status="killed", reason="killed by SIGKILL")
    write("finished")
    assert sweep.outcome(j, -signal.SIGKILL) == dict(status="finished")
    write("failed", "out of memory")
    assert sweep.outcome(j, -signal.SIGTERM) == dict(status="failed", reason="out of memory")
    write("interrupted", "SIGTERM")
    assert sweep.outcome(j, 143) == dict(status="interrupted", reason="SIGTERM")
    assert sweep.outcome(j, -signal.SIGTERM) == dict(status="killed", reason="killed by SIGTERM")
    write("running")
    assert sweep.outcome(j, 0) == dict(status="failed", reason="exit code 0, status 'running'")


def test_the_exit_code_lists_what_did_not_finish_and_how_to_rerun_it(capsys):
    report = {"a": dict(status="finished"), "b": dict(status="killed", reason="killed by SIGKILL"),
              "c": dict(status="interrupted")}
    assert sweep.exit_code(report, "sweep.py --resume x") == 1
    assert capsys.readouterr().err == ("b: killed: killed by SIGKILL\nc: interrupted: None\n2 of 3 jobs did not "
                                       "finish; the others kept their rows. Rerun them with: sweep.py --resume x\n")
    assert sweep.exit_code({"a": dict(status="finished")}, "r") == 0 and capsys.readouterr().err == ""


def test_the_jobs_described_per_experiment_in_the_plans_order():
    a = resolve_config(env="square", agent="dgpq", seeds=[0, 1, 2], episodes=5)
    b = resolve_config(env="corridor", agent="random", seeds=[4], episodes=2)
    jobs = sweep.plan({"b": b, "a": a}, "out", 2)
    text = sweep.describe_jobs(jobs)
    first, second = text.split("; ")
    assert first.startswith("b: ") and first.endswith(", 1 seed in 1 job") and "corridor" in first
    assert second.startswith("a: ") and second.endswith(", 3 seeds in 2 jobs") and "square" in second
    assert "square" not in first and "corridor" not in second                           # each its own config


def test_a_plan_slices_each_experiments_seeds_and_gives_each_job_its_own_folder_and_one_thread():
    a = resolve_config(env="square", agent="dgpq", seeds=[5, 6, 7, 8, 9], episodes=5)
    jobs = sweep.plan({"a": a}, "out", 2)
    assert [(j.index, j.seeds, j.folder) for j in jobs] == [
        (0, [5, 6], str(Path("out/a/jobs/j000"))), (1, [7, 8], str(Path("out/a/jobs/j001"))),
        (2, [9], str(Path("out/a/jobs/j002")))]
    assert all(j.config["run"]["seeds"] == j.seeds and j.config["run"]["threads"] == 1 for j in jobs)
    assert a["run"]["seeds"] == [5, 6, 7, 8, 9] and jobs[0].config["env"] == a["env"]      # the config untouched
    assert [j.seeds for j in sweep.plan({"a": a}, "out", None)] == [[5, 6, 7, 8, 9]]
    assert [j.seeds for j in sweep.plan({"a": a}, "out", 2, groups={"a": 3})] == [[5, 6], [7, 8], [9]]
    assert [j.seeds for j in sweep.plan({"a": a}, "out", None, groups={"a": 5})] == [[5], [6], [7], [8], [9]]
    assert [j.seeds for j in sweep.plan({"a": a}, "out", None, groups={"b": 2})] == [[5, 6, 7, 8, 9]]
    assert [j.seeds for j in sweep.plan({"a": a}, "out", None, groups={"a": 1})] == [[5, 6, 7, 8, 9]]
    assert [j.seeds for j in sweep.plan({"a": a}, "out", 1)] == [[5], [6], [7], [8], [9]]
    two = resolve_config(env="square", agent="dgpq", seeds=[5, 6], episodes=5, threads=2)
    assert two["run"]["threads"] == 2 and [j.config["run"]["threads"] for j in sweep.plan({"t": two}, "o", 1)] == [1, 1]
    for bad in (0, 6):
        with pytest.raises(sweep.SweepError, match=rf"^a: {bad} jobs for 5 seeds$"):
            sweep.plan({"a": a}, "out", None, groups={"a": bad})
    with pytest.raises(sweep.SweepError, match="^seeds_per_job must be >= 1, got 0$"):
        sweep.plan({"a": a}, "out", 0)


def test_a_sweep_file_is_refused_in_one_line_naming_the_experiment(tmp_path):
    def refused(text, words):
        path = tmp_path / "s.toml"
        path.write_text(text)
        with pytest.raises(sweep.SweepError) as err:
            sweep.read_sweep_file(path)
        assert str(err.value) == words.format(path=path)
    with pytest.raises(sweep.SweepError, match=r"^cannot read .*nowhere\.toml: No such file or directory$"):
        sweep.read_sweep_file(tmp_path / "nowhere.toml")
    path = tmp_path / "s.toml"
    path.write_text("[[experiment]\n")
    with pytest.raises(sweep.SweepError, match=r"^.*s\.toml: not valid TOML: .*line 1"):   # tomllib's own words
        sweep.read_sweep_file(path)
    refused("[other]\n[[experiment]]\nname = 'a'\n", "{path}: unknown tables ['other'] (use [defaults] and "
                                                     "[[experiment]])")
    refused("[defaults]\nepisodes = 2\n", "{path}: no [[experiment]] entries")
    refused("experiment = 3\n", "{path}: no [[experiment]] entries")
    refused("[[experiment]]\nname = 'a'\nlr = 0.1\n", "{path}: experiment 1 ('a'): unknown keys ['lr']; settings go "
                                                      "under [experiment.set]")
    refused("[[experiment]]\nenv = 'square'\n", "{path}: experiment 1: needs a name that can be a folder name, got "
                                                "None")
    for name in ("a/b", ".hidden", ""):
        refused(f"[[experiment]]\nname = '{name}'\n", "{path}: experiment 1" + (f" ({name!r})" if name else "")
                + f": needs a name that can be a folder name, got {name!r}")
    refused("[[experiment]]\nname = 'a'\n[[experiment]]\nname = 'a'\n", "{path}: experiment 2 ('a'): the name 'a' "
                                                                       "is used twice")
    path.write_text("[[experiment]]\nname = 'a'\nenv = 'square'\n[experiment.set]\nnoise_var = -1.0\n")
    with pytest.raises(sweep.SweepError, match=r"^.*s\.toml: experiment 1 \('a'\): .*noise_var"):
        sweep.read_sweep_file(path)


def test_a_sweep_file_with_defaults_under_every_experiment(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text("[defaults]\nepisodes = 3\nenv = 'square'\n[defaults.set]\nnoise_var = 0.2\nsigma_tol2 = 0.5\n"
                    "[[experiment]]\nname = 'a'\nseeds = '0-2'\n[experiment.set]\nnoise_var = 0.3\n"
                    "[[experiment]]\nname = 'b'\nepisodes = 4\nseeds = '5'\n")
    got = sweep.read_sweep_file(path)
    assert list(got) == ["a", "b"]
    assert got["a"] == resolve_config(env="square", episodes=3, seeds="0-2", noise_var=0.3, sigma_tol2=0.5)
    assert got["b"] == resolve_config(env="square", episodes=4, seeds="5", noise_var=0.2, sigma_tol2=0.5)


def test_an_experiments_rows_are_merged_from_its_finished_jobs_with_the_job_named(tmp_path, monkeypatch):
    rows = {"j0": pd.DataFrame(dict(seed=[0, 0], episode=[1, 2], steps=[5, 6])),
            "j1": pd.DataFrame(dict(seed=[1], episode=[1], steps=[7]))}
    finished = {"j0": True, "j1": True}
    monkeypatch.setattr(runner.RunFolder, "finished", lambda self: finished[self.path.name])
    monkeypatch.setattr(runner.RunFolder, "episodes", lambda self: rows[self.path.name])
    jobs = [job([0], index=0, folder=str(tmp_path / "e" / "jobs" / "j0")),
            job([1], index=1, folder=str(tmp_path / "e" / "jobs" / "j1"))]
    (tmp_path / "e").mkdir()
    merged = sweep.merge(tmp_path, "e", jobs)
    assert merged.to_dict("list") == dict(seed=[0, 0, 1], episode=[1, 2, 1], steps=[5, 6, 7], job=[0, 0, 1])
    assert pd.read_csv(tmp_path / "e" / "episodes.csv").to_dict("list") == merged.to_dict("list")
    finished["j1"] = False
    assert sweep.merge(tmp_path, "e", jobs) is None
