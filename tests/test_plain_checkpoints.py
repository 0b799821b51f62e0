"""Checkpoints hold plain data only: a crafted checkpoint.pt cannot run code on --resume or
evaluate (issue 21, item 1)."""
import pickle

import pytest
import torch

from trl_dgpq.collectors.evaluate import evaluate
from trl_dgpq.collectors.runner import RunError
from trl_dgpq.commands import train


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
