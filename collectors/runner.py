"""A run in a folder: nothing finished is lost, and an interrupted run continues exactly.

    OUT/config.json     the resolved config + versions, git commit and model knowledge (written once)
    OUT/status.json     running | finished | interrupted | failed, with the reason
    OUT/episodes.csv    one row per episode, appended (and flushed) as episodes end;
                        rewritten sorted by (seed, episode) when the run finishes
    OUT/checkpoint.pt   env, agent and collector state + how much of episodes.csv
                        it covers; every ``checkpoint_every`` episodes per seed, on
                        SIGINT/SIGTERM and at the end (while it runs, the one before it
                        is kept as checkpoint.prev.pt; a finished run drops it)
    OUT/checkpoint.extend.pt   the state at the first step in which seeds stopped (if not
                        all at once): where ``lengthen`` (more episodes, a larger budget)
                        goes on from

Every file is replaced atomically (written to a temporary file, then renamed), so
a kill at any moment leaves the previous version whole. ``resume`` cuts
``episodes.csv`` back to the rows the last checkpoint covers and continues from it; the
rows it then writes are those the interrupted run had written (same seeds, same
streams), so the finished file equals an uninterrupted run's, timing aside. A run
lengthened (``lengthen``, then ``resume``) ends as a run asked for that length from
the start would have: the seeds that ran on past checkpoint.extend.pt run again.
"""
from __future__ import annotations

import csv
import io
import json
import os
import pickle
import signal
import subprocess
import sys
import threading
import time
import zipfile
from contextlib import contextmanager
from pathlib import Path
from typing import Optional

import pandas as pd
import torch

from trl_dgpq.analysis.runs import read_csv_exact

from .experiment import (MemoryLimit, build, check_memory, classes, describe, load_sections, memory_estimate,
                         memory_guard, use_threads)
from .online import OnlineCollector

CONFIG, EPISODES, STATUS, CHECKPOINT = "config.json", "episodes.csv", "status.json", "checkpoint.pt"
LOCK = "run.lock"  # held (an OS lock) by the one process writing the run; holds its pid
PREVIOUS = "checkpoint.prev.pt"  # the checkpoint before the latest: where a damaged latest falls back to
EXTEND = "checkpoint.extend.pt"  # the first step at which seeds stopped: where a lengthened run goes on from
RUN_FILES = (CONFIG, EPISODES, STATUS, CHECKPOINT, PREVIOUS, EXTEND)
FALLBACKS = (PREVIOUS, EXTEND)   # read in this order when the latest checkpoint cannot be
LENGTHS = ("episodes", "env_steps")  # the settings a run can be lengthened in
# 2: GP state in the kernel-batch layout (gp/kernels.py) with its likelihood module; format 1
# checkpoints are refused rather than loaded into renamed or reshaped fields
CHECKPOINT_FORMAT = 2


class DamagedCheckpoint(ValueError):
    """A checkpoint file that cannot be read (cut short, corrupted, or holding more than plain data)."""


class RunError(ValueError):
    """A user-caused problem with the run folder (one line, exit 2)."""


class RowsMissing(RunError):
    """episodes.csv lacks rows (or repeats some) that a checkpoint covers: a file cut or edited."""


class Interrupted(Exception):
    def __init__(self, signum: int, folder: "RunFolder", episodes_done: int):
        self.signum, self.folder, self.episodes_done = signum, folder, episodes_done
        super().__init__(f"interrupted by {signal.Signals(signum).name}")

    @property
    def exit_code(self) -> int:
        return 128 + self.signum


def disk_note(config: dict) -> str:
    """What a run's checkpoints will take on disk, from its agents' state at the start: replay
    buffers are saved at their capacity; a sparse GP saves the slots it uses, up to its
    budget. An agent whose state has no bound (``grows``: DGPQ's Q̂ keeps every pair it is
    given) is said to take more as it learns."""
    one = memory_estimate(config) / 1e6
    if getattr(classes(config["run"])[1], "grows", False):
        size = f"from ~{one:.3g} MB each, growing as the agent learns (its state has no bound)"
    else:
        size = f"up to ~{one:.3g} MB each (its agents' state when full)"
    return f"checkpoints {size}: 3 while it runs, 2 once finished"


