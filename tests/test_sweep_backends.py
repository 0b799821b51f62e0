"""collectors/sweep.py's job and Ray backend in this process: ``run_job`` and ``_job_process``
(which test_sweep's real sweeps run in worker processes, where no mutation run sees them), and
``check_nodes`` and ``run_ray`` against a recording stand-in for Ray (the real Ray, ~15 s to start,
runs in test_sweep's slow tests)."""
import logging
import signal
import sys
import types

import pytest
import torch

from trl_dgpq.collectors import runner, sweep
from trl_dgpq.collectors.experiment import TIMING_COLUMNS, resolve_config


def tiny(seeds=(0, 1)):
    return resolve_config(env="square", agent="random", seeds=list(seeds), episodes=2, max_steps=5)


def free(folder) -> bool:
    """Whether this process can take ``folder``'s lock (no open descriptor of it holds it)."""
    f = runner.RunFolder(folder)
    try:
        f.acquire()
    except runner.RunError:
        return False
    f.release()
    return True


def refuse(*args, **kwargs):
    raise AssertionError("not to be called")


def test_a_job_runs_here_at_one_thread_quietly_and_gives_its_folder_back(tmp_path, capsys):
    folder = tmp_path / "e" / "jobs" / "j000"
    torch.set_num_threads(2)
    logging.getLogger("torchrl").setLevel(logging.DEBUG)
    sweep.run_job(tiny(), str(folder))
    assert torch.get_num_threads() == 1 and logging.getLogger("torchrl").level == logging.WARNING
    assert runner.RunFolder(folder).finished() and len(runner.RunFolder(folder).episodes()) == 4
    assert capsys.readouterr().err == ""                       # no progress bar in a worker
    assert free(folder)


def test_a_finished_job_is_left_alone_and_its_folder_given_back(tmp_path, monkeypatch):
    folder = tmp_path / "j000"
    sweep.run_job(tiny(), str(folder))
    before = runner.RunFolder(folder).file(runner.EPISODES).read_bytes()
    monkeypatch.setattr(runner, "start", refuse)
    monkeypatch.setattr(runner, "resume", refuse)
    sweep.run_job(tiny(), str(folder))
    assert runner.RunFolder(folder).file(runner.EPISODES).read_bytes() == before
    assert free(folder)


def test_a_begun_job_is_resumed_to_the_rows_of_one_run_at_one_thread(tmp_path, capsys):
    """Begun by an older version (its recorded config without ``threads``, which the runner then leaves
    as it finds them): the job still runs at one thread."""
    sweep.run_job(tiny(), str(tmp_path / "whole"))
    begun = runner.RunFolder(tmp_path / "begun")
    begun.path.mkdir()
    older = runner.recorded(tiny())
    del older["run"]["threads"]
    begun.write_json(runner.CONFIG, older)                      # started, nothing run yet
    capsys.readouterr()
    torch.set_num_threads(2)
    sweep.run_job(resolve_config(env="square", agent="random", seeds=[5], episodes=9), str(begun.path))
    assert torch.get_num_threads() == 1 and capsys.readouterr().err == ""
    whole = runner.RunFolder(tmp_path / "whole").episodes()
    timing = list(TIMING_COLUMNS)
    assert begun.episodes().drop(columns=timing).equals(whole.drop(columns=timing))
    assert free(begun.path)


def test_a_job_whose_folder_another_holds_is_refused_before_anything_is_written(tmp_path):
    holder = runner.RunFolder(tmp_path / "j000")
    holder.acquire()
    try:
        with pytest.raises(runner.RunError, match="being written by process"):
            sweep.run_job(tiny(), str(holder.path))
        assert not holder.file(runner.CONFIG).exists()
    finally:
        holder.release()


def test_a_workers_job_ends_its_process_with_the_runs_code_or_one_line(tmp_path, monkeypatch, capsys):
    calls = []
    monkeypatch.setattr(sweep, "run_job", lambda config, folder: calls.append((config, folder)))
    assert sweep._job_process({"a": 1}, "F") is None and calls == [({"a": 1}, "F")]

    def stopped(config, folder):
        raise runner.Interrupted(signal.SIGTERM, runner.RunFolder(tmp_path), 3)
    monkeypatch.setattr(sweep, "run_job", stopped)
    with pytest.raises(SystemExit) as ended:
        sweep._job_process({}, "F")
    assert ended.value.code == 143 and capsys.readouterr().err == ""

    for err, line in ((ValueError("bad seed"), "ValueError: bad seed"), (KeyboardInterrupt(), "KeyboardInterrupt: ")):
        def failing(config, folder, err=err):
            raise err
        monkeypatch.setattr(sweep, "run_job", failing)
        with pytest.raises(SystemExit) as ended:
            sweep._job_process({}, "OUT/e/jobs/j001")
        assert ended.value.code == 1
        assert capsys.readouterr().err == f"job in OUT/e/jobs/j001 failed: {line}\n"


