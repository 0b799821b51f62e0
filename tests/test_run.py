"""scripts/train.py and its run folder: files, status, refusals, one-line errors, signals."""
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
import torch

from trl_dgpq.collectors import runner
from trl_dgpq.collectors.experiment import TIMING_COLUMNS, resolve_config
from trl_dgpq.collectors.runner import RunFolder, read_csv_exact
from trl_dgpq.commands import plot, train

ROOT = Path(__file__).resolve().parent.parent
TRAIN = ROOT / "scripts" / "train.py"


def csv(path):
    return read_csv_exact(Path(path) / "episodes.csv").drop(columns=list(TIMING_COLUMNS))


def run(*argv):
    return train.main([*map(str, argv), "--no-progress"])


def test_run_folder_files_status_and_provenance(tmp_path):
    out = tmp_path / "run"
    assert run("--seeds", 2, "--episodes", 3, "--out", out) == 0
    assert sorted(p.name for p in out.iterdir()) == ["checkpoint.extend.pt", "checkpoint.pt", "config.json",
                                                     "episodes.csv", "run.lock", "status.json"]
    df = pd.read_csv(out / "episodes.csv")
    assert list(df.seed) == [0, 0, 0, 1, 1, 1] and list(df.episode) == [1, 2, 3] * 2
    cfg = json.loads((out / "config.json").read_text())
    assert set(cfg) == {"run", "env", "agent", "versions", "git", "model_knowledge"} and cfg["model_knowledge"] == ["reward: the distance to the goal (its position)"]
    assert {"torch", "torchrl", "tensordict", "numpy"} <= set(cfg["versions"])
    assert cfg["run"]["preset"] == "shaped" and cfg["run"]["seeds"] == [0, 1]
    assert set(cfg["git"]) == {"commit", "dirty"} and len(cfg["git"]["commit"]) == 40
    status = json.loads((out / "status.json").read_text())
    assert status["status"] == "finished" and status["episodes_done"] == 6


def test_config_json_repeats_a_run_and_takes_overrides(tmp_path):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    run("--seeds", "1,4", "--episodes", 3, "--gp", "exact", "--max-steps", 80, "--out", a)
    run("--config", a / "config.json", "--out", b)
    pd.testing.assert_frame_equal(csv(a), csv(b))
    assert json.loads((b / "config.json").read_text())["agent"] == json.loads((a / "config.json").read_text())["agent"]
    run("--config", a / "config.json", "--episodes", 2, "--out", c)
    assert csv(c).episode.max() == 2 and json.loads((c / "config.json").read_text())["env"]["max_steps"] == 80


def test_out_holding_a_run_is_refused_unless_overwrite(tmp_path, capsys):
    out = tmp_path / "run"
    run("--seeds", 1, "--episodes", 1, "--out", out)
    before = (out / "episodes.csv").read_bytes()
    with pytest.raises(SystemExit) as exc:
        run("--seeds", 1, "--episodes", 2, "--out", out)
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2 and "--resume" in err and "--overwrite" in err and len(err.splitlines()) == 1
    assert (out / "episodes.csv").read_bytes() == before          # nothing touched
    assert run("--seeds", 1, "--episodes", 2, "--out", out, "--overwrite") == 0
    assert len(pd.read_csv(out / "episodes.csv")) == 2
    other = tmp_path / "papers"
    other.mkdir()
    (other / "draft.tex").write_text("x")
    with pytest.raises(SystemExit):
        run("--episodes", 1, "--out", other, "--overwrite")       # not a run: never overwritten
    assert (other / "draft.tex").exists()


def test_default_run_folders_are_unique(tmp_path):
    made = {RunFolder.create(None, "square-dgpq-shaped", root=str(tmp_path)).path for _ in range(3)}
    assert len(made) == 3 and all(p.is_dir() for p in made)


