"""Sweeps: several experiments, each one's seeds split into jobs, run on a pool of
worker processes on this machine or as Ray tasks on a cluster.

    OUT/sweep.json                   the experiments as resolved and the jobs (written once)
    OUT/<experiment>/config.json     the experiment's resolved config (all its seeds)
    OUT/<experiment>/jobs/j000/      a job: an ordinary run folder (see runner.py) for one
                                     slice of the seeds: its own rows, checkpoint, status
    OUT/<experiment>/episodes.csv    the jobs' rows, merged and sorted, with a ``job`` column;
                                     written once every job of the experiment has finished
    OUT/report.json                  each job's outcome (finished, failed, killed) and wall time
    OUT/<experiment>/reused.json     where its jobs were copied from (``reuse``), if they were

A job is (config, seeds): the lock-step batched loop over those seeds, in one process
with torch at one thread. Why one: a pool of N workers already fills N cores, and the
per-step tensors are small, so intra-op threads would only oversubscribe the cores.
Seeds never depend on their batch, so how they are split into jobs changes no row.

A job that dies (killed, out of memory, an exception, a NaN from the env) is reported
with its seeds and reason; the others run on and keep their rows. ``resume`` reruns
only the jobs that have not finished, each from its own last checkpoint.
"""
from __future__ import annotations

import json
import multiprocessing as mp
import os
import shutil
import signal
import sys
import threading
import time
import tomllib
from contextlib import contextmanager
from dataclasses import dataclass
from multiprocessing.connection import wait
from pathlib import Path
from typing import Callable, Dict, List, Optional

import pandas as pd

from trl_dgpq.analysis import count
from trl_dgpq.config import leaves

from . import runner
from .experiment import RunConfig, describe, quiet_torchrl, resolve_config

SWEEP, REPORT = "sweep.json", "report.json"
EXPERIMENT_KEYS = {"name", "set"} | {leaf.key for leaf in leaves(RunConfig)}
BACKENDS = ("local", "ray")


