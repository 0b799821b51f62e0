"""Claims as code: each claim is declared, with its number, its rule and its direction, before
any run is judged; its verdict is computed from an interval over the runs, by one rule per kind.

A domain with a reproduction lists its claims in ``CLAIMS`` (``envs/<domain>/analysis.py``):
a ``Claim`` names whose claim it is, says it in words, measures our side as an ``Interval``
from the experiments it ``needs``, and judges that interval by its ``rule``:

- ``Agrees(value, factor)``, a source's number. Within the band [value / factor, value x factor]
  either way: **agrees** when the whole interval lies inside the band; **exceeds** (better than
  the source beyond the band -- its own verdict, never counted as agreeing) or **below** when it
  lies wholly beyond one edge; **undecided** when it straddles an edge (more seeds decide it).
  With factor 1, a closed form checked by simulation: agrees when the value lies inside the
  interval. Values cut by a step cap may be larger than recorded: their interval reaches up
  without end, and where that leaves the claim open the verdict is **capped** (a longer cap
  decides it, not more seeds).
- ``Bound(value)``, a goal of this suite or a comparison of learners (P(improvement) against
  0.5): **met** when the whole interval lies strictly on the good side, **not met** when it lies
  wholly on the other, **undecided** otherwise.
- ``NoNumber()``: the source gave none (**no number to compare**).

Where a claim names a trivial ``baseline`` (doing nothing, TWAP, a random policy), the learner's
interval must clear the baseline's, measured alike; if it does not, the verdict is **no
learning**, which no other verdict overrides. A claim is judged only at the scales that decide
it (``decided_at``); at another it says which scale does (**not judged at this scale**).

A run whose reward, potential or state uses the environment's model (``model_knowledge``) is a
documented variant: its claims carry what it uses, and the tally counts them apart, never as a
model-free claim reproduced.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Optional, Tuple

import numpy as np

AGREES, EXCEEDS, BELOW, UNDECIDED = "agrees", "exceeds", "below", "undecided"
MET, NOT_MET = "met", "not met"
NO_LEARNING, NO_NUMBER, NOT_JUDGED = "no learning", "no number to compare", "not judged at this scale"
CAPPED = "capped"   # the runs were cut (a step cap) where the claim lies: a longer cap decides it, not more seeds
VERDICTS = (AGREES, EXCEEDS, BELOW, MET, NOT_MET, UNDECIDED, CAPPED, NO_LEARNING, NO_NUMBER, NOT_JUDGED)


@dataclass(frozen=True)
class Interval:
    """Our side of a claim: a point estimate and its 95 % interval, and how they were computed
    (``statistic``, e.g. "IQM over 10 seeds [95 % CI]"). ``censored``: why the values may be larger
    than recorded (e.g. "episodes capped at 200 steps"): the interval then says only that the
    truth lies at or above its low end, and decides nothing above it."""
    point: float
    low: float
    high: float
    statistic: str
    censored: str = ""

    def __post_init__(self):
        if math.isnan(self.point) or math.isnan(self.low) or math.isnan(self.high):
            raise ValueError(f"an interval of NaN ({self.statistic}): no value to judge")
        if not (self.low <= self.point <= self.high):
            raise ValueError(f"an interval holds its point: {self.low} <= {self.point} <= {self.high}")

    @property
    def top(self) -> float:
        """The interval's upper end, or infinity where the values were cut from above."""
        return math.inf if self.censored else self.high

    def text(self, fmt: str = "{:,.4g}") -> str:
        if self.low == self.high == self.point:
            return fmt.format(self.point)
        return f"{fmt.format(self.point)} [{fmt.format(self.low)}, {fmt.format(self.high)}]"


def seeds_interval(values, what: str = "seeds") -> Interval:
    """rliable's IQM over per-seed values with its 95 % stratified bootstrap CI (NaN dropped)."""
    from .stats import iqm
    v = np.asarray(values, dtype=float)
    v = v[~np.isnan(v)]
    if not len(v):
        raise ValueError("no seed has a value in the claim's window")
    point, low, high = iqm(v)
    return Interval(point, low, high, f"IQM over {len(v)} {what} [95 % CI]")


