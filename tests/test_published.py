"""What the repository keeps of a reproduction: per-episode data from which every published file is
rebuilt, with no runs/ folder."""
import json
import lzma
import shutil
import tempfile
from pathlib import Path
from types import SimpleNamespace

import pandas as pd
import pytest

from trl_dgpq.analysis import published
from trl_dgpq.analysis.claims import Agrees, Claim, seeds_interval, table
from trl_dgpq.collectors import runner, sweep
from trl_dgpq.commands import report, reproduce

ROOT = Path(__file__).resolve().parent.parent


def corridor_domain(monkeypatch, seeds=(0, 1)):
    """One domain of two constant-agent experiments on the corridor, and a claim on the first."""
    def measure(runs):
        return seeds_interval(runs["c1"].df.groupby("seed")["return"].mean())
    analysis = SimpleNamespace(
        REPRODUCE=[("c1", dict(agent="constant")), ("c2", dict(agent="constant"))],
        SCALES={"smoke": (len(seeds), 3)}, TITLE="The corridor", SUMMARY="Two constant agents.",
        CLAIMS=[Claim("c/k", "this suite", "the return is about -3", Agrees(-3, 2, True), measure, ("c1",),
                      decided_at=("smoke",))],
        reproduce_section=lambda runs, out, label, title, judged: "## Corridor\n\n" + "\n".join(
            j.bullet() for j in judged) + "\n")
    monkeypatch.setattr(reproduce, "reproductions", lambda only=None: [
        (SimpleNamespace(name="corridor", examples=lambda: ["corridor"]), analysis)])
    return analysis


def run_all(out, only=None):
    planned = reproduce.experiments("smoke", only)
    sweep.create(out, planned, jobs := sweep.plan(planned, out, None))
    for job in jobs:
        folder = runner.RunFolder(job.folder)
        folder.path.mkdir(parents=True)
        runner.start(job.config, folder, progress=False)
        sweep.merge(out, job.experiment, [job])
    return planned


def files(folder) -> dict:
    """Every file under ``folder`` and its bytes."""
    return {p: p.read_bytes() for p in Path(folder).rglob("*") if p.is_file()}


def test_publish_keeps_the_rows_and_rebuilds_every_file_from_them_alone(tmp_path, monkeypatch, capsys):
    corridor_domain(monkeypatch)
    out, to = tmp_path / "repro", tmp_path / "results" / "report"
    run_all(out)
    to.mkdir(parents=True)
    (to / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="neither an earlier publication nor empty"):   # never deletes what is not its own
        reproduce.publish(out, to, "smoke")
    with pytest.raises(ValueError, match="apart from the runs'"):
        reproduce.publish(out, out / "pub", "smoke")
    assert (to / "notes.txt").read_text() == "mine" and (out / "c1" / "episodes.csv").is_file()
    (to / "notes.txt").unlink()
    reproduce.publish(out, to, "smoke")
    (to / "stale.png").write_text("x")                       # a figure an earlier publication drew: replaced whole
    reproduce.publish(out, to, "smoke")
    assert not (to / "stale.png").exists() and not (to.parent / ".report.new").exists()
    # the rows: every (seed, episode) the runs wrote, floats to 7 digits, less us_per_step (wall_s / steps)
    kept = pd.read_csv(to / "data" / "c1.csv.xz")
    ran = pd.read_csv(out / "c1" / "episodes.csv")
    assert list(kept.columns) == [c for c in ran.columns if c != "us_per_step"]
    assert len(kept) == len(ran) == 6 and (kept["return"] == ran["return"]).all()
    assert kept["wall_s"].to_numpy() == pytest.approx(ran["wall_s"].to_numpy(), rel=1e-6)
    config = json.loads((to / "data" / "c1.json").read_text())
    assert config["run"]["seeds"] == [10, 11] and config["jobs"][0]["commit"] == runner.provenance()["git"]["commit"]
    stamp = published.manifest(to)
    assert stamp["experiments"] == ["c1", "c2"] and stamp["scale"] == "smoke"
    assert stamp["command"] == "python scripts/reproduce.py --scale smoke"
    text = (to / "REPORT.md").read_text()
    assert "Built from the per-episode data in `data/`" in text and "## Corridor" in text
    assert (to / "summary.md").read_text().startswith("The claims of corridor, each judged by its rule on the "
                                                      "published data of `python scripts/reproduce.py --scale smoke`")
    assert "**The corridor.** Two constant agents." in (to / "summary.md").read_text()
    assert (to / "sections" / "corridor.md").is_file()
    # no runs/: the rebuild gives every file back, byte for byte
    shutil.rmtree(out)
    before = files(to)
    for p in ("REPORT.md", "claims.md", "results.csv", "summary.md"):
        (to / p).unlink()
    capsys.readouterr()
    assert report.main([str(to)]) == 0
    assert "wrote" in capsys.readouterr().out
    assert files(to) == before