class SweepError(ValueError):
    """Something wrong with what was asked (one line, exit 2)."""


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the sweep's process as Ctrl-C raises KeyboardInterrupt, so that it
    stops the same way (``run_script``): its workers checkpoint, then one line."""


@dataclass
class Job:
    experiment: str
    index: int
    seeds: List[int]
    folder: str          # the job's run folder
    config: dict         # the experiment's config with run.seeds = this job's seeds

    @property
    def name(self) -> str:
        return f"{self.experiment} job {self.index} (seeds {_span(self.seeds)})"


def planned_seed_steps(job: Job) -> int:
    """The seed-steps ``job`` may take: its seeds times its env-step budget or its episodes times
    the episode cap, the smaller. Jobs of one sweep differ by 100x (an F-16 DGPQ job against a
    scripted one), so the time left is guessed from these, not from a count of jobs."""
    from trl_dgpq.config import from_dict
    from trl_dgpq.envs import env_class
    run = job.config["run"]
    cls = env_class(run["env"])   # checked: a gym id's cap of 0 is its registered one
    per_seed = run["episodes"] * cls.checked_config(from_dict(cls.Config, job.config["env"])).max_steps
    if run.get("env_steps"):
        per_seed = min(per_seed, run["env_steps"])
    return len(job.seeds) * per_seed


def minutes_left(minutes: float, done: List[Job], left: List[Job],
                 cost: Callable[[Job], float] = planned_seed_steps, running: int = 0) -> float:
    """The time the jobs ``left`` need at the rate the ``done`` ones took ``minutes``, by their
    ``cost`` (default: planned seed-steps; reproduce passes each job's estimated seconds, since a
    scripted job's step costs a hundredth of a learner's). The first ``running`` of ``left`` are
    under way: half of each counts as done (the minutes went to them too). For a backend that
    does not say when each job starts (Ray); the local one uses ``seconds_left``."""
    under_way = sum(map(cost, left[:running])) / 2
    spent = sum(map(cost, done)) + under_way
    return minutes * (sum(map(cost, left)) - under_way) / spent if spent > 0 else 0.0


OVERRUN = 0.25   # a running job has at least this share of what it has run to go (from 80 % of its estimate on)


def rate(done: List[tuple], cost: Callable[[Job], float] = planned_seed_steps, prior: float = 0.0) -> Optional[float]:
    """Seconds per unit of ``cost`` the ``done`` jobs took ([(job, seconds from its start to its
    end)]), with ``prior`` units of cost counted as taken at one second each (for a cost in
    estimated seconds: the estimate trusted as much as that many seconds of jobs run); None before
    any has ended with a positive cost."""
    spent = sum(cost(job) for job, _ in done)
    return (sum(seconds for _, seconds in done) + prior) / (spent + prior) if spent > 0 else None


def running_left(expected: float, ran: float) -> float:
    """A running job's seconds left: what it is expected to take less what it has run, and at least
    ``OVERRUN`` of what it has run. With no floor a job past its estimate would count 0 left, and the
    guide would say the sweep is ending while its last long job runs on."""
    return max(expected - ran, OVERRUN * ran)


def seconds_left(done: List[tuple], running: List[tuple], pending: List[Job], workers: int,
                 cost: Callable[[Job], float] = planned_seed_steps, prior: float = 0.0) -> Optional[float]:
    """Seconds until the last job ends: every job takes its ``cost`` times the seconds per unit of
    cost the ``done`` jobs took (``rate``, with ``prior``); a ``running`` one ([(job, seconds it has run)]) what it
    has left (``running_left``); the ``pending`` ones, in the order they start, each to the worker
    free first. A sum of costs over a rate would miss the tail: one long job left on one of two
    workers takes all its time, not half. None until a job has finished with a positive cost."""
    import heapq
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    per = rate(done, cost, prior)
    if per is None:
        return None
    free = [running_left(cost(job) * per, ran) for job, ran in running] + [0.0] * max(workers - len(running), 0)
    heapq.heapify(free)
    for job in pending:
        heapq.heappush(free, heapq.heappop(free) + cost(job) * per)
    return max(free, default=0.0)


def clock(minutes: float) -> str:
    """"0.4 min", "12 min", "2.5 h": a duration as the progress lines print it."""
    return f"{minutes / 60:.1f} h" if minutes >= 120 else f"{minutes:.0f} min" if minutes >= 10 else f"{minutes:.1f} min"


def makespan(seconds: List[float], workers: int) -> float:
    """The wall time of jobs taking ``seconds`` each on ``workers`` workers, each job given whole
    to the worker free first, longest first (LPT: within 4/3 of the best schedule). How long a
    sweep would take on a Ray cluster of that many cores, ignoring start-up and transfers."""
    import heapq
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    free = [0.0] * workers
    for s in sorted(seconds, reverse=True):
        heapq.heappush(free, heapq.heappop(free) + s)
    return max(free)


def _span(seeds: List[int]) -> str:
    return f"{seeds[0]}-{seeds[-1]}" if seeds == list(range(seeds[0], seeds[-1] + 1)) and len(seeds) > 1 \
        else ",".join(map(str, seeds))


# ------------------------------------------------------------------ the sweep file
def read_sweep_file(path) -> Dict[str, dict]:
    """{experiment name: resolved config} from a TOML file; every experiment is checked
    before anything runs, and a bad one is refused with one line naming it.

        [defaults]               # optional, under every experiment
        episodes = 50
        [[experiment]]
        name = "square-shaped"   # a folder name
        env = "square"           # env, agent, preset, seeds, episodes, checkpoint_every
        agent = "dgpq"
        seeds = "0-63"
        [experiment.set]         # any other setting, by name or dotted path
        noise_var = 0.2
    """
    try:
        data = tomllib.loads(Path(path).read_text())
    except OSError as err:
        raise SweepError(f"cannot read {path}: {err.strerror}") from None
    except tomllib.TOMLDecodeError as err:
        raise SweepError(f"{path}: not valid TOML: {err}") from None
    unknown = set(data) - {"defaults", "experiment"}
    if unknown:
        raise SweepError(f"{path}: unknown tables {sorted(unknown)} (use [defaults] and [[experiment]])")
    experiments = data.get("experiment", [])
    if not isinstance(experiments, list) or not experiments:
        raise SweepError(f"{path}: no [[experiment]] entries")
    defaults = data.get("defaults", {})
    out = {}
    for i, entry in enumerate(experiments):
        entry = {**defaults, **entry, "set": {**defaults.get("set", {}), **entry.get("set", {})}}
        name = entry.get("name")
        where = f"{path}: experiment {i + 1}" + (f" ({name!r})" if name else "")
        bad = set(entry) - EXPERIMENT_KEYS
        if bad:
            raise SweepError(f"{where}: unknown keys {sorted(bad)}; settings go under [experiment.set]")
        if not isinstance(name, str) or not name or Path(name).name != name or name.startswith("."):
            raise SweepError(f"{where}: needs a name that can be a folder name, got {name!r}")
        if name in out:
            raise SweepError(f"{where}: the name {name!r} is used twice")
        settings = {k: v for k, v in entry.items() if k not in ("name", "set")}
        try:
            out[name] = resolve_config({**settings, **entry["set"]})
        except (ValueError, KeyError) as err:
            raise SweepError(f"{where}: {err}") from None
    return out


def plan(experiments: Dict[str, dict], out, seeds_per_job: Optional[int],
         groups: Optional[Dict[str, int]] = None) -> List[Job]:
    """Each experiment's seeds in slices of ``seeds_per_job`` (None: one job each), or, for an
    experiment named in ``groups``, in that many jobs of consecutive seeds, as equal as they go
    (10 seeds in 3: 4, 3, 3). A seed's rows do not depend on its batch, so a split changes when
    and where seeds run, not what they give."""
    if seeds_per_job is not None and seeds_per_job < 1:
        raise SweepError(f"seeds_per_job must be >= 1, got {seeds_per_job}")
    jobs = []
    for name, config in experiments.items():
        seeds = list(config["run"]["seeds"])
        if groups and name in groups:
            k = groups[name]
            if not 1 <= k <= len(seeds):
                raise SweepError(f"{name}: {k} jobs for {count(len(seeds), 'seed')}")
            sizes = [len(seeds) // k + (i < len(seeds) % k) for i in range(k)]
            parts = [seeds[sum(sizes[:i]):sum(sizes[:i + 1])] for i in range(k)]
        else:
            k = seeds_per_job or len(seeds)
            parts = [seeds[start:start + k] for start in range(0, len(seeds), k)]
        for j, part in enumerate(parts):
            jobs.append(Job(name, j, part, str(Path(out) / name / "jobs" / f"j{j:03d}"), _with_seeds(config, part)))
    return jobs


def _with_seeds(config: dict, seeds: List[int]) -> dict:
    """The experiment's config for one job's seeds, at one thread (see the module doc)."""
    return {**config, "run": {**config["run"], "seeds": seeds, "threads": 1}}


# ------------------------------------------------------------------ one job
def run_job(config: dict, folder: str) -> None:
    """Run (or continue) one job in this process, torch at one thread (see the module doc)."""
    import torch
    torch.set_num_threads(1)
    quiet_torchrl()
    path = runner.RunFolder(folder)
    path.acquire()  # one writer per job folder, even if a job is started twice
    if path.file(runner.CONFIG).is_file():
        if path.finished():
            return
        runner.resume(path, runner.resumable_config(path), progress=False)
    else:
        path.path.mkdir(parents=True, exist_ok=True)
        runner.start(config, path, progress=False)


def _job_process(config: dict, folder: str) -> None:
    """Entry point of a local worker process: one line on stderr instead of a traceback."""
    try:
        run_job(config, folder)
    except runner.Interrupted as err:
        sys.exit(err.exit_code)
    except BaseException as err:  # noqa: BLE001 -- reported through the job's status.json too
        print(f"job in {folder} failed: {type(err).__name__}: {err}", file=sys.stderr)
        sys.exit(1)


def outcome(job: Job, exitcode: Optional[int] = None, error: Optional[str] = None) -> dict:
    """What became of a job, from its folder's status.json and how its process ended."""
    status = runner.RunFolder(job.folder).status() or {}
    state = status.get("status")
    if state == "finished":
        return dict(status="finished")
    if state == "failed":
        return dict(status="failed", reason=status.get("reason"))
    if exitcode is not None and exitcode < 0:
        return dict(status="killed", reason=f"killed by {signal.Signals(-exitcode).name}")
    if state == "interrupted":
        return dict(status="interrupted", reason=status.get("reason"))
    return dict(status="failed", reason=error or f"exit code {exitcode}, status {state!r}")


