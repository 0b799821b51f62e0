"""The reproduce command's ``main`` with the sweep's and the report's work stubbed: what each of
--sweep-file, --plan, --report and a run hands on, in which order, and what it prints. (Real smoke
reproductions, their reports and publications: test_sweep and test_published.)"""
import itertools
import os
from pathlib import Path

import pytest

from trl_dgpq.collectors import sweep
from trl_dgpq.commands import reproduce

PLANNED = {"a-dgpq": {"run": {"agent": "dgpq"}}, "a-dqn": {"run": {"agent": "dqn"}}, "b-x": {"run": {"agent": "x"}}}
GIVEN = {"a-dgpq": {"env": "a", "agent": "dgpq"}, "a-dqn": {"env": "a", "agent": "dqn"}, "b-x": {"env": "b"}}


class Made(list):
    """The calls, in order; ``jobs``: the jobs the stubbed plan gives."""


@pytest.fixture
def calls(monkeypatch):
    made = Made()

    def record(name, result=None):
        def f(*args, **kwargs):
            made.append((name, args, {k: v for k, v in kwargs.items() if k not in ("log", "same")}))
            for k in ("log", "same"):
                if k in kwargs:
                    made.append((f"{name}.{k}", kwargs[k]))
            if "log" in kwargs:
                kwargs["log"](f"{name} says")
            return result(*args) if callable(result) else result
        return f
    monkeypatch.setattr(reproduce, "experiments", record("experiments", dict(PLANNED)))
    monkeypatch.setattr(reproduce, "plan_settings", record("plan_settings", dict(GIVEN)))
    monkeypatch.setattr(reproduce, "sweep_file", record("sweep_file", "the file\n"))
    monkeypatch.setattr(reproduce, "plan_text", record("plan_text", "the plan\n"))
    monkeypatch.setattr(reproduce, "write_report", record("write_report", Path("OUT/REPORT.md")))
    monkeypatch.setattr(reproduce, "publish", record("publish", ["f1", "f2", "f3"]))
    monkeypatch.setattr(reproduce, "finished", lambda out, name: name != "b-x")
    monkeypatch.setattr(reproduce, "estimate", record("estimate", ["found"]))
    monkeypatch.setattr(reproduce, "seed_groups", record("seed_groups", {"groups": 1}))
    monkeypatch.setattr(reproduce, "own_time_left", record("own_time_left", {"own": 1}))
    monkeypatch.setattr(reproduce, "job_cost", record("job_cost", "the cost"))
    monkeypatch.setattr(reproduce, "guide_prior", record("guide_prior", 240.0))
    monkeypatch.setattr(reproduce, "in_order", record("in_order", lambda jobs, workers, cost: list(reversed(jobs))))
    monkeypatch.setattr(sweep, "job_modules", record("job_modules", lambda configs: list(configs)))
    monkeypatch.setattr(sweep, "start_forkserver", record("start_forkserver"))
    jobs = [sweep.Job(n, 0, [0], f"{n}/jobs/j000", {}) for n in PLANNED]
    monkeypatch.setattr(sweep, "plan", record("plan", jobs))
    monkeypatch.setattr(sweep, "create", record("create"))
    monkeypatch.setattr(sweep, "grow", record("grow", jobs[1:]))
    monkeypatch.setattr(sweep, "reuse", record("reuse", jobs[:1]))
    monkeypatch.setattr(sweep, "execute", record("execute", {"report": 1}))
    monkeypatch.setattr(sweep, "exit_code", record("exit_code", 0))
    monkeypatch.setattr(sweep, "run_script", lambda script, rerun, body: made.append(("script", script, rerun))
                        or body())
    made.jobs = jobs
    return made


def named(calls, name):
    return [c for c in calls if c[0] == name]


