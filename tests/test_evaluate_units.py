"""collectors/evaluate.py's own parts on a hand-made sweep experiment: the jobs it finds, the
episodes it accepts, and eval.csv as one table sorted by seed and episode (mutmut's survivors)."""
import json

import pandas as pd
import pytest

from trl_dgpq.collectors import runner
from trl_dgpq.collectors.evaluate import EVAL, evaluate, job_folders, jobs, restore
from trl_dgpq.collectors.experiment import resolve_config


@pytest.fixture(scope="module")
def experiment(tmp_path_factory):
    """A sweep experiment's folder: jobs/0 ran seeds 2 and 3, jobs/1 seeds 0 and 1 (the constant
    agent on the corridor: every episode takes the same steps), and jobs/2 only a config."""
    folder = tmp_path_factory.mktemp("exp")
    for name, seeds in (("0", [2, 3]), ("1", [0, 1])):
        job = runner.RunFolder.create(str(folder / "jobs" / name), "x")
        runner.start(resolve_config(env="corridor", agent="constant", seeds=seeds, episodes=2), job, progress=False)
    (folder / "jobs" / "2").mkdir()
    (folder / "jobs" / "2" / "config.json").write_text((folder / "jobs" / "0" / "config.json").read_text())
    return folder


def test_the_jobs_are_the_folders_with_a_config_and_a_checkpoint_in_order(experiment, tmp_path):
    assert job_folders(experiment) == [experiment / "jobs" / "0", experiment / "jobs" / "1"]
    assert job_folders(experiment / "jobs" / "1") == [experiment / "jobs" / "1"]      # a run folder itself
    lone = tmp_path / "lone"
    lone.mkdir()
    (lone / runner.CHECKPOINT).write_bytes(b"")                                     # a checkpoint alone is no run
    assert job_folders(lone) == []
    with pytest.raises(runner.RunError, match="holds no run with a checkpoint"):
        jobs(lone)
    with pytest.raises(runner.RunError, match="holds no checkpoint"):
        restore(experiment / "jobs" / "2")


def test_eval_csv_is_every_jobs_seeds_sorted_with_a_plain_index(experiment):
    df = evaluate(experiment, 1)
    assert df.seed.tolist() == [0, 1, 2, 3] and df.episode.tolist() == [1, 1, 1, 1]
    assert df.index.tolist() == [0, 1, 2, 3] and "index" not in df
    written = pd.read_csv(experiment / EVAL)
    assert list(written.columns) == list(df.columns)                               # no index column
    pd.testing.assert_frame_equal(written, df, check_dtype=False)
    assert json.loads((experiment / "jobs" / "0" / "status.json").read_text())["status"] == "finished"


@pytest.mark.parametrize("episodes", [0, -1, 1.5])
def test_evaluation_episodes_must_be_a_positive_integer(experiment, episodes):
    with pytest.raises(ValueError, match=f"episodes must be a positive integer, got {episodes}"):
        evaluate(experiment, episodes)


def test_evaluate_plays_ten_episodes_per_seed_quietly_by_default(experiment, capfd):
    df = evaluate(experiment)
    assert df.groupby("seed").episode.max().tolist() == [10] * 4
    assert capfd.readouterr().err == ""                       # no progress bar unless asked


def test_episode_steps_without_a_row_plays_until_every_seed_is_done():
    """The corridor of 4 cells without slip, row 0 moving right (3 steps to the goal), row 1
    left (the 5-step cap): with no row, the steps go on until both are done, row 0 staying done."""
    import torch

    from trl_dgpq.collectors.evaluate import episode_steps
    from trl_dgpq.envs.corridor.env import CorridorEnv
    env = CorridorEnv([3, 8], length=4, slip=0.0, max_steps=5)
    done = [d.tolist() for _, _, d in episode_steps(env, lambda td: torch.tensor([1, 0]), env.reset())]
    assert done == [[False, False], [False, False], [True, False], [True, False], [True, True]]
    env = CorridorEnv([3, 8], length=4, slip=0.0, max_steps=5)
    assert len(list(episode_steps(env, lambda td: torch.tensor([1, 0]), env.reset(), row=0))) == 3