# ------------------------------------------------------------------ backends
def job_modules(configs) -> List[str]:
    """This module and the modules a job of each of ``configs`` imports to run: its env's and its
    agent's (a config without them, as a test's, adds none; one naming an env or agent this checkout
    cannot load adds none either: its job fails on its own, saying why, not the sweep)."""
    from trl_dgpq.agents import agent_class
    from trl_dgpq.envs import env_class
    found = {__name__}
    for config in configs:
        run = config.get("run", {})
        try:
            found |= {env_class(run["env"]).__module__, agent_class(run["agent"], run["env"]).__module__}
        except (KeyError, ValueError, ImportError):
            pass
    return sorted(found)


def start_forkserver(modules: List[str]) -> None:
    """Start the local workers' forkserver now, if it is not running, importing ``modules`` once:
    every worker it forks starts with them imported (a job then starts in ~0.1 s instead of
    importing its env and agent, 0.1-0.4 s each). Started before a long plan (reproduce's), its
    imports (~5 s) overlap the plan's on another core."""
    from multiprocessing import forkserver
    mp.get_context("forkserver").set_forkserver_preload(modules)
    forkserver.ensure_running()


def run_local(jobs: List[Job], workers: int, on_done: Callable[[Job, dict], None],
              on_start: Callable[[Job], None] = lambda job: None) -> None:
    """Each job in its own process, ``workers`` at a time. A process per job, not a
    ProcessPoolExecutor: a killed worker breaks the whole executor, here it loses one job.
    Processes come from a forkserver that has imported the package and the jobs' envs and agents
    once (fast starts, and no fork of a process whose torch threads are running); one started
    before (``start_forkserver``) is used as it is."""
    ctx = mp.get_context("forkserver")
    ctx.set_forkserver_preload(job_modules(job.config for job in jobs))
    pending, running = list(jobs), {}
    try:
        while pending or running:
            while pending and len(running) < workers:
                job = pending.pop(0)
                # a worker started but not yet in `running` would be left running by a SIGTERM
                with _sigterm_held():
                    proc = ctx.Process(target=_job_process, args=(job.config, job.folder), name=job.name)
                    proc.start()
                    running[proc.sentinel] = (proc, job)
                    on_start(job)
            for sentinel in wait(list(running)):
                with _sigterm_held():
                    proc, job = running.pop(sentinel)
                    proc.join()
                    on_done(job, outcome(job, proc.exitcode))
    except KeyboardInterrupt as stop:
        # Ctrl-C reaches the workers too (one process group), a SIGTERM only this process: pass
        # it on (they are the forkserver's children, nothing else would stop them); then let them
        # checkpoint and stop
        if isinstance(stop, Terminated):
            for proc, _ in running.values():
                proc.terminate()
        for proc, job in running.values():
            proc.join()
            on_done(job, outcome(job, proc.exitcode))
        raise


