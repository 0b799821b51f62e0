"""analysis/runs.py by hand: a run's CSV read back exactly or refused in one line, a folder loaded
with its seeds' cumulative steps, and what a Run says of itself."""
import io
import json

import pandas as pd
import pytest

from trl_dgpq.analysis.runs import Run, UnreadableCSV, ends_mid_row, load_run, read_csv_exact

ROWS = "seed,episode,steps,return,wall_s\n1,2,5,0.1,0.5\n0,1,3,-0.30000000000000004,1e-3\n1,1,4,2.5,0.25\n0,2,2,1,2\n"


def test_floats_come_back_exactly_and_columns_can_be_left_unparsed(tmp_path):
    path = tmp_path / "e.csv"
    path.write_text(ROWS)
    df = read_csv_exact(path)
    assert list(df.columns) == ["seed", "episode", "steps", "return", "wall_s"]
    assert df["return"].tolist()[1] == -0.30000000000000004 and df["return"].tolist()[1] != -0.3
    only = read_csv_exact(path, columns=("seed", "return", "absent"))
    assert list(only.columns) == ["seed", "return"] and only["return"].tolist()[1] == -0.30000000000000004
    with pytest.raises(TypeError, match="got the text 'seed'"):
        read_csv_exact(path, columns="seed")
    ragged = tmp_path / "ragged.csv"
    ragged.write_text(ROWS + "1,3,1,0.5,0.5,9\n")
    with pytest.raises(UnreadableCSV):
        read_csv_exact(ragged)
    assert len(read_csv_exact(ragged, columns=("seed",))) == 5        # as its docstring says: not counted


def test_a_file_cut_mid_row_or_unparseable_is_refused_naming_it(tmp_path):
    cut = tmp_path / "cut.csv"
    cut.write_text(ROWS[:-3])
    whole = tmp_path / "whole.csv"
    whole.write_text(ROWS)
    assert ends_mid_row(cut) and not ends_mid_row(whole)
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    assert not ends_mid_row(empty)
    with pytest.raises(UnreadableCSV) as err:
        read_csv_exact(cut)
    assert str(err.value) == (f"cannot read {cut}: it ends mid-row (the run was stopped while writing it, or the file "
                              "was cut); resume the run (train --resume) to cut it back to its last checkpoint")
    with pytest.raises(UnreadableCSV) as err:
        read_csv_exact(empty)
    assert str(err.value) == f"cannot read {empty}: No columns to parse from file"
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n3,4,5\n")
    with pytest.raises(UnreadableCSV) as err:
        read_csv_exact(bad)
    assert str(err.value).startswith(f"cannot read {bad}: Error tokenizing data") and "\n" not in str(err.value)
    binary = tmp_path / "binary.csv"
    binary.write_bytes(b"a,b\n\xff\xfe,1\n")
    with pytest.raises(UnreadableCSV, match=f"^cannot read {binary}: "):
        read_csv_exact(binary)


def test_a_compressed_file_is_not_checked_for_a_cut_row(tmp_path):
    path = tmp_path / "e.csv.xz"
    pd.read_csv(io.StringIO(ROWS)).to_csv(path, index=False)
    assert read_csv_exact(path)["steps"].tolist() == [5, 3, 4, 2]


def config(env="square", agent="dgpq", **agent_settings):
    return {"run": {"env": env, "agent": agent, "preset": "shaped"}, "env": {}, "agent": agent_settings}


def test_a_folder_loads_sorted_with_each_seeds_cumulative_steps(tmp_path):
    (tmp_path / "episodes.csv").write_text(ROWS)
    (tmp_path / "config.json").write_text(json.dumps(config(gamma=0.9)))
    run = load_run(tmp_path)
    assert run.df[["seed", "episode"]].values.tolist() == [[0, 1], [0, 2], [1, 1], [1, 2]]
    assert run.df["env_steps"].tolist() == [3, 5, 4, 9] and run.df.index.tolist() == [0, 1, 2, 3]
    assert list(run.df.columns) == ["seed", "episode", "steps", "return", "wall_s", "env_steps"]
    assert (run.path, run.env, run.agent, run.preset, run.gamma, run.env_id) == (tmp_path, "square", "dgpq",
                                                                                 "shaped", 0.9, None)
    assert run.domain.name == "square" and run.measure() == run.domain.measure(None)


def test_a_sweeps_experiment_takes_its_first_jobs_config_and_a_bare_csv_none(tmp_path):
    (tmp_path / "episodes.csv").write_text(ROWS)
    for job, agent in (("j001", "dqn"), ("j000", "random")):
        (tmp_path / "jobs" / job).mkdir(parents=True)
        (tmp_path / "jobs" / job / "config.json").write_text(json.dumps(config(agent=agent)))
    assert load_run(tmp_path).agent == "random"
    (tmp_path / "config.json").write_text(json.dumps(config(agent="dgpq")))
    assert load_run(tmp_path).agent == "dgpq"                       # the folder's own first
    bare = tmp_path / "bare"
    bare.mkdir()
    (bare / "episodes.csv").write_text(ROWS)
    with pytest.raises(ValueError) as err:
        load_run(bare)
    assert str(err.value) == f"{bare} is not a run folder (needs episodes.csv and a config.json)"
    run = load_run(bare, need_config=False)
    assert run.config is None and run.domain is None and len(run.df) == 4
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "config.json").write_text(json.dumps(config()))
    with pytest.raises(ValueError, match="is not a run folder"):
        load_run(empty, need_config=False)


def test_a_run_without_its_measure_or_a_gamma_says_so(tmp_path):
    run = Run(tmp_path, pd.DataFrame({"seed": [0], "return": [1.0]}), config(env="gym:CartPole-v1"))
    assert run.env_id == "CartPole-v1" and run.gamma is None
    run.need("return")
    with pytest.raises(ValueError) as err:
        run.need("ac_cost")
    assert str(err.value) == (f"{tmp_path}: episodes.csv has no 'ac_cost' column, what gym:CartPole-v1 runs are "
                              "measured by (a run made before its env recorded it): run it again")
    liquidation = Run(tmp_path, pd.DataFrame({"seed": [0], "return": [1.0]}), config(env="liquidation"))
    column, _ = liquidation.domain.measure(None)
    assert column != "return"
    with pytest.raises(ValueError, match=f"has no '{column}' column, what liquidation runs"):
        liquidation.measure()
