"""commands/reproduce.py's small parts by hand: the scale's label, the README's paragraph and
summary, a row's seconds, a job's share of an estimate, the hours, the minutes a flag takes, a
job's time left where its folder cannot be read, and the refusal of a part that does not exist.
(The plan, the estimate, the guide and the publication: test_sweep, test_reproduce_plan and
test_published.)"""
import argparse
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from trl_dgpq.commands import reproduce


def test_the_scales_label_names_each_parts_seeds_and_lengths():
    assert reproduce.scale_label("quick", ["square"]) == (
        "*Scale: quick* -- fewer seeds and episodes than the seed report (the quick scale; numbers are noisier): "
        "square 4 seeds x 15 episodes (some agents fewer: see the tables).")
    assert reproduce.scale_label("full", ["square", "push"]) == (
        "*Scale: full* -- the seed report's lengths: square 10 seeds x 100 episodes, push 10 seeds x 100 episodes "
        "(some agents fewer: see the tables).")
    assert reproduce.scale_label("report", ["square"]).startswith("*Scale: report* -- the seed report's lengths: ")
    assert reproduce.scale_label("report", ["gym"]).endswith(": gym 10 seeds x 20,000-120,000 env steps (some "
                                                             "agents fewer: see the tables).")
    assert "square-paper-tuned 4 seeds x 1,000 env steps" in reproduce.scale_label("quick", ["square-paper-tuned"])
    assert "f16-model-gwh14 1 seed x 2 episodes" in reproduce.scale_label("quick", ["f16-model-gwh14"])
    assert reproduce.scale_label("smoke", ["f16"]).startswith("*Scale: smoke* -- fewer seeds and episodes than the "
                                                              "seed report (the smoke scale; ")


def judged(source, statement, ours, verdict, model=()):
    return SimpleNamespace(claim=SimpleNamespace(source=source, statement=statement), ours=ours, verdict=verdict,
                           variant=bool(model))


def test_a_domains_paragraph_is_its_title_summary_and_a_row_per_claim():
    d = SimpleNamespace(name="dom")
    analysis = SimpleNamespace(TITLE="The domain", SUMMARY="What it runs.")
    rows = [judged("GWH14", "a | b", "1.0 [0.9, 1.1]", "met"), judged("this suite", "c", "x | y", "not met", ("m",))]
    assert reproduce.domain_summary(d, analysis, rows) == (
        "**The domain.** What it runs.\n\n| claim | ours | verdict |\n|---|---|---|\n"
        "| GWH14: a \\| b | 1.0 [0.9, 1.1] | met |\n"
        "| this suite: c *(uses the model)* | x \\| y | not met |\n")
    assert reproduce.domain_summary(d, SimpleNamespace(), []) == "**dom.** \n\n"


def test_the_summary_tallies_the_claims_of_the_domains_shown_and_names_those_not_yet(tmp_path, monkeypatch):
    from trl_dgpq.analysis import claims
    monkeypatch.setattr(claims, "tally", lambda j: f"TALLY of {len(j)}")
    every = [part.name for part, _ in reproduce.reproductions()]
    domains = list(dict.fromkeys(d.name for d in (part.domain for part, _ in reproduce.reproductions())))
    assert "square" in every and "square" in domains
    reproduce.write_summary(tmp_path, "reproduce --scale quick", [1, 2], ["PARA 1", "PARA 2"], ["square", "push"])
    missing = [d for d in every if d not in ("square", "push")]
    words = ", ".join(missing[:-1]) + " and " + missing[-1]
    assert (tmp_path / "summary.md").read_text() == (
        "The claims of square and push, each judged by its rule on the runs of `reproduce --scale quick` "
        f"([the report](results/report/REPORT.md)): TALLY of 2. Not in this report yet: {words}.\n\nPARA 1\nPARA 2")
    reproduce.write_summary(tmp_path, "c", [], [], every)
    assert (tmp_path / "summary.md").read_text().startswith("The claims of " + ", ".join(every[:-1]) + " and "
                                                            + every[-1] + ", each judged")
    assert "Not in this report yet" not in (tmp_path / "summary.md").read_text()
    from trl_dgpq.analysis.published import DATA, MANIFEST
    (tmp_path / DATA).mkdir()
    (tmp_path / DATA / MANIFEST).write_text("{}")
    reproduce.write_summary(tmp_path, "c", [], [], ["square"])
    assert "each judged by its rule on the published data of `c`" in (tmp_path / "summary.md").read_text()
    reproduce.write_summary(tmp_path, "c", [], [], [])
    assert (tmp_path / "summary.md").read_text().startswith("The claims of none, each judged")


