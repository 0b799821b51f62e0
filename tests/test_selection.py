"""trl_dgpq/selection.py: seeds that chose a preset (a study's tuning and validation seeds) are
never reported on; reporting seeds are 0-99 and studies never touch them. Checked here on every
committed preset, result, reproduction experiment and sweep file, and in report and tune."""
import csv
import json
from pathlib import Path

import pytest

from tests.test_report import fake_run
from trl_dgpq import presets
from trl_dgpq.collectors.experiment import parse_seeds, resolve_config
from trl_dgpq.collectors.sweep import read_sweep_file
from trl_dgpq.commands import report, reproduce, tune
from trl_dgpq.envs import domains
from trl_dgpq.selection import (REPORTING, SelectionSeedsError, check_reportable, check_selection_seeds,
                                selection_seeds)

ROOT = Path(__file__).resolve().parent.parent


def run_config(env="liquidation", agent="dgpq", preset="flat", seeds=range(10)) -> dict:
    return {"run": {"env": env, "agent": agent, "preset": preset, "seeds": list(seeds)}}


# ---------------------------------------------------------------- which seeds chose a preset
def test_selection_seeds_of_a_study_preset_and_a_hand_set_one():
    assert selection_seeds("liquidation", "dgpq", "flat") == {"tuning": [1000, 1001],
                                                              "validation": [2000, 2001, 2002, 2003]}
    assert selection_seeds("gym:CartPole-v1", "dqn", "tuned") == {"tuning": list(range(1000, 1005)),
                                                                  "validation": list(range(1005, 1015))}
    # hand-set (envs/liquidation/presets.py): nothing chose it
    assert selection_seeds("liquidation", "dgpq", "shortfall") == {"tuning": [], "validation": []}
    # the same name as a study's preset of another agent or env does not count
    assert selection_seeds("square", "dgpq", "flat") == {"tuning": [], "validation": []}


def test_a_preset_built_on_another_study_preset_counts_its_seeds_too(monkeypatch):
    """'b' was tuned on top of 'a' (its base_preset): the seeds that chose 'a' chose 'b' as well;
    a base that is hand-set adds none, and a loop of bases ends."""
    entries = {"dgpq": {
        "a": {"preset": {}, "provenance": {"seeds": [1500, 1501], "validation": {"seeds": [1600]},
                                           "base_preset": "shaped"}},
        "b": {"preset": {}, "provenance": {"seeds": [1700], "base_preset": "a"}},
        "x": {"preset": {}, "provenance": {"seeds": [1800], "base_preset": "y"}},
        "y": {"preset": {}, "provenance": {"seeds": [1900], "base_preset": "x"}}}}
    monkeypatch.setattr(presets, "tuned_entries", lambda env: entries)
    assert selection_seeds("square", "dgpq", "b") == {"tuning": [1500, 1501, 1700], "validation": [1600]}
    assert selection_seeds("square", "dgpq", "a") == {"tuning": [1500, 1501], "validation": [1600]}
    assert selection_seeds("square", "dgpq", "x") == {"tuning": [1800, 1900], "validation": []}
    with pytest.raises(SelectionSeedsError, match=r"1600 \(validation\)"):
        check_reportable(run_config("square", "dgpq", "b", [3, 1600]))


# ---------------------------------------------------------------- check_reportable
def test_a_run_on_its_presets_tuning_seeds_is_refused_in_one_line():
    with pytest.raises(SelectionSeedsError) as err:
        check_reportable(run_config(seeds=[0, 1, 1000, 1001]), "liq-flat")
    text = str(err.value)
    assert isinstance(err.value, ValueError) and len(text.splitlines()) == 1
    assert text.startswith("liq-flat (dgpq on liquidation, preset 'flat')") and "1000-1001 (tuning)" in text
    assert "validation" not in text


