"""How much of the model does DGPQ need on the F-16? A potential ablation with model error,
reproduced apart, one part per formulation (``reproduce --only f16-model`` for flight-05,
``f16-model-gwh14`` for GWH14's; ``APART`` in analysis.py).

Each learner flies under one potential at a time (potential.py): none; ``cost``, the state's own
cost paid for ever (model-free); ``lqr``, the LQR's value from the true linearisation; and the
LQR's value from a **wrong model**, every entry of the linearisation's A and B scaled by its own
factor in [1 - e, 1 + e] (``dynamics.perturbed``: a fixed draw, recorded as
``potential_model_draw``), at e = 0.2 and 0.5, three draws each. The reward recorded, and every
number here, is GWH14's unshaped reward, so learners and potentials compare on the same reward.

Two formulations: ``flight-05`` (a decision every 0.5 s, 20 per episode, gamma 0.9) under every
potential; GWH14's own (0.05 s, 200 per episode) at gamma 0.99, the potential's too (the
``gamma99-shaped`` settings: at gamma 0.9 flying is worth less than holding from the start state,
presets.py), under none, cost, lqr and one draw per error level -- its DGPQ runs cost 1-4 hours
of one core each, ten times flight-05's, so its wrong models are one draw each.

Learners: DGPQ at L_Q 5 and 10 and DQN, each with its formulation's settings under every
potential (flight-05's and gamma99's presets, hand-set on seeds 2000-2003). On flight-05 also DQN
tuned by its own validated studies (tuned.json): ``flight-05-tuned`` (the study without a
potential) under none and ``cost`` (no study was made with ``cost``), ``flight-05-shaped-tuned``
(the study with the LQR's potential) under the LQR's, true or wrong: a wrong model changes the
potential's values, not its scale or shape, so settings carry over within that family if they
carry at all. DGPQ has no study per potential (its flight-05 study searched the metric without a
potential and found only holding); GWH14's formulation has no study for either learner. TD3 is
not run: GWH14's elevator is three-valued (-1, 0, +1), and a continuous one is another problem.

Seeds 30-49 (``FIRST_SEED``): some configurations here (no potential and the true LQR's on
flight-05, the true LQR's on GWH14's formulation) had already run on seeds 10-19 for the
republication when these claims were first written, so the ablation runs on seeds no F-16 run
has used.

The claims are fixed here, before any of their runs: for each formulation and potential, P(DGPQ
at L_Q 5 improves on DQN) at episodes 91-100 above 0.5 -- the tuned DQN on flight-05, DQN at its
default settings on GWH14's formulation --, and DGPQ at L_Q 5 past halfway from doing nothing to
PD there. An error level's draws count per seed: each seed's mean over its draws, so an interval
is over 20 seeds, not 60 correlated runs. Where the learner ahead with the true model stops being
clearly ahead along the model error is read off the same intervals, by ``advantage_lost`` (not a
claim).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from trl_dgpq.analysis import ms_per_seed_step, rolling, seed_means


WINDOWS = ((1, 10), (91, 100), (191, 200), (901, 1000))     # the episodes (1-10: where each starts)
JUDGED = (91, 100)                                          # the claims' window
ERRORS = (0.2, 0.5)
DRAWS = {"05": (1, 2, 3), "gwh14": (1,)}


def potentials(formulation: str) -> list:
    """[(name, group, env overrides)]: a group pools an error level's draws."""
    out = [("none", "none", dict(potential="none")), ("cost", "cost", dict(potential="cost")),
           ("lqr", "lqr", dict(potential="lqr"))]
    for e in ERRORS:
        out += [(f"lqr-e{round(e * 100)}-d{d}", f"lqr-e{round(e * 100)}",
                 dict(potential="lqr", potential_model_error=e, potential_model_draw=d)) for d in DRAWS[formulation]]
    return out


GROUPS = {"none": "no potential", "cost": "`cost` (model-free)", "lqr": "LQR, true model",
          **{f"lqr-e{round(e * 100)}": f"LQR, model off by up to {round(e * 100)} %" for e in ERRORS}}
FORMULATIONS = {  # name: (heading, the learners' preset, the scripted agents' preset, the part's folder)
    "05": ("`flight-05` (a decision every 0.5 s, γ 0.9)", "flight-05-shaped", "flight-05", "f16-model"),
    "gwh14": ("GWH14's formulation (a decision every 0.05 s) at γ 0.99", "gamma99-shaped", "default",
              "f16-model-gwh14"),
}
LEARNERS = {"dgpq-lq5": dict(agent="dgpq"), "dgpq-lq10": dict(agent="dgpq", lipschitz=10.0), "dqn": dict(agent="dqn"),
            "dqn-tuned": dict(agent="dqn")}