def test_publish_refuses_runs_on_seeds_outside_the_reporting_ones(tmp_path, monkeypatch):
    corridor_domain(monkeypatch, seeds=(0, 1))
    out = tmp_path / "repro"
    planned = run_all(out)
    # the plan's seeds moved to a study's: the publication is refused before anything is written
    monkeypatch.setattr(reproduce, "experiments", lambda scale, only=None: {
        n: {**c, "run": {**c["run"], "seeds": [1000, 1001]}} for n, c in planned.items()})
    with pytest.raises(ValueError, match="reporting seeds are 0-99"):
        reproduce.publish(out, tmp_path / "to", "smoke")
    assert not (tmp_path / "to").exists()


@pytest.mark.full_bootstraps
def test_the_committed_publication_rebuilds_to_the_committed_files():
    """results/report rebuilt from its own data/ for one domain (the square and its part apart:
    seconds) gives the committed claims' rows and results.csv's."""
    to = ROOT / "results" / "report"
    if not published.is_published(to):
        pytest.skip("results/report holds no published data yet")
    stamp = published.manifest(to)
    names = [n for n in stamp["experiments"] if n.startswith("square-")]
    assert names, "the publication has the square"
    runs = {n: published.load(to, n) for n in names}
    parts = [m for p, m in reproduce.reproductions(["square", "square-paper-tuned"]) if p.name in stamp["only"]]
    judged = [reproduce_judge(c, runs, stamp["scale"]) for m in parts for c in declared_now(m)]
    from trl_dgpq.analysis import results
    committed = pd.read_csv(to / "results.csv").set_index("experiment")
    lines = {line.split(",", 1)[0]: line for line in (to / "results.csv").read_text().splitlines()[1:]}
    for name, run in runs.items():
        row = results.row(name, run)
        for column in ("median", "iqm", "iqm_low", "iqm_high"):
            assert row[column] == pytest.approx(committed.loc[name, column], rel=1e-9), (name, column)
        assert row["commit"] == committed.loc[name, "commit"], name
        with tempfile.TemporaryDirectory() as tmp:   # every column, as results.csv writes it
            rebuilt = results.write([row], Path(tmp) / "r.csv").read_text().splitlines()[1]
        assert rebuilt == lines[name], name
    claims = (to / "claims.md").read_text()
    for j in judged:
        assert table([j]).splitlines()[2] in claims, j.claim.key


def declared_now(part) -> list:
    """A part's claims built now (``declared_claims``), not the list its module built on import: a
    test then reaches the code that declares them."""
    return part.declared_claims()


def test_every_published_claim_is_as_declared_now():
    """A claim is fixed before its run: every declared claim of each published part has the source,
    words and rule that claims.md published with it, and every published row is a declared claim
    (a claim reworded or its rule moved after publication fails here until published again)."""
    from trl_dgpq.analysis.claims import Judged
    to = ROOT / "results" / "report"
    if not published.is_published(to):
        pytest.skip("results/report holds no published data yet")
    published_rows = [r for r in (to / "claims.md").read_text().splitlines() if r.startswith("| ")][1:]
    heads = []
    for part, module in reproduce.reproductions(published.manifest(to)["only"]):
        for claim in declared_now(module):
            row = table([Judged(claim, "-", "-", ())]).splitlines()[2]
            heads.append(row[:row.index(" | - | - |")] + " | ")
    assert len(heads) == len(published_rows)
    for head, row in zip(heads, published_rows):
        assert row.startswith(head), (head, row)


def reproduce_judge(claim, runs, scale):
    from trl_dgpq.analysis.claims import judge
    return judge(claim, runs, scale)


def test_the_published_data_stay_small():
    """The data are compressed rows; the repository keeps them under a size said in the docs."""
    to = ROOT / "results" / "report"
    if not published.is_published(to):
        pytest.skip("results/report holds no published data yet")
    assert published.size(to) < 64 * 2 ** 20   # docs/reproducing.md: 54.3 MiB with liquidation-reward (2026-11-29)
    for path in (to / "data").glob("*.csv.xz"):
        with lzma.open(path, "rt") as f:
            assert "us_per_step" not in f.readline()