# ------------------------------------------------------------------ a stand-in for Ray
class Affinity:
    def __init__(self, node_id, soft):
        self.node_id, self.soft = node_id, soft


class Ref:
    def __init__(self, ray, fn, args, strategy):
        self.ray, self.fn, self.args, self.strategy = ray, fn, args, strategy

    def value(self):
        if self.fn is sweep.writable_here:      # each node answers for itself
            return self.ray.answers.get(self.strategy.node_id)
        raised = self.ray.raises.get(self.args[1])
        if raised:
            raise raised
        return None


class Remote:
    def __init__(self, ray, fn, opts, strategy=None):
        self.ray, self.fn, self.opts, self.strategy = ray, fn, opts, strategy

    def options(self, scheduling_strategy):
        return Remote(self.ray, self.fn, self.opts, scheduling_strategy)

    def remote(self, *args):
        strategy = self.strategy and (self.strategy.node_id, self.strategy.soft)
        self.ray.log.append(("remote", self.fn.__name__, self.opts, strategy, args))
        return Ref(self.ray, self.fn, args, self.strategy)


class FakeRay(types.ModuleType):
    """What sweep.py calls of Ray, recorded: nodes answering the probe (``answers``: node id ->
    problem or None), tasks raising (``raises``: job folder -> exception), ``wait`` one at a time."""

    def __init__(self, nodes=(), answers=None, raises=None, initialized=False):
        super().__init__("ray")
        self._nodes, self.answers, self.raises = list(nodes), answers or {}, raises or {}
        self.initialized, self.log = initialized, []

    def is_initialized(self):
        return self.initialized

    def init(self, **kwargs):
        self.log.append(("init", kwargs))
        self.initialized = True

    def nodes(self):
        return self._nodes

    def remote(self, **opts):
        return lambda fn: Remote(self, fn, opts)

    def get(self, refs):
        return [r.value() for r in refs] if isinstance(refs, list) else refs.value()

    def wait(self, refs, num_returns):
        if num_returns > len(refs):
            raise ValueError("num_returns cannot be greater than the number of objects")
        self.log.append(("wait", len(refs), num_returns))
        return refs[:num_returns], refs[num_returns:]


@pytest.fixture
def fake_ray(monkeypatch):
    def install(**kw):
        ray = FakeRay(**kw)
        strategies = types.ModuleType("ray.util.scheduling_strategies")
        strategies.NodeAffinitySchedulingStrategy = Affinity
        monkeypatch.setitem(sys.modules, "ray", ray)
        monkeypatch.setitem(sys.modules, "ray.util", types.ModuleType("ray.util"))
        monkeypatch.setitem(sys.modules, "ray.util.scheduling_strategies", strategies)
        return ray
    return install


def probes(ray):
    return [(e[2], e[3], e[4]) for e in ray.log if e[0] == "remote" and e[1] == "writable_here"]


def test_every_alive_node_is_asked_whether_it_can_write_out_and_the_first_problem_named(fake_ray):
    nodes = [dict(NodeID="a", Alive=True), dict(NodeID="b", Alive=False), dict(NodeID="c"), dict(NodeID="d", Alive=1)]
    ray = fake_ray(nodes=nodes)
    assert sweep.check_nodes(ray, "/shared/out") is None
    assert probes(ray) == [({"num_cpus": 0}, ("a", False), ("/shared/out",)),
                           ({"num_cpus": 0}, ("d", False), ("/shared/out",))]
    ray = fake_ray(nodes=nodes, answers={"d": "node d cannot write /x: Read-only file system"})
    with pytest.raises(sweep.SweepError) as refused:
        sweep.check_nodes(ray, "/x")
    assert str(refused.value) == "--out must be on storage every node reaches: node d cannot write /x: Read-only file system"
    nodes = [dict(NodeID=n, Alive=True) for n in "abc"]
    ray = fake_ray(nodes=nodes, answers={"b": "node b: no", "c": "node c: no"})
    with pytest.raises(sweep.SweepError) as refused:
        sweep.check_nodes(ray, "/x")
    assert str(refused.value) == "--out must be on storage every node reaches: node b: no (and 1 more nodes)"
    ray = fake_ray(nodes=nodes, answers=dict.fromkeys("abc", "no"))
    with pytest.raises(sweep.SweepError, match=r"reaches: no \(and 2 more nodes\)$"):
        sweep.check_nodes(ray, "/x")