RAY_RETRIES = 3  # a task whose worker dies (a node lost, the OOM killer) runs again, from its checkpoint


def writable_here(folder: str) -> Optional[str]:
    """None if this machine can write ``folder`` (creating it), else why not: run by Ray on
    every node before a sweep, so an --out a node cannot reach is refused up front."""
    import socket
    try:
        path = Path(folder)
        path.mkdir(parents=True, exist_ok=True)
        probe = path / f".probe-{socket.gethostname()}-{os.getpid()}"
        probe.write_text("")
        probe.unlink()
        return None
    except OSError as err:
        return f"node {socket.gethostname()} cannot write {folder}: {err.strerror or err}"


def check_nodes(ray, out: str) -> None:
    """SweepError (one line) if any alive Ray node cannot write ``out``."""
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy
    probe = ray.remote(num_cpus=0)(writable_here)
    refs = [probe.options(scheduling_strategy=NodeAffinitySchedulingStrategy(node["NodeID"], soft=False)).remote(out)
            for node in ray.nodes() if node.get("Alive")]
    problems = [p for p in ray.get(refs) if p]
    if problems:
        raise SweepError(f"--out must be on storage every node reaches: {problems[0]}"
                         + (f" (and {len(problems) - 1} more nodes)" if len(problems) > 1 else ""))


