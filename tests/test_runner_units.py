"""Fast unit tests of the run folder's pieces (collectors/runner.py) on tmp_path, without training."""
import errno
import os

import pytest

from trl_dgpq.collectors import runner
from trl_dgpq.collectors.runner import RunFolder, atomic_write


def test_atomic_write_replaces_whole_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "f.txt"
    path.write_bytes(b"old")
    order = []
    atomic_write(path, lambda f: (order.append("write"), f.write(b"new")),
                 before_replace=lambda: order.append(("before", path.read_bytes())))
    assert path.read_bytes() == b"new"
    assert order == ["write", ("before", b"old")]  # the hook runs after the write, before the rename
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.txt"]


def test_atomic_write_names_the_path_on_an_oserror_and_leaves_the_file_as_it_was(tmp_path):
    path = tmp_path / "f.txt"
    path.write_bytes(b"old")

    def full(f):
        f.write(b"part")
        raise OSError(errno.ENOSPC, "No space left on device")
    with pytest.raises(OSError) as exc:
        atomic_write(path, full)
    assert exc.value.errno == errno.ENOSPC and exc.value.strerror == "No space left on device"
    assert exc.value.filename == str(path)
    assert path.read_bytes() == b"old" and sorted(p.name for p in tmp_path.iterdir()) == ["f.txt"]

    def refused(f):
        raise PermissionError("denied by a test")          # no errno, no strerror: its text stands in
    with pytest.raises(PermissionError) as exc:
        atomic_write(path, refused)
    assert (exc.value.strerror, exc.value.filename) == ("denied by a test", str(path))


def test_interrupted_exit_code_and_message():
    err = runner.Interrupted(15, None, 7)
    assert err.exit_code == 143 and str(err) == "interrupted by SIGTERM" and err.episodes_done == 7
    assert runner.Interrupted(2, None, 0).exit_code == 130


def test_the_lock_is_held_once_and_released(tmp_path):
    a = RunFolder(tmp_path / "r")
    a.acquire()
    a.acquire()  # a second acquire by the holder is a no-op
    try:
        assert (tmp_path / "r" / runner.LOCK).read_text() == str(os.getpid())
        with pytest.raises(runner.RunError, match=f"process {os.getpid()}"):
            RunFolder(tmp_path / "r").acquire()
    finally:
        a.release()
    assert a._lock is None
    b = RunFolder(tmp_path / "r")
    b.acquire()  # free again
    b.release()


def test_holds_run_sees_each_run_file(tmp_path):
    folder = RunFolder(tmp_path)
    assert not folder.holds_run()
    (tmp_path / runner.LOCK).write_text("1")
    (tmp_path / "notes.txt").write_text("x")
    assert not folder.holds_run()
    for name in runner.RUN_FILES:
        (tmp_path / name).write_text("x")
        assert folder.holds_run()
        (tmp_path / name).unlink()