def atomic_write(path: Path, write, before_replace=None) -> None:
    """``write(file)`` into a temporary file beside ``path``, then rename it over ``path``
    (``before_replace()`` runs between the two, once the new file is whole). An OSError
    (a full disk, a file-size limit) names ``path``; ``path`` is then as it was."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        if before_replace is not None:
            before_replace()
        os.replace(tmp, path)
    except OSError as err:
        raise type(err)(err.errno, err.strerror or str(err), str(path)) from None
    finally:
        if tmp.exists():
            tmp.unlink()


def write_csv(df: pd.DataFrame, path: Path) -> None:
    """``df`` as a CSV file at ``path`` without its index, written whole or not at all (``atomic_write``)."""
    buf = io.StringIO()
    df.to_csv(buf, index=False)
    atomic_write(path, lambda f: f.write(buf.getvalue().encode()))


CODE = ("trl_dgpq", "envs", "collectors", "scripts", "setup.py", "pyproject.toml")   # what a run's code is


def provenance() -> dict:
    """Versions and the git commit of this code, for config.json."""
    import numpy
    import tensordict
    import torchrl
    versions = dict(python=sys.version.split()[0], torch=torch.__version__, torchrl=torchrl.__version__,
                    tensordict=tensordict.__version__, numpy=numpy.__version__, pandas=pd.__version__)
    root = Path(__file__).resolve().parent.parent
    git = dict(commit=None, dirty=None)
    try:
        out = lambda *a: subprocess.run(["git", *a], cwd=root, capture_output=True, text=True,  # noqa: E731
                                        timeout=10, check=True).stdout.strip()
        git["commit"] = out("rev-parse", "HEAD")
        # the code differs from the commit: a change to, or a new file among, what runs (docs and
        # results may change without making a run's provenance less true)
        git["dirty"] = bool(out("status", "--porcelain", "--", *CODE))
    except (OSError, subprocess.SubprocessError):
        pass  # not a git checkout (an installed wheel): versions still say what ran
    return dict(versions=versions, git=git)


class RunFolder:
    """The files of one run (see the module docstring)."""

    def __init__(self, path):
        self.path = Path(path)
        self._lock = None  # the file descriptor holding LOCK, while this process writes the run

    # ------------------------------------------------------------ one writer
    def acquire(self) -> None:
        """Hold the folder for this process: an exclusive OS lock on run.lock, released by
        ``release`` or when the process ends however it ends (so a killed run never leaves
        it held). RunError naming the holder if another process holds it."""
        if self._lock is not None:
            return
        try:
            import fcntl
        except ImportError:  # no flock here (Windows): status.json's pid check remains
            return
        self.path.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.file(LOCK), os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = os.read(fd, 32).decode(errors="replace").strip() or "another process"
            os.close(fd)
            raise RunError(f"{self.path} is being written by process {holder}: wait for it to end, or stop it "
                           "first") from None
        os.ftruncate(fd, 0)
        os.write(fd, str(os.getpid()).encode())
        self._lock = fd

    def release(self) -> None:
        if self._lock is not None:
            os.close(self._lock)  # closing the descriptor drops the lock
            self._lock = None

    def __del__(self):
        self.release()

    def file(self, name: str) -> Path:
        return self.path / name

    def holds_run(self) -> bool:
        return any(self.file(n).exists() for n in RUN_FILES)

    # ------------------------------------------------------------ creation
    @classmethod
    def create(cls, out: Optional[str], name: str, overwrite: bool = False, root: str = "runs") -> "RunFolder":
        """A new run folder: ``out`` (refused if it holds a run, unless ``overwrite``), or
        a unique ``root/name-<timestamp>[-k]`` (exclusive mkdir: two runs started in
        the same second get different folders)."""
        try:
            if out is None:
                base = Path(root) / f"{name}-{time.strftime('%Y%m%d-%H%M%S')}"
                base.parent.mkdir(parents=True, exist_ok=True)
                for k in range(1000):
                    path = base if k == 0 else base.with_name(f"{base.name}-{k}")
                    try:
                        path.mkdir()
                    except FileExistsError:
                        continue
                    folder = cls(path)
                    folder.acquire()
                    return folder
                raise RunError(f"could not create a unique run folder under {root}")
            folder = cls(out)
            if folder.path.exists() and not folder.path.is_dir():
                raise RunError(f"--out {out} exists and is not a folder")
            if folder.path.is_dir() and folder.file(LOCK).exists():
                folder.acquire()  # a run still being written is never overwritten or joined
            return cls._prepare(folder, out, overwrite)
        except PermissionError as err:
            raise RunError(f"cannot write the run folder: {err.strerror}: {err.filename}") from None
        except OSError as err:
            raise RunError(f"cannot create the run folder: {err.strerror or err}: {err.filename or out}") from None

    @classmethod
    def _prepare(cls, folder: "RunFolder", out: str, overwrite: bool) -> "RunFolder":
        """``out`` emptied of a run (``overwrite``) or checked empty, and held; the lock is let
        go again if it is refused."""
        try:
            if folder.holds_run():
                if not overwrite:
                    raise RunError(f"--out {out} holds a run: continue it with --resume {out}, "
                                   f"replace it with --overwrite, or choose another folder")
                for path in [folder.file(n) for n in RUN_FILES] + list(folder.path.glob("*.png")):
                    if path.exists():  # the run's files and the figures made from them
                        path.unlink()
            elif folder.path.exists() and any(p.name != LOCK for p in folder.path.iterdir()):
                raise RunError(f"--out {out} is not empty and holds no run: choose another folder")
            folder.path.mkdir(parents=True, exist_ok=True)
            folder.acquire()
            probe = folder.file(f".write-test-{os.getpid()}")
            probe.touch()
            probe.unlink()
            return folder
        except BaseException:
            folder.release()
            raise

    @classmethod
    def existing(cls, path) -> "RunFolder":
        folder = cls(path)
        if not folder.file(CONFIG).is_file():
            raise RunError(f"{path} holds no run to resume (no {CONFIG})")
        if not os.access(folder.path, os.W_OK):
            raise RunError(f"cannot write to {path}")
        folder.acquire()
        return folder

    # ------------------------------------------------------------ files
    def write_json(self, name: str, obj: dict) -> None:
        atomic_write(self.file(name), lambda f: f.write((json.dumps(obj, indent=2) + "\n").encode()))

    def read_json(self, name: str) -> Optional[dict]:
        try:
            return json.loads(self.file(name).read_text())
        except FileNotFoundError:
            return None
        except (OSError, ValueError) as err:
            raise RunError(f"cannot read {self.file(name)}: {err}") from None

    def set_status(self, status: str, reason: Optional[str] = None, **info) -> None:
        self.write_json(STATUS, dict(status=status, reason=reason, time=time.strftime("%Y-%m-%d %H:%M:%S"),
                                     pid=os.getpid(), **info))

    def status(self) -> Optional[dict]:
        return self.read_json(STATUS)

    def append_rows(self, rows) -> int:
        """Append rows to episodes.csv (header first if new), flushed; returns its size."""
        path = self.file(EPISODES)
        new = not path.exists() or path.stat().st_size == 0
        df = pd.DataFrame(rows)
        if not new:
            df = self._to_header(df)
        try:
            with open(path, "a", newline="") as f:
                df.to_csv(f, header=new, index=False)
                f.flush()
                return f.tell()
        except OSError as err:  # a part row may be on disk: past the checkpoint, cut on resume
            raise type(err)(err.errno, err.strerror or str(err), str(path)) from None

    def _to_header(self, df: pd.DataFrame) -> pd.DataFrame:
        """``df``'s columns in episodes.csv's order. A run resumed by newer code whose env or
        agent reports more per episode: the file gains those columns (empty in its earlier
        rows) rather than rows that no longer match its header; a column it no longer
        reports stays, empty in the new rows."""
        path = self.file(EPISODES)
        with open(path, newline="") as f:
            header = next(csv.reader(f))
        added = [c for c in df.columns if c not in header]
        if added:
            self.write_episodes(self.episodes().reindex(columns=header + added))
        return df.reindex(columns=header + added)

    def csv_size(self) -> int:
        path = self.file(EPISODES)
        return path.stat().st_size if path.exists() else 0

    def keep_rows(self, episodes: dict) -> None:
        """Cut episodes.csv to the rows a checkpoint covers, each seed's first ``episodes[seed]``
        (the rows past them come again). Chosen by (seed, episode), not by a byte offset: a
        finished run's file has been rewritten sorted since its older checkpoints (prev, extend)
        were taken. Rewritten atomically, and only if a row goes."""
        path, covered = self.file(EPISODES), sum(episodes.values())
        if not covered:
            path.unlink(missing_ok=True)
            return
        if not path.exists():
            raise RowsMissing(f"{path} is missing: its checkpoint covers {covered} episodes")
        self._drop_unfinished_row()
        df, kept, found = self._covered(episodes)
        if len(kept) != covered or found != covered:
            raise RowsMissing(f"{path} does not hold the {covered} episodes its checkpoint covers once each "
                              f"({covered - found} missing, {len(kept) - found} repeated)")
        if len(kept) < len(df):
            self.write_episodes(kept)

    def _drop_unfinished_row(self) -> None:
        """Cut off a last row that a crash or a full disk left half-written: it is past every
        checkpoint, and parsed it could pass for another row (``3,1`` of ``3,12,...``)."""
        with open(self.file(EPISODES), "rb+") as f:
            size = f.seek(0, os.SEEK_END)
            tail = f.seek(max(0, size - 2**16))  # far longer than a row
            last = f.read()
            if not last.endswith(b"\n"):
                f.truncate(tail + last.rfind(b"\n") + 1)

    def episodes(self) -> pd.DataFrame:
        return read_csv_exact(self.file(EPISODES))

    def write_episodes(self, df: pd.DataFrame) -> pd.DataFrame:
        """Write ``df`` as episodes.csv sorted by (seed, episode), atomically; returns it sorted."""
        df = df.sort_values(["seed", "episode"], kind="stable").reset_index(drop=True)
        write_csv(df, self.file(EPISODES))
        return df

    def finalize_csv(self) -> pd.DataFrame:
        """Rewrite episodes.csv sorted by (seed, episode), atomically."""
        return self.write_episodes(self.episodes())

    def finished(self) -> bool:
        return (self.status() or {}).get("status") == "finished"

    def save_checkpoint(self, state: dict) -> None:
        """Write the checkpoint atomically; the one it replaces becomes checkpoint.prev.pt (at
        every moment one of the two is whole)."""
        latest = self.file(CHECKPOINT)

        def rotate():  # only once the new one is whole: a failed write leaves both as they were
            if latest.exists():
                os.replace(latest, self.file(PREVIOUS))
        atomic_write(latest, lambda f: torch.save(state, f), before_replace=rotate)

    def drop_previous(self) -> None:
        """A finished run's final checkpoint is whole (written atomically): the one before it
        only took a third of the disk (evaluate and lengthening read the final one and
        checkpoint.extend.pt)."""
        self.file(PREVIOUS).unlink(missing_ok=True)

    def save_extension_point(self, state: dict) -> None:
        atomic_write(self.file(EXTEND), lambda f: torch.save(state, f))

    def load_extension_point(self) -> dict:
        try:
            return self._read_checkpoint(self.file(EXTEND))
        except DamagedCheckpoint as err:
            raise RunError(f"{self.path} cannot be lengthened exactly: {err} (it keeps where its seeds stopped; "
                           "runs finished by versions before it have none): start it again at the new length") \
                from None

    def load_checkpoint(self, log=None) -> Optional[dict]:
        """The latest checkpoint; if it cannot be read, the previous one, saying so through
        ``log`` (default: stderr) in one line; None if there is none. RunError if neither
        can be read."""
        latest = self.file(CHECKPOINT)
        # a finished run has dropped checkpoint.prev.pt; where seeds stopped is an earlier state too
        earlier = [p for p in map(self.file, FALLBACKS) if p.exists()]
        if not latest.exists() and not earlier:
            return None
        try:
            return self._read_checkpoint(latest)
        except DamagedCheckpoint as err:  # another format is not damage: no fallback
            errors = [str(err)]
            for path in earlier:
                try:
                    state = self._read_checkpoint(path)
                except DamagedCheckpoint as err2:
                    errors.append(str(err2))
                    continue
                (log or (lambda line: print(line, file=sys.stderr)))(
                    f"{'; '.join(errors)}; continuing from {path.name} ({state['episodes_done']} episodes done)")
                return state
            raise RunError("; and ".join(errors) + "; no checkpoint of this run can be read: start it again "
                           "(--overwrite)") from None

    def checkpointed(self, seeds) -> Optional[dict]:
        """{seed: episodes} that a resume keeps (those of the checkpoint ``load_checkpoint`` would
        read; the rows after them run again); None if no checkpoint can be read. Memory-mapped: a
        glance at a checkpoint of hundreds of MB costs milliseconds."""
        for name in (CHECKPOINT, *FALLBACKS):
            try:
                state = torch.load(self.file(name), mmap=True, weights_only=True)
                return dict(zip(seeds, state["collector"]["episode"].tolist()))
            except Exception:   # missing or damaged: the next, as load_checkpoint falls back (its format
                continue        # unchecked: a guide's count, not a resume)
        return None

    def earlier_checkpoint_held(self, latest: Optional[dict], seeds) -> Optional[tuple]:
        """(file name, state) of the checkpoint before ``latest`` if episodes.csv holds its
        episodes, each once (a run to resume from when the file lost rows the latest covers);
        None if it does not, or cannot be read."""
        if latest is None or not self.file(EPISODES).exists():
            return None
        try:
            state = self._read_checkpoint(self.file(PREVIOUS))
        except DamagedCheckpoint:   # (missing too)
            return None
        if state["episodes_done"] >= latest["episodes_done"]:
            return None
        episodes = dict(zip(seeds, state["collector"]["episode"].tolist()))
        _, kept, found = self._covered(episodes)
        return (PREVIOUS, state) if len(kept) == found == sum(episodes.values()) else None

    def _covered(self, episodes: dict) -> tuple:
        """(episodes.csv, its rows within each seed's first ``episodes[seed]``, how many of those
        are distinct (seed, episode)s): what a checkpoint covering ``episodes`` needs there once each."""
        df = self.episodes()
        kept = df[df.episode <= df.seed.map(episodes)]
        return df, kept, len(kept.drop_duplicates(["seed", "episode"]))

    def _read_checkpoint(self, path: Path) -> dict:
        if not path.exists():
            raise DamagedCheckpoint(f"{path} is missing")
        try:
            state = torch.load(path, weights_only=True)
        except Exception as err:  # a damaged file, or one holding more than plain data
            if isinstance(err, pickle.UnpicklingError) and zipfile.is_zipfile(path):  # not damage: refused, no
                raise RunError(f"cannot read {path}: {damage(path, err)}") from None   # fallback works around it
            raise DamagedCheckpoint(f"cannot read {path}: {damage(path, err)}") from None
        if not isinstance(state, dict):
            raise DamagedCheckpoint(f"cannot read {path}: it holds a {type(state).__name__}, not a checkpoint")
        if state.get("format") != CHECKPOINT_FORMAT:
            raise RunError(f"{path} has checkpoint format {state.get('format')}, this code reads {CHECKPOINT_FORMAT}: "
                           "it was written by an older version, which can resume it; or start the run again")
        return state


def damage(path: Path, err: Exception) -> str:
    """What is wrong with a checkpoint torch could not load, in our words: torch's own text is
    long (cut, it ends mid-sentence) and, for a file that is not plain data, advises loading
    with weights_only=False, which would run code from the file. torch writes zip archives."""
    if not zipfile.is_zipfile(path):
        with open(path, "rb") as f:
            begins_as_zip = f.read(4) == b"PK\x03\x04"  # a zip's start without its end (its directory)
        return ("the file is cut short (a write that did not finish, or a full disk) or damaged" if begins_as_zip
                else "the file is damaged: it is not a checkpoint (torch writes zip archives)")
    if isinstance(err, pickle.UnpicklingError):
        return ("it holds more than plain data (tensors, numbers, strings), so it is not a checkpoint this "
                "suite wrote; it is not loaded, as loading it could run code from the file")
    return f"the file is damaged ({type(err).__name__} while reading it)"


@contextmanager
def deferred_signals():
    """SIGINT/SIGTERM set a flag instead of raising, so the run stops between steps
    with its state whole. Yields a dict whose "signum" is set when one arrives."""
    caught = {"signum": None}
    if threading.current_thread() is not threading.main_thread():
        yield caught
        return
    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}

    def handler(signum, frame):
        caught["signum"] = signum
    for s in previous:
        signal.signal(s, handler)
    try:
        yield caught
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def recorded(config: dict) -> dict:
    """What config.json holds: the resolved config, the versions and commit that ran it, and what
    of the env's model it uses (``model_knowledge``: empty for a model-free run)."""
    from trl_dgpq.envs import model_knowledge
    return {**config, **provenance(), "model_knowledge": model_knowledge(config)}


