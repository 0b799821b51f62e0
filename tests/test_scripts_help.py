"""Every script in scripts/ answers --help, and bench.py each of its sub-commands' --help: argparse
formats help strings with %, so a stray "95 % CI" in one crashes the whole help (it did)."""
import runpy
import sys
from pathlib import Path

import pytest

SCRIPTS = Path(__file__).resolve().parent.parent / "scripts"


def help_of(monkeypatch, capsys, script, *argv):
    monkeypatch.setattr(sys, "argv", [str(script), *argv, "--help"])
    monkeypatch.syspath_prepend(str(SCRIPTS))
    with pytest.raises(SystemExit) as ended:
        runpy.run_path(str(script), run_name="__main__")
    assert ended.value.code in (0, None)
    return capsys.readouterr().out


@pytest.mark.parametrize("script", sorted(p.name for p in SCRIPTS.glob("*.py") if "__main__" in p.read_text()
                                          and "run it as" not in p.read_text()))  # bench_parity: via bench.py
def test_each_script_answers_help(script, monkeypatch, capsys):
    assert "usage:" in help_of(monkeypatch, capsys, SCRIPTS / script)


def test_each_bench_sub_command_answers_help(monkeypatch, capsys):
    top = help_of(monkeypatch, capsys, SCRIPTS / "bench.py")
    subs = top.split("{", 1)[1].split("}", 1)[0].split(",")
    assert {"qhat", "same-curves", "bound", "parity"} <= set(subs)
    for name in subs:
        assert f"usage: bench.py {name}" in help_of(monkeypatch, capsys, SCRIPTS / "bench.py", name)


def test_bench_against_published_finds_the_same_rows_and_a_changed_one(tmp_path, capsys):
    """A run "published" by hand (its rows at 7 significant digits, its config) against the same
    run: the same rows, CPU ratio 1 in every window; a return changed in the publication is named;
    a run longer than the publication is compared over the publication's episodes; a run with other
    settings (more seeds) is refused by name."""
    import json

    import pandas as pd

    from tests.test_run import run
    from trl_dgpq.analysis import published
    assert run("--seeds", "0-1", "--episodes", 4, "--out", tmp_path / "a") == 0
    assert run("--seeds", "0-2", "--episodes", 4, "--out", tmp_path / "b") == 0
    data = tmp_path / "pub" / published.DATA
    data.mkdir(parents=True)
    rows = pd.read_csv(tmp_path / "a" / "episodes.csv").drop(columns=["us_per_step"])
    config = json.loads((tmp_path / "a" / "config.json").read_text())
    (data / "x.json").write_text(json.dumps(config))
    bench = runpy.run_path(str(SCRIPTS / "bench.py"), run_name="bench")["main"]
    argv = ["against-published", "--experiment", "x", "--publication", str(tmp_path / "pub"), "--window", "2"]
    for changed in (False, True):
        if changed:
            rows.loc[3, "return"] += 1.0
        rows.to_csv(data / "x.csv.xz", index=False, float_format=published.FLOAT_FORMAT)
        bench([*argv, "--run", str(tmp_path / "a"), "--out", str(tmp_path / "r.json")])
        got = json.loads((tmp_path / "r.json").read_text())
        assert got["same_rows"] is not changed and got["differ"] == (["return"] if changed else [])
        assert [w["episodes"] for w in got["windows"]] == ["1-2", "3-4"] and {w["ratio"] for w in got["windows"]} == {1.0}
    assert "the same rows in seed, episode, steps, return" in capsys.readouterr().out
    rows[rows.episode <= 3].to_csv(data / "x.csv.xz", index=False, float_format=published.FLOAT_FORMAT)
    bench([*argv, "--run", str(tmp_path / "a"), "--out", str(tmp_path / "r.json")])   # the run is the longer
    got = json.loads((tmp_path / "r.json").read_text())
    assert got["meta"]["episodes"] == 3 and [w["episodes"] for w in got["windows"]] == ["1-2", "3-3"]
    with pytest.raises(SystemExit, match="is not x's settings: run.seeds differ"):
        bench([*argv, "--run", str(tmp_path / "b")])


def test_bench_against_published_takes_another_run_as_its_baseline(tmp_path, capsys):
    """--baseline: a run of the same settings in place of the publication, both runs' floats written
    as the publication writes them before they are compared (a full-precision row against itself
    is the same row); one with other settings refused by name."""
    import json

    import pandas as pd

    from tests.test_run import run
    for name, seeds in (("a", "0-1"), ("same", "0-1"), ("b", "0-2")):
        assert run("--seeds", seeds, "--episodes", 3, "--out", tmp_path / name) == 0
    bench = runpy.run_path(str(SCRIPTS / "bench.py"), run_name="bench")["main"]
    argv = ["against-published", "--experiment", "x", "--run", str(tmp_path / "a"), "--out", str(tmp_path / "r.json")]
    bench([*argv, "--baseline", str(tmp_path / "same")])
    got = json.loads((tmp_path / "r.json").read_text())
    assert got["same_rows"] and got["meta"]["baseline_is_a_run"] and got["meta"]["publication"] == str(tmp_path / "same")
    assert "baseline CPU s" in capsys.readouterr().out
    rows = pd.read_csv(tmp_path / "same" / "episodes.csv")
    rows.loc[2, "return"] += 1.0
    rows.to_csv(tmp_path / "same" / "episodes.csv", index=False)
    bench([*argv, "--baseline", str(tmp_path / "same")])
    assert json.loads((tmp_path / "r.json").read_text())["differ"] == ["return"]
    with pytest.raises(SystemExit, match="is not x's settings: run.seeds differ"):
        bench([*argv, "--baseline", str(tmp_path / "b")])


def test_bench_finished_seeds_counts_by_hand(tmp_path):
    """Two seeds of 30 and 10 env steps: the batch stepped 30 times, 20 of its 60 seed-steps by the
    finished seed (1/3); CPU the rows' cpu_s summed."""
    import json

    import pandas as pd

    from trl_dgpq.analysis import published
    data = tmp_path / "pub" / published.DATA
    data.mkdir(parents=True)
    pd.DataFrame(dict(seed=[0, 0, 1], episode=[1, 2, 1], steps=[20, 10, 10], wall_s=[9.0, 9.0, 9.0],
                      cpu_s=[30.0, 60.0, 30.0])).to_csv(data / "x.csv.xz", index=False)
    (data / "x.json").write_text(json.dumps(dict(run=dict(agent="td3", env="liquidation", seeds=[0, 1]))))
    (data / published.MANIFEST).write_text(json.dumps(dict(experiments=["x"])))
    bench = runpy.run_path(str(SCRIPTS / "bench.py"), run_name="bench")["main"]
    bench(["finished-seeds", "--publication", str(tmp_path / "pub"), "--out", str(tmp_path / "f.json")])
    got = json.loads((tmp_path / "f.json").read_text())["results"]
    assert got == [dict(experiment="x", agent="td3", seeds=2, batched_steps=30, seed_steps=40, finished_share=0.333,
                        cpu_min=2.0)]