def mean_interval(values, what: str = "seed-episodes") -> Interval:
    """The mean of many independent values (episodes of a fixed policy) with its normal 95 % CI."""
    v = np.asarray(values, dtype=float)
    v = v[~np.isnan(v)]
    if len(v) < 2:
        raise ValueError("a mean's interval needs two values or more")
    m, se = float(v.mean()), float(v.std(ddof=1) / math.sqrt(len(v)))
    return Interval(m, m - 1.96 * se, m + 1.96 * se, f"mean over {len(v):,} {what} [95 % CI]")


def share_interval(hits: int, n: int, what: str) -> Interval:
    """A share of ``n`` seeds with Wilson's 95 % interval."""
    if n < 1:
        raise ValueError("a share of no seeds")
    z, p = 1.96, hits / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return Interval(p, max(0.0, min(p, centre - half)), min(1.0, max(p, centre + half)),
                    f"share of {n} seeds {what} [Wilson 95 % CI]")


def improvement_interval(x, y, lower_is_better: bool) -> Interval:
    """rliable's P(a run of X improves on a run of Y) over per-seed values, with its 95 % CI."""
    from .stats import oriented, probability_of_improvement
    point, low, high = probability_of_improvement(oriented(x, lower_is_better), oriented(y, lower_is_better))
    return Interval(point, low, high, f"P(improvement) over {len(x)} x {len(y)} seeds [95 % CI]")


# ------------------------------------------------------------------ rules
@dataclass(frozen=True)
class Agrees:
    """A source's number, judged two-sided within ``factor`` (1: a closed form, which must lie
    inside our interval). ``higher_is_better`` says which side of the band is "exceeds"."""
    value: float
    factor: float
    higher_is_better: bool

    def __post_init__(self):
        if self.factor < 1:
            raise ValueError(f"a factor is at least 1, got {self.factor}")

    def band(self) -> Tuple[float, float]:
        return tuple(sorted((self.value / self.factor, self.value * self.factor)))

    def text(self) -> str:
        if self.factor == 1:
            return "agrees if the value lies inside our 95 % interval"
        low, high = self.band()
        return f"agrees if our interval lies within {self.factor:.3g}x either way ({low:,.4g} to {high:,.4g})"

    def judge(self, ours: Interval) -> str:
        top = ours.top                 # a censored interval reaches up without end
        if self.factor == 1:           # a closed form: inside our (uncut) interval
            low = high = self.value
            if ours.low <= self.value <= top and not ours.censored:
                return AGREES
        else:
            low, high = self.band()
            if low <= ours.low and top <= high:
                return AGREES
        above, beneath = ours.low > high, top < low     # wholly beyond the band's upper or lower edge
        if above or beneath:
            return EXCEEDS if above == self.higher_is_better else BELOW
        return CAPPED if ours.censored else UNDECIDED


@dataclass(frozen=True)
class Bound:
    """A goal or a comparison: the good side of ``value`` is above it if ``higher_is_better``."""
    value: float
    higher_is_better: bool

    def text(self) -> str:
        return f"met if our interval lies {'above' if self.higher_is_better else 'below'} {self.value:,.4g}"

    def judge(self, ours: Interval) -> str:
        top = ours.top                 # a censored interval reaches up without end
        good = ours.low > self.value if self.higher_is_better else top < self.value
        bad = top <= self.value if self.higher_is_better else ours.low >= self.value
        return MET if good else NOT_MET if bad else CAPPED if ours.censored else UNDECIDED


@dataclass(frozen=True)
class Beats:
    """This suite's claim that a learner beats the claim's trivial baseline: met when its interval
    clears the baseline's (``judge`` then says so), else no learning."""
    higher_is_better: bool

    def text(self) -> str:
        return "met if our interval clears the baseline's"

    def judge(self, ours: Interval) -> str:
        return MET


@dataclass(frozen=True)
class NoNumber:
    def text(self) -> str:
        return "the source gives no number"

    def judge(self, ours: Interval) -> str:
        return NO_NUMBER


# ------------------------------------------------------------------ claims
Measure = Callable[[dict], Interval]   # {experiment: Run} -> our interval


