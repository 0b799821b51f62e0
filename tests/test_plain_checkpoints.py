"""Checkpoints hold plain data only: a crafted checkpoint.pt cannot run code on --resume or
evaluate (issue 21, item 1)."""
import pickle

import numpy as np
import pytest
import torch

from trl_dgpq.collectors.evaluate import evaluate
from trl_dgpq.collectors.runner import RunError
from trl_dgpq.commands import train
from trl_dgpq.envs.gym.env import from_plain, to_plain


class Planted:
    """Unpickling it creates a file: the proof that code ran."""

    def __init__(self, path):
        self.path = path

    def __reduce__(self):
        return (open, (str(self.path), "w"))


def cartpole_run(tmp_path):
    out = tmp_path / "run"
    assert train.main(["--env", "gym:CartPole-v1", "--agent", "random", "--seeds", "2", "--episodes", "2",
                       "--out", str(out), "--no-progress"]) == 0
    return out


@pytest.mark.parametrize("where", ["env state", "whole file"])
def test_a_planted_pickle_is_refused_by_resume_and_evaluate_without_running(where, tmp_path, capsys):
    out = cartpole_run(tmp_path)
    marker = tmp_path / "code-ran"
    path = out / "checkpoint.pt"
    state = torch.load(path, weights_only=True)
    if where == "env state":  # the old format's bytes, now with a payload
        state["env"]["gym"] = [pickle.dumps(Planted(marker))] * 2
        torch.save(state, path)
    else:                     # an object anywhere in the file
        torch.save({**state, "extra": Planted(marker)}, path)
    (out / "status.json").write_text('{"status": "interrupted"}')
    assert not (out / "checkpoint.prev.pt").exists()  # one checkpoint: nothing to fall back to
    if where == "whole file":  # refused unread
        with pytest.raises(SystemExit) as stop:
            train.main(["--resume", str(out), "--no-progress"])
        err = capsys.readouterr().err
        assert stop.value.code == 2 and "cannot read" in err and "more than plain data" in err
        assert "weights_only" not in err  # torch's advice would run the file's code
        with pytest.raises(RunError, match="cannot read"):
            evaluate(out)
    else:
        with pytest.raises(SystemExit) as stop:
            train.main(["--resume", str(out), "--no-progress"])
        assert stop.value.code == 2 and "error:" in capsys.readouterr().err
        evaluate(out, episodes=1)   # evaluation never reads the training env's state
    assert not marker.exists()


def test_plain_data_round_trips_exactly():
    g = np.random.default_rng(7)
    g.random(3)
    value = {"state": np.array([0.1, -2.0], dtype=np.float32), "t": (1, 2.5, None, "s", np.int64(4)),
             "rng": g, 3: [np.bool_(True), np.array([[b"S", b"F"]])]}
    plain = to_plain(value)
    back = from_plain(plain)
    assert back["state"].dtype == np.float32 and np.array_equal(back["state"], value["state"])
    assert back["t"] == value["t"] and type(back["t"][4]) is np.int64
    assert back["rng"].random() == g.random()                 # the same stream from here on
    assert back[3][0] is np.True_ and back[3][1].tolist() == [[b"S", b"F"]]
    with pytest.raises(ValueError, match="plain data"):
        to_plain(object())
    with pytest.raises(ValueError, match="bit generator"):
        from_plain({"generator": {"bit_generator": "os.system"}})