@pytest.mark.parametrize("argv,words", [
    (["--bogus", "1"], "unrecognized"),
    (["--set", "bogus=1"], "unknown setting 'bogus'"),
    (["--set", "gamma"], "KEY=VALUE"),
    (["--set", "gamma=abc"], "gamma must be a number"),
    (["--episodes", "x"], "episodes must be an integer"),
    (["--episodes", "0"], "episodes must be >= 1"),
    (["--gamma", "2"], "gamma must be in [0, 1]"),
    (["--noise-var", "-1"], "noise_var"),
    (["--budget", "0"], "budget"),
    (["--kernel", "manifold"], "use --gp exact"),
    (["--kernel-hidden", "10,x"], "kernel_hidden"),
    (["--preset", "nope"], "unknown preset 'nope'"),
    (["--agent", "nope"], "agent must be one of"),
    (["--env", "nope"], "unknown env 'nope'"),
    (["--seeds", "5-2"], "seeds"),
    (["--max-steps", "0"], "max_steps"),
    (["--agent", "random", "--budget", "5"], "unknown setting 'budget'"),
    (["--budget", "100000000"], "GiB"),
    (["--resume", "/nonexistent/run"], "no run to resume"),
    (["--resume", "/tmp", "--gamma", "0.5"], "--resume continues a run"),
    (["--config", "/nonexistent.json"], "cannot read --config"),
    (["--out", "/etc/hostname/run"], "run folder"),
])
def test_user_errors_end_in_one_line_and_exit_2(argv, words, capsys, tmp_path):
    t0 = time.perf_counter()
    argv = argv if "--out" in argv or "--resume" in argv else argv + ["--out", str(tmp_path / "x")]
    with pytest.raises(SystemExit) as exc:
        run(*argv)
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2 and len(err.splitlines()) == 1 and words in err, err
    assert not (tmp_path / "x").exists()                        # refused before any work
    assert time.perf_counter() - t0 < 5


def test_resume_refuses_a_finished_run(tmp_path, capsys):
    run("--seeds", 1, "--episodes", 1, "--out", tmp_path / "r")
    with pytest.raises(SystemExit) as exc:
        train.main(["--resume", str(tmp_path / "r")])
    assert exc.value.code == 2 and "finished" in capsys.readouterr().err


def test_resume_with_more_episodes_runs_a_finished_run_longer(tmp_path, capsys):
    """The command line of lengthening (its exactness is in test_state): --episodes or --env-steps
    only, longer only, each refusal one line and exit 2."""
    run("--seeds", 2, "--episodes", 2, "--max-steps", 30, "--out", tmp_path / "r")
    run("--seeds", 2, "--episodes", 3, "--max-steps", 30, "--out", tmp_path / "ref")
    for argv, words in [(["--episodes", "1"], "fewer"), (["--gamma", "0.5"], "no settings other than"),
                        (["--env-steps", "50"], "smaller budget")]:
        capsys.readouterr()
        with pytest.raises(SystemExit) as exc:
            train.main(["--resume", str(tmp_path / "r"), *argv])
        err = capsys.readouterr().err
        assert exc.value.code == 2 and words in err and len(err.strip().splitlines()) == 1, err
    assert train.main(["--resume", str(tmp_path / "r"), "--set", "run.episodes=3", "--no-progress"]) == 0
    assert "(3 episodes per seed)" in capsys.readouterr().out
    pd.testing.assert_frame_equal(csv(tmp_path / "ref"), csv(tmp_path / "r"))


def test_an_episodes_csv_that_cannot_be_read_is_named_in_one_line_by_every_command(tmp_path, capsys):
    """A row cut short with the next one run on into it (what a cut at a byte offset of a rewritten
    file left): --resume, plot, evaluate and report each say which file, in one line, exit 2."""
    from trl_dgpq.commands import evaluate, report
    out = tmp_path / "r"
    assert run("--seeds", 2, "--episodes", 2, "--max-steps", 30, "--out", out) == 0
    path = out / "episodes.csv"
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines[:2] + [lines[2][:9] + lines[3]] + lines[4:]) + "\n")
    for main, argv in [(train.main, ["--resume", out, "--episodes", 3]), (plot.main, [out]),
                       (evaluate.main, [out, "--no-progress"]), (report.main, [out])]:
        capsys.readouterr()
        try:
            code = main(list(map(str, argv)))
        except SystemExit as exc:
            code = exc.code
        err = capsys.readouterr().err.strip()
        assert code == 2 and len(err.splitlines()) == 1 and f"cannot read {path}: " in err, (main, err)