def run_ray(jobs: List[Job], address: Optional[str], cpus_per_job: float,
            on_done: Callable[[Job, dict], None]) -> None:
    """One Ray task per job (``num_cpus`` each). A task whose worker dies is retried up to
    RAY_RETRIES times, each retry resuming the job from its own last checkpoint; a job
    that fails in its own code is reported, and ``resume`` reruns it. Outputs go to the
    job folders, which must be on a path every node can reach (checked on every node
    first)."""
    try:
        import ray
    except ImportError:
        raise SweepError('--backend ray needs Ray: pip install -e ".[ray]"') from None
    address = address or os.environ.get("RAY_ADDRESS")
    if not ray.is_initialized():
        if address:
            ray.init(address=address, log_to_driver=False)
        else:   # a local instance, with this process's working directory and package
            ray.init(num_cpus=os.cpu_count(), include_dashboard=False, log_to_driver=False)
    check_nodes(ray, str(Path(jobs[0].folder).parents[2]))  # OUT (a job folder is OUT/experiment/jobs/jNNN)
    task = ray.remote(num_cpus=cpus_per_job, max_retries=RAY_RETRIES, retry_exceptions=False)(run_job)
    refs = {task.remote(job.config, job.folder): job for job in jobs}
    while refs:
        done, _ = ray.wait(list(refs), num_returns=1)
        for ref in done:
            job, error = refs.pop(ref), None
            try:
                ray.get(ref)
            except Exception as err:  # noqa: BLE001 -- RayTaskError, WorkerCrashedError, ...
                error = f"{type(err).__name__}: {str(err).strip().splitlines()[-1]}"
            result = outcome(job, error=error)
            if error and result["status"] == "failed" and "WorkerCrashed" in error:
                result = dict(status="killed", reason=error)
            on_done(job, result)


# ------------------------------------------------------------------ the sweep
def merge(out, name: str, jobs: List[Job]) -> Optional[pd.DataFrame]:
    """The experiment's episodes.csv from its finished jobs (None unless all finished)."""
    folders = [runner.RunFolder(job.folder) for job in jobs]
    if not all(f.finished() for f in folders):
        return None
    frames = [f.episodes().assign(job=job.index) for f, job in zip(folders, jobs)]
    return runner.RunFolder(Path(out) / name).write_episodes(pd.concat(frames, ignore_index=True))