def test_a_checkpoints_figure_is_drawn_again_from_what_it_kept(tmp_path, monkeypatch):
    """Q̂ over the square: drawn once from a (faked) checkpoint, kept as plain data, drawn again
    byte for byte without it; with neither, no figure."""
    from trl_dgpq.envs.square import analysis as sq
    q = [[[0.1 * (i + j + a) for a in range(4)] for j in range(3)] for i in range(3)]
    drawn = dict(q=q, names=["N", "S", "E", "W"], pairs=[[[0.1, 0.2]], [], [[0.5, 0.5], [0.6, 0.6]], []],
                 path=[[0.0, 0.0], [0.1, 0.0], [0.1, 0.1]], goal=[1.0, 1.0], radius=0.15, seed=3, run="square-shaped")
    monkeypatch.setattr(sq, "qhat_drawn", lambda folder: drawn)
    pub = tmp_path / "pub"
    (pub / "data").mkdir(parents=True)
    (pub / "data" / "manifest.json").write_text("{}")
    (pub / "square").mkdir()
    first = sq.qhat_figure(tmp_path / "run", pub / "square", "t").read_bytes()
    monkeypatch.setattr(sq, "qhat_drawn", lambda folder: pytest.fail("the checkpoint was read"))
    (pub / "square" / "qhat.png").unlink()
    assert sq.qhat_figure(None, pub / "square", "t").read_bytes() == first
    assert sq.qhat_figure(None, pub / "none", "t") is None
    (tmp_path / "plotted").mkdir()                    # kept data outside a publication: never drawn from
    (pub / "square" / "qhat.json.xz").rename(tmp_path / "plotted" / "qhat.json.xz")
    assert sq.qhat_figure(None, tmp_path / "plotted", "t") is None