@dataclass(frozen=True)
class Claim:
    """One claim, fixed before any run: ``source`` ("GWH14", "the seed report", "AC00", "this
    suite"), ``statement`` in words with its number, ``rule``, ``measure`` over the experiments
    it ``needs`` (the first is the learner whose model knowledge counts), an optional trivial
    ``baseline`` experiment measured by ``measure`` too, and the scales that decide it."""
    key: str
    source: str
    statement: str
    rule: object
    measure: Measure
    needs: Tuple[str, ...]
    baseline: Optional[str] = None
    baseline_measure: Optional[Measure] = None   # default: ``measure`` on the baseline's run in place of the learner's
    decided_at: Tuple[str, ...] = ("full", "report")
    fmt: str = "{:,.4g}"
    source_model: Tuple[str, ...] = ()   # model knowledge the source itself used (not a variant then)

    def __post_init__(self):
        if isinstance(self.rule, Beats) and not self.baseline:
            raise ValueError(f"claim {self.key!r}: 'beats' needs a baseline")
        if isinstance(self.rule, NoNumber) and self.baseline:
            raise ValueError(f"claim {self.key!r}: a claim with no number has no baseline to clear")


@dataclass(frozen=True)
class Judged:
    claim: Claim
    verdict: str
    ours: str                                  # our interval (or why there is none) with its statistic
    model: Tuple[str, ...] = field(default=())  # what of the env's model the judged runs use

    @property
    def variant(self) -> bool:
        return bool(self.model)

    def bullet(self) -> str:
        c = self.claim
        uses = f" Uses the model: {'; '.join(self.model)}." if self.model else ""
        return f"- {c.source}: {c.statement} ({c.rule.text()}). Ours: {self.ours} -- **{self.verdict}**.{uses}"


def variant_of(claim: Claim, config: Optional[dict]) -> Tuple[str, ...]:
    """What of the model the learner of ``config`` uses beyond what the claim's source used."""
    from trl_dgpq.envs import model_knowledge
    return tuple(k for k in (model_knowledge(config) if config else ()) if k not in claim.source_model)


def judge(claim: Claim, runs: dict, scale: str, planned: Optional[dict] = None) -> Judged:
    """``claim``'s verdict on ``runs`` ({experiment: Run}) at ``scale``; ``planned``
    ({experiment: config}) says what a claim not judged here would have used of the model."""
    if scale not in claim.decided_at:
        config = (planned or {}).get(claim.needs[0])
        return Judged(claim, NOT_JUDGED, f"the {' or '.join(claim.decided_at)} scale decides it",
                      variant_of(claim, config))
    missing = [n for n in claim.needs + ((claim.baseline,) if claim.baseline else ()) if n not in runs]
    if missing:
        raise ValueError(f"claim {claim.key!r} needs {', '.join(missing)}, which did not run")
    model = variant_of(claim, runs[claim.needs[0]].config)
    ours = claim.measure(runs)
    verdict = claim.rule.judge(ours)
    text = f"{ours.text(claim.fmt)} ({ours.statistic}" + (f"; {ours.censored}" if ours.censored else "") + ")"
    if claim.baseline:
        if claim.baseline_measure is not None:
            base = claim.baseline_measure(runs)
        else:
            base = claim.measure({**runs, claim.needs[0]: runs[claim.baseline]})
        higher = claim.rule.higher_is_better
        clears = ours.low > base.top if higher else ours.top < base.low
        text += f"; {claim.baseline.split('-', 1)[-1]} {base.text(claim.fmt)}"
        unknown = ours.censored and not higher     # cut from above: whether it clears below is not known
        if not clears and not unknown:
            verdict = NO_LEARNING
    return Judged(claim, verdict, text, model)


def tally(judged) -> str:
    """"2 agree, 1 below, ...; variants using the model: 1 exceeds": the model-free claims'
    verdicts, then the variants' apart."""
    def counts(items):
        return ", ".join(f"{sum(j.verdict == v for j in items)} {v}" for v in VERDICTS
                         if any(j.verdict == v for j in items))
    free = [j for j in judged if not j.variant]
    variants = [j for j in judged if j.variant]
    text = counts(free) or "none"
    return text + (f"; variants using the model: {counts(variants)}" if variants else "")


def table(judged) -> str:
    """The markdown table of judged claims and the tally."""
    cell = lambda text: text.replace("|", "\\|")  # noqa: E731
    rows = ["| source | claim | rule | ours | verdict | uses the model |", "|---|---|---|---|---|---|"]
    rows += [f"| {j.claim.source} | {cell(j.claim.statement)} | {cell(j.claim.rule.text())} | {cell(j.ours)} "
             f"| {j.verdict} | {cell('; '.join(j.model)) or 'no'} |" for j in judged]
    return "\n".join(rows) + "\n\n" + tally(judged) + "."