def test_a_run_on_its_presets_validation_seeds_is_refused():
    with pytest.raises(SelectionSeedsError) as err:
        check_reportable(run_config(seeds=[5, 2002]))
    assert "2002 (validation)" in str(err.value) and "(tuning)" not in str(err.value)
    # both roles named at once
    with pytest.raises(SelectionSeedsError, match=r"1001 \(tuning\) and 2000, 2003 \(validation\)"):
        check_reportable(run_config(seeds=[1001, 2000, 2003]))


def test_seeds_outside_0_99_are_refused_even_on_a_hand_set_preset():
    for seeds in ([5, 100], [150], "100-104"):
        with pytest.raises(SelectionSeedsError, match="reporting seeds are 0-99"):
            check_reportable(run_config(preset="shortfall", seeds=parse_seeds(seeds)))
    config = run_config(preset="shortfall")
    config["run"]["seeds"] = "98-100"   # a seeds text, as --seeds reads it
    with pytest.raises(SelectionSeedsError, match="seed 100 outside the reporting seeds"):
        check_reportable(config)


def test_reporting_seeds_pass_on_a_tuned_and_a_hand_set_preset():
    check_reportable(run_config(seeds=range(10)))
    check_reportable(run_config(seeds=[99]))
    check_reportable(run_config(preset="shortfall", seeds=REPORTING))
    check_reportable(resolve_config(env="gym:CartPole-v1", agent="dgpq", preset="tuned", seeds="0-9"))


def test_check_selection_seeds_refuses_reporting_seeds():
    for seeds in ([0], [99, 1000], range(0, 200)):
        with pytest.raises(ValueError, match="studies and validations never touch the reporting seeds 0-99"):
            check_selection_seeds(seeds, "tuning seeds")
    check_selection_seeds([100, 1000, 2003], "validation seeds")


# ---------------------------------------------------------------- every committed thing
def test_committed_presets_were_never_chosen_on_reporting_seeds():
    """Every study preset in an envs/<domain>/tuned.json was tuned and validated outside 0-99."""
    seen = 0
    for path in sorted(ROOT.glob("envs/*/tuned.json")):
        for env, agents in json.loads(path.read_text()).items():
            for agent, entries in agents.items():
                for name in entries:
                    chosen = selection_seeds(env, agent, name)
                    assert chosen["tuning"], f"{path}: {env} {agent} {name} has no tuning seeds"
                    for role, seeds in chosen.items():
                        check_selection_seeds(seeds, f"{path}: {env} {agent} {name}: {role} seeds")
                    seen += 1
    assert seen >= 20


def committed_results() -> list:
    rows = []
    for path in sorted((ROOT / "results").glob("**/results.csv")):
        with open(path, newline="") as f:
            rows += [(path.relative_to(ROOT), row) for row in csv.DictReader(f)]
    return rows


def test_every_committed_result_is_on_reportable_seeds():
    rows = committed_results()
    assert rows      # the publication has rows to check
    for path, row in rows:
        config = run_config(row["env"], row["agent"], row["preset"], parse_seeds(row["seeds"]))
        check_reportable(config, f"{path}: {row['experiment']}", publication=True)


@pytest.mark.parametrize("scale", reproduce.SCALES)
def test_every_reproduction_experiment_is_on_reportable_seeds(scale):
    planned = reproduce.experiments(scale)
    assert planned
    for name, config in planned.items():
        check_reportable(config, f"reproduce --scale {scale}: {name}", publication=True)


BENCHMARKS = ("smoke.toml", "throughput-liquidation.toml", "throughput-square.toml")   # timed, never reported


@pytest.mark.parametrize("path", [p for p in sorted((ROOT / "configs").glob("*.toml")) if p.name not in BENCHMARKS],
                         ids=lambda p: p.name)
def test_every_sweep_file_experiment_is_on_reportable_seeds(path):
    experiments = read_sweep_file(path)
    assert experiments
    for name, config in experiments.items():
        check_reportable(config, f"{path.name}: {name}")