def start(config: dict, folder: RunFolder, progress: bool = True) -> pd.DataFrame:
    """Run ``config`` into the (new) ``folder``."""
    check_memory(config)
    folder.write_json(CONFIG, recorded(config))
    return _execute(config, folder, None, progress)


def resumable_config(folder: RunFolder, lengthen: bool = False) -> dict:
    """The recorded config of the run in ``folder``, if it can be resumed, or with ``lengthen``
    run longer (RunError if not)."""
    status = folder.status() or {}
    if status.get("status") == "finished" and not lengthen:
        raise RunError(f"{folder.path} is finished; nothing to resume (to run it longer: --resume {folder.path} "
                       "--episodes N)")
    if status.get("status") == "running" and _alive(status.get("pid")):
        raise RunError(f"{folder.path} is being run by process {status['pid']}")
    recorded = folder.read_json(CONFIG)
    config = {k: recorded[k] for k in ("run", "env", "agent") if k in recorded}
    try:
        load_sections(config)
    except (ValueError, KeyError) as err:
        raise RunError(f"{folder.file(CONFIG)}: {err}") from None
    now = provenance()["versions"]
    changed = {k: (v, now.get(k)) for k, v in recorded.get("versions", {}).items() if now.get(k) != v}
    if changed:
        print(f"note: versions differ from the interrupted run: {changed}", file=sys.stderr)
    check_memory(config)
    return config