# the tuned DQN's preset per potential family, on flight-05 only (its studies; none on GWH14's formulation)
TUNED_DQN = {"none": "flight-05-tuned", "cost": "flight-05-tuned", "lqr": "flight-05-shaped-tuned"}
FIRST_SEED = 30
RIVAL = {"05": ("dqn-tuned", "DQN tuned by its validated study"), "gwh14": ("dqn", "DQN at its default settings")}


def learners(f: str) -> list:
    return [who for who in LEARNERS if who != "dqn-tuned" or f == "05"]


def settings_of(f: str, who: str, potential: str) -> dict:
    if who == "dqn-tuned":
        return dict(LEARNERS[who], preset=TUNED_DQN[potential.split("-")[0]])
    return dict(LEARNERS[who], preset=FORMULATIONS[f][1])
SCALES = {"smoke": (1, 2), "quick": (2, 14), "full": (20, 1000), "report": (20, 1000)}
GWH14_SCALES = {"smoke": (1, 2), "quick": (1, 2), "full": (20, 1000), "report": (20, 1000)}
SCRIPTED = {"nothing": dict(agent="constant"), "pd": dict(agent="pd")}


def name(formulation: str, who: str, potential: str = "") -> str:
    return f"f16-model-{formulation}-" + (f"{potential}-" if potential else "") + who


def plan(f: str, scales: dict) -> list:
    _, preset, scripted_preset, _ = FORMULATIONS[f]
    out = []
    for p, _, env in potentials(f):
        out += [(name(f, who, p), dict(settings_of(f, who, p), **env), scales) for who in learners(f)]
    return out + [(name(f, who), dict(settings, preset=scripted_preset),
                   {k: (s, min(e, 100)) for k, (s, e) in scales.items()}) for who, settings in SCRIPTED.items()]


# ------------------------------------------------------------ measures
def members(formulation: str, group: str, who: str) -> list:
    """The experiments of ``who`` under the potentials of ``group`` (an error level's draws)."""
    return [name(formulation, who, p) for p, g, _ in potentials(formulation) if g == group]


def per_seed(runs: dict, names: list, window=JUDGED) -> np.ndarray:
    """Each seed's mean reward over ``window``, averaged over the runs of ``names`` (an error level's
    draws: one value per seed, never one per run); an error if a seed did not run to its end."""
    values = []
    for n in names:
        df = runs[n].df
        short = df.groupby("seed")["episode"].max() < window[1]
        if short.any():
            raise ValueError(f"{n}: seed {short.idxmax()} ran {df[df.seed == short.idxmax()].episode.max()} "
                             f"episodes, not to episode {window[1]}")
        values.append(seed_means(df, "return", *window))
    return pd.concat(values, axis=1).mean(axis=1).to_numpy()


def reference(runs: dict, formulation: str, who: str) -> float:
    """A scripted agent's mean reward over every seed-episode it ran (it does not learn)."""
    return float(runs[name(formulation, who)].df["return"].mean())


def improvement(formulation: str, group: str, x: str = "dgpq-lq5", y: str = ""):
    y = y or RIVAL[formulation][0]

    def measure(runs):
        from trl_dgpq.analysis.claims import improvement_interval
        return improvement_interval(per_seed(runs, members(formulation, group, x)),
                                    per_seed(runs, members(formulation, group, y)), lower_is_better=False)
    return measure


def progress(formulation: str, group: str, who: str = "dgpq-lq5"):
    """Per seed at episodes 91-100: how far from doing nothing (0) to PD (1) it got."""
    def measure(runs):
        from trl_dgpq.analysis.claims import seeds_interval
        hold, pd_ = reference(runs, formulation, "nothing"), reference(runs, formulation, "pd")
        return seeds_interval((per_seed(runs, members(formulation, group, who)) - hold) / (pd_ - hold))
    return measure


def declared_claims(f: str) -> list:
    from trl_dgpq.analysis.claims import Bound, Claim
    out = []
    for heading in FORMULATIONS[f][:1]:
        refs = (name(f, "nothing"), name(f, "pd"))
        for group, words in GROUPS.items():
            key = f"f16-model/{f}/{group}"
            rival, rival_words = RIVAL[f]
            dgpq, dqn = members(f, group, "dgpq-lq5"), members(f, group, rival)
            out += [Claim(f"{key}/dgpq-vs-dqn", "this suite", f"{heading}, potential: {words}: DGPQ at L_Q 5 "
                          f"improves on {rival_words} at episodes {JUDGED[0]}-{JUDGED[1]} (P(improvement) of each "
                          "seed's mean there" + (", averaged over the draws" if len(dgpq) > 1 else "") + ")",
                          Bound(0.5, higher_is_better=True), improvement(f, group), tuple(dgpq + dqn), fmt="{:.2f}"),
                    Claim(f"{key}/halfway", "this suite", f"{heading}, potential: {words}: DGPQ at L_Q 5 is past "
                          f"halfway from doing nothing (0) to PD (1) by episodes {JUDGED[0]}-{JUDGED[1]}",
                          Bound(0.5, higher_is_better=True), progress(f, group), tuple(dgpq) + refs, fmt="{:.2f}")]
    return out


