import io
import os
import random
import signal

import numpy as np
import pytest
import torch

from trl_dgpq.collectors import runner


@pytest.fixture(autouse=True)
def seeded_global_generators():
    """Every test starts torch's, numpy's and Python's global generators from one seed: a test that
    draws from them (random test data, a library that samples) fails or passes the same way every
    run, never by chance (one such test caught its bug about 7 times in 40)."""
    torch.manual_seed(20141332)
    np.random.seed(20141332)
    random.seed(20141332)


@pytest.fixture(autouse=True)
def script_entry(monkeypatch):
    """Every test's commands name themselves as scripts (python scripts/X.py): a test that runs
    ``trl-dgpq X`` sets the module's ENTRY for the process, and later tests' messages must not
    depend on which tests ran before them."""
    import trl_dgpq.commands
    monkeypatch.setattr(trl_dgpq.commands, "ENTRY", None)


def through_disk(state):
    """What a checkpoint does to a state: torch.save, then torch.load(weights_only=True)."""
    buf = io.BytesIO()
    torch.save(state, buf)
    buf.seek(0)
    return torch.load(buf, weights_only=True)


@pytest.fixture
def stop_run_after(monkeypatch):
    """``stop_run_after(n, how)``: the next run stops right after its n-th batch of rows is on
    disk, by SIGINT ("signal") or by an exception ("crash"); later batches pass untouched."""
    def arm(batches: int, how: str = "signal"):
        calls, append = [0], runner.RunFolder.append_rows

        def append_then_stop(self, rows):
            size = append(self, rows)
            calls[0] += 1
            if calls[0] == batches:
                if how == "signal":
                    os.kill(os.getpid(), signal.SIGINT)
                else:
                    raise RuntimeError("simulated crash")
            return size
        monkeypatch.setattr(runner.RunFolder, "append_rows", append_then_stop)
    return arm