def test_the_published_rows_configs_and_manifest_by_hand(tmp_path, monkeypatch):
    """A sweep experiment of two jobs: each job's seeds, commit and dirty flag; rows sorted by seed and
    episode with env_steps counted per seed; floats to 7 digits; a plain run folder is one job; the
    stamp names what published it and when."""
    exp = tmp_path / "sweep" / "e"
    for j, (seeds, commit, dirty) in enumerate((([10, 11], "a" * 40, False), ([12], "b" * 40, True))):
        (exp / "jobs" / f"j{j:03d}").mkdir(parents=True)
        (exp / "jobs" / f"j{j:03d}" / "config.json").write_text(json.dumps(
            {"run": {"seeds": seeds}, "git": {"commit": commit, "dirty": dirty}}))
    (exp / "config.json").write_text(json.dumps({"run": {"env": "square", "seeds": [10, 11, 12]}}))
    pd.DataFrame(dict(seed=[11, 10, 10], episode=[1, 2, 1], steps=[5, 7, 3], wall_s=[0.123456789, 1.0, 2.0],
                      cpu_s=[9.0] * 3, us_per_step=[1.0] * 3)).to_csv(exp / "episodes.csv", index=False)
    assert published.job_commits(exp) == [dict(seeds=[10, 11], commit="a" * 40, dirty=False),
                                          dict(seeds=[12], commit="b" * 40, dirty=True)]
    to = tmp_path / "pub"
    written = published.write_data(tmp_path / "sweep", to, ["e"], {"scale": "s"})
    assert sorted(p.name for p in written) == ["e.csv.xz", "e.json", "manifest.json"]
    assert published.manifest(to) == {"scale": "s", "experiments": ["e"]}
    # the committed files' format (a change would rewrite every published config): one space an indent, keys sorted
    assert (to / "data" / "e.json").read_text() == ('{\n "jobs": [\n  {\n   "commit": "' + "a" * 40 + '",\n   "dirty": '
                                                   'false,\n   "seeds": [\n    10,\n    11\n   ]\n  },\n  {\n   '
                                                   '"commit": "' + "b" * 40 + '",\n   "dirty": true,\n   "seeds": [\n'
                                                   '    12\n   ]\n  }\n ],\n "run": {\n  "env": "square",\n  '
                                                   '"seeds": [\n   10,\n   11,\n   12\n  ]\n }\n}\n')
    assert (to / "data" / "manifest.json").read_text() == '{\n "scale": "s",\n "experiments": [\n  "e"\n ]\n}\n'
    narrow = published.load(to, "e", columns=("cpu_s",))                 # the columns asked for and the keys alone
    assert list(narrow.df.columns) == ["seed", "episode", "steps", "cpu_s", "env_steps"]
    with lzma.open(to / "data" / "e.csv.xz", "rt") as f:
        assert f.read().splitlines() == ["seed,episode,steps,wall_s,cpu_s", "11,1,5,0.1234568,9", "10,2,7,1,9",
                                         "10,1,3,2,9"]
    run = published.load(to, "e")
    assert run.path == to / "data" / "e" and list(run.df.index) == [0, 1, 2] and "index" not in run.df
    lean = tmp_path / "lean" / "f"                         # a run that never wrote cpu_s: kept as it is
    shutil.copytree(exp, lean)
    pd.read_csv(exp / "episodes.csv").drop(columns=["cpu_s", "us_per_step"]).to_csv(lean / "episodes.csv", index=False)
    published.write_data(tmp_path / "lean", tmp_path / "pub2", ["f"], {})
    assert list(published.load(tmp_path / "pub2", "f").df.columns) == ["seed", "episode", "steps", "wall_s", "env_steps"]
    assert run.df[["seed", "episode", "env_steps"]].values.tolist() == [[10, 1, 3], [10, 2, 10], [11, 1, 5]]
    assert run.config["jobs"][1] == dict(seeds=[12], commit="b" * 40, dirty=True)
    assert published.commits_of(run) == ["aaaaaaa", "bbbbbbb-dirty"]
    from trl_dgpq.analysis.runs import Run
    assert published.commits_of(Run(exp, run.df, {"run": {}})) == ["aaaaaaa", "bbbbbbb-dirty"]   # a sweep's jobs
    plain = tmp_path / "plain"
    plain.mkdir()
    (plain / "config.json").write_text(json.dumps({"git": {}}))          # a config of before its run section
    assert published.job_commits(plain) == [dict(seeds=None, commit=None, dirty=None)]
    (plain / "config.json").write_text(json.dumps({"run": {"seeds": [3]}, "git": {}}))
    assert published.job_commits(plain) == [dict(seeds=[3], commit=None, dirty=None)]
    assert published.commits_of(Run(plain, run.df, {"run": {}})) == ["?"]
    assert published.commits_of(Run(tmp_path / "nowhere.csv", run.df, None)) == []
    monkeypatch.setattr(runner, "provenance", lambda: {"git": {"commit": "c" * 40, "dirty": True}})
    monkeypatch.setattr(published.time, "strftime", lambda fmt: {"%Y-%m-%d %H:%M": "2026-01-02 03:04"}[fmt])
    assert published.stamp("report", ("f16",), "cmd") == dict(scale="report", only=["f16"], command="cmd",
                                                             published="2026-01-02 03:04", commit="c" * 40, dirty=True)
    assert published.stamp("quick", None, "cmd")["only"] == []


PARTS = {"corridor": ("c1", "c2"), "corridor-apart": ("c3",), "corridor-more": ("c4",), "corridor-last": ("c5",)}


def corridor_parts(monkeypatch, scales: dict):
    """The corridor as a domain ("corridor": c1, c2) and three parts apart (c3, c4, c5), each of
    constant-agent experiments at the sizes ``scales[part]`` (change them to change a part's plan)."""
    def part(name, experiments):
        return SimpleNamespace(
            REPRODUCE=[(n, dict(agent="constant")) for n in experiments], TITLE=name, SUMMARY=f"{name}.", CLAIMS=[],
            SCALES=scales[name],
            reproduce_section=lambda runs, out, label, title, judged: f"## {name}: " + ", ".join(runs) + "\n")
    parts = [(SimpleNamespace(name=n, examples=lambda: ["corridor"]), part(n, e)) for n, e in PARTS.items()]
    monkeypatch.setattr(reproduce, "reproductions", lambda only=None: [(p, a) for p, a in parts
                                                                       if not only or p.name in only])


def run_parts(out, only, figures="") -> None:
    """Every experiment of the ``only`` parts run in the sweep ``out``, and the checkpoint figures'
    kept data as each part's folder would hold them (their text: the part's name and ``figures``)."""
    run_all(out, only)
    for part in PARTS:
        (out / part).mkdir()
        (out / part / "drawn.json").write_text(f"{part} {figures}")


