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
def one_torch_thread():
    """Every test starts at one torch thread, the runs' default (``--threads``). Tests that build
    learners themselves would otherwise get torch's default (one per core), and on a loaded
    machine every small op then waits for a second thread: measured here at load 3, a max over 8
    numbers took 430 us at 2 threads and 18 us at 1, and DQN's schedule test 13 s."""
    torch.set_num_threads(1)


@pytest.fixture(autouse=True)
def fewer_bootstraps(request, monkeypatch):
    """2,000 bootstrap replications cost a few ms per interval (~0.2 s through rliable's own loop,
    before analysis/stats.py drew them all at once) and a report draws hundreds: outside
    tests/test_stats.py, which checks the intervals at the suite's REPS, tests check what a report
    says and writes, so 200 do (a test marked ``full_bootstraps`` compares with a committed report's
    intervals: it draws the suite's REPS)."""
    if request.module.__name__ != "test_stats" and "full_bootstraps" not in request.keywords:
        from trl_dgpq.analysis import stats
        monkeypatch.setattr(stats, "REPS", 200)


@pytest.fixture(autouse=True)
def script_entry(monkeypatch):
    """Every test's commands name themselves as scripts (python scripts/X.py): a test that runs
    ``trl-dgpq X`` sets the module's ENTRY for the process, and later tests' messages must not
    depend on which tests ran before them."""
    import trl_dgpq.commands
    monkeypatch.setattr(trl_dgpq.commands, "ENTRY", None)


@pytest.fixture(autouse=True)
def log_levels_put_back():
    """Commands quiet Optuna's and TorchRL's loggers for their own lines; each test's are put back
    after it, so what a later test's libraries print does not depend on which tests ran before."""
    import logging

    import optuna
    verbosity, torchrl = optuna.logging.get_verbosity(), logging.getLogger("torchrl").level
    yield
    optuna.logging.set_verbosity(verbosity)
    logging.getLogger("torchrl").setLevel(torchrl)


@pytest.fixture
def own_tuned_file(tmp_path, monkeypatch):
    """Presets read and written in a tuned.json of the test's own (tmp_path), never the checkout's."""
    from trl_dgpq import presets
    path = tmp_path / "tuned.json"
    monkeypatch.setattr(presets, "tuned_file", lambda env: path)
    return path


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


class SavedFigures(dict):
    """{file name: Figure} of the matplotlib figures a test saved (``saved_figures``)."""

    def problems(self, name: str) -> list:
        """What a reader would trip on in figure ``name``: a title missing or cut at the image's
        edge, a log axis with fewer than three labels, an episode axis ticked between episodes,
        a line's point outside its axes' limits (or at or below zero on a log axis), two labelled
        lines of one axes drawn alike (the same colour and line style)."""
        import math

        import matplotlib.colors
        fig, found = self[name], []
        fig.canvas.draw()
        box = fig.bbox
        titles = [t for t in [fig._suptitle, *(ax.title for ax in fig.axes)] if t is not None and t.get_text()]
        if not titles:
            found.append("no title")
        for t in titles:
            e = t.get_window_extent()
            if e.x0 < box.x0 - 1 or e.x1 > box.x1 + 1 or e.y0 < box.y0 - 1 or e.y1 > box.y1 + 1:
                found.append(f"title {t.get_text()!r} cut at the edge")
        for ax in fig.axes:
            looks = {}
            for line in ax.get_lines():
                if not line.get_label().startswith("_"):
                    looks.setdefault((matplotlib.colors.to_hex(line.get_color()), line.get_linestyle()), []).append(
                        line.get_label())
            found += [f"{labels} drawn alike" for labels in looks.values() if len(labels) > 1]
            for axis, (lo, hi) in (("x", sorted(ax.get_xlim())), ("y", sorted(ax.get_ylim()))):
                which = getattr(ax, f"{axis}axis")
                shown = [(loc, lab.get_text()) for loc, lab in zip(which.get_majorticklocs(), which.get_majorticklabels())
                         if lo <= loc <= hi and lab.get_text()]
                if which.get_scale() == "log" and len(shown) < 3:
                    found.append(f"log {axis} axis labelled {[s for _, s in shown]}")
                if axis == "x" and ax.get_xlabel().startswith("episode") and any(
                        not float(loc).is_integer() for loc, _ in shown):
                    found.append(f"episode ticks {[s for _, s in shown]}")
                for line in ax.get_lines():
                    data = [v for v in np.asarray(getattr(line, f"get_{axis}data")(), dtype=float) if math.isfinite(v)]
                    if line.get_transform() != ax.transData or not data:
                        continue  # axhline and the like: drawn in axes coordinates on one side
                    if min(data) < lo or max(data) > hi or (which.get_scale() == "log" and min(data) <= 0):
                        found.append(f"{line.get_label()!r} leaves the {axis} axis [{lo:g}, {hi:g}]: "
                                     f"{min(data):g}..{max(data):g}")
        return found


@pytest.fixture
def saved_figures(monkeypatch):
    """Every matplotlib figure saved during the test, by file name (closing a figure only ends
    pyplot's hold on it: its titles, ticks and lines stay there to inspect)."""
    from pathlib import Path

    import matplotlib.figure
    saved, savefig = SavedFigures(), matplotlib.figure.Figure.savefig

    def record(self, fname, *args, **kwargs):
        saved[Path(fname).name] = self
        return savefig(self, fname, *args, **kwargs)
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", record)
    return saved


@pytest.fixture
def drawn(monkeypatch):
    """{file name: (figure, title)} of what the figures hand to ``save``, which is stubbed: no PNG is
    drawn (the slow part; ``saved_figures`` keeps the drawn ones), the figure is closed and its
    axes, lines and texts stay there to read."""
    from pathlib import Path

    import matplotlib.pyplot as plt

    from trl_dgpq.analysis import figures
    got = {}

    def save(fig, path, title=""):
        got[Path(path).name] = (fig, title)
        plt.close(fig)
        return path
    monkeypatch.setattr(figures, "save", save)
    return got
