"""Signals outside a run: SIGINT / SIGTERM stop a study's process, never in the middle of writing
a trial's records (``held``); inside a run the runner checkpoints first."""
from __future__ import annotations

import signal
from contextlib import contextmanager


class Stopped(Exception):
    """SIGINT or SIGTERM arrived outside a run (inside one, the runner checkpoints first)."""

    def __init__(self, signum: int):
        self.signum = signum
        super().__init__(f"interrupted by {signal.Signals(signum).name}")


@contextmanager
def stop_on_signals():
    """SIGINT / SIGTERM raise Stopped: the first one, at once unless ``held``; later ones are
    ignored while stopping. Yields the state, whose "signum" a caller sets when the runner
    caught the signal instead (a run checkpoints before it stops)."""
    state = {"signum": None, "held": False}

    def handler(signum, frame):
        if state["signum"] is None:
            state["signum"] = signum
            if not state["held"]:
                raise Stopped(signum)
    previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield state
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


@contextmanager
def held(stop: dict):
    """A signal waits for the end of the block (the study's records of a trial are written whole:
    a trial asked for is always marked with its process), then raises Stopped."""
    stop["held"] = True
    try:
        yield
    finally:
        stop["held"] = False
    if stop["signum"] is not None:
        raise Stopped(stop["signum"])