def test_create_refuses_a_file_a_non_empty_folder_and_a_run_unless_overwrite(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(runner.RunError, match="exists and is not a folder"):
        RunFolder.create(str(tmp_path / "file"), "n")
    other = tmp_path / "other"
    other.mkdir()
    (other / "draft.tex").write_text("x")
    with pytest.raises(runner.RunError, match="is not empty and holds no run"):
        RunFolder.create(str(other), "n", overwrite=True)
    assert (other / "draft.tex").exists()
    run = tmp_path / "run"
    run.mkdir()
    for name in (runner.CONFIG, runner.EPISODES, runner.CHECKPOINT, runner.PREVIOUS, "returns.png"):
        (run / name).write_text("x")
    (run / "notes.txt").write_text("kept")
    with pytest.raises(runner.RunError, match="holds a run"):
        RunFolder.create(str(run), "n")
    assert (run / runner.CONFIG).exists() and not (run / runner.LOCK).exists()  # refused: the lock let go
    folder = RunFolder.create(str(run), "n", overwrite=True)
    try:
        assert sorted(p.name for p in run.iterdir()) == ["notes.txt", runner.LOCK]
        assert folder._lock is not None
    finally:
        folder.release()
    empty = RunFolder.create(str(tmp_path / "new" / "deep"), "n")  # made, with its parents
    assert empty.path.is_dir() and empty._lock is not None and list(empty.path.iterdir()) == [empty.file(runner.LOCK)]
    empty.release()


def test_create_under_root_names_folders_by_name_and_time(tmp_path):
    a = RunFolder.create(None, "sq", root=str(tmp_path / "runs"))
    b = RunFolder.create(None, "sq", root=str(tmp_path / "runs"))
    try:
        assert a.path.parent == tmp_path / "runs" and a.path.name.startswith("sq-")
        assert b.path.name.startswith(a.path.name) and b.path != a.path
        assert a._lock is not None and b._lock is not None
    finally:
        a.release()
        b.release()


def test_create_says_what_it_cannot_write_in_one_line(tmp_path, monkeypatch):
    from pathlib import Path

    def denied(self, *a, **k):
        raise PermissionError(errno.EACCES, "Permission denied", str(self))
    monkeypatch.setattr(Path, "touch", denied)  # the probe that the folder can be written
    with pytest.raises(runner.RunError) as exc:
        RunFolder.create(str(tmp_path / "run"), "n")
    assert str(exc.value).startswith("cannot write the run folder: Permission denied: ")
    assert ".write-test-" in str(exc.value)
    assert not (tmp_path / "run" / runner.LOCK).exists() or RunFolder(tmp_path / "run").acquire() is None

    def read_only(self, *a, **k):
        raise OSError(errno.EROFS, "Read-only file system", str(self))
    monkeypatch.setattr(Path, "touch", read_only)
    with pytest.raises(runner.RunError, match="^cannot create the run folder: Read-only file system: .*write-test"):
        RunFolder.create(str(tmp_path / "run2"), "n")


def test_existing_needs_a_config(tmp_path):
    with pytest.raises(runner.RunError, match="holds no run to resume"):
        RunFolder.existing(tmp_path)
    (tmp_path / runner.CONFIG).write_text("{}")
    folder = RunFolder.existing(tmp_path)
    try:
        assert folder._lock is not None
    finally:
        folder.release()


def test_json_files_round_trip_and_a_damaged_one_is_named(tmp_path):
    folder = RunFolder(tmp_path)
    assert folder.read_json("x.json") is None and folder.status() is None and not folder.finished()
    folder.write_json("x.json", {"a": [1, 2]})
    assert folder.read_json("x.json") == {"a": [1, 2]}
    assert (tmp_path / "x.json").read_text().endswith("\n")
    folder.set_status("finished", reason="done", episodes_done=4)
    s = folder.status()
    assert (s["status"], s["reason"], s["pid"], s["episodes_done"]) == ("finished", "done", os.getpid(), 4)
    assert folder.finished()
    folder.set_status("running")
    assert not folder.finished() and folder.status()["reason"] is None
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(runner.RunError, match="cannot read .*bad.json"):
        folder.read_json("bad.json")


def rows(seed, episodes):
    return [dict(seed=seed, episode=e, ret=float(10 * seed + e) + 0.1) for e in episodes]


def test_append_rows_writes_the_header_once_and_returns_the_size(tmp_path):
    folder = RunFolder(tmp_path)
    assert folder.csv_size() == 0
    n1 = folder.append_rows(rows(0, [1]))
    assert (tmp_path / runner.EPISODES).read_text() == "seed,episode,ret\n0,1,1.1\n" and n1 == folder.csv_size() == 25
    (tmp_path / runner.EPISODES).write_text("")  # an empty file gets its header too
    folder.append_rows(rows(0, [1]))
    n2 = folder.append_rows(rows(1, [1, 2]))
    assert (tmp_path / runner.EPISODES).read_text() == "seed,episode,ret\n0,1,1.1\n1,1,11.1\n1,2,12.1\n"
    assert n2 == folder.csv_size() == len("seed,episode,ret\n0,1,1.1\n1,1,11.1\n1,2,12.1\n")


def test_append_rows_names_the_file_on_an_oserror(tmp_path, monkeypatch):
    folder = RunFolder(tmp_path)

    def full(self, *a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")
    import pandas as pd
    monkeypatch.setattr(pd.DataFrame, "to_csv", full)
    with pytest.raises(OSError) as exc:
        folder.append_rows(rows(0, [1]))
    assert exc.value.errno == errno.ENOSPC and exc.value.filename == str(tmp_path / runner.EPISODES)
    assert exc.value.strerror == "No space left on device"


def test_write_episodes_sorts_by_seed_then_episode_stably(tmp_path):
    import pandas as pd
    folder = RunFolder(tmp_path)
    df = pd.DataFrame(dict(seed=[1, 0, 1, 0], episode=[2, 2, 1, 1], ret=[4.0, 3.0, 2.0, 1.0]))
    out = folder.write_episodes(df)
    assert list(out.index) == [0, 1, 2, 3] and list(out.ret) == [1.0, 3.0, 2.0, 4.0]
    assert (tmp_path / runner.EPISODES).read_text() == "seed,episode,ret\n0,1,1.0\n0,2,3.0\n1,1,2.0\n1,2,4.0\n"
    folder.append_rows([dict(seed=0, episode=3, ret=5.0)])
    assert list(folder.finalize_csv().ret) == [1.0, 3.0, 5.0, 2.0, 4.0]
    assert list(folder.episodes().ret) == [1.0, 3.0, 5.0, 2.0, 4.0]


def test_keep_rows_cuts_to_each_seeds_covered_episodes(tmp_path):
    folder = RunFolder(tmp_path)
    folder.append_rows(rows(0, [1, 2]) + rows(1, [1]) + rows(0, [3]) + rows(1, [2, 3]))
    before = (tmp_path / runner.EPISODES).read_bytes()
    folder.keep_rows({0: 3, 1: 3})                  # every row covered: the file is not rewritten
    assert (tmp_path / runner.EPISODES).read_bytes() == before
    folder.keep_rows({0: 2, 1: 1})
    df = folder.episodes()
    assert list(zip(df.seed, df.episode)) == [(0, 1), (0, 2), (1, 1)]
    folder.keep_rows({0: 0, 1: 0})                  # nothing covered: no file
    assert not (tmp_path / runner.EPISODES).exists()
    folder.keep_rows({0: 0})                        # and none needed


def test_keep_rows_refuses_a_file_missing_or_repeating_rows(tmp_path):
    folder = RunFolder(tmp_path)
    with pytest.raises(runner.RunError, match="is missing: its checkpoint covers 3 episodes"):
        folder.keep_rows({0: 2, 1: 1})
    folder.append_rows(rows(0, [1]) + rows(1, [1]))
    with pytest.raises(runner.RunError, match=r"the 3 episodes its checkpoint covers once each \(1 missing, 0 repeated\)"):
        folder.keep_rows({0: 2, 1: 1})
    folder.append_rows(rows(0, [1, 2]))
    with pytest.raises(runner.RunError, match=r"\(0 missing, 1 repeated\)"):
        folder.keep_rows({0: 2, 1: 1})


def test_keep_rows_refuses_a_row_repeated_in_place_of_a_missing_one(tmp_path):
    """Seed 0's episode 1 twice and its episode 2 missing: as many rows as the checkpoint covers
    (3), but not the 3 episodes, so resume refuses the file (a count of rows alone would take it,
    and the run would go on without episode 2's row); the file is left as it was."""
    folder = RunFolder(tmp_path)
    folder.append_rows(rows(0, [1, 1]) + rows(1, [1]))
    before = (tmp_path / runner.EPISODES).read_bytes()
    with pytest.raises(runner.RunError,
                       match=r"the 3 episodes its checkpoint covers once each \(1 missing, 1 repeated\)"):
        folder.keep_rows({0: 2, 1: 1})
    assert (tmp_path / runner.EPISODES).read_bytes() == before

def test_a_half_written_last_row_is_cut_off(tmp_path):
    folder = RunFolder(tmp_path)
    folder.append_rows(rows(0, [1, 2]))
    path = tmp_path / runner.EPISODES
    whole = path.read_bytes()
    with open(path, "ab") as f:
        f.write(b"0,3,3")                           # "0,3,3" of "0,3,3.1": would parse as a row
    folder.keep_rows({0: 2})
    assert path.read_bytes() == whole
    folder._drop_unfinished_row()                   # a whole file is left as it is
    assert path.read_bytes() == whole


def test_a_half_written_row_is_cut_off_past_64_kib(tmp_path):
    folder = RunFolder(tmp_path)
    folder.append_rows(rows(0, range(1, 6001)))     # far more than 64 KiB
    path = tmp_path / runner.EPISODES
    whole = path.read_bytes()
    assert len(whole) > 2 ** 16
    with open(path, "ab") as f:
        f.write(b"0,6001,1")
    folder._drop_unfinished_row()
    assert path.read_bytes() == whole


def ck(n):
    import torch
    return dict(format=runner.CHECKPOINT_FORMAT, episodes_done=n, agent={"w": torch.full((2,), float(n))})


def test_save_checkpoint_keeps_the_one_before_and_drop_previous_removes_it(tmp_path):
    folder = RunFolder(tmp_path)
    folder.save_checkpoint(ck(1))
    assert not folder.file(runner.PREVIOUS).exists()
    folder.save_checkpoint(ck(2))
    folder.save_checkpoint(ck(3))
    assert folder._read_checkpoint(folder.file(runner.CHECKPOINT))["episodes_done"] == 3
    assert folder._read_checkpoint(folder.file(runner.PREVIOUS))["episodes_done"] == 2
    folder.drop_previous()
    assert not folder.file(runner.PREVIOUS).exists() and folder.file(runner.CHECKPOINT).exists()
    folder.drop_previous()  # none: no error


def test_a_failed_checkpoint_write_leaves_both_as_they_were(tmp_path, monkeypatch):
    folder = RunFolder(tmp_path)
    folder.save_checkpoint(ck(1))
    folder.save_checkpoint(ck(2))

    def full(state, f):
        f.write(b"PK\x03\x04part")
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(runner.torch, "save", full)
    with pytest.raises(OSError, match="No space"):
        folder.save_checkpoint(ck(3))
    monkeypatch.undo()
    assert folder._read_checkpoint(folder.file(runner.CHECKPOINT))["episodes_done"] == 2
    assert folder._read_checkpoint(folder.file(runner.PREVIOUS))["episodes_done"] == 1


def test_the_extension_point_round_trips_and_a_missing_one_is_a_run_error(tmp_path):
    folder = RunFolder(tmp_path)
    with pytest.raises(runner.RunError, match="cannot be lengthened exactly: .*is missing .*start it again"):
        folder.load_extension_point()
    folder.save_extension_point(ck(5))
    state = folder.load_extension_point()
    assert state["episodes_done"] == 5 and state["agent"]["w"].tolist() == [5.0, 5.0]


def test_load_checkpoint_none_when_there_is_none(tmp_path):
    assert RunFolder(tmp_path).load_checkpoint() is None


def cut(path):
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def test_load_checkpoint_falls_back_to_the_previous_then_the_extension_point(tmp_path):
    folder = RunFolder(tmp_path)
    folder.save_extension_point(ck(1))
    folder.save_checkpoint(ck(2))
    folder.save_checkpoint(ck(3))
    lines = []
    assert folder.load_checkpoint(log=lines.append)["episodes_done"] == 3 and lines == []
    cut(folder.file(runner.CHECKPOINT))
    assert folder.load_checkpoint(log=lines.append)["episodes_done"] == 2
    assert len(lines) == 1 and lines[0].startswith(f"cannot read {folder.file(runner.CHECKPOINT)}: the file is cut short")
    assert lines[0].endswith("; continuing from checkpoint.prev.pt (2 episodes done)")
    cut(folder.file(runner.PREVIOUS))
    lines.clear()
    assert folder.load_checkpoint(log=lines.append)["episodes_done"] == 1
    assert len(lines) == 1 and lines[0].count("the file is cut short") == 2
    assert lines[0].endswith("; continuing from checkpoint.extend.pt (1 episodes done)")
    folder.drop_previous()  # a finished run: no previous, the extension point still
    lines.clear()
    assert folder.load_checkpoint(log=lines.append)["episodes_done"] == 1 and lines[0].count("cut short") == 1
    cut(folder.file(runner.EXTEND))
    with pytest.raises(runner.RunError) as exc:
        folder.load_checkpoint(log=lines.append)
    msg = str(exc.value)
    assert msg.count("cut short") == 2 and "; and cannot read" in msg
    assert msg.endswith("; no checkpoint of this run can be read: start it again (--overwrite)")


def test_load_checkpoint_says_so_on_stderr_by_default(tmp_path, capsys):
    folder = RunFolder(tmp_path)
    folder.save_checkpoint(ck(2))
    folder.save_checkpoint(ck(3))
    (tmp_path / runner.CHECKPOINT).write_bytes(b"garbage")
    assert folder.load_checkpoint()["episodes_done"] == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "it is not a checkpoint (torch writes zip archives)" in err


def test_load_checkpoint_with_only_a_previous_one(tmp_path):
    folder = RunFolder(tmp_path)
    folder.save_checkpoint(ck(2))
    folder.save_checkpoint(ck(3))
    (tmp_path / runner.CHECKPOINT).unlink()
    lines = []
    assert folder.load_checkpoint(log=lines.append)["episodes_done"] == 2
    assert "checkpoint.pt is missing" in lines[0]


def test_another_format_is_refused_without_a_fallback(tmp_path):
    folder = RunFolder(tmp_path)
    folder.save_checkpoint(ck(2))
    folder.save_checkpoint({**ck(3), "format": 1})
    with pytest.raises(runner.RunError, match=f"has checkpoint format 1, this code reads {runner.CHECKPOINT_FORMAT}: "
                                              "it was written by an older version"):
        folder.load_checkpoint(log=pytest.fail)
    folder.save_checkpoint({"episodes_done": 3})
    with pytest.raises(runner.RunError, match="has checkpoint format None"):
        folder.load_checkpoint(log=pytest.fail)


def test_a_checkpoint_holding_no_dict_is_damaged(tmp_path):
    import torch
    folder = RunFolder(tmp_path)
    folder.save_checkpoint(ck(2))
    folder.save_checkpoint([1, 2])
    lines = []
    assert folder.load_checkpoint(log=lines.append)["episodes_done"] == 2
    assert "it holds a list, not a checkpoint" in lines[0]
    torch.save(torch.zeros(2), tmp_path / "t.pt")
    with pytest.raises(runner.DamagedCheckpoint, match="it holds a Tensor, not a checkpoint"):
        folder._read_checkpoint(tmp_path / "t.pt")


class Planted:
    def __reduce__(self):
        return (print, ("ran",))


def test_a_planted_pickle_is_refused_without_a_fallback(tmp_path):
    import torch
    folder = RunFolder(tmp_path)
    folder.save_checkpoint(ck(2))
    torch.save({**ck(3), "x": Planted()}, tmp_path / runner.CHECKPOINT)
    with pytest.raises(runner.RunError) as exc:
        folder.load_checkpoint(log=pytest.fail)
    assert "it holds more than plain data" in str(exc.value) and "could run code" in str(exc.value)


def test_damage_tells_cut_short_from_not_a_checkpoint(tmp_path):
    import pickle
    import zipfile
    p = tmp_path / "f"
    p.write_bytes(b"PK\x03\x04" + b"\0" * 40)
    assert runner.damage(p, EOFError()).startswith("the file is cut short (a write that did not finish")
    p.write_bytes(b"PK\x03" + b"\0" * 40)
    assert runner.damage(p, EOFError()) == "the file is damaged: it is not a checkpoint (torch writes zip archives)"
    with zipfile.ZipFile(p, "w") as z:
        z.writestr("a", "b")
    assert runner.damage(p, RuntimeError("x")) == "the file is damaged (RuntimeError while reading it)"
    assert runner.damage(p, pickle.UnpicklingError("x")).startswith("it holds more than plain data")


def test_disk_note_is_the_memory_estimate_in_mb():
    from trl_dgpq.collectors.experiment import memory_estimate, resolve_config
    config = resolve_config(agent="dqn", seeds=[0, 1], episodes=3)
    mb = memory_estimate(config) / 1e6
    assert runner.disk_note(config) == (f"checkpoints up to ~{float(f'{mb:.3g}'):g} MB each (its agents' state when "
                                        "full): 3 while it runs, 2 once finished")


def test_disk_note_says_a_growing_agents_checkpoints_grow():
    """DGPQ's Q̂ has no bound: its note gives the size at the start and says it grows; DQN's
    replay memory is saved at its capacity: an upper bound."""
    from trl_dgpq.collectors.experiment import resolve_config
    note = runner.disk_note(resolve_config(env="square", agent="dgpq", seeds=[0], episodes=3))
    assert note.startswith("checkpoints from ~") and ", growing as the agent learns (its state has no bound): 3 " in note
    assert "up to ~" in runner.disk_note(resolve_config(agent="dqn", seeds=[0], episodes=3))


def test_deferred_signals_set_a_flag_and_put_the_handlers_back():
    import signal
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    with runner.deferred_signals() as caught:
        assert caught["signum"] is None
        os.kill(os.getpid(), signal.SIGTERM)
        assert caught["signum"] == signal.SIGTERM
        os.kill(os.getpid(), signal.SIGINT)
        assert caught["signum"] == signal.SIGINT
    assert {s: signal.getsignal(s) for s in before} == before


def test_deferred_signals_off_the_main_thread_change_nothing():
    import signal
    import threading
    seen = {}

    def body():
        before = signal.getsignal(signal.SIGINT)
        with runner.deferred_signals() as caught:
            seen.update(caught=dict(caught), same=signal.getsignal(signal.SIGINT) is before)
    t = threading.Thread(target=body)
    t.start()
    t.join()
    assert seen == dict(caught={"signum": None}, same=True)


def test_alive():
    import subprocess
    import sys
    assert not runner._alive(os.getpid()) and not runner._alive(None) and not runner._alive("1")
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    assert not runner._alive(proc.pid)  # gone (reaped)
    assert runner._alive(1)             # init: there (or not ours: PermissionError, still alive)


def recorded_run(tmp_path, status="interrupted", **settings):
    from trl_dgpq.collectors.experiment import resolve_config
    config = resolve_config(**{**dict(seeds=[0, 1], episodes=3), **settings})
    folder = RunFolder(tmp_path)
    folder.path.mkdir(parents=True, exist_ok=True)
    folder.write_json(runner.CONFIG, {**config, "versions": {"torch": "0.0"}, "git": {}})
    if status:
        folder.set_status(status, episodes_done=2)
    return folder, config


def test_resumable_config_refuses_a_finished_or_live_run(tmp_path, capsys):
    folder, config = recorded_run(tmp_path, status="finished")
    with pytest.raises(runner.RunError, match="is finished; nothing to resume"):
        runner.resumable_config(folder)
    assert runner.resumable_config(folder, lengthen=True) == config
    folder.set_status("running")
    assert runner.resumable_config(folder) == config    # this process's own pid: not another's
    folder.write_json(runner.STATUS, dict(status="running", pid=1))
    with pytest.raises(runner.RunError, match="is being run by process 1"):
        runner.resumable_config(folder)
    folder.write_json(runner.STATUS, dict(status="interrupted", pid=1))
    assert runner.resumable_config(folder) == config


def test_resumable_config_notes_changed_versions(tmp_path, capsys):
    folder, config = recorded_run(tmp_path)
    assert runner.resumable_config(folder) == config
    err = capsys.readouterr().err
    assert err.startswith("note: versions differ from the interrupted run: {'torch': ('0.0', ")
    assert err.count("\n") == 1
    folder.write_json(runner.CONFIG, {**config, "versions": runner.provenance()["versions"]})
    runner.resumable_config(folder)
    assert capsys.readouterr().err == ""


def test_resumable_config_names_a_broken_config(tmp_path):
    folder, config = recorded_run(tmp_path)
    folder.write_json(runner.CONFIG, {**config, "run": {**config["run"], "bogus": 1}})
    with pytest.raises(runner.RunError, match=r"config.json: .*bogus"):
        runner.resumable_config(folder)


def test_lengthen_records_the_new_length_status_first(tmp_path):
    folder, config = recorded_run(tmp_path)
    assert runner.lengthen(folder, config, episodes=3) is config  # nothing changes: nothing written
    assert "lengthened" not in folder.read_json(runner.CONFIG)
    longer = runner.lengthen(folder, config, episodes=5)
    assert longer["run"]["episodes"] == 5 and config["run"]["episodes"] == 3
    assert {k: v for k, v in longer["run"].items() if k != "episodes"} == \
        {k: v for k, v in config["run"].items() if k != "episodes"}
    s = folder.status()
    assert (s["status"], s["reason"], s["episodes_done"]) == ("interrupted", "lengthening: episodes 3 -> 5", 2)
    rec = folder.read_json(runner.CONFIG)
    assert rec["run"]["episodes"] == 5 and rec["versions"] == {"torch": "0.0"}
    assert len(rec["lengthened"]) == 1 and rec["lengthened"][0]["episodes"] == dict(was=3, now=5)
    assert "env_steps" not in rec["lengthened"][0] and "git" in rec["lengthened"][0]
    runner.lengthen(folder, longer, episodes=1200)
    rec = folder.read_json(runner.CONFIG)
    assert [e["episodes"] for e in rec["lengthened"]] == [dict(was=3, now=5), dict(was=5, now=1200)]
    assert folder.status()["reason"] == "lengthening: episodes 5 -> 1,200"


def test_lengthen_by_budget(tmp_path):
    folder, config = recorded_run(tmp_path, env_steps=100, episodes=100)
    longer = runner.lengthen(folder, config, env_steps=150)  # the cap the budget set follows it
    assert (longer["run"]["env_steps"], longer["run"]["episodes"]) == (150, 150)
    assert folder.status()["reason"] == "lengthening: episodes 100 -> 150, env_steps 100 -> 150"
    folder, config = recorded_run(tmp_path / "b", env_steps=100, episodes=7)
    longer = runner.lengthen(folder, config, env_steps=150)  # a cap of its own stays
    assert (longer["run"]["env_steps"], longer["run"]["episodes"]) == (150, 7)


def test_lengthen_refuses_anything_shorter(tmp_path):
    folder, config = recorded_run(tmp_path, env_steps=100, episodes=5)
    for lengths, words in [(dict(episodes=4), "^--episodes 4 is fewer than the run's 5: a run can only be lengthened$"),
                           (dict(env_steps=99), "--env-steps 99 is a smaller budget than the run's 100"),
                           (dict(gamma=0.5, seeds=[1]), "only be lengthened in episodes, env_steps, not gamma, seeds"),
                           (dict(episodes=0), "episodes")]:
        with pytest.raises(runner.RunError, match=words):
            runner.lengthen(folder, config, **lengths)
    folder, config = recorded_run(tmp_path / "b", episodes=5)
    with pytest.raises(runner.RunError, match=r"--env-steps 50 is a smaller budget than the run's none \(0\)"):
        runner.lengthen(folder, config, env_steps=50)
    assert folder.status()["status"] == "interrupted" and folder.status()["reason"] is None  # nothing written
    assert runner.lengthen(folder, config, episodes=6, env_steps=0)["run"]["episodes"] == 6


def small(**kw):
    from trl_dgpq.collectors.experiment import resolve_config
    return resolve_config(**{**dict(seeds=[0, 1], episodes=3, agent="random", max_steps=20), **kw})


def test_a_crash_marks_the_run_failed_and_is_raised_as_it_was(tmp_path, stop_run_after):
    folder = RunFolder.create(str(tmp_path / "r"), "x")
    stop_run_after(2, "crash")
    with pytest.raises(RuntimeError, match="simulated crash"):
        runner.start(small(), folder, progress=False)
    s = folder.status()
    assert s["status"] == "failed" and s["reason"] == "RuntimeError: simulated crash"
    assert s["episodes_done"] >= 2 and folder._lock is None  # released however it ends


def test_a_signal_marks_the_run_interrupted_with_a_checkpoint_covering_the_rows(tmp_path, stop_run_after):
    import signal
    folder = RunFolder.create(str(tmp_path / "r"), "x")
    stop_run_after(1, "signal")
    with pytest.raises(runner.Interrupted) as exc:
        runner.start(small(), folder, progress=False)
    s = folder.status()
    assert (s["status"], s["reason"]) == ("interrupted", "SIGINT") and exc.value.signum == signal.SIGINT
    done = folder.load_checkpoint(log=pytest.fail)["episodes_done"]
    assert exc.value.episodes_done == s["episodes_done"] == done == len(folder.episodes()) >= 1
    assert exc.value.folder is folder and folder._lock is None


def test_a_full_disk_mid_run_is_one_line_and_resume_finishes(tmp_path, monkeypatch):
    folder = RunFolder.create(str(tmp_path / "r"), "x")
    whole = runner.start(small(), RunFolder.create(str(tmp_path / "whole"), "x"), progress=False)
    calls, append = [0], RunFolder.append_rows

    def fills(self, rows):
        calls[0] += 1
        if calls[0] == 2:
            raise OSError(errno.ENOSPC, "No space left on device", str(self.file(runner.EPISODES)))
        return append(self, rows)
    monkeypatch.setattr(RunFolder, "append_rows", fills)
    with pytest.raises(runner.RunError) as exc:
        runner.start(small(), folder, progress=False)
    assert str(exc.value) == (f"cannot write {folder.file(runner.EPISODES)}: No space left on device; the rows and "
                              f"the checkpoint written before are whole: free space, then --resume {folder.path}")
    s = folder.status()
    assert s["status"] == "failed" and s["reason"].startswith("OSError: [Errno 28] No space left on device")
    assert isinstance(s["episodes_done"], int) and s["episodes_done"] >= 1
    monkeypatch.undo()
    folder = RunFolder.existing(folder.path)
    df = runner.resume(folder, runner.resumable_config(folder), progress=False)
    import pandas as pd
    from trl_dgpq.collectors.experiment import TIMING_COLUMNS
    pd.testing.assert_frame_equal(df.drop(columns=list(TIMING_COLUMNS)), whole.drop(columns=list(TIMING_COLUMNS)))


def test_a_full_disk_also_for_the_status_is_still_one_line(tmp_path, monkeypatch):
    folder = RunFolder.create(str(tmp_path / "r"), "x")

    def full(self, *a, **k):
        raise OSError(errno.ENOSPC, "No space left on device", str(self.file(runner.EPISODES)))
    monkeypatch.setattr(RunFolder, "append_rows", full)
    statuses = []
    set_status = RunFolder.set_status

    def status_fails_when_failed(self, status, *a, **k):
        statuses.append(status)
        if status == "failed":
            raise OSError(errno.ENOSPC, "No space left on device", "status.json")
        return set_status(self, status, *a, **k)
    monkeypatch.setattr(RunFolder, "set_status", status_fails_when_failed)
    with pytest.raises(runner.RunError, match="^cannot write .*episodes.csv: No space left on device; the rows"):
        runner.start(small(), folder, progress=False)
    assert statuses == ["running", "failed"] and folder.status()["status"] == "running"
    assert folder.status()["episodes_done"] == 0


def test_a_full_disk_when_sorting_leaves_every_row_and_says_resume_finishes_it(tmp_path, monkeypatch):
    folder = RunFolder.create(str(tmp_path / "r"), "x")

    def full(self):
        raise OSError(errno.ENOSPC, "No space left on device", str(self.file(runner.EPISODES)))
    monkeypatch.setattr(RunFolder, "finalize_csv", full)
    with pytest.raises(runner.RunError) as exc:
        runner.start(small(), folder, progress=False)
    assert str(exc.value) == (f"cannot write {folder.file(runner.EPISODES)}: No space left on device; every episode "
                              f"is in episodes.csv (unsorted): free space, then --resume {folder.path} to finish it")
    assert folder.status()["status"] == "running" and len(folder.episodes()) == 6
    monkeypatch.undo()
    folder = RunFolder.existing(folder.path)
    df = runner.resume(folder, runner.resumable_config(folder), progress=False)
    assert list(zip(df.seed, df.episode)) == [(0, 1), (0, 2), (0, 3), (1, 1), (1, 2), (1, 3)]
    assert folder.finished() and not folder.file(runner.PREVIOUS).exists()


def test_a_finished_run_has_its_final_checkpoint_and_drops_the_previous(tmp_path):
    folder = RunFolder.create(str(tmp_path / "r"), "x")
    df = runner.start(small(seeds=[0], episodes=4, checkpoint_every=1), folder, progress=False)
    assert list(df.episode) == [1, 2, 3, 4]
    s = folder.status()
    assert (s["status"], s["episodes_done"]) == ("finished", 4)
    assert folder.load_checkpoint(log=pytest.fail)["episodes_done"] == 4
    assert not folder.file(runner.PREVIOUS).exists()
    assert not folder.file(runner.EXTEND).exists()           # one seed: every seed stopped at once
    assert folder.read_json(runner.CONFIG)["run"]["episodes"] == 4 and "git" in folder.read_json(runner.CONFIG)


def test_checkpoints_are_taken_every_so_many_episodes_per_seed(tmp_path, monkeypatch):
    saved, save = [], RunFolder.save_checkpoint

    def counting(self, state):
        saved.append(state["episodes_done"])
        return save(self, state)
    monkeypatch.setattr(RunFolder, "save_checkpoint", counting)
    runner.start(small(seeds=[0], episodes=7, checkpoint_every=3), RunFolder.create(str(tmp_path / "a"), "x"),
                 progress=False)
    assert saved == [3, 6, 7]
    saved.clear()
    runner.start(small(seeds=[0], episodes=3, checkpoint_every=0), RunFolder.create(str(tmp_path / "b"), "x"),
                 progress=False)
    assert saved == [3]


def test_a_zip_that_is_no_checkpoint_is_damaged_by_name(tmp_path):
    import zipfile
    with zipfile.ZipFile(tmp_path / "z.pt", "w") as z:
        z.writestr("a", "b")
    with pytest.raises(runner.DamagedCheckpoint, match=r"the file is damaged \(RuntimeError while reading it\)"):
        RunFolder(tmp_path)._read_checkpoint(tmp_path / "z.pt")


def test_a_half_written_header_and_a_long_half_row_are_cut_off(tmp_path):
    folder = RunFolder(tmp_path)
    path = tmp_path / runner.EPISODES
    path.write_bytes(b"seed,epi")
    folder._drop_unfinished_row()
    assert path.read_bytes() == b""
    path.write_bytes(b"seed,episode,ret\n0,1,1.5\n" + b"0,2," + b"1" * 100)  # a part row longer than 32 bytes
    folder._drop_unfinished_row()
    assert path.read_bytes() == b"seed,episode,ret\n0,1,1.5\n"


def test_existing_refuses_a_folder_it_cannot_write(tmp_path, monkeypatch):
    (tmp_path / runner.CONFIG).write_text("{}")
    monkeypatch.setattr(runner.os, "access", lambda path, mode: False)
    with pytest.raises(runner.RunError, match=f"^cannot write to {tmp_path}$"):
        RunFolder.existing(tmp_path)


def test_alive_sends_no_signal_and_counts_a_process_not_ours(monkeypatch):
    import subprocess
    import sys
    import time
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        assert runner._alive(proc.pid)
        time.sleep(0.1)
        assert proc.poll() is None           # only asked (signal 0), not hung up
    finally:
        proc.kill()
        proc.wait()

    def not_ours(pid, sig):
        raise PermissionError(errno.EPERM, "Operation not permitted")
    monkeypatch.setattr(runner.os, "kill", not_ours)
    assert runner._alive(12345)


def test_resumable_config_names_both_versions_and_takes_a_config_without_them(tmp_path, capsys):
    import torch
    folder, config = recorded_run(tmp_path)
    runner.resumable_config(folder)
    assert f"{{'torch': ('0.0', '{torch.__version__}')}}" in capsys.readouterr().err
    folder.write_json(runner.CONFIG, config)  # recorded without versions
    assert runner.resumable_config(folder) == config and capsys.readouterr().err == ""


def test_lengthen_edges_of_the_budget(tmp_path):
    import re
    folder, config = recorded_run(tmp_path, env_steps=100, episodes=100)
    longer = runner.lengthen(folder, config, env_steps=150, episodes=120)  # both given: the episodes as given
    assert (longer["run"]["env_steps"], longer["run"]["episodes"]) == (150, 120)
    assert re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d", folder.read_json(runner.CONFIG)["lengthened"][0]["time"])
    with pytest.raises(runner.RunError, match="--env-steps 1 is a smaller budget than the run's 150"):
        runner.lengthen(folder, longer, env_steps=1)
    folder, config = recorded_run(tmp_path / "b", env_steps=100, episodes=7)
    longer = runner.lengthen(folder, config, env_steps=0)                # no budget: longer
    assert (longer["run"]["env_steps"], longer["run"]["episodes"]) == (0, 7)


def test_acquire_makes_the_folder_and_a_lock_file_others_can_read(tmp_path):
    old = os.umask(0o022)
    try:
        folder = RunFolder(tmp_path / "a" / "b")
        folder.acquire()
        try:
            assert (os.stat(folder.file(runner.LOCK)).st_mode & 0o777) == 0o644
        finally:
            folder.release()
    finally:
        os.umask(old)


def test_default_folder_names_carry_the_time(tmp_path):
    import re
    folder = RunFolder.create(None, "sq", root=str(tmp_path))
    folder.release()
    assert re.fullmatch(r"sq-\d{8}-\d{6}", folder.path.name)


# ------------------------------------------------------------ provenance
def test_provenance_names_each_version_as_its_library_reports_it():
    import platform

    import numpy
    import pandas
    import tensordict
    import torch
    import torchrl
    assert runner.provenance()["versions"] == dict(
        python=platform.python_version(), torch=torch.__version__, torchrl=torchrl.__version__,
        tensordict=tensordict.__version__, numpy=numpy.__version__, pandas=pandas.__version__)


def git_repo(path):
    """A git repository at ``path`` with one commit of tracked.txt; its commit id."""
    import subprocess
    path.mkdir(parents=True)
    g = lambda *a: subprocess.run(["git", "-C", str(path), *a], check=True, capture_output=True,  # noqa: E731
                                  text=True).stdout.strip()
    g("init", "-q")
    (path / "tracked.txt").write_text("a\n")
    g("add", "tracked.txt")
    g("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-m", "one")
    return g("rev-parse", "HEAD")


def test_provenance_says_dirty_when_the_code_differs_from_the_commit(tmp_path, monkeypatch):
    """The checkout is the folder above the package: runner.py's grandparent. Files outside the code
    (notes, docs, results) leave it clean, tracked or not; a changed file of the code, or a new one
    among it, makes it dirty."""
    repo = tmp_path / "repo"
    commit = git_repo(repo)
    (repo / "pkg").mkdir()
    monkeypatch.setattr(runner, "__file__", str(repo / "pkg" / "runner.py"))
    (repo / "untracked.txt").write_text("new\n")
    (repo / "tracked.txt").write_text("changed\n")                    # not code: a run's code is unchanged
    assert runner.provenance()["git"] == dict(commit=commit, dirty=False)
    (repo / "envs").mkdir()
    (repo / "envs" / "new.py").write_text("x = 1\n")                  # a new module among the code
    assert runner.provenance()["git"] == dict(commit=commit, dirty=True)
    (repo / "envs" / "new.py").unlink()
    (repo / "setup.py").write_text("")
    assert runner.provenance()["git"] == dict(commit=commit, dirty=True)


def test_provenance_outside_a_git_checkout_has_no_commit(tmp_path, monkeypatch):
    (tmp_path / "installed" / "pkg").mkdir(parents=True)
    monkeypatch.setattr(runner, "__file__", str(tmp_path / "installed" / "pkg" / "runner.py"))
    monkeypatch.setenv("GIT_CEILING_DIRECTORIES", str(tmp_path))   # git must not find a repository above
    got = runner.provenance()
    assert got["git"] == dict(commit=None, dirty=None) and got["versions"]["torch"]
    monkeypatch.setenv("PATH", str(tmp_path / "no-git-here"))         # no git at all: the same
    assert runner.provenance()["git"] == dict(commit=None, dirty=None)


# ------------------------------------------------------------ checkpoints in a run, status while it runs
def test_checkpoints_fall_at_each_multiple_of_checkpoint_every_times_the_seeds(tmp_path, monkeypatch):
    """5 seeds on the slippery corridor (episodes of random lengths, so seeds finish them out of
    step and the count can jump past a multiple): a checkpoint at the first batched step where the
    episodes done reach each next multiple of 5, worked out from the rows' own step counts, then
    one at the end; status.json says "running" from the start (0 done) while it runs."""
    import json

    import pandas as pd

    from trl_dgpq.commands import train
    out = tmp_path / "run"
    saved, statuses = [], []
    original = RunFolder.save_checkpoint

    def spy(self, state):
        saved.append(state["episodes_done"])
        statuses.append(json.loads((self.path / runner.STATUS).read_text()))
        return original(self, state)
    monkeypatch.setattr(RunFolder, "save_checkpoint", spy)
    assert train.main(["--env", "corridor", "--agent", "constant", "--slip", "0.4", "--seeds", "0-4", "--episodes",
                       "8", "--checkpoint-every", "1", "--out", str(out), "--no-progress"]) == 0
    df = pd.read_csv(out / "episodes.csv")
    df["end"] = df.groupby("seed")["steps"].cumsum()          # the batched step each episode ended at
    done = df.groupby("end").size().cumsum()                  # episodes done after those steps
    want, next_at = [], 5
    for count in done.tolist():
        if count >= next_at and count < 40:
            want.append(count)
            next_at = (count // 5 + 1) * 5
    assert saved == want + [40] and any(c % 5 for c in want)  # a jump past a multiple happened
    assert all(s["status"] == "running" and s["episodes_done"] == 0 for s in statuses)


def test_status_json_has_the_time_and_the_writers_pid(tmp_path):
    import json
    import time
    (tmp_path / "run").mkdir()
    folder = RunFolder(tmp_path / "run")
    before = time.time()
    folder.set_status("running", episodes_done=3)
    got = json.loads((tmp_path / "run" / runner.STATUS).read_text())
    assert got["status"] == "running" and got["reason"] is None and got["episodes_done"] == 3
    assert got["pid"] == os.getpid()
    stamp = time.mktime(time.strptime(got["time"], "%Y-%m-%d %H:%M:%S"))
    assert before - 1 <= stamp <= time.time() + 1


def test_alive_asks_without_disturbing_the_process():
    import subprocess
    import sys
    import time
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        assert runner._alive(child.pid) is True
        time.sleep(0.2)                         # a signal sent by mistake would have ended it by now
        assert child.poll() is None
    finally:
        child.kill()
        child.wait()
    assert runner._alive(child.pid) is False and runner._alive(os.getpid()) is False
    assert runner._alive("123") is False


def test_a_new_run_folder_is_made_with_its_missing_parents(tmp_path):
    folder = RunFolder.create(None, "square-dgpq", root=str(tmp_path / "a" / "b"))
    assert folder.path.parent == tmp_path / "a" / "b" and folder.path.name.startswith("square-dgpq")


def test_a_new_run_folder_goes_under_runs_by_default(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    folder = RunFolder.create(None, "square-dgpq")
    assert folder.path.parent.resolve() == (tmp_path / "runs").resolve()


def test_no_unique_run_folder_left_is_one_line_naming_the_root(tmp_path, monkeypatch):
    from pathlib import Path
    real = Path.mkdir

    def taken(self, *a, **kw):
        if self.name.startswith("square-dgpq"):
            raise FileExistsError(self)
        return real(self, *a, **kw)
    monkeypatch.setattr(Path, "mkdir", taken)
    with pytest.raises(runner.RunError, match=f"could not create a unique run folder under {tmp_path / 'r'}$"):
        RunFolder.create(None, "square-dgpq", root=str(tmp_path / "r"))


def test_out_holding_a_run_is_refused_naming_it(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / runner.CONFIG).write_text("{}")
    (out / runner.STATUS).write_text('{"status": "finished"}')
    with pytest.raises(runner.RunError, match=f"--out {out} holds a run: continue it with --resume {out}, "):
        RunFolder.create(str(out), "x")


def test_rows_with_columns_the_file_lacks_add_them_and_fewer_columns_leave_gaps(tmp_path):
    """A run begun by older code and resumed by newer code whose env reports more per episode:
    the rows still line up with the header (the old rows empty in the new column), never a
    row with more fields than the header."""
    import pandas as pd
    folder = RunFolder(tmp_path / "r")
    folder.path.mkdir()
    folder.append_rows([dict(seed=0, episode=1, steps=5, ac_cost=2.5)])
    folder.append_rows([dict(seed=0, episode=2, steps=6, ac_cost=3.5, cost_ratio=1.25)])
    folder.append_rows([dict(seed=1, episode=1, steps=7, cost_ratio=0.5, ac_cost=4.5)])  # another order
    folder.append_rows([dict(seed=1, episode=2, steps=8, ac_cost=5.5)])                 # one fewer
    df = pd.read_csv(folder.file(runner.EPISODES))
    assert list(df.columns) == ["seed", "episode", "steps", "ac_cost", "cost_ratio"]
    assert df.ac_cost.tolist() == [2.5, 3.5, 4.5, 5.5] and df.steps.tolist() == [5, 6, 7, 8]
    assert df.cost_ratio.tolist()[1:3] == [1.25, 0.5] and df.cost_ratio.isna().tolist() == [True, False, False, True]
