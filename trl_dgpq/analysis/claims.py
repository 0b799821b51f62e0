"""Claims of the papers and what the reproduction measured: REPORT.md's first table.

Each domain with a reproduction may give ``claims(runs)`` in its ``analysis.py``: a list of
``Claim`` (whose claim, its substance with its number, ours beside it, and a verdict from
``VERDICTS``), which its section lists as bullets and ``reproduce`` gathers into one table,
so a reader sees at once what reproduces and what does not.
"""
from __future__ import annotations

from dataclasses import dataclass

VERDICTS = ("reproduced", "partly", "not reproduced", "no number to compare", "not measured")


@dataclass(frozen=True)
class Claim:
    source: str    # whose: "GWH14", "seed report", "AC00", "this suite"
    claim: str     # its substance, with the number it gave
    ours: str      # what we measured, with its number
    verdict: str   # one of VERDICTS

    def __post_init__(self):
        if self.verdict not in VERDICTS:
            raise ValueError(f"a claim's verdict is one of {VERDICTS}, got {self.verdict!r}")

    def bullet(self) -> str:
        return f"- {self.source}: {self.claim}. Ours: {self.ours} -- **{self.verdict}**."


def within(ours: float, theirs: float, factor: float) -> str:
    """"reproduced" if ``ours`` is within ``factor`` times ``theirs`` either way (of either sign:
    -60 is within 1.5x of -47, -80 is not)."""
    low, high = sorted((theirs / factor, theirs * factor))
    return "reproduced" if low <= ours <= high else "not reproduced"


def table(claims) -> str:
    """The markdown table of ``claims`` and a count per verdict."""
    cell = lambda text: text.replace("|", "\\|")  # noqa: E731
    rows = ["| source | claim | ours | verdict |", "|---|---|---|---|"]
    rows += [f"| {c.source} | {cell(c.claim)} | {cell(c.ours)} | {c.verdict} |" for c in claims]
    counts = [f"{sum(c.verdict == v for c in claims)} {v}" for v in VERDICTS if any(c.verdict == v for c in claims)]
    return "\n".join(rows) + "\n\n" + ", ".join(counts) + "."
