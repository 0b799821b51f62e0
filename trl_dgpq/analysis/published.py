"""What the repository keeps of a reproduction, so every published number can be recomputed.

``reproduce --publish DIR`` writes, for every finished experiment, its per-episode rows and its
config into ``DIR/data/`` and a manifest naming the run; then REPORT.md, claims.md, results.csv,
summary.md and the figures drawn from episodes are *rebuilt from DIR/data alone*
(``rebuild``), so what the pages quote and what the data say cannot drift apart.
``trl-dgpq report DIR`` rebuilds them again, with no runs/ folder.

    DIR/data/manifest.json      the scale, the domains, the plan's experiments (``planned``) and
                                those finished and kept (``experiments``), the command, and when
                                and at which commit the data were published; where some parts
                                were published into an earlier publication, which of its
                                experiments were kept and who published them (``kept``)
    DIR/data/<experiment>.json  its resolved config (every seed), the versions and commit the
                                sweep was made with, what of the env's model it uses, and each
                                job's seeds and commit
    DIR/data/<experiment>.csv.xz  every (seed, episode) row the runs wrote, floats to 7
                                significant digits, less us_per_step (wall_s / steps); cpu_s
                                kept, what ``reproduce --plan`` estimates a run's cost by (the
                                wall time grows with the load; +4 % of the file)

Four figures are drawn from a trained agent's checkpoint, not from episodes, and checkpoints are
not kept. Three keep what they draw as plain data beside them (``figures.save_drawn``: Q̂ over
the square, the F-16's trace, liquidation's holdings), which is published and from which a
rebuild draws them again; the push animation (pybullet's camera frames) is kept as drawn at the
run (REPORT.md says so).
"""
from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

from .runs import Run, read_csv_exact

DATA, MANIFEST = "data", "manifest.json"
DROPPED = ("us_per_step",)
FLOAT_FORMAT = "%.7g"
# what a checkpoint drew: the data three figures are drawn from, and the animation as it was drawn
CHECKPOINT_FIGURES = ("square/qhat.json.xz", "push/push.gif", "f16/f16_trace.json.xz", "liquidation/holdings.json.xz")


def is_published(folder) -> bool:
    return (Path(folder) / DATA / MANIFEST).is_file()


def job_commits(folder: Path) -> list:
    """[{seeds, commit, dirty}] of each job of a sweep experiment (or the run itself)."""
    out = []
    configs = sorted(folder.glob("jobs/*/config.json")) or [folder / "config.json"]
    for config in configs:
        recorded = json.loads(config.read_text())
        git = recorded.get("git") or {}
        out.append(dict(seeds=recorded.get("run", {}).get("seeds"), commit=git.get("commit"), dirty=git.get("dirty")))
    return out


def write_data(out: Path, to: Path, names: list, manifest: dict, kept_from=None, kept=()) -> list:
    """The rows and configs of ``names`` (finished experiments of the sweep in ``out``) into
    ``to/data`` (a new folder: ``reproduce.publish`` builds a publication apart, then puts it in
    place), those of ``kept`` copied byte for byte from the publication ``kept_from``, and the
    manifest (its experiments in the plan's order); returns the paths written."""
    data = to / DATA
    data.mkdir(parents=True, exist_ok=True)
    written = []
    for name in kept:
        for suffix in (".csv.xz", ".json"):
            written.append(Path(shutil.copy2(Path(kept_from) / DATA / f"{name}{suffix}", data / f"{name}{suffix}")))
    for name in names:
        folder = out / name
        df = read_csv_exact(folder / "episodes.csv").drop(columns=[c for c in DROPPED], errors="ignore")
        rows = data / f"{name}.csv.xz"
        df.to_csv(rows, index=False, float_format=FLOAT_FORMAT, compression={"method": "xz", "preset": 9})
        config = json.loads((folder / "config.json").read_text())
        config["jobs"] = job_commits(folder)
        (data / f"{name}.json").write_text(json.dumps(config, indent=1, sort_keys=True) + "\n")
        written += [rows, data / f"{name}.json"]
    planned, every = manifest.get("planned", []), {*names, *kept}
    order = [n for n in planned if n in every] + [n for n in [*names, *kept] if n not in planned]
    (data / MANIFEST).write_text(json.dumps({**manifest, "experiments": order}, indent=1) + "\n")
    return written + [data / MANIFEST]


def manifest(folder) -> dict:
    return json.loads((Path(folder) / DATA / MANIFEST).read_text())


def recorded_config(folder, name: str) -> dict:
    """A published experiment's recorded config, without reading its rows."""
    return json.loads((Path(folder) / DATA / f"{name}.json").read_text())


def load(folder, name: str, columns=None) -> Run:
    """A published experiment as ``load_run`` gives a run folder's (``Run.path``: where its data lie);
    with ``columns``, only those (and seed, episode, steps) read."""
    data = Path(folder) / DATA
    keep = None if columns is None else {"seed", "episode", "steps", *columns}
    df = read_csv_exact(data / f"{name}.csv.xz", keep).sort_values(["seed", "episode"], kind="stable")
    df["env_steps"] = df.groupby("seed")["steps"].cumsum()
    return Run(data / name, df.reset_index(drop=True), recorded_config(folder, name))


def commits_of(run: Run, length: int = 7) -> list:
    """Each job's commit (its first ``length`` digits, "-dirty" if the tree was) of a run folder,
    a sweep experiment or a published experiment: the code that made its rows."""
    jobs = run.config.get("jobs") if run.config else None
    if jobs is None:
        path = Path(run.path)
        jobs = job_commits(path) if path.is_dir() else []
    return [(j.get("commit") or "?")[:length] + ("-dirty" if j.get("dirty") else "") for j in jobs]


def stamp(scale: str, only, command: str) -> dict:
    """The manifest's description of a publication made now, at this code's commit."""
    from trl_dgpq.collectors import runner
    git = runner.provenance()["git"]
    return dict(scale=scale, only=list(only or []), command=command, published=time.strftime("%Y-%m-%d %H:%M"),
                commit=git["commit"], dirty=git["dirty"])


PROVENANCE = ("command", "published", "commit", "dirty")


def kept_record(earlier: dict, parts: list, names: list) -> list:
    """The manifest's ``kept``: for each publication the kept experiments ``names`` (of ``parts``)
    were first published by, [{parts, experiments, command, published, commit, dirty}], from the
    earlier publication's manifest (its own experiments, and those it had kept in turn)."""
    before = earlier.get("kept", [])
    carried = {n for k in before for n in k["experiments"]}
    out = [{**k, "parts": [p for p in k["parts"] if p in parts],
            "experiments": [n for n in k["experiments"] if n in names]} for k in before]
    out.append({"parts": [p for p in parts if not any(p in k["parts"] for k in before)],
                "experiments": [n for n in names if n not in carried], **{f: earlier[f] for f in PROVENANCE}})
    return [k for k in out if k["experiments"]]


def size(folder) -> int:
    """Bytes of the published data."""
    return sum(p.stat().st_size for p in (Path(folder) / DATA).iterdir())