def test_publishing_a_part_into_an_earlier_publication_keeps_its_other_parts_as_published(tmp_path, monkeypatch):
    """Adding or replacing a part never needs the runs of the rest: the earlier publication's other
    parts are kept byte for byte, the manifest and REPORT.md name who published them (through a
    later publication too), and the whole rebuilds from data/ alone; a kept part whose plan changed
    since, or another scale, is refused before anything moves."""
    scales = {part: {"smoke": (2, 3), "quick": (2, 3)} for part in PARTS}
    corridor_parts(monkeypatch, scales)
    monkeypatch.setattr(published, "CHECKPOINT_FIGURES", tuple(f"{part}/drawn.json" for part in PARTS))
    first, to = tmp_path / "first", tmp_path / "pub"
    run_parts(first, None, "first")
    reproduce.publish(first, to, "smoke", ["corridor", "corridor-more"])
    stamp = json.loads((to / "data" / "manifest.json").read_text())    # an older publication than today's, dirty
    stamp.update(published="2000-01-01 00:00", commit="e" * 40, dirty=True)
    (to / "data" / "manifest.json").write_text(json.dumps(stamp))
    before = {p.name: p.read_bytes() for p in (to / "data").glob("c[124].*")}
    assert len(before) == 6

    scales["corridor-apart"]["smoke"] = (2, 4)         # the part apart's plan changes; it runs again, alone
    second = tmp_path / "second"
    run_parts(second, ["corridor-apart"], "second")
    reproduce.publish(second, to, "smoke", ["corridor-apart"])
    assert {p.name: p.read_bytes() for p in (to / "data").glob("c[124].*")} == before
    assert published.load(to, "c3").df.episode.max() == 4
    assert [(to / part / "drawn.json").read_text() for part in ("corridor", "corridor-more", "corridor-apart")] == [
        "corridor first", "corridor-more first", "corridor-apart second"]      # a kept part's as published
    assert not (to / "corridor-last" / "drawn.json").exists()                   # a part in neither
    now = published.manifest(to)
    assert now["only"] == ["corridor", "corridor-more", "corridor-apart"]
    assert now["experiments"] == now["planned"] == ["c1", "c2", "c3", "c4"]
    assert now["command"] == "python scripts/reproduce.py --scale smoke --only corridor corridor-more corridor-apart"
    earliest = dict(parts=["corridor", "corridor-more"], experiments=["c1", "c2", "c4"],
                    command="python scripts/reproduce.py --scale smoke --only corridor corridor-more",
                    published="2000-01-01 00:00", commit="e" * 40, dirty=True)
    assert now["kept"] == [earliest]
    assert (to / "REPORT.md").read_text().split("\n\n")[1].endswith(
        f"; those of corridor, corridor-more (3 experiments) as `{earliest['command']}` published them on 2000-01-01 "
        f"00:00 at commit {'e' * 40} (dirty), kept unchanged. Every number and figure below is computed from those "
        "files (a trained agent's figures from what its checkpoint showed, kept beside them: Q̂ over the square, the "
        "F-16's trace, liquidation's holdings), but the push animation, kept as drawn at the run.")
    assert "## corridor: c1, c2" in (to / "REPORT.md").read_text()
    stamp = json.loads((to / "data" / "manifest.json").read_text())    # the second publication, clean
    stamp.update(dirty=False)
    (to / "data" / "manifest.json").write_text(json.dumps(stamp))

    second_stamp = {k: stamp[k] for k in published.PROVENANCE}
    third = tmp_path / "third"                         # one more part: both earlier publishers are named
    run_parts(third, ["corridor-last"], "third")
    returned = reproduce.publish(third, to, "smoke", ["corridor-last"])
    assert returned == sorted(files(to))
    kept = published.manifest(to)["kept"]
    assert kept == [earliest, dict(parts=["corridor-apart"], experiments=["c3"], **second_stamp)]
    head = (to / "REPORT.md").read_text().split("\n\n")[1]
    assert head.endswith(f"(dirty), kept unchanged; those of corridor-apart (1 experiment) as `{second_stamp['command']}` "
                         f"published them on {second_stamp['published']} at commit {second_stamp['commit']}, kept "
                         "unchanged. Every number and figure below is computed from those files (a trained agent's "
                         "figures from what its checkpoint showed, kept beside them: Q̂ over the square, the F-16's "
                         "trace, liquidation's holdings), but the push animation, kept as drawn at the run.")
    third_stamp = {k: published.manifest(to)[k] for k in published.PROVENANCE}
    scales["corridor-apart"]["smoke"] = (2, 2)         # a part the publication holds, run and published again
    fourth = tmp_path / "fourth"
    run_parts(fourth, ["corridor-apart"], "fourth")
    reproduce.publish(fourth, to, "smoke", ["corridor-apart"])
    assert published.load(to, "c3").df.episode.max() == 2
    assert (to / "corridor-apart" / "drawn.json").read_text() == "corridor-apart fourth"
    assert published.manifest(to)["kept"] == [earliest, dict(parts=["corridor-last"], experiments=["c5"], **third_stamp)]
    assert not (tmp_path / ".pub.old").exists() and not (tmp_path / ".pub.new").exists()
    rebuilt = files(to)
    (to / "REPORT.md").unlink()
    reproduce.rebuild(to)
    assert files(to) == rebuilt
    stamp = published.manifest(to)
    for dirty, mark in ((True, " (dirty)"), (False, "")):       # the publisher's own mark; a manifest without
        (to / "data" / "manifest.json").write_text(json.dumps(   # its plan (older ones) is its experiments
            {**{k: v for k, v in stamp.items() if k != "planned"}, "dirty": dirty}))
        reproduce.rebuild(to)
        text = (to / "REPORT.md").read_text()
        assert f"at commit {stamp['commit']}{mark}; those of corridor, corridor-more" in text and "Partial" not in text
    (to / "data" / "manifest.json").write_text(json.dumps(stamp, indent=1) + "\n")
    reproduce.rebuild(to)
    assert files(to) == rebuilt

    scales["corridor"]["smoke"] = (2, 5)               # a kept part's plan moved on: its rows are not the plan's
    with pytest.raises(ValueError, match=r"^the plan of c1, c2 changed since they were published: run them again "
                                         r"\(their parts' --only\) and publish those parts too$"):
        reproduce.publish(third, to, "smoke", ["corridor-last"])
    with pytest.raises(ValueError, match="^the folder holds the smoke scale's publication of corridor, corridor-more: "
                                         "publishing corridor-apart, corridor-last at the quick scale into it would "
                                         "lose them; publish into another folder, or every part$"):
        reproduce.publish(fourth, to, "quick", ["corridor-apart", "corridor-last"])
    assert files(to) == rebuilt
    scales["corridor"]["smoke"] = (2, 3)
    reproduce.publish(first, to, "smoke")               # every part: nothing kept
    assert "kept" not in published.manifest(to) and (to / "corridor-apart" / "drawn.json").read_text() == \
        "corridor-apart first"