def test_a_committed_style_config_on_tuned_seeds_would_be_caught(tmp_path):
    """The sweep-file check above can fail: the same file on a tuned preset's tuning seeds does."""
    toml = tmp_path / "bad.toml"
    toml.write_text('[[experiment]]\nname = "cartpole-tuned"\nenv = "gym:CartPole-v1"\nagent = "dqn"\n'
                    'preset = "tuned"\nseeds = "1000-1004"\nepisodes = 1\n')
    (config,) = read_sweep_file(toml).values()
    with pytest.raises(SelectionSeedsError, match=r"1000-1004 \(tuning\)"):
        check_reportable(config)


# ---------------------------------------------------------------- tune
def test_tunes_defaults_are_outside_the_reporting_seeds_as_committed_studies_used():
    from trl_dgpq.study import DEFAULT_SEEDS, DEFAULT_VALIDATION_SEEDS
    parser = tune.make_parser()
    assert parser.get_default("validation_seeds") == DEFAULT_VALIDATION_SEEDS == "1005-1014"
    assert DEFAULT_SEEDS == "1000-1004"
    check_selection_seeds(parse_seeds(DEFAULT_SEEDS), "tuning seeds")
    check_selection_seeds(parse_seeds(DEFAULT_VALIDATION_SEEDS), "validation seeds")


@pytest.mark.parametrize("flags, said", [
    (["--seeds", "0-4"], "tuning seeds [0, 1, 2, 3, 4] are reporting seeds"),
    (["--seeds", "5"], "tuning seeds [0, 1, 2, 3, 4] are reporting seeds"),      # a count: seeds 0-4
    (["--set", "run.seeds=1000,99"], "tuning seeds [99] are reporting seeds"),
    (["--validation-seeds", "90-99"], "validation seeds [90, 91, 92, ..., 99] (10) are reporting seeds"),
    (["--validate", "2", "--validation-seeds", "1005,7"], "validation seeds [7] are reporting seeds"),
])
def test_tune_refuses_reporting_seeds_before_anything_runs(tmp_path, capsys, monkeypatch, flags, said):
    from trl_dgpq import study

    def never(*args, **kw):
        raise AssertionError("the study was opened")
    monkeypatch.setattr(study.Study, "open", never)
    out = tmp_path / "study"
    with pytest.raises(SystemExit) as exc:
        tune.main(["--env", "square", "--agent", "dgpq", "--episodes", "2", "--trials", "1", "--out", str(out),
                   *flags])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert said in err[-1] and "studies and validations never touch the reporting seeds 0-99" in err[-1]
    assert not out.exists()


# ---------------------------------------------------------------- report
def tuned_fake_run(folder, seeds, config_seeds=None):
    """A run of DQN's study preset 'tuned' on the square (tuned on 1000-1004)."""
    fake_run(folder, "square", {s: [30, 20] * 6 for s in seeds})
    config = json.loads((folder / "config.json").read_text())
    config["run"].update(preset="tuned", seeds=list(seeds if config_seeds is None else config_seeds))
    (folder / "config.json").write_text(json.dumps(config))
    return folder


