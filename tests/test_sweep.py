"""Sweeps: jobs on a process pool and on Ray give the rows of one process; a dead job is
reported and resumable while the others finish; bad input is refused before any job."""
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from tests.fake_process import FakeProcess
from tests.fake_process import fake_context as fake_processes
from trl_dgpq.collectors import runner, sweep
from trl_dgpq.collectors.experiment import TIMING_COLUMNS, resolve_config
from trl_dgpq.commands import reproduce
from trl_dgpq.commands import sweep as sweep_script

SWEEP_FILE = """
[defaults]
seeds = "0-3"
episodes = 3

[[experiment]]
name = "square"
env = "square"
agent = "dgpq"
[experiment.set]
max_steps = 30

[[experiment]]
name = "liq"
env = "liquidation"
agent = "dgpq"
preset = "shortfall"
[experiment.set]
trades = 8
horizon = 8
"""


def write(tmp_path, text=SWEEP_FILE, name="s.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def rows(path, keep_job=False):
    df = runner.read_csv_exact(path).drop(columns=list(TIMING_COLUMNS))
    return df if keep_job else df.drop(columns=["job"], errors="ignore")


def one_process(config, folder):
    """The experiment as one run, all seeds in one batch (what train.py does)."""
    f = runner.RunFolder(folder)
    f.path.mkdir(parents=True)
    runner.start(config, f, progress=False)
    return rows(f.file("episodes.csv"))


def square_text(episodes: int) -> str:
    """SWEEP_FILE's square experiment alone, ``episodes`` per seed."""
    return SWEEP_FILE.split("[[experiment]]\nname = \"liq\"")[0].replace("episodes = 3", f"episodes = {episodes}")


def square_sweep(tmp_path, episodes: int, seeds_per_job: int):
    """``square_text`` planned and created in tmp_path/sw: (experiments, out, jobs)."""
    experiments = sweep.read_sweep_file(write(tmp_path, square_text(episodes)))
    out = tmp_path / "sw"
    jobs = sweep.plan(experiments, out, seeds_per_job)
    sweep.create(out, experiments, jobs)
    return experiments, out, jobs


def run_sweep(tmp_path, out, backend="local", workers=2, seeds_per_job=2, text=SWEEP_FILE):
    experiments = sweep.read_sweep_file(write(tmp_path, text))
    jobs = sweep.plan(experiments, out, seeds_per_job)
    sweep.create(out, experiments, jobs)
    return experiments, jobs, sweep.execute(out, jobs, backend, workers, log=lambda line: None)


def test_pool_gives_the_rows_of_one_process(tmp_path):
    """Two workers, two jobs per experiment: the merged rows are one process's, each seed's
    job the plan's. (One worker runs the same jobs: the other tests here run on one.)"""
    experiments, jobs, report = run_sweep(tmp_path, tmp_path / "pool")
    assert len(jobs) == 4 and all(r["status"] == "finished" for r in report.values())
    for name, config in experiments.items():
        merged = rows(tmp_path / "pool" / name / "episodes.csv", keep_job=True)
        assert sorted(merged["job"].unique()) == [0, 1]
        assert (merged.groupby("seed")["job"].first() == [0, 0, 1, 1]).all()
        pd.testing.assert_frame_equal(merged.drop(columns="job"), one_process(config, tmp_path / f"single-{name}"))


@pytest.mark.slow  # Ray's start-up: ~15 s
def test_ray_gives_the_rows_of_the_pool(tmp_path):
    ray = pytest.importorskip("ray")
    try:
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
        _, _, report = run_sweep(tmp_path, tmp_path / "ray", backend="ray")
    finally:
        ray.shutdown()
    assert all(r["status"] == "finished" for r in report.values())
    run_sweep(tmp_path, tmp_path / "pool")
    for name in ("square", "liq"):
        pd.testing.assert_frame_equal(rows(tmp_path / "ray" / name / "episodes.csv", keep_job=True),
                                      rows(tmp_path / "pool" / name / "episodes.csv", keep_job=True))


# behind slow: real workers, one killed (~9 s); a job that ended unfinished counted so is
# test_a_job_that_ended_unfinished_counts_as_not_finished_in_the_progress_line's, finished jobs kept and
# only the others run again test_a_plan_that_grew_keeps_the_finished_jobs_and_adds_the_new_ones's
@pytest.mark.slow
def test_a_killed_job_is_reported_the_others_finish_and_resume_completes_it(tmp_path):
    """SIGKILL one job's process once it has written rows: it is reported as killed with its
    seeds, the other job finishes, no merged file yet; resume reruns only the killed job,
    and the merged rows equal one process's."""
    experiments, out, jobs = square_sweep(tmp_path, episodes=40, seeds_per_job=2)
    victim = runner.RunFolder(jobs[1].folder)
    killed = {}

    def killer():
        deadline = time.time() + 120
        while time.time() < deadline and not killed:
            status = victim.status() or {}
            if status.get("status") == "running" and victim.csv_size() > 0 and victim.file("checkpoint.pt").exists():
                os.kill(status["pid"], signal.SIGKILL)
                killed["pid"] = status["pid"]
            time.sleep(0.02)
    thread = threading.Thread(target=killer)
    thread.start()
    report = sweep.execute(out, jobs, "local", 2, log=lambda line: None)
    thread.join()
    assert killed, "the job finished before it could be killed"
    assert report[jobs[1].name]["status"] == "killed" and report[jobs[1].name]["seeds"] == [2, 3]
    assert "SIGKILL" in report[jobs[1].name]["reason"]
    assert report[jobs[0].name]["status"] == "finished"
    assert not (out / "square" / "episodes.csv").exists()
    assert json.loads((out / "report.json").read_text())[jobs[1].name]["status"] == "killed"
    _, again = sweep.load(out)
    report = sweep.execute(out, again, "local", 2, log=lambda line: None)
    assert report[jobs[0].name].get("note") == "finished before" and report[jobs[1].name]["status"] == "finished"
    pd.testing.assert_frame_equal(rows(out / "square" / "episodes.csv"),
                                  one_process(experiments["square"], tmp_path / "single"))


def test_a_nan_from_the_env_fails_that_job_with_where_and_the_others_finish(tmp_path):
    """Liquidation with an absurd volatility drives the price negative: log-returns are NaN.
    That experiment's job fails naming seed, episode and step; the other finishes; the
    script exits 1 and says how to rerun."""
    text = SWEEP_FILE.replace('[experiment.set]\ntrades = 8', '[experiment.set]\nannual_volatility = 200.0\ntrades = 8')
    path = write(tmp_path, text)
    out = tmp_path / "sw"
    assert sweep_script.main([str(path), "--out", str(out), "--workers", "2"]) == 1
    report = json.loads((out / "report.json").read_text())
    bad = [r for r in report.values() if r["status"] != "finished"]
    assert len(bad) == 1 and bad[0]["experiment"] == "liq"
    assert "NonFiniteError" in bad[0]["reason"] and "seed 0, episode 1, step" in bad[0]["reason"]
    assert (out / "square" / "episodes.csv").exists() and not (out / "liq" / "episodes.csv").exists()


SWEEP_SCRIPT = Path(__file__).resolve().parent.parent / "scripts" / "sweep.py"


def descendants(pid: int) -> list:
    """The processes below ``pid``, from /proc: a sweep's forkserver, the workers it forked, its resource tracker."""
    try:
        children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    except OSError:
        return []
    return [p for c in map(int, children) for p in (c, *descendants(c))]


def alive(pid: int) -> bool:
    """Running (not gone, nor a zombie waiting for its parent to reap it)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.slow  # a real sweep.py and its workers (~25 s): the held sections' units below stand in for it
def test_sigterm_stops_the_workers_as_ctrl_c_does_and_resume_finishes(tmp_path):
    """SIGTERM to a real sweep.py while both its jobs write rows: as Ctrl-C, the workers checkpoint
    and stop before it exits (they are the forkserver's children, so only the sweep can stop them),
    nothing it started outlives it, one line on stderr names --resume, exit 143; --resume then
    continues the jobs from their checkpoints and ends with the rows of one process."""
    experiments = sweep.read_sweep_file(write(tmp_path, square_text(20)))
    out = tmp_path / "sw"
    proc = subprocess.Popen([sys.executable, str(SWEEP_SCRIPT), str(tmp_path / "s.toml"), "--out", str(out),
                             "--workers", "2", "--seeds-per-job", "2"], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    jobs = [runner.RunFolder(out / "square" / "jobs" / f"j00{k}") for k in range(2)]
    family = []
    try:
        while not all((job.status() or {}).get("status") == "running" and job.csv_size() for job in jobs):
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.02)
        family = descendants(proc.pid)
        workers = {job.status()["pid"] for job in jobs}
        assert workers <= set(family)
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=60)
        assert not [pid for pid in workers if alive(pid)]           # stopped before the sweep exited
        deadline = time.time() + 10                                 # the forkserver ends once the sweep has
        while [pid for pid in family if alive(pid)] and time.time() < deadline:
            time.sleep(0.05)
        assert not [pid for pid in family if alive(pid)]
    finally:
        for pid in [proc.pid] + family:
            if alive(pid):
                os.kill(pid, signal.SIGKILL)
    with proc.stderr:
        err = proc.stderr.read()    # (read only now: a worker left running would hold the pipe open)
    lines = err.strip().splitlines()
    assert proc.returncode == 143 and len(lines) == 1 and f"--resume {out}" in lines[0], err
    for job in jobs:
        assert job.status()["status"] == "interrupted" and job.status()["reason"] == "SIGTERM"
        assert job.load_checkpoint()["episodes_done"] == job.status()["episodes_done"] > 0
    assert sweep_script.main(["--resume", str(out)]) == 0
    pd.testing.assert_frame_equal(rows(out / "square" / "episodes.csv"),
                                  one_process(experiments["square"], tmp_path / "single"))


@pytest.mark.parametrize("text, message", [
    (SWEEP_FILE.replace("max_steps = 30", "max_step = 30"), "experiment 1 ('square'): unknown setting 'max_step'"),
    (SWEEP_FILE.replace('name = "liq"', 'name = "square"'), "used twice"),
    (SWEEP_FILE.replace('preset = "shortfall"', 'preset = "nope"'), "experiment 2 ('liq'): unknown preset 'nope'"),
    (SWEEP_FILE.replace('name = "liq"', 'name = "liq"\nepisode = 3'), "unknown keys ['episode']"),
    (SWEEP_FILE.replace('name = "liq"', 'name = "../liq"'), "folder name"),
    ("[[experiment]\nname = 1", "not valid TOML"),
])
def test_a_bad_sweep_file_is_refused_before_any_job_starts(tmp_path, text, message):
    out = tmp_path / "never"
    with pytest.raises(sweep.SweepError) as err:
        sweep.read_sweep_file(write(tmp_path, text))
    assert message in str(err.value)
    assert sweep_script.main([str(tmp_path / "s.toml"), "--out", str(out)]) == 2
    assert not out.exists()


def test_an_existing_sweep_is_not_overwritten_by_accident(tmp_path):
    experiments = sweep.read_sweep_file(write(tmp_path))
    jobs = sweep.plan(experiments, tmp_path / "sw", 2)
    sweep.create(tmp_path / "sw", experiments, jobs)
    with pytest.raises(sweep.SweepError, match="--resume"):
        sweep.create(tmp_path / "sw", experiments, jobs)
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("mine")
    with pytest.raises(sweep.SweepError, match="holds no sweep"):
        sweep.create(tmp_path / "other", experiments, jobs, overwrite=True)
    assert (tmp_path / "other" / "notes.txt").exists()


@pytest.mark.slow
def test_reproduce_writes_every_figure_and_the_report(tmp_path):
    """scripts/reproduce.py at its smoke scale (1 seed, a few episodes per experiment)."""
    out = tmp_path / "repro"
    assert reproduce.main(["--scale", "smoke", "--out", str(out), "--workers", "2"]) == 0
    text = (out / "REPORT.md").read_text()
    for section in ("## Square", "## Block pushing", "## Optimal liquidation", "## Aircraft altitude hold",
                    "### A decision every 0.5 s", "## DGPQ against DQN", "## Claims, and whether they reproduce",
                    "## What it cost", "smoke scale"):
        assert section in text
    for fig in ("square/steps_per_episode.png", "square/time_per_step.png", "square-kernels/steps_per_episode.png",
                "push/push.png", "push/push.gif", "liquidation/liquidation_cost.png", "liquidation/liquidation_time.png",
                "liquidation/holdings.png", "square/qhat.png", "f16/f16_reward.png", "f16/f16_trace.png",
                "f16-05/f16_reward.png", "gym/compare-gym-CartPole-v1.png", "gym-zoo/compare-gym-CartPole-v1.png"):
        assert (out / fig).is_file(), fig
    import csv

    from trl_dgpq.analysis import results
    with open(out / "results.csv") as f:
        rows = list(csv.DictReader(f))
    assert tuple(rows[0]) == results.COLUMNS and {r["experiment"] for r in rows} == set(reproduce.experiments("smoke"))
    assert (out / "claims.md").read_text().startswith("| source | claim | ours | verdict |")
    assert reproduce.main(["--scale", "smoke", "--out", str(out)]) == 0          # again: nothing to rerun
    assert reproduce.main(["--scale", "quick", "--out", str(out)]) == 2          # another sweep's folder


def test_reproduce_on_one_worker_runs_domain_by_domain_the_smallest_first(tmp_path):
    """At the report scale push plans 3 x 10 seeds x 100 episodes x 50 steps = 150,000 seed-steps
    (at most: the step caps), square-paper-tuned 3 x 20 seeds x its 10,000-step budget = 600,000, gym
    10 seeds x its budgets, and the square, whose runs for GWH14's claims are capped at 20,000 steps,
    10 x 100 x 20,000 for one of them alone: push's jobs run first, then square-paper-tuned's, then
    gym's, each part's jobs together; on two workers the longest first by their estimates, or without
    them DDPG and TD3 (the costliest per step)."""
    planned = reproduce.experiments("report")
    jobs = sweep.plan(planned, tmp_path / "r", None)
    domains = {name: d.name for d, a in reproduce.reproductions() for name, *_ in a.REPRODUCE}
    ordered = [domains[j.experiment] for j in reproduce.in_order(jobs, 1)]
    runs = [d for k, d in enumerate(ordered) if k == 0 or d != ordered[k - 1]]
    assert runs[:3] == ["push", "square-paper-tuned", "gym"] and len(runs) == len(set(runs)) == 9   # one stretch each
    assert sorted(reproduce.in_order(jobs, 1), key=id) == sorted(jobs, key=id)     # every job, once
    liq = [j.experiment for j in reproduce.in_order(jobs, 1) if domains[j.experiment] == "liquidation"]
    assert liq[0] == "liq-td3-shortfall"                  # within a domain the shortest first (3,000 episodes)
    agents = [j.config["run"]["agent"] for j in reproduce.in_order(jobs, 2)]
    first = len([a for a in agents if a in ("ddpg", "td3")])
    assert first == 10 and set(agents[:first]) == {"ddpg", "td3"}
    # with each job's estimate: the longest first, ties in the plan's order
    seconds = {j.name: float(k % 5) for k, j in enumerate(jobs)}
    longest = reproduce.in_order(jobs, 2, lambda j: seconds[j.name])
    assert [seconds[j.name] for j in longest] == sorted(seconds.values(), reverse=True)
    assert [j.name for j in longest if seconds[j.name] == 4.0] == [j.name for j in jobs if seconds[j.name] == 4.0]
    assert reproduce.in_order(jobs, 1, lambda j: seconds[j.name]) == reproduce.in_order(jobs, 1)   # one worker: by domain


def test_reproduce_only_plans_the_named_domains():
    f16 = reproduce.experiments("smoke", ["f16"])
    every = reproduce.experiments("smoke")
    assert f16 and all(name.startswith("f16-") for name in f16)
    assert set(f16) < set(every) and any(name.startswith("square-") for name in every)
    assert f16["f16-dgpq-lq10"]["agent"]["lipschitz"] == 10.0 and f16["f16-nothing"]["agent"]["action"] == "hold"
    report = reproduce.experiments("report", ["f16", "liquidation"])
    flight = report["f16-05-dgpq-lq10"]            # issue 28's formulation: a decision every 0.5 s, GWH14's L_Q 10
    assert (flight["agent"]["lipschitz"], flight["env"]["decision_steps"], flight["run"]["episodes"]) == (10.0, 10, 3000)
    assert report["f16-05-nothing"]["run"]["episodes"] == 100 and report["f16-dgpq-lq5"]["env"]["decision_steps"] == 1
    assert (report["liq-td3-shortfall"]["run"]["agent"], report["liq-td3-shortfall"]["run"]["episodes"]) == ("td3", 3_000)
    assert report["liq-dgpq-tuned"]["run"]["preset"] == "tuned"
    late = report["liq-dgpq-late"]                  # issue 28's late-scoring study, at the report's length
    assert (late["run"]["preset"], late["run"]["episodes"], late["env"]["pace"]) == ("late", 11_000, True)
    slack = report["liq-dgpq-late-eps1"]            # the same with eps1 0.002, the rest of late's own settings
    assert (slack["run"]["preset"], slack["run"]["episodes"], slack["agent"]["eps1"]) == ("late", 11_000, 0.002)
    assert {k: v for k, v in slack["agent"].items() if k != "eps1"} == {k: v for k, v in late["agent"].items()
                                                                       if k != "eps1"} and late["agent"]["eps1"] > 0.005
    with pytest.raises(SystemExit):  # an unknown domain: argparse's one line, exit 2
        reproduce.main(["--only", "nowhere"])


def test_reproduce_runs_the_chosen_experiments_now_and_the_rest_later(tmp_path, capsys):
    planned = reproduce.experiments("smoke", ["f16"])
    assert reproduce.chosen(planned, None) == list(planned)
    assert reproduce.chosen(planned, ["f16-dgpq-*", "f16-pd"]) == ["f16-dgpq-lq5", "f16-dgpq-lq10", "f16-dgpq-gamma99",
                                                                 "f16-pd"]       # plan order, each once
    with pytest.raises(sweep.SweepError):          # names are matched as written
        reproduce.chosen(planned, ["F16-PD"])
    with pytest.raises(sweep.SweepError, match="f16-nobody.*planned: f16-dgpq-lq5"):
        reproduce.chosen(planned, ["f16-pd", "f16-nobody*"])
    out = tmp_path / "r"
    assert reproduce.main(["--scale", "smoke", "--only", "f16", "--out", str(out), "--workers", "1",
                           "--experiments", "f16-pd", "f16-nothing"]) == 0
    assert "2 of them now" in capsys.readouterr().out
    assert sorted(n for n in planned if reproduce.finished(out, n)) == ["f16-nothing", "f16-pd"]
    assert set(sweep.load(out)[0]) == set(planned)       # the plan stays whole
    assert reproduce.main(["--scale", "smoke", "--only", "f16", "--out", str(out), "--workers", "1",
                           "--experiments", "nowhere"]) == 2      # refused in one line, nothing run
    assert "no planned experiment matches" in capsys.readouterr().err
    assert reproduce.main(["--scale", "smoke", "--only", "f16", "--out", str(out), "--report",
                           "--experiments", "f16-pd"]) == 2
    assert "drop --experiments" in capsys.readouterr().err
    with pytest.raises(ValueError, match="no part named f16-nowhere; the parts: square, "):
        reproduce.experiments("smoke", ["f16-nowhere"])


def test_each_finished_job_reports_how_many_are_done_failed_and_to_go(tmp_path):
    experiments = {"a": resolve_config(env="corridor", agent="constant", seeds=[0, 1], episodes=1),
                   "b": resolve_config(env="corridor", agent="constant", seeds=[2], episodes=1)}
    jobs = sweep.plan(experiments, tmp_path / "s", 1)
    sweep.create(tmp_path / "s", experiments, jobs)
    lines = []
    report = sweep.execute(tmp_path / "s", jobs, "local", 1, log=lines.append)
    assert all(r["status"] == "finished" for r in report.values())
    progress = [line for line in lines if "jobs done" in line]
    assert [line.split(";")[0] for line in progress] == [f"[{k}/3 jobs done, 0 not finished, {3 - k} to go"
                                                        + (" (1 running)" if k < 3 else "") for k in (1, 2, 3)]
    assert [("min left at this rate" in line) for line in progress] == [True, True, False]
    # each experiment's rows are merged once its own jobs have finished, not when the sweep ends
    # (a report of a sweep of many hours reads them), and ones that finished before on the next call
    assert ["job" if "jobs done" in line else line.split(":")[0] for line in lines] == ["job", "job", "a", "job", "b"]
    (tmp_path / "s" / "a" / "episodes.csv").unlink()
    again = []
    sweep.execute(tmp_path / "s", jobs, "local", 1, log=again.append)
    assert [line.split(":")[0] for line in again] == ["a", "b"] and (tmp_path / "s" / "a" / "episodes.csv").is_file()


def test_a_job_that_ended_unfinished_counts_as_not_finished_in_the_progress_line(tmp_path, monkeypatch):
    """Each line counts the jobs that have ended (done + to go = all), and among them those that
    did not finish: an interrupted job (Ctrl-C: it checkpointed, --resume goes on) is not
    finished, nor is a killed or a failed one. Four jobs ending finished, interrupted, killed
    and failed in turn (the backend stubbed): 0, 1, 2, 3 not finished."""
    experiments = {"a": resolve_config(env="corridor", agent="constant", seeds=[0, 1, 2, 3], episodes=1)}
    jobs = sweep.plan(experiments, tmp_path / "s", 1)
    sweep.create(tmp_path / "s", experiments, jobs)
    ends = [dict(status="finished"), dict(status="interrupted", reason="SIGINT"),
            dict(status="killed", reason="killed by SIGKILL"), dict(status="failed", reason="exit code 1")]
    monkeypatch.setattr(sweep, "run_local", lambda todo, workers, on_done, on_start: [
        (on_start(j), on_done(j, r)) for j, r in zip(todo, ends)])
    lines = []
    report = sweep.execute(tmp_path / "s", jobs, "local", 1, log=lines.append)
    assert [line.split(";")[0] for line in lines] == [
        "[1/4 jobs done, 0 not finished, 3 to go (1 running)", "[2/4 jobs done, 1 not finished, 2 to go (1 running)",
        "[3/4 jobs done, 2 not finished, 1 to go (1 running)", "[4/4 jobs done, 3 not finished, 0 to go"]
    assert [line.split("] ")[1] for line in lines] == [
        "a job 0 (seeds 0): finished", "a job 1 (seeds 1): interrupted -- SIGINT",
        "a job 2 (seeds 2): killed -- killed by SIGKILL", "a job 3 (seeds 3): failed -- exit code 1"]
    assert [r["status"] for r in report.values()] == ["finished", "interrupted", "killed", "failed"]
    assert not (tmp_path / "s" / "a" / "episodes.csv").exists()                # not merged: not all finished


def test_an_out_that_is_a_file_is_refused_in_one_line(tmp_path, capsys):
    """--out naming an existing regular file: one line naming it, exit 2 (not a raw "[Errno 20]
    Not a directory"), and the file untouched; so too a folder under that file, and --resume of
    the file."""
    write(tmp_path)
    blocker = tmp_path / "a-file"
    blocker.write_text("mine")
    assert sweep_script.main([str(tmp_path / "s.toml"), "--out", str(blocker)]) == 2
    err = capsys.readouterr().err
    assert err == f"sweep.py: error: --out {blocker} is a file, not a folder: choose another --out\n"
    assert sweep_script.main([str(tmp_path / "s.toml"), "--out", str(blocker / "sw")]) == 2
    err = capsys.readouterr().err
    assert err == f"sweep.py: error: cannot create --out {blocker / 'sw'}: Not a directory: choose another --out\n"
    assert sweep_script.main(["--resume", str(blocker)]) == 2
    assert capsys.readouterr().err == f"sweep.py: error: {blocker} holds no sweep to resume (no sweep.json)\n"
    assert blocker.read_text() == "mine"

def test_the_time_left_is_weighed_by_each_jobs_planned_steps():
    """Square (200-step cap) 2 seeds x 10 episodes: 4,000 seed-steps; with a budget of 500 env
    steps: 1,000; liquidation 3 seeds x 4 episodes of 60 trades: 720. One minute for the first
    two (5,000 seed-steps) leaves 720 / 5,000 of a minute, not half of one per job."""
    experiments = {"a": resolve_config(env="square", agent="random", seeds=[0, 1], episodes=10),
                   "b": resolve_config(env="square", agent="random", seeds=[0, 1], episodes=10, env_steps=500),
                   "c": resolve_config(env="liquidation", agent="twap", seeds=[0, 1, 2], episodes=4)}
    a, b, c = (sweep.Job(name, 0, cfg["run"]["seeds"], "x", cfg) for name, cfg in experiments.items())
    assert [sweep.planned_seed_steps(j) for j in (a, b, c)] == [4000, 1000, 720]
    assert sweep.minutes_left(1.0, [a, b], [c]) == pytest.approx(720 / 5000)
    # a gym id's cap is its registered one (CartPole-v1: 500), not the config's 0
    cart = resolve_config(env="gym:CartPole-v1", agent="random", seeds=[0, 1], episodes=3)
    long = resolve_config(env="gym:CartPole-v1", agent="random", seeds=[0, 1], episodes=100, env_steps=700)
    assert [sweep.planned_seed_steps(sweep.Job("d", 0, [0, 1], "x", cfg)) for cfg in (cart, long)] == [3000, 1400]
    # weighed by another cost (reproduce's estimated seconds): a job costing 3 left after 1 + 2 in a minute
    seconds = {"a": 1.0, "b": 2.0, "c": 3.0}
    assert sweep.minutes_left(1.0, [a, b], [c], cost=lambda j: seconds[j.experiment]) == pytest.approx(1.0)
    assert sweep.minutes_left(1.0, [], [c]) == 0.0              # nothing done yet: no guess
    # c under way on one worker: half of it counts as done: 1 minute for 1 + 2 + 1.5, 1.5 left
    assert sweep.minutes_left(1.0, [a, b], [c], cost=lambda j: seconds[j.experiment], running=1) == pytest.approx(
        1.5 / 4.5)
    assert [sweep.clock(m) for m in (0.44, 9.96, 10.4, 119, 150)] == ["0.4 min", "10.0 min", "10 min", "119 min",
                                                                    "2.5 h"]


def test_reproduce_weighs_the_time_left_by_each_jobs_estimated_seconds():
    """A job of an experiment the publication estimates costs its start and its share of the
    estimate's steps (half the seeds: half); one of an experiment it cannot estimate (the corridor,
    never published) its start and its planned seed-steps at the median seconds per planned
    seed-step of the estimated ones."""
    publication = Path(__file__).resolve().parent.parent / "results" / "report"
    planned = {**reproduce.experiments("report", ["square-paper-tuned"]),
               "walk": resolve_config(env="corridor", agent="random", seeds=[0, 1], episodes=5)}
    found = reproduce.estimate(planned, publication)
    estimated = {n: s for n, s, _ in found if s is not None}
    assert set(estimated) == {"square-pt-dgpq", "square-pt-dqn", "square-pt-random"}
    cost = reproduce.job_cost(planned, found)
    half = sweep.Job("square-pt-dqn", 0, planned["square-pt-dqn"]["run"]["seeds"][:10], "x", planned["square-pt-dqn"])
    start = reproduce.JOB_START_S
    assert cost(half) == pytest.approx(start + (estimated["square-pt-dqn"] - start) / 2)
    rates = sorted((estimated[n] - start) / (20 * 10_000) for n in estimated)   # 20 seeds x the 10,000-step budget
    walk = sweep.Job("walk", 0, [0, 1], "x", planned["walk"])
    assert cost(walk) == pytest.approx(start + 2 * 5 * 50 * rates[1])   # 2 seeds x 5 episodes of at most 50 steps
    # the median of four rates (1, 2, 3, 4 s a step: the upper middle, 3); none estimated: 1 s a step
    ones = {f"e{k}": resolve_config(env="corridor", agent="constant", seeds=[0], episodes=1) for k in range(1, 5)}
    four = reproduce.job_cost({**ones, "walk": planned["walk"]},
                              [(n, start + 50 * k, "x") for k, n in enumerate(ones, 1)] + [("walk", None, "none")])
    assert four(walk) == pytest.approx(start + 500 * 3)                       # 2 seeds x 5 episodes x 50 steps
    assert reproduce.job_cost({"walk": planned["walk"]}, [("walk", None, "none")])(walk) == pytest.approx(start + 500)
    # a job begun before costs what its own episodes say it has left; the others as before
    resumed = reproduce.job_cost(planned, found, {"x-walk": 7.5})
    assert resumed(sweep.Job("walk", 0, [0, 1], "x-walk", planned["walk"])) == 7.5
    assert resumed(walk) == pytest.approx(cost(walk)) and resumed(half) == pytest.approx(cost(half))


def checkpoint(folder: Path, episodes: list) -> None:
    """A checkpoint covering each seed's first ``episodes`` (all that ``RunFolder.checkpointed`` reads)."""
    torch.save(dict(collector=dict(episode=torch.tensor(episodes))), folder / runner.CHECKPOINT)


def test_a_checkpoint_says_how_many_episodes_each_seed_keeps_in_the_runs_seed_order(tmp_path):
    """Seeds 7, 3, 5 (not sorted) with 1, 2 and 3 episodes in the latest checkpoint; a damaged latest one:
    the previous; neither readable: None."""
    folder = runner.RunFolder(tmp_path / "r")
    folder.path.mkdir()
    assert folder.checkpointed([7, 3, 5]) is None
    checkpoint(folder.path, [1, 2, 3])
    assert folder.checkpointed([7, 3, 5]) == {7: 1, 3: 2, 5: 3}
    os.replace(folder.file(runner.CHECKPOINT), folder.file(runner.PREVIOUS))
    folder.file(runner.CHECKPOINT).write_bytes(b"damaged")
    assert folder.checkpointed([7, 3, 5]) == {7: 1, 3: 2, 5: 3}
    folder.file(runner.PREVIOUS).write_bytes(b"damaged too")
    assert folder.checkpointed([7, 3, 5]) is None


def test_a_begun_job_is_estimated_by_its_own_episode_times(tmp_path):
    """Episodes 1-100 of 3 seeds done, each episode's batch 0.1 e seconds (0.1 e / 3 a seed-row; wall time
    where the rows record no CPU time): the
    line through the second half is t = 0.1 e, so episodes 101-200 take 0.1 (20,100 - 5,050) = 1,505 s
    (a mean of the episodes done would say 505); an env-step budget: its steps left at its time per
    step over the second half; finished: 0; no episodes yet: no own estimate. Only the rows the
    checkpoint covers count: after a hard kill a resume runs those after it again."""
    out = tmp_path / "s"
    plan = {"a": resolve_config(env="corridor", agent="constant", seeds=[0, 1, 2], episodes=200),
            "b": resolve_config(env="corridor", agent="constant", seeds=[0, 1, 2], episodes=1000, env_steps=3000),
            "c": resolve_config(env="corridor", agent="constant", seeds=[3], episodes=1),
            "d": resolve_config(env="corridor", agent="constant", seeds=[4, 5], episodes=1)}
    jobs = sweep.plan(plan, out, None, {"d": 2})             # d in two jobs: one run, one not started
    sweep.create(out, plan, jobs)
    folders = {j.experiment: Path(j.folder) for j in jobs}
    e = np.repeat(np.arange(1, 101), 3)
    rows = pd.DataFrame(dict(seed=np.tile([0, 1, 2], 100), episode=e, steps=10, wall_s=0.1 * e / 3))
    folders["a"].mkdir(parents=True)
    rows.to_csv(folders["a"] / "episodes.csv", index=False)
    start = reproduce.JOB_START_S
    assert reproduce.seconds_left(str(folders["a"]), plan["a"]["run"]) is None          # no checkpoint: from the start
    checkpoint(folders["a"], [90, 90, 90])                  # killed 10 episodes after its last checkpoint
    assert reproduce.seconds_left(str(folders["a"]), plan["a"]["run"]) == pytest.approx(start + 0.1 * (20100 - 4095))
    # the latest checkpoint damaged: the previous one, as a resume falls back to it
    os.replace(folders["a"] / runner.CHECKPOINT, folders["a"] / runner.PREVIOUS)
    (folders["a"] / runner.CHECKPOINT).write_bytes(b"not a checkpoint")
    assert reproduce.seconds_left(str(folders["a"]), plan["a"]["run"]) == pytest.approx(start + 0.1 * (20100 - 4095))
    (folders["a"] / runner.PREVIOUS).unlink()
    checkpoint(folders["a"], [100, 100, 100])
    assert reproduce.seconds_left(str(folders["a"]), plan["a"]["run"]) == pytest.approx(start + 1505)
    # with the CPU time recorded (here half the wall time: another process shared the core), by that
    rows.assign(cpu_s=rows.wall_s / 2).to_csv(folders["a"] / "episodes.csv", index=False)
    assert reproduce.seconds_left(str(folders["a"]), plan["a"]["run"]) == pytest.approx(start + 1505 / 2)
    # a seed behind the others: its episode is not yet counted as done
    rows.iloc[:-1].to_csv(folders["a"] / "episodes.csv", index=False)
    assert reproduce.seconds_left(str(folders["a"]), plan["a"]["run"]) == pytest.approx(
        start + 0.1 * (20100 - 4950))
    # budget of 3,000 steps: 1,000 ran (100 x 10); the second half (episodes 51-100) took 0.1 x 3,775 s for
    # 500 steps: 2,000 steps left at 0.755 s each
    folders["b"].mkdir(parents=True)
    rows.to_csv(folders["b"] / "episodes.csv", index=False)
    checkpoint(folders["b"], [100, 100, 100])
    assert reproduce.seconds_left(str(folders["b"]), plan["b"]["run"]) == pytest.approx(start + 2000 * 0.755)
    sweep.execute(out, [j for j in jobs if j.experiment == "c" or j.seeds == [4]], "local", 1, log=lambda line: None)
    assert reproduce.seconds_left(str(folders["c"]), plan["c"]["run"]) == 0.0
    # the time-left guide of a reproduction continued costs each job begun there by its own episodes;
    # one whose rows cannot be read is left to its estimate (the reproduction goes on)
    damaged = Path(next(j.folder for j in jobs if j.seeds == [5]))
    damaged.mkdir(parents=True)
    (damaged / "episodes.csv").write_text("seed,episode\n5,1\n")     # no time columns
    checkpoint(damaged, [1])
    with pytest.raises(KeyError):
        reproduce.seconds_left(str(damaged), plan["d"]["run"])
    own = reproduce.own_time_left(jobs)
    assert own == {str(folders["a"]): pytest.approx(start + 0.1 * (20100 - 4950)),
                   str(folders["b"]): pytest.approx(start + 2000 * 0.755), str(folders["c"]): 0.0,
                   next(j.folder for j in jobs if j.seeds == [4]): 0.0}
    begun = reproduce.begun(out, plan)
    assert set(begun) == {"a", "b", "c", "d"} and begun["c"] == [(1, 0.0)] and begun["d"] == [(1, 0.0), (1, None)]
    assert reproduce.seconds_left(str(tmp_path / "none"), plan["a"]["run"]) is None
    text = reproduce.plan_text(plan, tmp_path / "no-publication", out=out)
    assert f"a: 3 seeds x 200, ~{(start + 0.1 * (20100 - 4950)) / 60:,.1f} min left (begun in {out}" in text
    assert f"c: 1 seed x 1, finished in {out}" in text and "4 of them begun" in text
    # no publication to estimate d's job not started from: not "finished", and the total says so
    assert "d: 2 seeds x 1, begun, 1 job not started and not estimated" in text and "without the 1 not estimated" in text


@pytest.mark.slow
def test_a_ray_worker_killed_mid_job_is_retried_from_its_checkpoint(tmp_path):
    """SIGKILL the Ray worker running the only job once it is writing rows: Ray runs the task
    again (max_retries), which resumes the job from its checkpoint; the rows equal one process's."""
    ray = pytest.importorskip("ray")
    experiments, out, jobs = square_sweep(tmp_path, episodes=60, seeds_per_job=4)
    folder = runner.RunFolder(jobs[0].folder)
    killed = []

    def kill_the_worker():
        for _ in range(600):
            status = folder.status() or {}
            if status.get("status") == "running" and folder.file("episodes.csv").exists():
                os.kill(status["pid"], signal.SIGKILL)
                killed.append(status["pid"])
                return
            time.sleep(0.05)
    try:
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
        threading.Thread(target=kill_the_worker, daemon=True).start()
        report = sweep.execute(out, jobs, "ray", log=lambda line: None)
    finally:
        ray.shutdown()
    assert killed and all(r["status"] == "finished" for r in report.values())
    (name, config), = experiments.items()
    pd.testing.assert_frame_equal(rows(out / name / "episodes.csv"), one_process(config, tmp_path / "single"))


def test_an_out_a_node_cannot_write_is_named_in_one_line(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    reason = sweep.writable_here(str(blocker / "out"))
    assert reason.startswith("node ") and reason.endswith(f"cannot write {blocker / 'out'}: Not a directory")
    assert sweep.writable_here(str(tmp_path / "fine" / "new")) is None and (tmp_path / "fine" / "new").is_dir()
    assert list((tmp_path / "fine" / "new").iterdir()) == []                      # its probe removed
    assert sweep.writable_here(str(tmp_path / "fine" / "new")) is None             # a folder there already


def test_a_plan_that_grew_keeps_the_finished_jobs_and_adds_the_new_ones(tmp_path):
    out = tmp_path / "s"
    a = resolve_config(env="corridor", agent="constant", seeds=[0, 1], episodes=1)
    b = resolve_config(env="corridor", agent="constant", seeds=[2], episodes=2)
    sweep.create(out, {"a": a}, sweep.plan({"a": a}, out, None))
    sweep.execute(out, sweep.load(out)[1], "local", 1, log=lambda line: None)
    rows_a = (out / "a" / "episodes.csv").read_text()
    jobs = sweep.grow(out, {"a": a, "b": b}, 1)
    assert [(j.experiment, j.seeds) for j in jobs] == [("a", [0, 1]), ("b", [2])]
    assert sweep.load(out)[0] == {"a": a, "b": b}                       # the plan on disk grew too
    report = sweep.execute(out, sweep.load(out)[1], "local", 1, log=lambda line: None)
    assert report["a job 0 (seeds 0-1)"]["note"] == "finished before"   # not run again
    assert report["b job 0 (seeds 2)"]["status"] == "finished"
    assert (out / "a" / "episodes.csv").read_text() == rows_a and len(pd.read_csv(out / "b" / "episodes.csv")) == 2
    assert sweep.grow(out, {"a": a, "b": b}, None) == jobs               # nothing new: the same jobs
    other = resolve_config(env="corridor", agent="constant", seeds=[0, 1], episodes=3)
    with pytest.raises(sweep.SweepError, match="planned otherwise now: a"):
        sweep.grow(out, {"a": other, "b": b}, None)
    with pytest.raises(sweep.SweepError, match="no longer planned: b"):
        sweep.grow(out, {"a": a}, None)
    assert sweep.grow(out, {"a": a, "b": b}, None, same=lambda x, y: True) == jobs  # the caller's sameness
    shutil.rmtree(out / "a")                                            # removed: planned anew
    jobs = sweep.grow(out, {"a": other, "b": b}, None)
    assert [(j.experiment, j.seeds) for j in jobs] == [("b", [2]), ("a", [0, 1])]
    assert sweep.load(out)[0]["a"] == other and not runner.RunFolder(jobs[1].folder).finished()


def test_the_time_left_gives_each_job_left_to_the_worker_free_first_at_the_rate_the_finished_took():
    """Jobs costing a 1 and b 3 took 20 s and 60 s: 20 s per unit. c (cost 2) has run 15 s of its
    40: 25 left; d (1: 20 s) and e (4: 80 s) wait, in that order, for 2 workers: d on the idle
    one (0 -> 20), then e on it again (20 -> 100), while c ends at 25: 100 s, not the 62.5 s a
    sum of costs over two workers would say. The order is the pool's: e first ends at 80."""
    a, b, c, d, e = (sweep.Job(name, 0, [0], "x", {}) for name in "abcde")
    units = {"a": 1, "b": 3, "c": 2, "d": 1, "e": 4}
    cost = lambda job: units[job.experiment]          # noqa: E731
    took = [(a, 20.0), (b, 60.0)]
    assert sweep.seconds_left(took, [(c, 15.0)], [d, e], 2, cost) == pytest.approx(100.0)
    assert sweep.seconds_left(took, [(c, 15.0)], [e, d], 2, cost) == pytest.approx(80.0)
    assert sweep.seconds_left(took, [(c, 15.0)], [d, e], 1, cost) == pytest.approx(125.0)   # one after another
    assert sweep.seconds_left(took, [(c, 15.0)], [d, e], 3, cost) == pytest.approx(80.0)    # each its own worker
    assert sweep.seconds_left(took, [(c, 15.0)], [], 2, cost) == pytest.approx(25.0)
    # a job past its guess (c: 40 s) still has a quarter of what it has run to go, not 0: else the
    # guide says the sweep is ending while its last long job runs on
    assert sweep.seconds_left(took, [(c, 50.0)], [], 2, cost) == pytest.approx(12.5)
    assert sweep.seconds_left(took, [(c, 36.0)], [], 2, cost) == pytest.approx(9.0)          # the floor above 4 s
    assert sweep.seconds_left(took, [(c, 30.0)], [], 2, cost) == pytest.approx(10.0)         # 10 s above the floor
    assert sweep.seconds_left(took, [(c, 50.0)], [d], 2, cost) == pytest.approx(20.0)
    assert sweep.seconds_left(took, [], [], 2, cost) == 0.0
    assert sweep.seconds_left([], [(c, 15.0)], [d], 2, cost) is None                        # no rate yet
    assert sweep.seconds_left([(a, 5.0)], [], [d], 2, lambda job: 0.0) is None
    with pytest.raises(ValueError, match="workers must be >= 1, got 0"):
        sweep.seconds_left(took, [], [d], 0, cost)


def test_a_prior_counts_the_estimate_as_seconds_of_jobs_taken_at_one_second_a_unit():
    """a (cost 10) took 5 s: 0.5 s a unit alone; with a prior of 30 units at 1 s each,
    (5 + 30) / (10 + 30) = 0.875; d (cost 4) then waits 3.5 s. No rate before a job ends, prior
    or not."""
    a, d = sweep.Job("a", 0, [0], "x", {}), sweep.Job("d", 0, [0], "x", {})
    cost = lambda job: {"a": 10.0, "d": 4.0}[job.experiment]          # noqa: E731
    assert sweep.rate([(a, 5.0)], cost) == 0.5
    assert sweep.rate([(a, 5.0)], cost, prior=30.0) == 0.875
    assert sweep.rate([], cost, prior=30.0) is None
    assert sweep.seconds_left([(a, 5.0)], [], [d], 1, cost, prior=30.0) == pytest.approx(3.5)
    assert sweep.seconds_left([(a, 5.0)], [], [d], 1, cost) == pytest.approx(2.0)


def test_the_progress_line_says_how_many_running_jobs_are_past_their_estimate(tmp_path, monkeypatch):
    """Three jobs of one unit each on two workers (the backend and the clock stubbed): a ends at 10 s
    while b, begun with it, has run its 10 s, not past; c begun at 10 ends at 30, the rate now
    15 s a unit, and b has run 30: one past its estimate, a quarter of its 30 s left (7.5 s)."""
    experiments = {"x": resolve_config(env="corridor", agent="constant", seeds=[0, 1, 2], episodes=1)}
    jobs = sweep.plan(experiments, tmp_path / "s", 1)
    sweep.create(tmp_path / "s", experiments, jobs)
    now = [0.0]
    monkeypatch.setattr(sweep.time, "perf_counter", lambda: now[0])
    a, b, c = jobs

    def run_local(todo, workers, on_done, on_start):
        on_start(a), on_start(b)
        now[0] = 10.0
        on_done(a, dict(status="finished"))
        on_start(c)
        now[0] = 30.0
        on_done(c, dict(status="finished"))
        on_done(b, dict(status="finished"))
    monkeypatch.setattr(sweep, "run_local", run_local)
    lines = []
    sweep.execute(tmp_path / "s", jobs, "local", 2, log=lines.append, cost=lambda job: 1.0)
    progress = [line.split("; ")[1].split("]")[0] for line in lines if "jobs done" in line]
    assert progress == ["0.2 min, ~0.2 min left at this rate",
                        "0.5 min, ~0.1 min left at this rate (1 past its estimate)", "0.5 min"]
    # a prior of 10 s at 1 s a unit: 20 / 11 s a unit after a, 40 / 12 after c; b, begun at 0, has
    # run 10 s of its 20 / 11 (past: 2.5 s left, c's 20 / 11 beside it), then 30 s of its 10 / 3 (7.5 left)
    lines.clear()
    now[0] = 0.0
    sweep.create(tmp_path / "s", experiments, jobs, overwrite=True)
    sweep.execute(tmp_path / "s", jobs, "local", 2, log=lines.append, cost=lambda job: 1.0, prior=10.0)
    progress = [line.split("; ")[1].split("]")[0] for line in lines if "jobs done" in line]
    assert progress == ["0.2 min, ~0.0 min left at this rate (1 past its estimate)",
                        "0.5 min, ~0.1 min left at this rate (1 past its estimate)", "0.5 min"]


def test_makespan_gives_each_job_longest_first_to_the_worker_free_first():
    # 2 workers: 5 | 4, then 3 -> the 4 (7), 3 -> the 5 (8), 3 -> the 7 (10); the best split is 9
    assert sweep.makespan([3, 5, 3, 4, 3], 2) == 10
    assert sweep.makespan([3, 5, 3, 4, 3], 1) == 18 and sweep.makespan([3, 5, 3, 4, 3], 64) == 5
    assert sweep.makespan([], 4) == 0
    with pytest.raises(ValueError, match="workers"):
        sweep.makespan([1.0], 0)


def test_the_reports_cost_section_sums_each_jobs_rows_and_projects_them(tmp_path):
    from trl_dgpq.analysis.runs import Run
    for name, config in (("a", {"git": {"commit": "abcdef1234"}}), ("b", {"git": {"commit": "1234567890"}}),
                         ("c", {})):                                       # c's job config has no commit
        (tmp_path / name / "jobs" / "j000").mkdir(parents=True)
        (tmp_path / name / "jobs" / "j000" / "config.json").write_text(json.dumps(config))
    # a: two jobs of 1,800 s and 3,600 s (two rows each); b: one job of 360,000 s (100 h); c: a plain run
    # folder, no job column: one job of 36 s
    a = pd.DataFrame(dict(seed=[0, 0, 1, 1], job=[0, 0, 1, 1], steps=[10, 10, 10, 10], wall_s=[900.0, 900, 1800, 1800]))
    b = pd.DataFrame(dict(seed=[0, 1], job=[0, 0], steps=[100, 100], wall_s=[180_000.0, 180_000]))
    c = pd.DataFrame(dict(seed=[0, 0], steps=[6, 6], wall_s=[18.0, 18.0]))
    loaded = [(None, {"a": Run(tmp_path / "a", a, {}), "b": Run(tmp_path / "b", b, {})}),
              (None, {"c": Run(tmp_path / "c", c, {})})]
    text = reproduce.cost_section(loaded)
    assert text.startswith("## What it cost\n\nEach experiment's wall time is the sum of its rows' `wall_s` (the time "
                           "of the seed batch, shared among its seeds; process start-up not counted)")
    assert ("measured on this machine while other work shared its cores, so a quiet machine is faster.\n\n"
            "| experiment | seeds | seed-steps | wall, min | ms per seed-step |\n|---|---|---|---|---|\n"
            "| a | 2 | 40 | 90.0 | 135000.00 |\n| b | 2 | 200 | 6,000.0 | 1800000.00 |\n| c | 1 | 12 | 0.6 | 3000.00 |\n\n"
            "In all 101.51 h of one core over 4 jobs.") in text
    assert "the longest job, 100.00 h, bounds it): 2 cores 100.00 h, 16 cores 100.00 h" in text
    assert text.endswith("Runs made at commits 1234567, ?, abcdef1.\n")
    assert reproduce.cost_section([(None, {})]) == ""


def test_reuse_copies_an_experiment_that_finished_elsewhere_with_the_same_settings_only(tmp_path, capsys):
    """The rows a run here would write (seeds never depend on their batch), taken from a sweep
    where the same config finished; a config that differs in one setting, one unfinished
    there, or one begun here runs here."""
    def square(max_steps=5, episodes=2):
        return resolve_config(env="square", agent="random", seeds=[0, 1, 2], episodes=episodes, max_steps=max_steps)
    a = square()
    src = tmp_path / "src"
    there = {"done": a, "other": square(max_steps=6), "open": square(episodes=3)}
    sweep.create(src, there, jobs := sweep.plan(there, src, 2))
    sweep.execute(src, [j for j in jobs if j.experiment != "open"], "local", 1, log=lambda line: None)
    out = tmp_path / "here"
    planned = {"x": a, "y": square(max_steps=7), "z": square(episodes=3), "begun": a}
    sweep.create(out, planned, jobs := sweep.plan(planned, out, None))
    (out / "begun" / "jobs" / "j000").mkdir(parents=True)
    runner.RunFolder(out / "begun" / "jobs" / "j000").write_json(runner.CONFIG, {})     # a job here has begun
    lines = []
    jobs = sweep.reuse(out, jobs, [out, src], log=lines.append)        # its own folder among the sources: skipped
    assert lines == [f"x: reused the finished {src / 'done'} (2 jobs)"]
    assert [(j.experiment, j.seeds) for j in jobs] == [("x", [0, 1]), ("x", [2]), ("y", [0, 1, 2]), ("z", [0, 1, 2]),
                                                       ("begun", [0, 1, 2])]
    assert sweep.load(out)[1] == jobs and json.loads((out / "x" / "reused.json").read_text()) == \
        {"from": str(src / "done"), "jobs": 2}
    assert not (out / "x" / "jobs" / "j001" / runner.LOCK).exists()
    report = sweep.execute(out, [j for j in jobs if j.experiment != "begun"], "local", 1, log=lambda line: None)
    assert report["x job 0 (seeds 0-1)"]["note"] == "finished before" and report["y job 0 (seeds 0-2)"]["status"] == \
        "finished"
    pd.testing.assert_frame_equal(rows(out / "x" / "episodes.csv"), one_process(a, tmp_path / "fresh"))  # x run here
    assert sweep.reuse(out, jobs, [src], log=lines.append) == jobs and len(lines) == 1   # once only
    text = ('[defaults]\nseeds = "0-2"\nepisodes = 2\n[[experiment]]\nname = "w"\nenv = "square"\nagent = "random"\n'
            '[experiment.set]\nmax_steps = 5\n')
    assert sweep_script.main([str(write(tmp_path, text)), "--out", str(tmp_path / "cli"), "--workers", "1",
                              "--reuse", str(src)]) == 0
    assert "w: reused the finished" in capsys.readouterr().out


def test_reproduce_reuses_only_an_experiment_equal_in_every_setting():
    """grow lets a recorded experiment stand when its run section is the same; reuse takes
    rows from elsewhere only when every env and agent setting is the same too."""
    a = resolve_config(env="square", agent="dgpq", seeds=[0, 1], episodes=2)
    b = resolve_config(env="square", agent="dgpq", seeds=[0, 1], episodes=2, lipschitz=2.0)
    assert reproduce.same_run(a) == reproduce.same_run(b) and reproduce.same_config(a) != reproduce.same_config(b)
    older = {**a, "run": {k: v for k, v in a["run"].items() if k != "max_memory"}}   # recorded before max_memory
    assert reproduce.same_config(older) == reproduce.same_config(a)
    # an env or agent setting added since takes its default: equal to a run recorded before it
    # existed, unless set to something else (the F-16's potential, added after GWH14's runs)
    f16 = resolve_config(env="f16", agent="pd", seeds=[0], episodes=2)
    before = {**f16, "env": {k: v for k, v in f16["env"].items() if not k.startswith("potential")}}
    assert reproduce.same_config(before) == reproduce.same_config(f16)
    assert reproduce.same_config(before) != reproduce.same_config(
        resolve_config(env="f16", agent="pd", seeds=[0], episodes=2, potential="lqr"))
    assert reproduce.same_config({**a, "agent": {k: v for k, v in a["agent"].items() if k != "eps1"}}) == \
        reproduce.same_config(a)


def test_reproduce_reports_the_domains_whose_experiments_all_finished(tmp_path, capsys, monkeypatch):
    """--report runs nothing: a finished domain gets its section, claims and rows; one still
    running gets a line naming what it waits for; the head says how far the run got."""
    from types import SimpleNamespace

    from trl_dgpq.analysis.claims import Claim, Interval, NoNumber

    def domain(name, experiments):
        return (SimpleNamespace(name=name, examples=lambda: ["corridor"]),
                SimpleNamespace(REPRODUCE=[(e, dict(agent="constant")) for e in experiments],
                                SCALES={"smoke": (1, 2), "report": (1, 2), "full": (1, 2)},
                                reproduce_section=lambda runs, out, label, title, judged: calls.append((out, label, title))
                                or f"## Section {name} ({len(runs)})\n",
                                CLAIMS=[Claim(f"{name}/k", "GWH14", f"{name} claim", NoNumber(),
                                              lambda runs: Interval(len(runs), len(runs), len(runs), "n"),
                                              (experiments[0],), decided_at=("smoke",))]))
    calls = []
    both = [domain("a", ["a1", "a2"]), domain("b", ["b1", "b2", "b3"])]
    monkeypatch.setattr(reproduce, "reproductions", lambda only=None: [d for d in both if not only or d[0].name in only])
    out = tmp_path / "repro"
    planned = reproduce.experiments("smoke")
    sweep.create(out, planned, jobs := sweep.plan(planned, out, None))
    assert reproduce.main(["--scale", "smoke", "--out", str(out), "--report"]) == 0
    text = (out / "REPORT.md").read_text()
    assert "Partial: 0 of 5 experiments have finished" in text and "## Claims" not in text
    assert "the run continues with the same command.\n\n## a: not finished" in text             # no claims: nothing
    assert "## a: not finished\n\n0 of 2 experiments have finished; waiting for a1, a2.\n" in text
    for job in jobs:                                   # a's experiments finish, and one of b's
        if job.experiment in ("a1", "a2", "b2"):
            folder = runner.RunFolder(job.folder)
            folder.path.mkdir(parents=True)
            runner.start(job.config, folder, progress=False)
            sweep.merge(out, job.experiment, [job])
    capsys.readouterr()
    assert reproduce.main(["--scale", "smoke", "--out", str(out), "--report", "--publish", str(tmp_path / "pub")]) == 0
    assert "(3 of 5 experiments finished)" in capsys.readouterr().out
    text = (out / "REPORT.md").read_text()
    assert ("**Partial: 3 of 5 experiments have finished.** A domain's section and claims appear once all its "
            "experiments have; the run continues with the same command.\n\n## Claims") in text
    assert "## Section a (2)" in text and text.startswith("# Reproduction of the seed report (smoke scale)\n")
    label = ("*Scale: smoke* -- fewer seeds and episodes than the seed report (the smoke scale; numbers are noisier): "
             "a 1 seed x 2 episodes, b 1 seed x 2 episodes (some agents fewer: see the tables).")
    # the report here, then the publication rebuilt from its data alone
    assert calls == [(out, label, "smoke scale (fewer seeds and episodes than the seed report)"),
                     (tmp_path / ".pub.new", label, "smoke scale (fewer seeds and episodes than the seed report)")]
    assert "## b: not finished\n\n1 of 3 experiments have finished; waiting for b1, b3.\n" in text
    assert "## Section b" not in text and "## a: not finished" not in text
    assert (out / "claims.md").read_text() == (
        "| source | claim | rule | ours | verdict | uses the model |\n|---|---|---|---|---|---|\n"
        "| GWH14 | a claim | the source gives no number | 2 (n) | no number to compare | no |\n\n"
        "1 no number to compare.\n")
    assert sorted(pd.read_csv(out / "results.csv").experiment) == ["a1", "a2", "b2"]
    assert "| b2 | 1 |" in text                                      # what it cost so far counts b2 too
    pub = (tmp_path / "pub" / "REPORT.md").read_text()
    assert pub.split("## Claims")[1] == text.split("## Claims")[1] and "Built from the per-episode data" in pub
    assert reproduce.main(["--scale", "smoke", "--out", str(out), "--only", "a", "--report"]) == 0   # a is whole
    text = (out / "REPORT.md").read_text()
    assert "reproduce.py --scale smoke --only a` on " in text and "Partial" not in text and "Section b" not in text
    assert calls[-1][1].startswith("*Scale: smoke* -- fewer seeds and episodes than the seed report (the smoke scale; "
                                   "numbers are noisier): a 1 seed x 2 episodes (some")            # a's alone
    assert reproduce.main(["--scale", "smoke", "--out", str(out), "--only", "a", "b", "--report"]) == 0
    assert "reproduce.py --scale smoke --only a b` on " in (out / "REPORT.md").read_text()
    for job in jobs:
        if job.experiment in ("b1", "b3"):
            folder = runner.RunFolder(job.folder)
            folder.path.mkdir(parents=True)
            runner.start(job.config, folder, progress=False)
            sweep.merge(out, job.experiment, [job])
    for dirty in (True, False):           # the commit's marker says whether the work tree had changes
        monkeypatch.setattr(reproduce.runner, "provenance", lambda: {"git": {"commit": "abc1234", "dirty": dirty}})
        assert reproduce.main(["--scale", "smoke", "--out", str(out), "--report"]) == 0
        head = (out / "REPORT.md").read_text()
        assert ("commit abc1234 (dirty), " in head) is dirty and ("commit abc1234, " in head) is not dirty
    text = (out / "REPORT.md").read_text()
    import re
    claims = (out / "claims.md").read_text().removesuffix("\n")
    assert re.fullmatch(
        r"# Reproduction of the seed report \(smoke scale\)\n\nGenerated by `python scripts/reproduce.py --scale smoke` "
        r"on \d{4}-\d\d-\d\d \d\d:\d\d, commit \S+( \(dirty\))?, \d+ cores; sweep wall time 0.0 min \(this invocation\)."
        r"\n\n## Claims, and whether they reproduce\n\nEach claim of GWH14, the seed report, AC00 \(the model's closed "
        r"form\) and this suite's own goals, with its rule, fixed before the run, and what this run measured "
        r"\(`trl_dgpq/analysis/claims.py` says how each kind is judged; a claim judged on a run that uses the env's "
        r"model is a variant, counted apart\); the sections below have the tables and figures.\n\n" + re.escape(claims) + r"\n\n## Section a \(2\)\n\n## Section b \(3\)\n\n## What it cost\n.*",
        text, re.S), text[:800]
    assert "| a claim | the source gives no number | 2 (n) |" in claims and "| b claim | the source gives no number | 3 (n) |" in claims
    calls.clear()
    del both[1][1].CLAIMS                                   # a domain without claims: its section alone
    reproduce.write_report(out, "report", 600.0)            # the report scale's title and label; the wall time
    text = (out / "REPORT.md").read_text()
    assert "sweep wall time 10.0 min (this invocation)" in text and "b claim" not in text and "a claim" in text
    assert [c[1:] for c in calls] == [("*Scale: report* -- the seed report's lengths: a 1 seed x 2 episodes, b 1 seed "
                                       "x 2 episodes (some agents fewer: see the tables).", "report scale")] * 2
    reproduce.write_report(out, "full", 0.0)
    assert calls[-1][2] == "full scale" and calls[-1][1].startswith("*Scale: full* -- the seed report's lengths: ")
    assert reproduce.main(["--scale", "smoke", "--out", str(tmp_path / "none"), "--report"]) == 2


# ------------------------------------------------------------------ signals outside a run (issue 52)
def fake_context(monkeypatch, **hooks):
    context = fake_processes(monkeypatch, sweep.mp, **hooks)
    monkeypatch.setattr(sweep, "wait", lambda sentinels: sentinels[:1])
    return context


def sigterm_self():
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(0.05)       # the handler runs by now


def test_workers_come_from_a_forkserver_that_imported_each_jobs_env_and_agent(tmp_path, monkeypatch):
    """The forkserver preloads this module and every job's env and agent modules, so no job imports
    them again; a config without an env and agent (a test's) adds none."""
    configs = [resolve_config(env="square", agent="dgpq", seeds=[0], episodes=1),
               resolve_config(env="liquidation", agent="twap", seeds=[0], episodes=1),
               resolve_config(env="square", agent="random", seeds=[1], episodes=1)]
    assert sweep.job_modules(configs) == sorted({
        "trl_dgpq.collectors.sweep", "trl_dgpq.dgpq", "trl_dgpq.agents.random", "trl_dgpq.envs.square.env",
        "trl_dgpq.envs.liquidation.env", "trl_dgpq.envs.liquidation.baselines"})
    assert sweep.job_modules([{}, {"run": {"env": "square"}}]) == ["trl_dgpq.collectors.sweep"]
    unknown = [{"run": {"env": "nowhere", "agent": "dgpq"}}, {"run": {"env": "square", "agent": "nobody"}}]
    assert sweep.job_modules(unknown) == ["trl_dgpq.collectors.sweep"]       # their jobs fail, saying why
    context = fake_context(monkeypatch)
    jobs = [sweep.Job("e", k, c["run"]["seeds"], str(tmp_path / f"j{k}"), c) for k, c in enumerate(configs)]
    sweep.run_local(jobs, 2, lambda job, out: None)
    assert context.preload == sweep.job_modules(configs) and len(FakeProcess.made) == 3


def test_a_sigterm_while_a_worker_starts_still_stops_that_worker(tmp_path, monkeypatch):
    """Inside start(): the worker is recorded before Terminated, so it is passed the SIGTERM and
    reaped (on_done), not left running."""
    fake_context(monkeypatch, on_start=once(sigterm_self))
    jobs = [sweep.Job("e", 0, [0], str(tmp_path / "j0"), {}), sweep.Job("e", 1, [1], str(tmp_path / "j1"), {})]
    done = []
    with pytest.raises(sweep.Terminated):
        with sweep._sigterm_raises():
            sweep.run_local(jobs, 2, lambda job, out: done.append((job.index, out["status"])))
    assert len(FakeProcess.made) == 1 and FakeProcess.made[0].terminated        # the second never started
    assert done == [(0, "killed")]


def once(action):
    """``action`` the first time only (a second SIGTERM would end the test's process: by design)."""
    calls = []
    return lambda *_: None if calls else (calls.append(1), action())


def test_a_sigterm_while_a_worker_is_reaped_still_records_it(tmp_path, monkeypatch):
    fake_context(monkeypatch, on_join=once(sigterm_self))
    jobs = [sweep.Job("e", 0, [0], str(tmp_path / "j0"), {}), sweep.Job("e", 1, [1], str(tmp_path / "j1"), {})]
    done = []
    with pytest.raises(sweep.Terminated):
        with sweep._sigterm_raises():
            sweep.run_local(jobs, 2, lambda job, out: done.append(job.index))
    assert sorted(done) == [0, 1]          # the one reaped when it came, and the other stopped and reaped
    assert [p.terminated for p in FakeProcess.made] == [False, True]


def test_sigterm_outside_a_held_section_stops_at_once_and_a_second_one_kills():
    """Outside ``_sigterm_held`` a SIGTERM raises at once; the handler then gives SIGTERM back to
    its default, so a second one ends a stuck sweep without waiting. The handler before is restored
    after the block, with nothing left pending."""
    before = signal.getsignal(signal.SIGTERM)
    ran = []
    with pytest.raises(sweep.Terminated):
        with sweep._sigterm_raises():
            try:
                sigterm_self()
                ran.append("never")
            finally:
                second = signal.getsignal(signal.SIGTERM)
    assert ran == [] and second == signal.SIG_DFL
    assert signal.getsignal(signal.SIGTERM) is before and sweep._SIGTERM == {"held": False, "pending": False}
    with pytest.raises(sweep.Terminated):          # held: the block runs to its end, then Terminated
        with sweep._sigterm_raises():
            with sweep._sigterm_held():
                sigterm_self()
                ran.append("held")
            ran.append("never")
    assert ran == ["held"] and sweep._SIGTERM == {"held": False, "pending": False}


@pytest.mark.parametrize("stop, code, name", [(KeyboardInterrupt(), 130, "SIGINT"), (sweep.Terminated(), 143, "SIGTERM")])
def test_sweep_and_reproduce_end_a_signal_with_one_line_and_its_code(tmp_path, monkeypatch, capsys, stop, code, name):
    given, started = [], []

    def interrupted(*args, **kwargs):
        given.append(kwargs)
        raise stop
    monkeypatch.setattr(sweep, "execute", interrupted)
    monkeypatch.setattr(sweep, "start_forkserver", started.append)
    assert reproduce.main(["--scale", "smoke", "--only", "f16", "--out", str(tmp_path / "r"), "--workers", "1"]) == code
    assert capsys.readouterr().err == f"interrupted by {name}: continue with the same command\n"
    assert given[0]["prior"] == reproduce.GUIDE_PRIOR_S == 120.0        # the guide's trust in the estimate
    # the workers' forkserver started before the plan, with the planned jobs' modules
    assert started == [sweep.job_modules(reproduce.experiments("smoke", ["f16"]).values())]
    assert "trl_dgpq.envs.f16.env" in started[0] and "trl_dgpq.agents.dqn" in started[0]
    assert sweep.run_script("sweep.py", "--resume X", interrupted) == code
    assert capsys.readouterr().err == f"interrupted by {name}: continue with --resume X\n"


def test_the_guides_prior_is_seconds_only_where_something_is_estimated():
    """With no experiment estimated (no publication), the guide's costs are seed-steps: no prior."""
    assert reproduce.guide_prior([("a", None, ""), ("b", 12.0, "measured")]) == 120.0
    assert reproduce.guide_prior([("a", None, ""), ("b", None, "")]) == 0.0 == reproduce.guide_prior([])


def test_the_plan_estimates_each_experiment_from_the_published_one_like_it(tmp_path, capsys):
    """A publication holding one corridor run (1 seed x 10 episodes, 1 s per episode for 4, then 2 s):
    4 episodes of 2 seeds cost 2 x 4 x 1 = 8 s; 20 episodes, past the published 10, cost
    2 x (10 x 1.6 + 10 x 2) = 72 s (the extra episodes at its last 10 %'s rate); each job 1 s more
    to start; another agent has none like it."""
    data = tmp_path / "pub" / "data"
    data.mkdir(parents=True)
    a = resolve_config(env="corridor", agent="constant", seeds=[5], episodes=10)
    pd.DataFrame(dict(seed=5, episode=range(1, 11), steps=3, wall_s=[1.0] * 4 + [2.0] * 6)).to_csv(
        data / "a.csv.xz", index=False)
    (data / "a.json").write_text(json.dumps(a))
    (data / "manifest.json").write_text(json.dumps({"experiments": ["a"]}))
    planned = {"b": resolve_config(env="corridor", agent="constant", seeds=[10, 11], episodes=4),
               "c": resolve_config(env="corridor", agent="constant", seeds=[10, 11], episodes=20, slip=0.3),
               "d": resolve_config(env="corridor", agent="random", seeds=[10], episodes=4),
               "a": a}
    got = {name: (seconds, how) for name, seconds, how in reproduce.estimate(planned, tmp_path / "pub")}
    start = reproduce.JOB_START_S
    assert start == 1.0
    assert got["b"] == (pytest.approx(1 + 8.0), "like a, 0 settings apart")
    assert got["c"] == (pytest.approx(1 + 72.0), "like a, 1 setting apart")
    assert got["d"] == (None, "no published experiment like it") and got["a"] == (pytest.approx(1 + 16.0), "measured")
    text = reproduce.plan_text(planned, tmp_path / "pub")
    assert "  c: 2 seeds x 20, ~1.2 min (like a, 1 setting apart)\n" in text         # 73 s
    assert "4 experiments, one job each: ~1.6 min of one core and wall time 2 cores ~1.2 min" in text   # 99 s; 73 s
    assert "both without the 1 not estimated (longest job first" in text
    budget = {"e": resolve_config(env="corridor", agent="constant", seeds=[10], episodes=4, env_steps=9),
              "g": resolve_config(env="corridor", agent="constant", seeds=[10], episodes=100, env_steps=9)}
    got = {n: s for n, s, _ in reproduce.estimate(budget, tmp_path / "pub")}   # a: 3 steps an episode, 16 s over 30 steps
    assert got["e"] == pytest.approx(1 + 9 * 16 / 30) and got["g"] == pytest.approx(1 + 9 * 16 / 30)
    small = {"h": resolve_config(env="corridor", agent="constant", seeds=[10], episodes=2, env_steps=9)}
    assert reproduce.estimate(small, tmp_path / "pub")[0][1] == pytest.approx(1 + 2 * 3 * 16 / 30)  # its 2 episodes first
    # rows that record their CPU time are costed by it (the wall time grows with whatever shares the
    # cores); a row without it, by its wall time: episodes 1-4 at 0.5 s of CPU, the rest as before
    pd.DataFrame(dict(seed=5, episode=range(1, 11), steps=3, wall_s=[1.0] * 4 + [2.0] * 6,
                      cpu_s=[0.5] * 4 + [None] * 6)).to_csv(data / "a.csv.xz", index=False)
    got = {name: seconds for name, seconds, _ in reproduce.estimate(planned, tmp_path / "pub")}
    assert got["b"] == pytest.approx(1 + 2 * 4 * 0.5) and got["c"] == pytest.approx(1 + 2 * (10 * 1.4 + 10 * 2))
    assert "CPU time where recorded, else wall time" in reproduce.plan_text(planned, tmp_path / "pub")
    # a published batch of 4 seeds at 1 s a seed-episode: a batch of fewer seeds costs as much per
    # batched step (4 x 1 s an episode), one of more seeds 1 s a seed-episode
    wide = resolve_config(env="corridor", agent="random", seeds=[1, 2, 3, 4], episodes=10)
    pd.DataFrame(dict(seed=[1, 2, 3, 4] * 10, episode=sorted(list(range(1, 11)) * 4), steps=3, wall_s=1.0,
                      cpu_s=1.0)).to_csv(data / "w.csv.xz", index=False)
    (data / "w.json").write_text(json.dumps(wide))
    (data / "manifest.json").write_text(json.dumps({"experiments": ["a", "w"]}))
    batches = {f"r{n}": resolve_config(env="corridor", agent="random", seeds=list(range(10, 10 + n)), episodes=5)
               for n in (1, 4, 6)}
    got = {name: seconds for name, seconds, _ in reproduce.estimate(batches, tmp_path / "pub")}
    assert got == {"r1": pytest.approx(1 + 4 * 5), "r4": pytest.approx(1 + 4 * 5), "r6": pytest.approx(1 + 6 * 5)}
    assert reproduce.main(["--scale", "smoke", "--only", "f16", "--plan", "--experiments", "f16-pd"]) == 0
    assert capsys.readouterr().out.startswith("  f16-pd: 1 seed x 3, ~")


def test_a_split_plan_gives_each_experiment_its_seeds_in_consecutive_groups(tmp_path):
    """10 seeds in 3 jobs: 4, 3, 3 consecutive seeds, each job's config its own seeds; an
    experiment not named stays one job; more jobs than seeds, or none, is refused."""
    cfg = resolve_config(env="square", agent="random", seeds=list(range(10, 20)), episodes=1)
    jobs = sweep.plan({"a": cfg, "b": cfg}, tmp_path, None, {"a": 3})
    assert [(j.experiment, j.index, j.seeds) for j in jobs] == [
        ("a", 0, [10, 11, 12, 13]), ("a", 1, [14, 15, 16]), ("a", 2, [17, 18, 19]), ("b", 0, list(range(10, 20)))]
    assert [Path(j.folder).relative_to(tmp_path).as_posix() for j in jobs] == [
        "a/jobs/j000", "a/jobs/j001", "a/jobs/j002", "b/jobs/j000"]
    assert all(j.config["run"]["seeds"] == j.seeds and j.config["run"]["threads"] == 1 for j in jobs)
    for bad in (0, 11):
        with pytest.raises(sweep.SweepError, match=f"^a: {bad} jobs for 10 seeds$"):
            sweep.plan({"a": cfg}, tmp_path, None, {"a": bad})


def test_max_job_minutes_splits_each_experiment_estimated_over_it():
    """20 minutes of one core (1,200 s, each job's start included): an experiment of 3,000 s of
    steps in 3 jobs (1,200, 900 and 900 s of its 10 seeds' steps), one of 500 s whole, one with no
    estimate whole; at most one seed a job; without the option, one job each."""
    cfg = lambda n: resolve_config(env="square", agent="random", seeds=list(range(n)), episodes=1)  # noqa: E731
    planned = {"long": cfg(10), "short": cfg(4), "unknown": cfg(2)}
    start = reproduce.JOB_START_S
    found = [("long", start + 3000.0, "x"), ("short", start + 500.0, "x"), ("unknown", None, "x")]
    assert reproduce.seed_groups(planned, found, 20) == {"long": 3}
    assert reproduce.seed_groups(planned, found, None) == {}
    assert reproduce.seed_groups(planned, found, 0.1) == {"long": 10, "short": 4}
    assert reproduce.seed_groups(planned, found, 0.01) == {"long": 10, "short": 4}   # under a job's start
    assert reproduce.job_seconds(planned, found, {"long": 3}) == pytest.approx(
        [start + 1200, start + 900, start + 900, start + 500])
    assert reproduce.job_seconds(planned, found, {}) == pytest.approx([start + 3000, start + 500])


SPLIT_ARGS = ["--scale", "quick", "--only", "square", "--workers", "1", "--experiments", "square-random"]


def estimated_an_hour(monkeypatch):
    """The estimate stubbed (the published rows' times are test_reproduce_plan's): an hour for square-random."""
    monkeypatch.setattr(reproduce, "estimate", lambda planned, pub: [
        (n, 3600.0 if n == "square-random" else 10.0, "measured") for n in planned])


def test_max_job_minutes_is_planned_as_jobs_and_must_be_positive(capsys, monkeypatch):
    estimated_an_hour(monkeypatch)
    assert reproduce.main(SPLIT_ARGS + ["--plan", "--max-job-minutes", "40"]) == 0
    assert "  square-random: 4 seeds x 15, ~60.0 min in 2 jobs (" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        reproduce.main(SPLIT_ARGS + ["--plan", "--max-job-minutes", "0"])
    assert "must be a number of minutes > 0, got '0'" in capsys.readouterr().err


# behind slow: a real reproduction (~10 s); the plan and the refusal are
# test_max_job_minutes_is_planned_as_jobs_and_must_be_positive's, the split itself
# test_a_split_plan_gives_each_experiment_its_seeds_in_consecutive_groups's
@pytest.mark.slow
def test_reproduce_runs_a_split_experiment_in_its_jobs_and_keeps_them_when_continued(tmp_path, monkeypatch):
    """square-random (4 seeds) estimated at an hour: --max-job-minutes 40 runs it as two jobs of two
    seeds each, whose rows are the experiment's; continued with another limit, the run keeps the jobs
    it began with."""
    estimated_an_hour(monkeypatch)
    out = tmp_path / "r"
    assert reproduce.main(SPLIT_ARGS + ["--out", str(out), "--max-job-minutes", "40"]) == 0
    jobs = sorted((out / "square-random" / "jobs").iterdir())
    assert [json.loads((j / "config.json").read_text())["run"]["seeds"] for j in jobs] == [[10, 11], [12, 13]]
    rows = pd.read_csv(out / "square-random" / "episodes.csv")
    assert sorted(set(rows.seed)) == [10, 11, 12, 13] and len(rows) == 60            # 4 seeds x 15 episodes
    assert reproduce.main(SPLIT_ARGS + ["--out", str(out), "--max-job-minutes", "1000"]) == 0
    assert sorted(p.name for p in (out / "square-random" / "jobs").iterdir()) == ["j000", "j001"]
