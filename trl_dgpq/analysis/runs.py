"""Loading runs: a run folder (``train.py --out``) or a sweep's experiment folder (its
merged ``episodes.csv``, the config of its first job)."""
from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Optional

import pandas as pd


class UnreadableCSV(ValueError):
    """A run's CSV that cannot be parsed (cut, corrupted): one line naming the file."""


def read_csv_exact(path, columns=None) -> pd.DataFrame:
    """read_csv that gives back exactly the floats written (pandas >= 3 does by default;
    older pandas needs the round-trip parser). Every command reads runs through it, so a
    file that cannot be parsed is named here (pandas' message names only a line).
    ``columns``: only those of them the file has, the others not parsed -- nor counted, so a row with
    a field too many then passes (for a few columns of a file checked whole elsewhere: the
    published data, rebuilt and compared by the tests)."""
    if isinstance(columns, str):
        raise TypeError(f"columns must be a collection of names, got the text {columns!r}")
    exact = {} if int(pd.__version__.split(".")[0]) >= 3 else {"float_precision": "round_trip"}
    if str(path).endswith(".csv") and ends_mid_row(path):
        raise UnreadableCSV(f"cannot read {path}: it ends mid-row (the run was stopped while writing it, or the "
                            "file was cut); resume the run (train --resume) to cut it back to its last checkpoint")
    try:
        if columns is not None:
            exact["usecols"] = set(columns).__contains__
        return pd.read_csv(path, **exact)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as err:
        raise UnreadableCSV(f"cannot read {path}: {str(err).strip().splitlines()[0]}") from None


def ends_mid_row(path) -> bool:
    """Whether a CSV's last byte is not a line end: every row the runner writes ends with one, so a
    file that does not was cut in the middle of a row (its last row, parsed, could pass for another:
    ``3,1`` of ``3,12,...``)."""
    with open(path, "rb") as f:
        f.seek(0, 2)
        if f.tell() == 0:
            return False
        f.seek(-1, 2)
        return f.read(1) != b"\n"


@dataclass
class Run:
    """A finished run's episodes (sorted by seed and episode, with each seed's cumulative
    ``env_steps``) and its config."""
    path: Path
    df: pd.DataFrame
    config: Optional[dict]  # None for a folder without config.json (load_run(..., need_config=False))

    @property
    def env(self) -> str:
        return self.config["run"]["env"]

    @property
    def agent(self) -> str:
        return self.config["run"]["agent"]

    @property
    def preset(self) -> str:
        return self.config["run"]["preset"]

    @property
    def gamma(self):
        """The agent's discount (None for agents without one, e.g. schedules)."""
        return self.config["agent"].get("gamma")

    @cached_property
    def domain(self):
        """The run's ``Domain`` (None without a config)."""
        from trl_dgpq.envs import domain
        return None if self.config is None else domain(self.env)

    def measure(self):
        """(column, label) of the domain's measure; ValueError (one line) if episodes.csv lacks
        the column (a run made before the env recorded it)."""
        column, label = self.domain.measure(self.env_id)
        self.need(column)
        return column, label

    def need(self, column: str) -> None:
        if column not in self.df:
            raise ValueError(f"{self.path}: episodes.csv has no {column!r} column, what {self.env} runs are "
                             "measured by (a run made before its env recorded it): run it again")

    @property
    def env_id(self):
        from trl_dgpq.envs import split_name
        return split_name(self.env)[1]


def load_run(folder, need_config: bool = True) -> Run:
    """The run in ``folder`` (finished or not); ValueError (one line) if it holds none.
    Without ``need_config``, episodes.csv alone will do (``Run.config`` is then None)."""
    folder = Path(folder)
    configs = [folder / "config.json"] + sorted((folder / "jobs").glob("*/config.json"))
    config = next((c for c in configs if c.exists()), None)
    if not (folder / "episodes.csv").exists() or (config is None and need_config):
        raise ValueError(f"{folder} is not a run folder (needs episodes.csv and a config.json)")
    df = read_csv_exact(folder / "episodes.csv").sort_values(["seed", "episode"], kind="stable")
    df["env_steps"] = df.groupby("seed")["steps"].cumsum()
    return Run(folder, df.reset_index(drop=True), None if config is None else json.loads(config.read_text()))