def advantage_lost(runs: dict, formulation: str, window=JUDGED, x: str = "dgpq-lq5", y: str = "") -> str:
    """Along the LQR potential's model error (0, then ``ERRORS``): where the learner clearly ahead
    with the true model (its P(improvement) interval wholly on its side of 0.5) is first no longer
    clearly ahead (the interval reaches 0.5: not shown behind, only not shown ahead)."""
    from trl_dgpq.analysis.claims import improvement_interval
    y = y or RIVAL[formulation][0]
    levels = [("lqr", 0.0)] + [(f"lqr-e{round(e * 100)}", e) for e in ERRORS]
    got = [(e, improvement_interval(per_seed(runs, members(formulation, g, x), window),
                                    per_seed(runs, members(formulation, g, y), window), lower_is_better=False))
           for g, e in levels]
    trail = "; ".join(f"±{e:.0%} {i.text('{:.2f}')}" for e, i in got)
    first = got[0][1]
    if first.low <= 0.5 <= first.high:
        return f"With the true model neither {x} nor {y} is ahead, so there is no advantage to lose (P({x} improves " \
               f"on {y}) [95 % CI] at model error {trail})."
    ahead = x if first.low > 0.5 else y
    lost = next((e for e, i in got if not (i.low > 0.5 if ahead == x else i.high < 0.5)), None)
    return (f"{ahead} is clearly ahead with the true model; " + (
            f"from a model error of ±{lost:.0%} it is no longer clearly ahead" if lost is not None
            else f"it stays clearly ahead up to ±{ERRORS[-1]:.0%}, the largest error run")
            + f" (P({x} improves on {y}) [95 % CI] at model error {trail}).")


def window_of(runs: dict, formulation: str) -> tuple:
    """The claims' episodes where every learner of ``formulation`` got there, else the last 10 all ran
    (a short scale)."""
    shortest = min(int(runs[name(formulation, who, p)].df.episode.max()) for p, _, _ in potentials(formulation)
                   for who in learners(formulation))
    return JUDGED if shortest >= JUDGED[1] else (max(1, shortest - 9), shortest)


# ------------------------------------------------------------ the section
def stable(df: pd.DataFrame, pd_mean: float) -> tuple:
    """(seeds whose 10-episode mean came within 10 % of PD's at some episode, seeds)."""
    met = rolling(df, "return", 10, full=True) >= 1.1 * pd_mean       # both negative: 1.1 x is 10 % worse
    return int(df[met]["seed"].nunique()), int(df["seed"].nunique())


def cell(df: pd.DataFrame, window) -> str:
    from trl_dgpq.analysis.claims import seeds_interval
    if df.episode.max() < window[1]:
        return "-"
    return seeds_interval(seed_means(df, "return", *window)).text("{:.0f}")


def table(runs: dict, formulation: str) -> str:
    pd_mean = reference(runs, formulation, "pd")
    head = ("| potential | uses the model | learner | " + " | ".join(f"episodes {a}-{b:,}" for a, b in WINDOWS)
            + " | seeds ever within 10 % of PD (10-episode mean) | ms per seed-step |\n|---|---|---|"
            + "---|" * len(WINDOWS) + "---|---|")
    rows = []
    for p, _, env in potentials(formulation):
        for who in learners(formulation):
            run = runs[name(formulation, who, p)]
            df = run.df
            hits, n = stable(df, pd_mean)
            uses = "yes" if env["potential"] == "lqr" else "no"
            rows.append(f"| {p} | {uses} | {who} ({run.config['run']['preset']}) | "
                        + " | ".join(cell(df, w) for w in WINDOWS) + f" | {hits} of {n} | {ms_per_seed_step(df):.2f} |")
    refs = ", ".join(f"{who} {reference(runs, formulation, who):.1f}" for who in SCRIPTED)
    return (head + "\n" + "\n".join(rows) + f"\n\nEach cell: IQM over seeds of each seed's mean episode reward in "
            f"the window [95 % CI] (GWH14's unshaped reward). Scripted references, mean over every seed-episode: "
            f"{refs}.\n")