def create(out, experiments: Dict[str, dict], jobs: List[Job], overwrite: bool = False) -> None:
    """Lay out a new sweep folder (refused if ``out`` holds anything, unless it holds a sweep
    and ``overwrite``)."""
    out = Path(out)
    if out.exists() and not out.is_dir():  # else iterdir's raw "[Errno 20] Not a directory"
        raise SweepError(f"--out {out} is a file, not a folder: choose another --out")
    if out.exists() and any(out.iterdir()):
        if not (out / SWEEP).is_file():
            raise SweepError(f"--out {out} is not empty and holds no sweep: choose another folder")
        if not overwrite:
            raise SweepError(f"--out {out} holds a sweep: continue it with --resume {out}, replace it with "
                             f"--overwrite, or choose another folder")
        old = json.loads((out / SWEEP).read_text()).get("experiments", {})
        for name in old:
            shutil.rmtree(out / name, ignore_errors=True)
        for f in (SWEEP, REPORT):
            (out / f).unlink(missing_ok=True)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:  # a file on its path: "[Errno 20] Not a directory" alone names neither
        raise SweepError(f"cannot create --out {out}: {err.strerror or err}: choose another --out") from None
    _write_experiments(out, experiments)
    _write_plan(out, experiments, jobs)


def grow(out, experiments: Dict[str, dict], seeds_per_job: Optional[int],
         same: Callable[[dict, dict], bool] = lambda a, b: a == b,
         groups: Optional[Dict[str, int]] = None) -> List[Job]:
    """The jobs of the sweep in ``out`` with the experiments of ``experiments`` that it lacks
    added (a plan that grew: hours of finished jobs are kept, the new ones join them). A
    recorded experiment planned again must be the ``same``; one planned otherwise, or not
    planned at all, is refused by name: removing its folder lets it be planned anew."""
    recorded, jobs = load(out)
    recorded = {k: v for k, v in recorded.items() if (Path(out) / k).is_dir()}
    changed = sorted(k for k in recorded if k in experiments and not same(recorded[k], experiments[k]))
    dropped = sorted(set(recorded) - set(experiments))
    if changed or dropped:
        raise SweepError(f"{out} holds another plan: " + "; ".join(
            f"{what}: {', '.join(names)}" for what, names in (("planned otherwise now", changed),
                                                               ("no longer planned", dropped)) if names)
            + f" (remove those folders of {out} to plan them anew, or choose another --out)")
    added = {k: v for k, v in experiments.items() if k not in recorded}
    kept = [j for j in jobs if j.experiment in recorded]
    new = plan(added, out, seeds_per_job, groups)
    for name in added:
        shutil.rmtree(Path(out) / name, ignore_errors=True)   # a removed experiment's leftovers
    _write_experiments(Path(out), added)
    _write_plan(out, {**recorded, **added}, kept + new)
    return kept + new


REUSED = "reused.json"


def reuse(out, jobs: List[Job], sources, same: Callable[[dict, dict], bool] = lambda a, b: a == b,
          log=print) -> List[Job]:
    """The jobs of the sweep in ``out``, where an experiment none of whose jobs has begun is
    the ``same`` as one that finished in a sweep of ``sources``: that one's job folders are
    copied in (its split into jobs with them) and its source is recorded in the
    experiment's reused.json. A seed's rows do not depend on its batch or the machine's load,
    so they are the rows a run here would write; their wall times and commits stay the
    source's. Nothing is taken from an experiment with a job unfinished."""
    out = Path(out)
    experiments, _ = load(out)
    todo = {name for name in experiments
            if not any(runner.RunFolder(j.folder).file(runner.CONFIG).is_file() for j in jobs if j.experiment == name)}
    taken = {}
    for src in map(Path, sources):
        if src.resolve() == out.resolve():
            continue
        src_experiments, src_jobs = load(src)
        for name in sorted(todo - set(taken)):
            for src_name, config in src_experiments.items():
                done = [j for j in src_jobs if j.experiment == src_name]
                if same(config, experiments[name]) and done and all(runner.RunFolder(j.folder).finished()
                                                                    for j in done):
                    taken[name] = (src / src_name, done)
                    break
    for name, (where, done) in taken.items():
        shutil.rmtree(out / name / "jobs", ignore_errors=True)
        for j in done:
            shutil.copytree(j.folder, out / name / "jobs" / Path(j.folder).name,
                            ignore=shutil.ignore_patterns(runner.LOCK))
        runner.RunFolder(out / name).write_json(REUSED, {"from": str(where), "jobs": len(done)})
        log(f"{name}: reused the finished {where} ({count(len(done), 'job')})")
    if not taken:
        return jobs
    new = []
    for name in experiments:
        if name in taken:
            done = taken[name][1]
            new += [Job(name, j.index, j.seeds, str(out / name / "jobs" / Path(j.folder).name),
                        _with_seeds(experiments[name], j.seeds)) for j in done]
        else:
            new += [j for j in jobs if j.experiment == name]
    _write_plan(out, experiments, new)
    return new