def test_interrupt_writes_a_checkpoint_covering_every_episode_on_disk(tmp_path, stop_run_after):
    """checkpoint_every=0 means "only on interrupt and at the end": a SIGINT after the 2nd
    batch of rows (3 seeds, all truncated at step 10 -> 3 rows a batch) must leave a
    checkpoint of exactly those 6 episodes and the whole CSV."""
    config = resolve_config(agent="random", seeds=[0, 1, 2], episodes=4, max_steps=10, checkpoint_every=0)
    folder = runner.RunFolder.create(str(tmp_path / "run"), "x")
    stop_run_after(2, "signal")
    with pytest.raises(runner.Interrupted):
        runner.start(config, folder, progress=False)
    ckpt = folder.load_checkpoint()
    assert ckpt is not None
    assert ckpt["episodes_done"] == 6 == folder.status()["episodes_done"] == len(folder.episodes())
    assert ckpt["collector"]["episode"].tolist() == folder.episodes().groupby("seed").size().tolist() == [2, 2, 2]


def test_checkpoint_every_counts_episodes_per_seed(tmp_path, monkeypatch):
    """3 seeds, all truncated at step 10 (episodes end 3 at a time), 4 episodes each,
    checkpoint_every=2 per seed: one periodic checkpoint at 6 episodes, then the final one at 12."""
    config = resolve_config(agent="random", seeds=[0, 1, 2], episodes=4, max_steps=10, checkpoint_every=2)
    saved, save = [], runner.RunFolder.save_checkpoint

    def spy(self, state):
        saved.append(state["episodes_done"])
        return save(self, state)
    monkeypatch.setattr(runner.RunFolder, "save_checkpoint", spy)
    runner.start(config, runner.RunFolder.create(str(tmp_path / "run"), "x"), progress=False)
    assert saved == [6, 12]


@pytest.mark.slow  # a real process; test_state's interrupted-run tests cover the same resume in-process
def test_sigint_on_a_real_run_checkpoints_and_resumes_to_the_same_csv(tmp_path):
    """The whole path a user meets: Ctrl-C in the middle of train.py -> exit 130, one line
    naming --resume, every finished episode on disk; --resume -> the uninterrupted CSV."""
    ref, out = tmp_path / "ref", tmp_path / "run"
    settings = ["--seeds", "3", "--episodes", "40", "--checkpoint-every", "5"]
    proc = subprocess.Popen([sys.executable, str(TRAIN), *settings, "--out", str(out), "--no-progress"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    while not ((out / "episodes.csv").exists() and len((out / "episodes.csv").read_text().splitlines()) > 10):
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    lines = err.strip().splitlines()
    assert proc.returncode == 130 and len(lines) == 1 and f"--resume {out}" in lines[0], err
    status = json.loads((out / "status.json").read_text())
    assert status["status"] == "interrupted" and status["reason"] == "SIGINT"
    assert len(pd.read_csv(out / "episodes.csv")) == status["episodes_done"] < 120
    assert train.main(["--resume", str(out), "--no-progress"]) == 0
    run(*settings, "--out", ref)
    pd.testing.assert_frame_equal(csv(ref), csv(out))


@pytest.mark.slow
def test_crash_check_script(tmp_path):
    """SIGINT, SIGTERM and SIGKILL at random points of real runs (scripts/crash_check.py)."""
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "crash_check.py"), "--trials", "3", "--seeds", "3",
                           "--episodes", "40", "--work", str(tmp_path), "--json", str(tmp_path / "cc.json")])
    assert done.returncode == 0


@pytest.mark.slow
def test_crash_check_removes_its_temporary_folder(tmp_path):
    import os
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "crash_check.py"), "--trials", "1", "--seeds", "2",
                           "--episodes", "20", "--json", str(tmp_path / "cc.json")],
                          env={**os.environ, "TMPDIR": str(tmp_path)})
    assert done.returncode == 0 and not list(tmp_path.glob("crash-check-*"))