def lengthen(folder: RunFolder, config: dict, **lengths) -> dict:
    """Record in ``folder`` (config from ``resumable_config(lengthen=True)``) that its run
    is to be longer: more ``episodes`` and/or a larger ``env_steps`` budget (0: none).
    Returns the new config; ``resume`` then runs it on. RunError for anything shorter."""
    unknown = set(lengths) - set(LENGTHS)
    if unknown:
        raise RunError(f"a run can only be lengthened in {', '.join(LENGTHS)}, not {', '.join(sorted(unknown))}")
    old = load_sections(config)[0]
    given = dict(lengths)
    if "env_steps" in given and "episodes" not in given and old.episodes == old.env_steps:
        given["episodes"] = given["env_steps"]  # the cap a budget alone set (resolve_config) follows it
    try:
        new = load_sections({**config, "run": {**config["run"], **given}})[0]
    except (ValueError, KeyError) as err:
        raise RunError(str(err)) from None
    if new.episodes < old.episodes:
        raise RunError(f"--episodes {new.episodes} is fewer than the run's {old.episodes}: a run can only be "
                       "lengthened")
    if (new.env_steps and not old.env_steps) or 0 < new.env_steps < old.env_steps:
        raise RunError(f"--env-steps {new.env_steps} is a smaller budget than the run's "
                       f"{old.env_steps or 'none (0)'}: a run can only be lengthened")
    changed = {k: (getattr(old, k), getattr(new, k)) for k in LENGTHS if getattr(new, k) != getattr(old, k)}
    if not changed:
        return config
    what = ", ".join(f"{k} {a:,} -> {b:,}" for k, (a, b) in changed.items())
    # status first: a kill before the config is written leaves a run that --resume finishes as it was
    folder.set_status("interrupted", reason=f"lengthening: {what}", episodes_done=(folder.status() or {})
                      .get("episodes_done"))
    now = {k: b for k, (a, b) in changed.items()}
    recorded = folder.read_json(CONFIG)
    recorded["run"] = {**recorded["run"], **now}
    recorded.setdefault("lengthened", []).append(dict(time=time.strftime("%Y-%m-%d %H:%M:%S"), **{
        k: dict(was=a, now=b) for k, (a, b) in changed.items()}, **provenance()))
    folder.write_json(CONFIG, recorded)
    return {**config, "run": {**config["run"], **now}}


