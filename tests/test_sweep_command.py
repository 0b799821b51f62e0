"""The sweep command (trl_dgpq/commands/sweep.py) with the sweep's work stubbed: which options go
together and each refusal's words, and what a fresh, resumed, grown or reusing sweep hands on."""
import os

import pytest

from trl_dgpq.collectors import sweep
from trl_dgpq.commands import sweep as command


@pytest.mark.parametrize("argv, words", [
    (["f.toml", "--out", "o", "--workers", "0"], "--workers must be >= 1"),
    (["--resume", "o", "f.toml"], "--resume continues a sweep as it was planned: give no file, --out, --overwrite "
                                  "or --seeds-per-job with it"),
    (["--resume", "o", "--out", "p"], "--resume continues a sweep as it was planned"),
    (["--resume", "o", "--overwrite"], "--resume continues a sweep as it was planned"),
    (["--resume", "o", "--seeds-per-job", "2"], "--resume continues a sweep as it was planned"),
    (["f.toml"], "give a sweep file and --out (or --resume OUT)"),
    (["--out", "o"], "give a sweep file and --out (or --resume OUT)"),
    (["f.toml", "--out", "o", "--grow", "--overwrite"], "--grow keeps the sweep in --out, --overwrite replaces it: "
                                                         "give one"),
])
def test_options_that_do_not_go_together_are_refused_in_words(argv, words, capsys):
    with pytest.raises(SystemExit) as stop:
        command.main(argv)
    assert stop.value.code == 2 and f"sweep.py: error: {words}" in capsys.readouterr().err


@pytest.fixture
def calls(monkeypatch):
    made = []

    def record(name, result=None):
        def f(*args, **kwargs):
            made.append((name, args, {k: v for k, v in kwargs.items() if k != "log"}))
            if "log" in kwargs:
                kwargs["log"](f"{name} says")
            return result
        return f
    monkeypatch.setattr(sweep, "read_sweep_file", record("read", {"e": "config"}))
    monkeypatch.setattr(sweep, "plan", record("plan", ["j0", "j1"]))
    monkeypatch.setattr(sweep, "create", record("create"))
    monkeypatch.setattr(sweep, "load", record("load", ({"e": "config"}, ["j1"])))
    monkeypatch.setattr(sweep, "grow", record("grow", ["j2"]))
    monkeypatch.setattr(sweep, "reuse", record("reuse", ["j3"]))
    monkeypatch.setattr(sweep, "describe_jobs", lambda jobs: f"{len(jobs)} jobs")
    monkeypatch.setattr(sweep, "execute", record("execute", {"report": 1}))
    monkeypatch.setattr(sweep, "exit_code", lambda report, rerun: made.append(("exit", report, rerun)) or 5)
    monkeypatch.setattr(sweep, "run_script", lambda script, rerun, body: made.append(("script", script, rerun))
                        or body())
    return made


def test_a_fresh_sweep_is_read_planned_created_and_run(calls, capsys):
    assert command.main(["f.toml", "--out", "my out", "--workers", "1", "--seeds-per-job", "4"]) == 5
    rerun = "python scripts/sweep.py --resume 'my out'"
    assert calls == [("script", "sweep.py", rerun), ("read", ("f.toml",), {}), ("plan", ({"e": "config"}, "my out", 4), {}),
                     ("create", ("my out", {"e": "config"}, ["j0", "j1"]), {"overwrite": False}),
                     ("execute", ("my out", ["j0", "j1"], "local", 1, None, 1), {}), ("exit", {"report": 1}, rerun)]
    assert capsys.readouterr().out == "sweep -> my out: 2 jobs; backend local\nexecute says\n"


def test_overwrite_backend_address_and_cpus_are_handed_on(calls):
    command.main(["f.toml", "--out", "o", "--overwrite", "--backend", "ray", "--ray-address", "h:1",
                  "--cpus-per-job", "0.5"])
    assert [c for c in calls if c[0] == "create"][0][2] == {"overwrite": True}
    assert [c for c in calls if c[0] == "execute"][0][1] == ("o", ["j0", "j1"], "ray", os.cpu_count(), "h:1", 0.5)


def test_a_resumed_sweep_is_loaded_and_runs_what_is_left(calls):
    assert command.main(["--resume", "o", "--workers", "2"]) == 5
    assert [c[0] for c in calls] == ["script", "load", "execute", "exit"]
    assert calls[1][1] == ("o",) and calls[2][1][:2] == ("o", ["j1"])


def test_grow_adds_to_a_sweep_that_exists_and_plans_one_that_does_not(calls, tmp_path):
    out = tmp_path / "o"
    command.main(["f.toml", "--out", str(out), "--grow"])
    assert [c[0] for c in calls][1:4] == ["read", "plan", "create"]          # nothing to grow yet
    out.mkdir()
    (out / sweep.SWEEP).write_text("{}")
    calls.clear()
    command.main(["f.toml", "--out", str(out), "--grow", "--seeds-per-job", "2"])
    assert [c[0] for c in calls] == ["script", "read", "grow", "execute", "exit"]
    assert calls[2][1] == (str(out), {"e": "config"}, 2)


def test_reuse_looks_in_the_other_sweeps_before_running(calls, capsys):
    command.main(["f.toml", "--out", "o", "--reuse", "a", "b"])
    assert [c for c in calls if c[0] == "reuse"] == [("reuse", ("o", ["j0", "j1"], ["a", "b"]), {})]
    assert [c for c in calls if c[0] == "execute"][0][1][1] == ["j3"]
    assert capsys.readouterr().out == "reuse says\nsweep -> o: 1 jobs; backend local\nexecute says\n"


def test_every_line_is_flushed_as_it_is_printed(calls, monkeypatch):
    printed = []
    monkeypatch.setattr(command, "print", lambda *a, **k: printed.append((a, k)), raising=False)
    command.main(["f.toml", "--out", "o", "--reuse", "a"])
    assert printed == [(("reuse says",), {"flush": True}), (("sweep -> o: 1 jobs; backend local",), {"flush": True}),
                       (("execute says",), {"flush": True})]