def test_which_parts_a_publication_keeps(monkeypatch):
    """Those of the earlier publication that ``only`` does not name; all its parts where its ``only``
    was every part; none without an earlier one or when every part is published now; another scale
    refused only where a part would be lost."""
    corridor_parts(monkeypatch, {part: {"smoke": (2, 3)} for part in PARTS})
    every = dict(scale="smoke", only=[])
    assert reproduce.kept_parts(every, "smoke", ["corridor-apart"]) == ["corridor", "corridor-more", "corridor-last"]
    assert reproduce.kept_parts(dict(scale="smoke", only=["corridor-last", "corridor"]), "smoke", ["corridor"]) == \
        ["corridor-last"]
    assert reproduce.kept_parts(None, "smoke", ["corridor"]) == []
    assert reproduce.kept_parts(every, "smoke", None) == reproduce.kept_parts(every, "smoke", []) == []
    assert reproduce.kept_parts(dict(scale="quick", only=["corridor"]), "smoke", ["corridor"]) == []


def test_publish_writes_only_the_named_parts_and_leaves_nothing_half_done(tmp_path, monkeypatch):
    """A sweep holding every part published with ``only``: those parts' experiments alone; leftovers
    of a publication cut short removed; a publication that fails leaves the earlier one as it was and
    nothing beside it; a sweep with nothing finished refused."""
    corridor_parts(monkeypatch, {part: {"smoke": (2, 3)} for part in PARTS})
    out, to = tmp_path / "out", tmp_path / "pub"
    run_parts(out, None)
    for leftover in (".pub.new", ".pub.old"):           # a publication killed half-way
        (tmp_path / leftover).mkdir()
        (tmp_path / leftover / "stale.txt").write_text("x")
    reproduce.publish(out, to, "smoke", ["corridor-apart"])
    assert published.manifest(to)["experiments"] == ["c3"] and "kept" not in published.manifest(to)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "pub"] and not list(to.rglob("stale.txt"))
    earlier = files(to)
    with monkeypatch.context() as m, pytest.raises(ZeroDivisionError):
        m.setattr(reproduce, "write_report", lambda *a: 1 / 0)
        reproduce.publish(out, to, "smoke", ["corridor"])
    assert files(to) == earlier and sorted(p.name for p in tmp_path.iterdir()) == ["out", "pub"]
    (out / "c2" / "episodes.csv").unlink()             # c2 unfinished: a partial publication, and said so
    reproduce.publish(out, tmp_path / "partial", "smoke", ["corridor"])
    assert "**Partial: 1 of 2 experiments have finished.**" in (tmp_path / "partial" / "REPORT.md").read_text()
    empty = tmp_path / "empty"
    sweep.create(empty, planned := reproduce.experiments("smoke"), sweep.plan(planned, empty, None))
    with pytest.raises(ValueError, match=f"^{empty} holds no finished experiment to publish$"):
        reproduce.publish(empty, tmp_path / "pub2", "smoke")