def test_a_rows_seconds_are_its_cpu_time_where_recorded_else_its_wall_time():
    df = pd.DataFrame(dict(wall_s=[2.0, 3.0, 4.0], cpu_s=[1.0, np.nan, 0.5]))
    assert reproduce.spent_seconds(df).tolist() == [1.0, 3.0, 0.5]
    assert reproduce.spent_seconds(df.drop(columns="cpu_s")).tolist() == [2.0, 3.0, 4.0]


def test_a_jobs_share_is_its_start_and_its_seeds_share_of_the_steps():
    start = reproduce.JOB_START_S
    assert start == 1.0
    assert reproduce.job_share(101.0, 1, 4) == pytest.approx(1.0 + 100.0 / 4)
    assert reproduce.job_share(101.0, 4, 4) == pytest.approx(101.0)
    assert reproduce.job_share(1.0, 3, 4) == pytest.approx(1.0)


def test_every_estimated_experiments_jobs_are_counted_past_one_without_an_estimate():
    """1 s to start each job, the rest shared by its seeds: 4 seeds in 2 groups of 2."""
    from trl_dgpq.collectors.experiment import resolve_config
    planned = {name: resolve_config(env="square", agent="random", seeds=[0, 1, 2, 3], episodes=2)
               for name in ("x", "a")}
    found = [("x", None, "no published experiment like it"), ("a", 101.0, "like")]
    assert reproduce.job_seconds(planned, found, {"a": 2}) == pytest.approx([51.0, 51.0])
    assert reproduce.job_seconds(planned, found, {}) == pytest.approx([101.0])


@pytest.mark.parametrize("seconds, text", [(59.9, "1.0 min"), (3599.0, "60.0 min"), (3600.0, "1.00 h"),
                                           (5400.0, "1.50 h"), (1e7, "2,777.78 h")])
def test_hours(seconds, text):
    assert reproduce.hours(seconds) == text


def test_minutes_a_flag_takes_are_positive_and_finite():
    assert reproduce.positive_minutes("2.5") == 2.5 and reproduce.positive_minutes("1e-3") == 0.001
    for text in ("0", "-1", "inf", "nan"):
        with pytest.raises(argparse.ArgumentTypeError) as err:
            reproduce.positive_minutes(text)
        assert str(err.value) == f"must be a number of minutes > 0, got {text!r}"
    with pytest.raises(ValueError):
        reproduce.positive_minutes("soon")


@pytest.mark.parametrize("error", [ValueError, OSError, KeyError, TypeError, AttributeError])
def test_a_folder_that_cannot_be_read_leaves_the_job_to_its_estimate(monkeypatch, error):
    job = SimpleNamespace(folder="f", config={"run": {"episodes": 3}})

    def fails(folder, run):
        assert (folder, run) == ("f", {"episodes": 3})
        raise error("damaged")
    monkeypatch.setattr(reproduce, "seconds_left", fails)
    assert reproduce.readable_time_left(job) is None
    monkeypatch.setattr(reproduce, "seconds_left", lambda folder, run: 12.5)
    assert reproduce.readable_time_left(job) == 12.5
    monkeypatch.setattr(reproduce, "seconds_left", lambda folder, run: 1 / 0)
    with pytest.raises(ZeroDivisionError):                                    # a bug is not swallowed
        reproduce.readable_time_left(job)


def test_an_experiment_has_finished_once_its_rows_are_merged(tmp_path):
    assert not reproduce.finished(tmp_path, "e")
    (tmp_path / "e").mkdir()
    assert not reproduce.finished(tmp_path, "e")
    (tmp_path / "e" / "episodes.csv").write_text("seed\n")
    assert reproduce.finished(tmp_path, "e")


def test_a_part_that_does_not_exist_is_refused_naming_the_parts():
    parts = ", ".join(part.name for part, _ in reproduce.reproductions())
    with pytest.raises(ValueError) as err:
        reproduce.plan_settings("quick", ["square", "sqare", "cube"])
    assert str(err.value) == f"no part named cube, sqare; the parts: {parts}"
    assert "square-shaped" in reproduce.plan_settings("smoke", ["square"])