def test_report_refuses_a_run_on_selection_seeds_and_unpublished_looks_at_it(tmp_path, capsys):
    assert selection_seeds("square", "dqn", "tuned")["tuning"] == [1000, 1001, 1002, 1003, 1004]
    run, out = tuned_fake_run(tmp_path / "trial", [1002, 1003]), tmp_path / "out"
    assert report.main([str(run), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "1002-1003 (tuning)" in err and "--unpublished" in err
    assert str(run) in err and not out.exists()                     # nothing written
    assert report.main([str(run), "--out", str(out), "--unpublished"]) == 0
    assert (out / "compare.md").exists()


def test_report_checks_the_seeds_in_episodes_csv_and_each_run(tmp_path, capsys):
    """A config that names reporting seeds but whose episodes.csv holds a tuning seed is refused,
    as is one bad run among good ones; a run on seeds 0-99 of the same preset is reported."""
    good = tuned_fake_run(tmp_path / "good", [0, 1])
    hidden = tuned_fake_run(tmp_path / "hidden", [0, 1004], config_seeds=[0, 1])
    far = fake_run(tmp_path / "far", "square", {0: [30] * 12, 100: [30] * 12})   # hand-set preset 'p'
    assert report.main([str(good), "--out", str(tmp_path / "a")]) == 0
    capsys.readouterr()
    assert report.main([str(good), str(hidden), "--out", str(tmp_path / "b")]) == 2
    assert "1004 (tuning)" in capsys.readouterr().err and not (tmp_path / "b").exists()
    assert report.main([str(good), str(far), "--out", str(tmp_path / "c")]) == 2
    assert "reporting seeds are 0-99" in capsys.readouterr().err and not (tmp_path / "c").exists()


def test_the_seeds_development_explored_are_never_published():
    """Seeds 0-9 chose hand-set presets and the claims' windows: a run there is refused like one on a
    study's tuning seeds, and the reproduction begins past them."""
    from trl_dgpq.collectors.experiment import resolve_config
    from trl_dgpq.selection import EXPLORED, FIRST_REPORTING
    assert FIRST_REPORTING == EXPLORED.stop == 10
    with pytest.raises(SelectionSeedsError, match=r"seeds 3, 9 were explored .* use seeds from 10 up"):
        check_reportable(resolve_config(env="square", agent="dgpq", seeds=[3, 9, 10]), publication=True)
    check_reportable(resolve_config(env="square", agent="dgpq", seeds=[10, 99]), publication=True)
    check_reportable(resolve_config(env="square", agent="dgpq", seeds=[3, 9]))      # a user's own report: fine
    firsts = {min(c["run"]["seeds"]) for c in reproduce.experiments("report").values()}
    # 30: a part whose configurations had run on 10-19 before its claims; 50: liquidation on one reward,
    # on seeds no earlier liquidation run used (its presets' studies and validations: 1000-1014)
    assert firsts == {10, 30, 50}
    assert all(max(c["run"]["seeds"]) <= 99 for c in reproduce.experiments("report").values())


def test_the_refusals_in_full():
    from trl_dgpq.collectors.experiment import resolve_config
    one = resolve_config(env="square", agent="dgpq", seeds=[3, 10])
    with pytest.raises(SelectionSeedsError) as err:
        check_reportable(one, "exp", publication=True)
    assert str(err.value) == ("exp (dgpq on square, preset 'shaped'): seed 3 was explored while the hand-set presets "
                              "and the claims were chosen, so nothing is published on them: use seeds from 10 up "
                              "(reporting seeds are 0-99, less 0-9)")
    with pytest.raises(SelectionSeedsError) as err:
        check_reportable(resolve_config(env="square", agent="dgpq", seeds=[10, 100]))
    assert str(err.value) == ("dgpq on square, preset 'shaped': seed 100 outside the reporting seeds: reporting seeds "
                              "are 0-99 (the others are for studies and validations)")
    with pytest.raises(SelectionSeedsError) as err:
        check_reportable({"run": {"env": "square", "agent": "dgpq", "preset": "shaped", "seeds": []}}, "exp")
    assert str(err.value) == "exp: its config names no seeds, so nothing says it may be reported on"
    from trl_dgpq.selection import check_selection_seeds
    with pytest.raises(ValueError) as err:
        check_selection_seeds(range(0, 7), "tuning seeds")
    assert str(err.value).startswith("tuning seeds [0, 1, 2, ..., 6] (7) are reporting seeds")
    with pytest.raises(ValueError) as err:
        check_selection_seeds(range(0, 6), "tuning seeds")
    assert str(err.value).startswith("tuning seeds [0, 1, 2, 3, 4, 5] are reporting seeds")