def test_publish_refuses_seeds_explored_while_the_claims_were_chosen(tmp_path, monkeypatch):
    """The plan's seeds, and then the runs' own, among the seeds development explored: refused,
    naming the experiment; its rows, with a seed its config does not name, refused on rebuild."""
    corridor_parts(monkeypatch, {part: {"smoke": (2, 3)} for part in PARTS})
    out = tmp_path / "out"
    run_parts(out, ["corridor-apart"])
    planned = reproduce.experiments("smoke", ["corridor-apart"])
    explored = lambda scale, only=None: {n: {**c, "run": {**c["run"], "seeds": [3, 4]}} for n, c in planned.items()}
    with monkeypatch.context() as m:
        m.setattr(reproduce, "experiments", explored)
        with pytest.raises(ValueError, match=r"^c3 \(constant on corridor, preset 'default'\): seeds 3-4 were explored"):
            reproduce.publish(out, tmp_path / "to", "smoke", ["corridor-apart"])
    config = json.loads((out / "c3" / "config.json").read_text())
    (out / "c3" / "config.json").write_text(json.dumps({**config, "run": {**config["run"], "seeds": [5]}}))
    with pytest.raises(ValueError, match=r"^c3 \(constant on corridor, preset 'default'\): seed 5 was explored"):
        reproduce.publish(out, tmp_path / "to", "smoke", ["corridor-apart"])
    (out / "c3" / "config.json").write_text(json.dumps(config))
    to = tmp_path / "to"
    reproduce.publish(out, to, "smoke", ["corridor-apart"])
    rows = pd.read_csv(to / "data" / "c3.csv.xz")
    rows.loc[0, "seed"] = 7
    rows.to_csv(to / "data" / "c3.csv.xz", index=False)
    with pytest.raises(ValueError, match=r"^c3 \(constant on corridor, preset 'default'\): seed 7 was explored"):
        reproduce.rebuild(to)

def test_the_kept_record_names_each_experiments_first_publisher_by_hand():
    """Three parts: a kept since the first publication, b published by the second, c republished now.
    The record keeps a's first publisher, adds b's (the second's own), drops c and empty entries."""
    first = dict(command="cmd1", published="2000-01-01 00:00", commit="1" * 40, dirty=False)
    earlier = dict(command="cmd2", published="2001-01-01 00:00", commit="2" * 40, dirty=True, scale="s",
                   only=["a", "b", "c", "d"], experiments=["a1", "a2", "b1", "c1", "d1"],
                   kept=[dict(parts=["a", "d"], experiments=["a1", "a2", "d1"], **first)])
    assert published.kept_record(earlier, ["a", "b"], ["a1", "a2", "b1"]) == [
        dict(parts=["a"], experiments=["a1", "a2"], **first),
        dict(parts=["b"], experiments=["b1"], command="cmd2", published="2001-01-01 00:00", commit="2" * 40, dirty=True)]
    assert published.kept_record(earlier, ["b"], ["b1"]) == [
        dict(parts=["b"], experiments=["b1"], command="cmd2", published="2001-01-01 00:00", commit="2" * 40, dirty=True)]