def test_a_sweep_file_is_the_plan_of_the_experiments_picked_with_its_command(calls, tmp_path, capsys):
    path = str(tmp_path / "plan.toml")
    assert reproduce.main(["--scale", "full", "--only", "square", "push", "--experiments", "a-*", "--sweep-file", path]) == 0
    assert named(calls, "experiments") == [("experiments", ("full", ["square", "push"]), {})]
    assert named(calls, "plan_settings") == [("plan_settings", ("full", ["square", "push"]), {})]
    command = f"reproduce.py --scale full --only square push --experiments a-* --sweep-file {path}"
    assert named(calls, "sweep_file") == [("sweep_file", ({n: GIVEN[n] for n in ("a-dgpq", "a-dqn")}, command), {})]
    assert Path(path).read_text() == "the file\n"
    assert capsys.readouterr().out == f"wrote {path}: 2 experiments\n"
    assert calls[0] == ("experiments", ("full", ["square", "push"]), {}) and calls[1] == ("script", "reproduce.py",
                                                                                  "the same command")
    reproduce.main(["--sweep-file", path])
    assert named(calls, "sweep_file")[-1][1] == (GIVEN, f"reproduce.py --scale quick --sweep-file {path}")
    assert named(calls, "experiments")[-1] == ("experiments", ("quick", None), {})


def test_the_plan_is_printed_for_the_experiments_picked_and_the_folder_it_would_run_in(calls, capsys):
    assert reproduce.main(["--plan", "--experiments", "a-dqn", "b-*", "--max-job-minutes", "30"]) == 0
    (call,) = named(calls, "plan_text")
    assert call[1] == ({"a-dqn": PLANNED["a-dqn"], "b-x": PLANNED["b-x"]}, reproduce.PUBLICATION, 30.0,
                       Path("runs/reproduce-quick"))
    assert capsys.readouterr().out == "the plan\n"
    reproduce.main(["--plan", "--scale", "smoke", "--only", "square", "push"])
    assert named(calls, "plan_text")[-1][1][1:] == (reproduce.PUBLICATION, None, Path("runs/reproduce-smoke-square-push"))
    assert named(calls, "plan_text")[-1][1][0] == PLANNED
    assert not named(calls, "execute") and not named(calls, "write_report")


def test_an_unknown_experiment_pattern_and_experiments_with_report_are_refused(calls):
    with pytest.raises(sweep.SweepError, match="--experiments nothing-\\*: no planned experiment matches"):
        reproduce.main(["--plan", "--experiments", "nothing-*"])
    with pytest.raises(sweep.SweepError) as refused:
        reproduce.main(["--report", "--experiments", "a-*"])
    assert str(refused.value) == "--report writes the report of every finished experiment: drop --experiments"


def test_a_report_needs_a_reproduction_and_is_published_when_asked(calls, tmp_path, capsys):
    out = tmp_path / "r"
    with pytest.raises(sweep.SweepError) as refused:
        reproduce.main(["--report", "--out", str(out)])
    assert str(refused.value) == f"{out} holds no reproduction to report on"
    out.mkdir()
    (out / sweep.SWEEP).write_text("{}")
    assert reproduce.main(["--report", "--out", str(out), "--scale", "full", "--only", "push"]) == 0
    assert named(calls, "write_report") == [("write_report", (out, "full", 0.0, ["push"]), {})]
    assert capsys.readouterr().out == "wrote OUT/REPORT.md (2 of 3 experiments finished)\n"
    assert not named(calls, "publish")
    assert reproduce.main(["--report", "--out", str(out), "--publish", str(tmp_path / "pub")]) == 0
    assert named(calls, "publish") == [("publish", (out, tmp_path / "pub", "quick", None), {})]
    assert capsys.readouterr().out.endswith(f"published 3 files to {tmp_path / 'pub'}\n")
    assert not named(calls, "execute")