def test_liquidation_figures_and_table_pair_runs_by_seed_and_episode(tmp_path):
    """plot.py on liquidation runs: the table divides each run's mean ac_cost by the
    ac-optimal run's mean over the same (seed, episode) pairs only. TWAP runs seeds 1-2,
    ac-optimal seeds 0-1: only seed 1 is shared."""
    common = ("--env", "liquidation", "--episodes", 3, "--trades", 10, "--horizon", 10)
    assert run("--agent", "ac-optimal", "--seeds", "0-1", "--out", tmp_path / "opt", *common) == 0
    assert run("--agent", "twap", "--seeds", "1-2", "--out", tmp_path / "twap", *common) == 0
    assert plot.main([str(tmp_path / "opt"), str(tmp_path / "twap"), "--labels", "opt", "twap",
                      "--out", str(tmp_path / "fig"), "--block", "1"]) == 0
    assert (tmp_path / "fig" / "liquidation_cost.png").is_file() and (tmp_path / "fig" / "liquidation_time.png").is_file()
    opt, twap = pd.read_csv(tmp_path / "opt" / "episodes.csv"), pd.read_csv(tmp_path / "twap" / "episodes.csv")
    o = {e: c for s, e, c in zip(opt.seed, opt.episode, opt.ac_cost) if s == 1}
    t = {e: c for s, e, c in zip(twap.seed, twap.episode, twap.ac_cost) if s == 1}
    expected = sum(t.values()) / sum(o.values())
    rows = {line.split("|")[1].strip(): line.split("|") for line in
            (tmp_path / "fig" / "comparison.md").read_text().splitlines() if line.startswith("| ")}
    assert rows["opt"][2].strip() == "shortfall (uses the model)"   # the closed-form schedule
    assert rows["opt"][5].strip() == "all"   # 3 episodes: not "the last 1000"
    assert rows["opt"][7].strip() == "1.000"
    assert float(rows["twap"][7]) == pytest.approx(expected, abs=5e-4)
    assert plot.main([str(tmp_path / "opt"), "--out", str(tmp_path / "fig2"), "--last", "2"]) == 0
    assert "| opt 2 | last 2 |" not in (tmp_path / "fig2" / "comparison.md").read_text()  # labels are agent names
    assert "| last 2 |" in (tmp_path / "fig2" / "comparison.md").read_text()


def test_a_negative_comma_list_is_a_flag_value(tmp_path):
    """argparse would read '-0.3,0.2' as an option; it is joined to its flag. Plain negative
    numbers (argparse's own case), options and other values are left alone."""
    argv = ["--block-start", "-0.3,0.2", "--pusher-start", "0,-0.3", "--lam", "-1", "--goal", "-1e-2,-0.5",
            "--overwrite", "--seeds", "3-7"]
    assert train.attach_negative_lists(argv) == [
        "--block-start=-0.3,0.2", "--pusher-start", "0,-0.3", "--lam", "-1", "--goal=-1e-2,-0.5", "--overwrite",
        "--seeds", "3-7"]
    assert run("--env", "push", "--agent", "oracle", "--seeds", 1, "--episodes", 1, "--max-steps", 3,
               "--block-start", "-0.3,0.2", "--out", tmp_path / "p") == 0
    assert json.loads((tmp_path / "p" / "config.json").read_text())["env"]["block_start"] == [-0.3, 0.2]


def test_a_config_recorded_before_a_setting_existed_still_runs(tmp_path):
    """config.json files from before env_steps existed lack it: the default (no budget) applies."""
    config = resolve_config(seeds=[0], episodes=2)
    del config["run"]["env_steps"]
    folder = RunFolder.create(str(tmp_path / "old"), "x")
    assert len(runner.start(config, folder, progress=False)) == 2