def _write_experiments(out: Path, experiments: Dict[str, dict]) -> None:
    """Each experiment's folder with its resolved config (all its seeds)."""
    for name, config in experiments.items():
        (out / name).mkdir()
        runner.RunFolder(out / name).write_json(runner.CONFIG, runner.recorded(config))


def _write_plan(out, experiments: Dict[str, dict], jobs: List[Job]) -> None:
    runner.RunFolder(out).write_json(SWEEP, dict(experiments=experiments, jobs=[
        dict(experiment=j.experiment, index=j.index, seeds=j.seeds, folder=str(Path(j.folder).relative_to(out)))
        for j in jobs]))


def load(out) -> tuple:
    """(experiments, jobs) of the sweep in ``out``."""
    out = Path(out)
    try:
        data = json.loads((out / SWEEP).read_text())
    except (FileNotFoundError, NotADirectoryError):  # (a file given for the folder)
        raise SweepError(f"{out} holds no sweep to resume (no {SWEEP})") from None
    experiments = data["experiments"]
    jobs = [Job(j["experiment"], j["index"], j["seeds"], str(out / j["folder"]),
                _with_seeds(experiments[j["experiment"]], j["seeds"])) for j in data["jobs"]]
    return experiments, jobs


def execute(out, jobs: List[Job], backend: str = "local", workers: Optional[int] = None,
            ray_address: Optional[str] = None, cpus_per_job: float = 1, log=print,
            cost: Callable[[Job], float] = planned_seed_steps, prior: float = 0.0) -> dict:
    """Run the jobs that have not finished; merge each experiment as soon as its jobs all
    have (so that a sweep of many hours can be read before it ends: ``reproduce --report``).
    ``cost`` weighs the jobs for the time-left guide (``seconds_left``, with ``prior``; ``minutes_left`` on
    Ray). Returns the report {job name: outcome} (also in OUT/report.json)."""
    if backend not in BACKENDS:
        raise SweepError(f"backend must be one of {BACKENDS}, got {backend!r}")
    out = Path(out)
    todo = [j for j in jobs if not runner.RunFolder(j.folder).finished()]
    report = {j.name: dict(status="finished", seeds=j.seeds, note="finished before") for j in jobs if j not in todo}
    t0, done, finished, merged = time.perf_counter(), [0], [], set()
    started, took = {}, []   # job name -> when it started; [(job, its seconds)] of those that finished
    pool = workers or os.cpu_count() or 1   # local workers
    names = {j.name for j in todo}

    def merge_if_done(name: str) -> None:
        if name not in merged and merge(out, name, [j for j in jobs if j.experiment == name]) is not None:
            merged.add(name)
            log(f"{name}: all jobs finished -> {out / name / runner.EPISODES}")

    def on_start(job: Job) -> None:
        started[job.name] = time.perf_counter()

    def on_done(job: Job, result: dict) -> None:
        now = time.perf_counter()
        done[0] += 1
        finished.append(job)
        if result["status"] == "finished" and job.name in started:   # an interrupted job says nothing of a rate
            took.append((job, now - started[job.name]))
        report[job.name] = dict(**result, seeds=job.seeds, experiment=job.experiment, job=job.index,
                                elapsed_s=round(now - t0, 2))
        failed = sum(r["status"] != "finished" for name, r in report.items() if name in names)
        left = len(todo) - done[0]
        rest = [j for j in todo if j not in finished]   # the pool starts them in this order: its first run
        minutes = (now - t0) / 60
        if backend == "local":
            running = [(j, now - started[j.name]) for j in rest if j.name in started]
            pending = [j for j in rest if j.name not in started]
            busy = min(pool, left)   # the pool refills at once
            seconds = seconds_left(took, running, pending, pool, cost, prior)
            guess = None if seconds is None else seconds / 60
            per = rate(took, cost, prior)
            over = 0 if per is None else sum(cost(j) * per < ran for j, ran in running)
        else:   # Ray schedules what it was given and does not say when each job starts
            busy, guess, over = 0, minutes_left(minutes, finished, rest, cost), 0
        running_text = f" ({busy} running)" if busy else ""
        eta = f", ~{clock(guess)} left at this rate" if left and guess is not None else ""
        eta += f" ({over} past {'its' if over == 1 else 'their'} estimate)" if eta and over else ""
        line = (f"[{done[0]}/{len(todo)} jobs done, {failed} not finished, {left} to go{running_text}; "
                f"{minutes:.1f} min{eta}] {job.name}: {result['status']}")
        log(line + (f" -- {result['reason']}" if result.get("reason") else ""))
        merge_if_done(job.experiment)
        runner.RunFolder(out).write_json(REPORT, report)

    for name in dict.fromkeys(j.experiment for j in jobs if j not in todo):   # finished before, or reused
        merge_if_done(name)
    if todo:
        if backend == "local":
            run_local(todo, pool, on_done, on_start)
        else:
            run_ray(todo, ray_address, cpus_per_job, on_done)
    runner.RunFolder(out).write_json(REPORT, report)
    return report