def test_a_run_plans_runs_in_order_reports_and_publishes(calls, tmp_path, capsys, monkeypatch):
    t = itertools.chain([100.0, 160.0], itertools.repeat(160.0))     # any later reading: the end
    monkeypatch.setattr(reproduce.time, "perf_counter", lambda: next(t))
    out = tmp_path / "r"
    assert reproduce.main(["--out", str(out), "--workers", "3", "--experiments", "a-*", "--max-job-minutes", "5",
                           "--publish", str(tmp_path / "pub")]) == 0
    jobs = calls.jobs
    assert [c[0] for c in calls if not c[0].endswith((".log", ".same"))] == [
        "experiments", "script", "job_modules", "start_forkserver", "estimate", "seed_groups", "plan", "create",
        "own_time_left", "job_cost", "in_order", "guide_prior", "execute", "exit_code", "write_report", "publish"]
    assert named(calls, "start_forkserver") == [("start_forkserver", ([PLANNED["a-dgpq"], PLANNED["a-dqn"]],), {})]
    assert named(calls, "estimate") == [("estimate", (PLANNED, reproduce.PUBLICATION), {})]
    assert named(calls, "seed_groups") == [("seed_groups", (PLANNED, ["found"], 5.0), {})]
    assert named(calls, "plan") == [("plan", (PLANNED, out, None, {"groups": 1}), {})]
    assert named(calls, "create") == [("create", (out, PLANNED, jobs), {})]
    assert named(calls, "own_time_left") == [("own_time_left", (jobs,), {})]
    assert named(calls, "job_cost") == [("job_cost", (PLANNED, ["found"], {"own": 1}), {})]
    assert named(calls, "in_order") == [("in_order", (jobs[:2], 3, "the cost"), {})]
    assert named(calls, "execute") == [("execute", (out, [jobs[1], jobs[0]], "local", 3),
                                        {"cost": "the cost", "prior": 240.0})]
    assert named(calls, "guide_prior") == [("guide_prior", (["found"],), {})]
    assert named(calls, "exit_code") == [("exit_code", ({"report": 1}, "the same command"), {})]
    assert named(calls, "write_report") == [("write_report", (out, "quick", 60.0, None), {})]
    assert named(calls, "publish") == [("publish", (out, tmp_path / "pub", "quick", None), {})]
    assert capsys.readouterr().out == (f"reproduce (quick) -> {out}: 3 experiments, 2 of them now, 3 workers\n"
                                       f"execute says\nwrote OUT/REPORT.md, {out / 'results.csv'} and the figures\n"
                                       f"published 3 files to {tmp_path / 'pub'}\n")


def test_a_run_without_options_runs_every_experiment_on_every_core(calls, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert reproduce.main([]) == 0
    assert named(calls, "execute")[0][1][1:] == ([calls.jobs[2], calls.jobs[1], calls.jobs[0]], "local", os.cpu_count())
    assert named(calls, "plan")[0][1][1] == Path("runs/reproduce-quick")
    assert named(calls, "seed_groups")[0][1][2] is None
    assert not named(calls, "reuse") and not named(calls, "publish")
    out = capsys.readouterr().out
    assert out.startswith(f"reproduce (quick) -> runs/reproduce-quick: 3 experiments, {os.cpu_count()} workers\n")


def test_a_run_that_exists_grows_reuses_and_stops_on_a_failed_job(calls, tmp_path, capsys, monkeypatch):
    out = tmp_path / "r"
    out.mkdir()
    (out / sweep.SWEEP).write_text("{}")
    monkeypatch.setattr(sweep, "exit_code", lambda report, rerun: 1)
    assert reproduce.main(["--out", str(out), "--reuse", "x", "y", "--workers", "1"]) == 1
    jobs = calls.jobs
    assert named(calls, "grow") == [("grow", (out, PLANNED, None), {"groups": {"groups": 1}})]
    assert named(calls, "reuse") == [("reuse", (out, jobs[1:], ["x", "y"]), {})]
    assert named(calls, "own_time_left") == [("own_time_left", (jobs[:1],), {})]
    assert not named(calls, "plan") and not named(calls, "create") and not named(calls, "write_report")
    same = {name: f for name, f in (c for c in calls if c[0].endswith(".same"))}
    grown, reused = same["grow.same"], same["reuse.same"]
    a = {"run": {"env": "square", "agent": "random", "seeds": [0], "episodes": 1}}
    older = {"run": {"env": "square", "agent": "random", "seeds": [0], "episodes": 1, "threads": 1}}
    assert grown(a, older) and not grown(a, {"run": {**a["run"], "episodes": 2}})
    assert grown(a, {**a, "env": {"max_steps": 7}})                   # the run's settings alone
    full = {**a, "env": {}, "agent": {}}
    assert reused(full, full) and not reused(full, {**full, "env": {"max_steps": 7}})
    printed = capsys.readouterr().out
    assert printed.startswith(f"continuing {out}\nreuse says\nreproduce (quick)")