def test_a_checkpoint_of_another_format_is_refused_in_one_line(tmp_path, capsys):
    """Checkpoints written before the GP state's layout changed (format 1) must not load into the
    new fields: --resume refuses them in one line, exit 2."""
    out = tmp_path / "old"
    assert run("--seeds", 1, "--episodes", 2, "--out", out) == 0
    folder = RunFolder(out)
    state = torch.load(folder.file("checkpoint.pt"), weights_only=True)
    folder.save_checkpoint({**state, "format": 1})
    folder.set_status("interrupted")
    with pytest.raises(SystemExit) as exc:
        train.main(["--resume", str(out), "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2 and len(err.splitlines()) == 1 and "checkpoint format 1, this code reads 2" in err



def test_the_run_lock_holds_the_writers_pid_alone(tmp_path):
    """A lock file left with a longer pid (a writer long gone) is taken over: it then reads this
    process's pid and nothing of the old one, and a second writer is told that pid."""
    import os
    folder = RunFolder(tmp_path / "r")
    folder.path.mkdir()
    (folder.path / runner.LOCK).write_text("9" * 12)
    folder.acquire()
    try:
        assert (folder.path / runner.LOCK).read_text() == str(os.getpid())
        with pytest.raises(runner.RunError, match=f"being written by process {os.getpid()}: wait"):
            RunFolder(folder.path).acquire()
    finally:
        folder.release()


def test_a_folder_a_live_writer_holds_is_neither_overwritten_nor_resumed(tmp_path):
    """In-process (a second open of the lock file conflicts as another process's would): while a writer
    holds OUT, --overwrite and --resume of it are refused naming the writer's pid, and its files stay."""
    import os
    out = tmp_path / "live"
    writer = runner.RunFolder.create(str(out), "x")
    writer.write_json(runner.CONFIG, {"run": {"seeds": [0]}})
    try:
        for make in (lambda: runner.RunFolder.create(str(out), "x", overwrite=True),
                     lambda: runner.RunFolder.existing(out)):
            with pytest.raises(runner.RunError, match=f"^{out} is being written by process {os.getpid()}: wait"):
                make()
        assert json.loads((out / runner.CONFIG).read_text()) == {"run": {"seeds": [0]}}
    finally:
        writer.release()
    runner.RunFolder.existing(out).release()                 # the writer gone, it can be resumed


# behind slow: a real train.py (~6 s); the same refusals in-process are
# test_a_folder_a_live_writer_holds_is_neither_overwritten_nor_resumed's
@pytest.mark.slow
def test_a_running_run_can_be_neither_overwritten_nor_resumed_by_a_second_writer(tmp_path, capsys):
    """A real train.py process writing OUT: --overwrite and --resume of OUT are refused in one
    line naming it; once it is killed (SIGKILL: no clean-up), the lock is gone with it."""
    out = tmp_path / "live"
    proc = subprocess.Popen([sys.executable, str(TRAIN), "--seeds", "2", "--episodes", "100000", "--out", str(out),
                             "--no-progress"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        for _ in range(600):
            if (out / "status.json").exists() and '"running"' in (out / "status.json").read_text():
                break
            time.sleep(0.1)
        for argv in (["--seeds", 1, "--episodes", 1, "--out", out, "--overwrite"], ["--resume", out]):
            with pytest.raises(SystemExit) as exc:
                run(*argv)
            err = capsys.readouterr().err.strip()
            assert exc.value.code == 2 and len(err.splitlines()) == 1
            assert f"being written by process {proc.pid}" in err or f"being run by process {proc.pid}" in err
        assert json.loads((out / "config.json").read_text())["run"]["episodes"] == 100000  # untouched
    finally:
        proc.kill()
        proc.wait()
    assert run("--seeds", 1, "--episodes", 1, "--out", out, "--overwrite") == 0


def test_a_run_whose_storage_would_outgrow_its_memory_stops_checkpointed_in_one_line(tmp_path, capsys, monkeypatch):
    """Q̂ starts with room for 32 pairs per action and doubles when full (4 seeds x 4 actions x 32
    x (2 + 1) float64, 24 KiB, copied into twice that: 48 KiB). With the process's own memory taken
    as 0, --max-memory 40 KiB stops the run before its first doubling: checkpointed (it loads),
    marked failed with the reason, its rows kept; exit 2 and one line. 1 MiB lets it finish."""
    from trl_dgpq.collectors import experiment
    monkeypatch.setattr(experiment, "resident_bytes", lambda: 0)
    out = tmp_path / "run"
    with pytest.raises(SystemExit) as exc:
        run("--seeds", 4, "--episodes", 20, "--qhat-capacity", 32, "--max-memory", 40 / 2**20, "--out", out)
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2 and len(err.splitlines()) == 1 and "must grow by" in err and "--max-memory" in err
    status = json.loads((out / "status.json").read_text())
    assert status["status"] == "failed" and status["reason"].startswith("memory:")
    state = RunFolder(out).load_checkpoint()
    assert state["episodes_done"] == status["episodes_done"] == len(pd.read_csv(out / "episodes.csv")) > 0
    assert run("--seeds", 4, "--episodes", 20, "--qhat-capacity", 32, "--max-memory", 1 / 2**10,
               "--out", tmp_path / "roomy") == 0



def test_storage_growth_is_estimated_by_hand():
    from trl_dgpq.qhat import LipschitzQ
    q = LipschitzQ(3, 2, 4, 1.0, 0.0, capacity=2)
    assert q.growth_bytes() == 0
    for _ in range(2):
        q.insert(torch.rand(3, 4, dtype=torch.float64) + 10 * _, torch.zeros(3, dtype=torch.long),
                 torch.zeros(3, dtype=torch.float64) - _, torch.ones(3, dtype=torch.bool))
    # full: s (3 x 2 x 2 x 4) and mu (3 x 2 x 2) in float64, copied into storage twice as large
    assert q.width == q.capacity == 2 and q.growth_bytes() == 2 * 8 * (3 * 2 * 2 * 4 + 3 * 2 * 2)


# 5,000: the first checkpoint fails; 8,000: the CSV fails after a checkpoint, the path that can lose rows.
# Each a real train.py, ~9 s: behind slow. In-process, test_runner_units fails a write for a full disk on
# episodes.csv and status.json and in the atomic write a checkpoint goes through; a checkpoint failing
# inside a run is checked only here.
@pytest.mark.slow
@pytest.mark.parametrize("limit", [5_000, 8_000])
def test_a_full_disk_stops_the_run_in_one_line_and_resume_finishes_the_same_csv(tmp_path, limit):
    """A file-size limit (RLIMIT_FSIZE, SIGXFSZ ignored: writes past it fail with EFBIG, as on a
    full disk) in a real train.py process. Checkpoints take ~5.9 kB and rows ~95 B: at 5,000 the
    first checkpoint fails, at 8,000 the CSV does after ~80 rows. Either way: one line naming the
    file, exit 2, status failed, the last good checkpoint (if any) loads, and with the limit gone
    --resume ends with the rows of an uninterrupted run."""
    import resource

    def small_files():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)

    common = ["--agent", "random", "--seeds", "2", "--episodes", "60", "--max-steps", "20", "--checkpoint-every", "5",
              "--no-progress"]   # 20-step episodes: the rows and checkpoints (the sizes above) at a tenth of the steps
    assert run(*common[:-1], "--out", tmp_path / "whole") == 0
    done = subprocess.run([sys.executable, str(TRAIN), *common, "--out", str(tmp_path / "part")],
                          capture_output=True, text=True, preexec_fn=small_files, timeout=300)
    err = done.stderr.strip()
    assert done.returncode == 2 and len(err.splitlines()) == 1 and "cannot write" in err and str(tmp_path) in err
    part = RunFolder(tmp_path / "part")
    assert part.status()["status"] == "failed"
    state = part.load_checkpoint(log=lambda line: None)
    assert (state is None) == (limit < 5_900) and (state is None or state["episodes_done"] < 120)
    assert run("--resume", tmp_path / "part") == 0
    pd.testing.assert_frame_equal(csv(tmp_path / "whole"), csv(tmp_path / "part"))


def test_a_run_into_a_folder_holds_nothing_per_step_or_episode(tmp_path, monkeypatch):
    """A long run's memory stays flat (scripts/soak.py): the collector keeps no row (they are on
    disk) and no per-step time (a float per step was 26 MiB over a 20,000-episode soak)."""
    from trl_dgpq.collectors.online import OnlineCollector
    seen, original = [], OnlineCollector.run

    def spy(self, *args, **kwargs):
        rows = original(self, *args, **kwargs)
        seen.append((self, rows))
        return rows
    monkeypatch.setattr(OnlineCollector, "run", spy)
    runner.start(resolve_config(seeds=[0, 1], episodes=3, max_steps=20),
                 runner.RunFolder.create(str(tmp_path / "r"), "x"), progress=False)
    (collector, rows), = seen
    assert collector.total > 0 and collector.step_seconds == [] and len(rows) == 0


def test_an_episodes_csv_cut_mid_row_is_refused_by_every_reader_and_resume_cuts_it_back(tmp_path, capsys):
    """The file's last row cut short (the run stopped while writing it): plot, evaluate and report say
    so in one line and exit 2, never a silent NaN row."""
    from trl_dgpq.commands import evaluate, report
    out = tmp_path / "r"
    assert run("--seeds", 2, "--episodes", 2, "--max-steps", 30, "--out", out) == 0
    path = out / "episodes.csv"
    whole = path.read_bytes()
    path.write_bytes(whole[:-7])
    for main, argv in [(plot.main, [out]), (evaluate.main, [out, "--no-progress"]), (report.main, [out])]:
        capsys.readouterr()
        try:
            code = main(list(map(str, argv)))
        except SystemExit as exc:
            code = exc.code
        err = capsys.readouterr().err.strip()
        assert code == 2 and len(err.splitlines()) == 1 and "ends mid-row" in err and "--resume" in err, (main, err)
    # the cut row was one its checkpoint covers: resume says what is missing, in one line
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        run("--resume", out, "--episodes", 3)
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2
    assert len(err.splitlines()) == 1 and "(1 missing, 0 repeated)" in err


def test_printed_hints_quote_a_path_with_spaces(tmp_path, capsys):
    """The hint train prints ends with a command that, pasted into a shell, names the run."""
    import shlex
    out = tmp_path / "dir with spaces" / "my run"
    assert run("--seeds", 1, "--episodes", 1, "--max-steps", 5, "--out", out) == 0
    hint = capsys.readouterr().out.strip().splitlines()[-1].split("plot: ", 1)[1]
    assert shlex.split(hint)[-1] == str(out)


def test_an_interrupted_train_counts_its_episodes_over_all_seeds(tmp_path, stop_run_after, capsys):
    """3 seeds stopped after their 2nd batch of rows: 6 episodes summed over the 3 seeds (2 each), said
    so, and the hint to continue quotes the folder."""
    stop_run_after(2, "signal")
    out = tmp_path / "a run"
    code = run("--agent", "random", "--seeds", 3, "--episodes", 4, "--max-steps", 10, "--out", out)
    err = capsys.readouterr().err
    assert code == 130 and "interrupted by SIGINT after 6 episodes summed over 3 seeds; checkpoint saved." in err
    assert f"--resume '{out}'" in err


def test_resume_goes_back_to_the_previous_checkpoint_when_the_file_lost_rows(tmp_path, stop_run_after, capsys):
    """episodes.csv cut short (rows the latest checkpoint covers lost): resume says so in one line and
    goes on from checkpoint.prev.pt, whose rows are all there, with a DGPQ whose state (Q̂, GPs) is
    that checkpoint's alone, to the CSV an uninterrupted run writes; with rows lost that no
    checkpoint predates, or the file gone, it refuses in one line."""
    config = resolve_config(env="square", agent="dgpq", seeds=[0, 1, 2], episodes=8, max_steps=10, checkpoint_every=2)
    reference = runner.start(config, runner.RunFolder.create(str(tmp_path / "ref"), "x"), progress=False)

    def interrupted(name):
        folder = runner.RunFolder.create(str(tmp_path / name), "x")
        stop_run_after(7, "signal")    # 3 rows a batch: checkpoints at 6, 12 and 18 episodes, stopped at 21
        with pytest.raises(runner.Interrupted):
            runner.start(config, folder, progress=False)
        return folder, folder.file(runner.EPISODES)
    folder, path = interrupted("run")
    assert folder.load_checkpoint()["episodes_done"] == 21
    assert torch.load(folder.file(runner.PREVIOUS), weights_only=True)["episodes_done"] == 18
    path.write_text("".join(path.read_text().splitlines(keepends=True)[:-2]))   # 19 of the 21 covered
    by = ["seed", "episode"]
    kept = folder.episodes().query("episode <= 6").sort_values(by).reset_index(drop=True)   # what prev covers
    capsys.readouterr()
    again = runner.resume(folder, runner.resumable_config(folder), progress=False)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith("(2 missing, 0 repeated): continuing from checkpoint.prev.pt (18 episodes "
                                             "done), the episodes after it run again")
    timing = list(TIMING_COLUMNS)
    pd.testing.assert_frame_equal(again.drop(columns=timing), reference.drop(columns=timing))
    # the episodes prev covers are not run again: their rows, times included, are the file's
    pd.testing.assert_frame_equal(again.query("episode <= 6").sort_values(by).reset_index(drop=True), kept)

    folder, path = interrupted("cut")
    path.write_text("".join(path.read_text().splitlines(keepends=True)[:-5]))   # 16: fewer than prev's 18
    with pytest.raises(runner.RunError, match=r"\(5 missing, 0 repeated\), and no earlier checkpoint's episodes "
                                              r"are all there: start it again \(--overwrite\)"):
        runner.resume(folder, runner.resumable_config(folder), progress=False)
    path.unlink()
    with pytest.raises(runner.RunError, match="is missing: its checkpoint covers 21 episodes, and no earlier"):
        runner.resume(folder, runner.resumable_config(folder), progress=False)