def run_script(script: str, rerun: str, body: Callable[[], int]) -> int:
    """``body()``'s exit code; a bad request or a file that cannot be read or written -> one
    line and 2; Ctrl-C or SIGTERM -> the workers stopped, how to go on, and 130 / 143."""
    try:
        with _sigterm_raises():
            return body()
    except (ValueError, OSError) as err:  # SweepError, RunError, a run's CSV damaged, a folder not writable
        print(f"{script}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as stop:
        signum = signal.SIGTERM if isinstance(stop, Terminated) else signal.SIGINT
        print(f"interrupted by {signum.name}: continue with {rerun}", file=sys.stderr)
        return 128 + signum


_SIGTERM = {"held": False, "pending": False}  # the state of the handler below (signals are per process)


def _on_sigterm(signum, frame):
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # a second SIGTERM ends the process at once
    if _SIGTERM["held"]:
        _SIGTERM["pending"] = True
    else:
        raise Terminated()


@contextmanager
def _sigterm_raises():
    """SIGTERM raises Terminated in the main thread for the block (except where held)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
        _SIGTERM["pending"] = False


@contextmanager
def _sigterm_held():
    """Terminated raised as the block ends, not inside it. (Masking the signal would not do:
    another thread (torch's) takes it, and Python runs the handler in the main thread anyway.)"""
    _SIGTERM["held"] = True
    try:
        yield
    finally:
        _SIGTERM["held"] = False
    if _SIGTERM["pending"]:
        _SIGTERM["pending"] = False
        raise Terminated()


def exit_code(report: dict, rerun: str) -> int:
    """For the scripts: 0 when every job finished; else list the others on stderr, say how
    to rerun them, and return 1."""
    bad = {name: r for name, r in report.items() if r["status"] != "finished"}
    for name, r in bad.items():
        print(f"{name}: {r['status']}: {r.get('reason')}", file=sys.stderr)
    if bad:
        print(f"{len(bad)} of {len(report)} jobs did not finish; the others kept their rows. Rerun them with: "
              f"{rerun}", file=sys.stderr)
    return 1 if bad else 0


def describe_jobs(jobs: List[Job]) -> str:
    names = dict.fromkeys(j.experiment for j in jobs)
    return "; ".join(f"{n}: {describe(next(j.config for j in jobs if j.experiment == n))}, "
                     f"{count(sum(len(j.seeds) for j in jobs if j.experiment == n), 'seed')} in "
                     f"{count(sum(j.experiment == n for j in jobs), 'job')}" for n in names)