def ray_jobs(tmp_path, n):
    return [sweep.Job("e", i, [i], str(tmp_path / "out" / "e" / "jobs" / f"j{i:03d}"), {"run": {"seeds": [i]}})
            for i in range(n)]


def finish(job, status="finished", reason=None):
    f = runner.RunFolder(job.folder)
    f.path.mkdir(parents=True, exist_ok=True)
    f.set_status(status, reason)


class TaskError(Exception):
    pass


class WorkerCrashedError(Exception):
    pass


def test_ray_runs_each_job_as_a_task_and_reports_each_outcome(tmp_path, fake_ray, monkeypatch):
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    jobs = ray_jobs(tmp_path, 4)
    finish(jobs[0])
    finish(jobs[1], "failed", "NaN in the observation")
    finish(jobs[3])                                           # finished, though its worker then died
    ray = fake_ray(nodes=[dict(NodeID="n", Alive=True)], raises={
        jobs[1].folder: TaskError("Traceback (most recent call last):\n  File x\nRunError: NaN in the observation  \n"),
        jobs[2].folder: WorkerCrashedError("The worker died unexpectedly\n"),
        jobs[3].folder: WorkerCrashedError("lost")})
    done = []
    sweep.run_ray(jobs, None, 0.5, lambda job, result: done.append((job.index, result)))
    assert ray.log[0] == ("init", dict(num_cpus=__import__("os").cpu_count(), include_dashboard=False,
                                       log_to_driver=False))
    assert probes(ray) == [({"num_cpus": 0}, ("n", False), (str(tmp_path / "out"),))]
    tasks = [e for e in ray.log if e[0] == "remote" and e[1] == "run_job"]
    assert [(opts, args) for _, _, opts, _, args in tasks] == [
        (dict(num_cpus=0.5, max_retries=sweep.RAY_RETRIES, retry_exceptions=False), (j.config, j.folder)) for j in jobs]
    assert sweep.RAY_RETRIES == 3
    assert [e for e in ray.log if e[0] == "wait"] == [("wait", n, 1) for n in (4, 3, 2, 1)]
    assert done == [(0, dict(status="finished")),
                    (1, dict(status="failed", reason="NaN in the observation")),
                    (2, dict(status="killed", reason="WorkerCrashedError: The worker died unexpectedly")),
                    (3, dict(status="finished"))]


def test_a_tasks_error_is_its_last_line_and_only_a_crash_is_a_kill(tmp_path, fake_ray):
    jobs = ray_jobs(tmp_path, 2)
    fake_ray(initialized=True, raises={jobs[0].folder: TaskError("Traceback\n  File x\nValueError: bad  \n\n"),
                                       jobs[1].folder: TaskError("WorkerCrashed? no:\nOSError: disk full")})
    done = []
    sweep.run_ray(jobs, None, 1, lambda job, result: done.append(result))
    assert done == [dict(status="failed", reason="TaskError: ValueError: bad"),
                    dict(status="failed", reason="TaskError: OSError: disk full")]


def test_ray_joins_the_cluster_asked_for_or_the_one_it_is_in(tmp_path, fake_ray, monkeypatch):
    jobs = ray_jobs(tmp_path, 1)
    finish(jobs[0])
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    ray = fake_ray()
    sweep.run_ray(jobs, "head:6379", 1, lambda job, result: None)
    assert ray.log[0] == ("init", dict(address="head:6379", log_to_driver=False))
    monkeypatch.setenv("RAY_ADDRESS", "env-head:6379")
    ray = fake_ray()
    sweep.run_ray(jobs, None, 1, lambda job, result: None)
    assert ray.log[0] == ("init", dict(address="env-head:6379", log_to_driver=False))
    ray = fake_ray(initialized=True)
    sweep.run_ray(jobs, "head:6379", 1, lambda job, result: None)
    assert [e for e in ray.log if e[0] == "init"] == []


def test_ray_missing_is_said_in_one_line(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)
    with pytest.raises(sweep.SweepError) as refused:
        sweep.run_ray(ray_jobs(tmp_path, 1), None, 1, refuse)
    assert str(refused.value) == '--backend ray needs Ray: pip install -e ".[ray]"'
    assert refused.value.__cause__ is None and refused.value.__suppress_context__