def resume(folder: RunFolder, config: dict, progress: bool = True) -> pd.DataFrame:
    """Continue the run in ``folder`` (config from ``resumable_config``) from its last
    checkpoint, or from the start if it has none. Where the config is longer than the run
    (``lengthen``), from the last state at which the seeds to go on had just stopped. Where
    episodes.csv lost rows the latest checkpoint covers (a file cut short), from the previous
    checkpoint if the file holds its rows, saying so; else RunError."""
    checkpoint = folder.load_checkpoint()
    try:
        return _execute(config, folder, checkpoint, progress)
    except RowsMissing as err:   # raised before anything ran: nothing of that attempt is kept
        earlier = folder.earlier_checkpoint_held(checkpoint, load_sections(config)[0].seeds)
        if earlier is None:
            raise RunError(f"{err}, and no earlier checkpoint's episodes are all there: start it again "
                           "(--overwrite)") from None
        name, checkpoint = earlier
        print(f"{err}: continuing from {name} ({checkpoint['episodes_done']} episodes done), the episodes after "
              "it run again", file=sys.stderr)
        # the latest no longer matches the rows: the previous takes its place (else the next save
        # would keep the latest as the fallback)
        os.replace(folder.file(PREVIOUS), folder.file(CHECKPOINT))
        return _execute(config, folder, checkpoint, progress)


