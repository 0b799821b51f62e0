"""A study (``trl-dgpq tune``): Optuna trials of one agent on one env, every trial an ordinary
run with the same budget, seeds and settings but for the agent's ``SEARCH_SPACE``.

    DIR/study.db        Optuna's storage, sqlite:///DIR/study.db (or any URL given instead)
    DIR/study.lock      held while a process on this machine picks its next trial
    DIR/trials/NNNN/    trial NNNN's run folder; once it has ended, only config.json,
                        status.json and episodes.csv (its checkpoints are what resume needs)
    DIR/validation/NNNN/  trial NNNN run again on the validation seeds (``validate``)

A trial runs in stages (``stages``: fractions of the budget), lengthened between them with
the runner's exact ``lengthen``, so after the last it is the run asked for that budget from
the start. After each stage it reports the objective of what it has run so far (the rows a
run of that length has: ``analysis.objective.stage``) and MedianPruner may stop it there.

A trial whose process stops (Ctrl-C, SIGTERM, a crash, kill -9) is marked failed and its
parameters enqueued again, marked ``retry_of``: the trial that takes them renames the old
trial's folder to its own and goes on from its checkpoint (``runner.resume``), so nothing
run is lost. A stopped process does this itself; a killed one's trials are found by the
next process on the same machine that picks a trial (their pid is gone). Trials count
towards ``trials`` once ended: complete, pruned or failed in their own code (an exception,
recorded as ``error``), not those handed on to a retry.
"""
from .config import (DEFAULT_SEEDS, DEFAULT_VALIDATION_SEEDS, HOST, KEEP, UNMARKED_S, TuneConfig, plain, shown,
                     stage_lengths)
from .signals import Stopped, held, stop_on_signals
from .storage import open_storage, portable, quiet_optuna, storage_url
from .study import Study, work, worker

__all__ = ["TuneConfig", "Study", "Stopped", "stop_on_signals", "held", "stage_lengths", "storage_url", "work",
           "worker", "portable", "open_storage", "quiet_optuna", "plain", "shown", "DEFAULT_SEEDS",
           "DEFAULT_VALIDATION_SEEDS", "HOST", "KEEP", "UNMARKED_S"]