def improvements(runs: dict, formulation: str, window=JUDGED) -> str:
    from trl_dgpq.analysis.claims import improvement_interval
    pairs = [("dgpq-lq5", "dqn"), ("dgpq-lq10", "dqn"), ("dgpq-lq5", "dgpq-lq10")]
    if "dqn-tuned" in learners(formulation):
        pairs[1:1] = [("dgpq-lq5", "dqn-tuned"), ("dqn-tuned", "dqn")]
    rows = ["| potential | " + " | ".join(f"P({x} improves on {y})" for x, y in pairs) + " |",
            "|---|" + "---|" * len(pairs)]
    for group, words in GROUPS.items():
        if not members(formulation, group, "dqn"):
            continue
        cells = [improvement_interval(per_seed(runs, members(formulation, group, x), window),
                                      per_seed(runs, members(formulation, group, y), window), lower_is_better=False)
                 .text("{:.2f}") for x, y in pairs]
        rows.append(f"| {words} | " + " | ".join(cells) + " |")
    return (f"At episodes {window[0]}-{window[1]}, each seed's mean (an error level's: averaged over its draws), "
            "rliable's P(improvement) [95 % CI]:\n\n" + "\n".join(rows) + "\n")


def figure(runs: dict, f: str, out: Path, title: str) -> Path:
    """f16_model.png: reward at episodes 91-100 against the potential (none, cost, then the LQR's at
    growing model error), one line per learner with its IQM's interval, doing nothing and PD as
    horizontal lines."""
    import matplotlib.pyplot as plt

    from trl_dgpq.analysis.claims import seeds_interval
    from trl_dgpq.analysis.figures import save
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    groups = [g for g in GROUPS if members(f, g, "dqn")]
    window = window_of(runs, f)
    x = np.arange(len(groups))
    for k, who in enumerate(learners(f)):
        got = [seeds_interval(per_seed(runs, members(f, g, who), window)) for g in groups]
        point = np.array([i.point for i in got])
        err = np.array([[i.point - i.low for i in got], [i.high - i.point for i in got]])
        ax.errorbar(x + 0.07 * (k - 1.5), point, yerr=err, marker="o", ms=4, capsize=3, lw=1.2, label=who)
    for who, style in (("nothing", ":"), ("pd", "--")):
        value = reference(runs, f, who)
        ax.axhline(value, color="k", ls=style, lw=0.9, label=f"{who} ({value:.0f})")
    ax.set_xticks(x, [GROUPS[g].replace("`", "").replace(", model off by up to ", "\n±").replace(" (model-free)", "")
                      for g in groups], fontsize=7)
    ax.set_title(FORMULATIONS[f][0].replace("`", ""), fontsize=9)
    ax.set_ylabel(f"episode reward, episodes {window[0]}-{window[1]}\n(IQM over seeds [95 % CI])")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    return save(fig, out / "f16_model.png", title)


class Ablation:
    """One formulation's ablation as a part of the reproduction (``APART`` in analysis.py): what
    ``reproduce`` reads of a domain's analysis, for it alone."""

    def __init__(self, f: str, scales: dict):
        self.formulation, self.SCALES, self.FIRST_SEED = f, scales, FIRST_SEED
        heading, self.folder = FORMULATIONS[f][0], FORMULATIONS[f][3]
        self.REPRODUCE = plan(f, scales)
        self.CLAIMS = declared_claims(f)
        self.TITLE = (f"How much of the model does DGPQ need? The F-16, {heading}, under potentials from none to "
                      "a wrong model")
        dqn = " (at its defaults and tuned by its own validated studies)" if f == "05" else " at its defaults"
        draws = "three fixed draws" if len(DRAWS[f]) > 1 else "one fixed draw"
        self.SUMMARY = (f"DGPQ at L_Q 5 and 10 and DQN{dqn}, each shaped by no potential, a model-free one (`cost`), "
                        "the LQR's value from the true linearisation, or from one whose every entry is off by up to "
                        f"20 % or 50 % ({draws} each); 20 fresh seeds (30-49) x 1,000 episodes, judged on GWH14's "
                        "unshaped reward. The LQR potentials use the model: counted apart.")

    def declared_claims(self) -> list:
        """Its claims built anew, as a domain's analysis offers them (``CLAIMS`` is the list built once)."""
        return declared_claims(self.formulation)

    def reproduce_section(self, runs: dict, out: Path, label: str, title: str, judged: list) -> str:
        f = self.formulation
        (out / self.folder).mkdir(exist_ok=True)
        figure(runs, f, out / self.folder, title)
        window = window_of(runs, f)
        return (f"## {self.TITLE}\n\n{label}\n\n" + "\n".join(j.bullet() for j in judged) + "\n\n"
                + table(runs, f) + "\n" + improvements(runs, f, window) + "\n" + advantage_lost(runs, f, window)
                + f"\n\n![reward against the potential]({self.folder}/f16_model.png)\n")


FLIGHT_05 = Ablation("05", SCALES)
GWH14 = Ablation("gwh14", GWH14_SCALES)