def _alive(pid) -> bool:
    if not isinstance(pid, int) or pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
        return True
    except ProcessLookupError:
        return False
    except PermissionError:
        return True


def _execute(config: dict, folder: RunFolder, checkpoint: Optional[dict], progress: bool) -> pd.DataFrame:
    folder.acquire()  # (a no-op when create or existing already did)
    try:
        return _run(config, folder, checkpoint, progress)
    finally:
        folder.release()


def _run(config: dict, folder: RunFolder, checkpoint: Optional[dict], progress: bool) -> pd.DataFrame:
    run = load_sections(config)[0]  # with defaults for settings newer than a recorded config
    use_threads(config)
    env, agent = build(config)
    try:
        return _collect(run, config, folder, checkpoint, progress, env, agent)
    finally:  # now, not when the garbage collector gets to it: a study runs many trials in one process,
        env.close(raise_if_closed=False)  # and each push env holds a physics client per seed


def _collect(run, config: dict, folder: RunFolder, checkpoint: Optional[dict], progress: bool, env, agent):
    collector = OnlineCollector(env, agent, run.episodes, progress=progress, desc=describe(config),
                                env_steps=run.env_steps, before_step=memory_guard(agent, run.max_memory),
                                time_steps=False)  # its memory is flat however long it runs (soak.py)
    if checkpoint is not None:
        _restore(folder, checkpoint, env, agent, collector)
    folder.keep_rows(dict(zip(collector.seeds, collector.episode.tolist())))  # rows past this state come again
    every = run.checkpoint_every * len(run.seeds)
    next_at = (collector.episodes_done // every + 1) * every if every else None

    def state():
        return dict(format=CHECKPOINT_FORMAT, episodes_done=collector.episodes_done, env=env.state_dict(),
                    agent=agent.state_dict(), collector=collector.state_dict())

    def save():
        folder.save_checkpoint(state())

    with deferred_signals() as caught:
        def after_step(c: OnlineCollector) -> bool:
            nonlocal next_at
            # (every seed stopping at once: the final checkpoint is that state; none needed)
            if c.first_stop and not c.finished:
                folder.save_extension_point(state())
            if caught["signum"] is not None:
                return True
            if next_at is not None and c.episodes_done >= next_at and not c.finished:
                save()
                next_at = (c.episodes_done // every + 1) * every
            return False

        try:
            folder.set_status("running", episodes_done=collector.episodes_done)
            collector.run(on_rows=folder.append_rows, after_step=after_step, keep=False)  # rows live on disk
            save()
        except MemoryLimit as err:  # raised between steps: the state is whole, so keep it
            save()
            folder.set_status("failed", reason=f"memory: {err}", episodes_done=collector.episodes_done)
            raise RunError(f"{folder.path}: stopped after {collector.episodes_done} episodes, checkpointed: {err}") \
                from None
        except OSError as err:  # a full disk, a file-size limit: say where, keep what is whole
            try:
                folder.set_status("failed", reason=f"OSError: {err}", episodes_done=collector.episodes_done)
            except OSError:
                pass  # status.json cannot be written either: the message below is all there is
            raise RunError(f"cannot write {err.filename or folder.path}: {err.strerror or err}; the rows and the "
                           f"checkpoint written before are whole: free space, then --resume {folder.path}") from None
        except BaseException as err:
            folder.set_status("failed", reason=f"{type(err).__name__}: {err}",
                              episodes_done=collector.episodes_done)
            raise
        if caught["signum"] is not None and not collector.finished:
            name = signal.Signals(caught["signum"]).name
            folder.set_status("interrupted", reason=name, episodes_done=collector.episodes_done)
            raise Interrupted(caught["signum"], folder, collector.episodes_done)
    try:
        df = folder.finalize_csv()
        folder.set_status("finished", episodes_done=collector.episodes_done)
        folder.drop_previous()
    except OSError as err:  # every row and the final checkpoint are on disk; only the sorting failed
        raise RunError(f"cannot write {err.filename or folder.path}: {err.strerror or err}; every episode is in "
                       f"episodes.csv (unsorted): free space, then --resume {folder.path} to finish it") from None
    return df


def _restore(folder: RunFolder, checkpoint: dict, env, agent, collector: OnlineCollector) -> None:
    """Load ``checkpoint`` into env, agent and collector. If the run's length has grown
    (``lengthen``), seeds it stopped go on; from the latest checkpoint if they had just
    stopped there, else from checkpoint.extend.pt."""
    collector.load_state_dict(checkpoint["collector"])
    if collector.to_continue().any():
        try:
            collector.reactivate()
        except ValueError:
            checkpoint = folder.load_extension_point()
            collector.load_state_dict(checkpoint["collector"])
            try:
                collector.reactivate()
            except ValueError as err:
                raise RunError(f"{folder.path} cannot be lengthened exactly: {err} (the state kept in {EXTEND}); "
                               "start it again at the new length") from None
    env.load_state_dict(checkpoint["env"])
    agent.load_state_dict(checkpoint["agent"])
