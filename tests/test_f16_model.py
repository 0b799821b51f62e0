"""The F-16's potential ablation with model error (envs/f16/model_ablation.py): its plan, its
claims' measures on runs whose values are known, and its section."""
import numpy as np
import pandas as pd
import pytest

from trl_dgpq.envs.f16 import model_ablation as m
from trl_dgpq.analysis.claims import MET, NOT_MET, UNDECIDED, judge
from trl_dgpq.analysis.runs import Run
from trl_dgpq.commands import reproduce

CLAIMS = m.FLIGHT_05.CLAIMS + m.GWH14.CLAIMS


@pytest.fixture(scope="module")
def planned():
    return reproduce.experiments("report", ["f16-model", "f16-model-gwh14"])


def test_every_learner_meets_every_potential_with_its_formulations_settings(planned):
    parts = reproduce.reproductions(["f16-model", "f16-model-gwh14"])
    assert [(p.name, a) for p, a in parts] == [("f16-model", m.FLIGHT_05), ("f16-model-gwh14", m.GWH14)]
    assert not any(n.startswith("f16-model") for n in reproduce.experiments("report", ["f16"]))  # apart from f16's
    assert len(reproduce.experiments("report", ["f16-model"])) == 9 * 3 + 2 and len(planned) == 29 + 5 * 3 + 2
    wrong = {(c["env"]["potential_model_error"], c["env"]["potential_model_draw"]) for n, c in planned.items()
             if n.startswith("f16-model-05-") and n.endswith("-dqn")}
    assert wrong == {(0.0, 0)} | {(e, d) for e in (0.2, 0.5) for d in (1, 2, 3)}
    for f, steps, gamma in (("05", 10, 0.9), ("gwh14", 1, 0.99)):
        for who in m.LEARNERS:
            mine = [c for n, c in planned.items() if n.startswith(f"f16-model-{f}-") and n.endswith(f"-{who}")]
            assert len(mine) == (9 if f == "05" else 5)
            assert all(c["agent"] == mine[0]["agent"] for c in mine)        # one learner's settings throughout
            assert all(c["run"]["seeds"] == list(range(10, 30)) and c["run"]["episodes"] == 1000 for c in mine)
            assert {c["env"]["decision_steps"] for c in mine} == {steps}
            assert {c["env"]["potential"] for c in mine} == {"none", "cost", "lqr"}
            if "gamma" in mine[0]["agent"]:                                  # shaping at the learner's own gamma
                assert mine[0]["agent"]["gamma"] == gamma == mine[0]["env"]["potential_gamma"]
    assert planned["f16-model-05-lqr-dgpq-lq10"]["agent"]["lipschitz"] == 10.0
    assert planned["f16-model-gwh14-pd"]["run"]["episodes"] == 100
    assert planned["f16-model-05-nothing"]["agent"]["action"] == "hold"


def runs_with(planned, value) -> dict:
    """Every planned experiment on seeds 10-29 x 100 episodes, each seed's return ``value(name, seed)``."""
    out = {}
    for name, config in planned.items():
        seeds = config["run"]["seeds"]
        rows = [dict(seed=s, episode=e, steps=20, wall_s=0.01, terminated=False, **{"return": value(name, s)})
                for s in seeds for e in range(1, 101)]
        out[name] = Run(None, pd.DataFrame(rows), config)
    return out


def values(name, seed):
    """DGPQ at L_Q 5 at -70 (PD's), DQN at -100, L_Q 10 at -120, doing nothing at -140; at a 50 % model
    error DGPQ at L_Q 5 no better than DQN. Each seed 0.01 lower than the last, alike for all."""
    spread = (seed - 10) * 0.01
    if name.endswith(("nothing", "pd")):
        return -140.0 if name.endswith("nothing") else -70.0
    if name.endswith("dgpq-lq5"):
        return (-100.0 if "-e50-" in name else -70.0) - spread
    return (-120.0 if name.endswith("dgpq-lq10") else -100.0) - spread


def test_the_claims_measure_what_they_say(planned):
    runs = runs_with(planned, values)
    got = {c.key: judge(c, runs, "report", planned) for c in CLAIMS}
    assert len(got) == 20
    assert got["f16-model/05/lqr/dgpq-vs-dqn"].verdict == MET          # every DGPQ seed above every DQN seed: P 1
    assert got["f16-model/05/lqr/dgpq-vs-dqn"].ours.startswith("1.00")
    assert got["f16-model/05/lqr-e50/dgpq-vs-dqn"].verdict == UNDECIDED  # equal: P 0.5
    assert got["f16-model/05/lqr-e50/dgpq-vs-dqn"].ours.startswith("0.50")
    assert got["f16-model/05/none/halfway"].verdict == MET              # (-70 + 140) / (-70 + 140) = 1
    halfway = m.progress("05", "lqr-e50")(runs)       # (-100 + 140) / (-70 + 140), less each seed's spread
    assert halfway.point == pytest.approx((-100.095 + 140) / 70, abs=0.002) and halfway.low > 0.5
    assert got["f16-model/05/lqr-e50/halfway"].verdict == MET
    slow = runs_with(planned, lambda n, s: -120.0 if n.endswith("dgpq-lq5") else values(n, s))
    assert judge(next(c for c in CLAIMS if c.key == "f16-model/05/cost/halfway"), slow, "report",
                 planned).verdict == NOT_MET                           # (-120 + 140) / 70 = 0.29


def test_pooled_draws_and_model_knowledge(planned):
    runs = runs_with(planned, values)
    pooled = m.per_seed(runs, m.members("05", "lqr-e20", "dqn"))
    assert len(pooled) == 60 and m.members("gwh14", "lqr-e20", "dqn") == ["f16-model-gwh14-lqr-e20-d1-dqn"]
    variant = {c.key: judge(c, runs, "report", planned).variant for c in CLAIMS}
    assert not variant["f16-model/05/none/dgpq-vs-dqn"] and not variant["f16-model/gwh14/cost/halfway"]
    assert variant["f16-model/05/lqr-e50/halfway"] and variant["f16-model/gwh14/lqr/dgpq-vs-dqn"]
    with pytest.raises(ValueError, match="not to episode 100"):
        m.per_seed({n: Run(None, r.df[r.df.episode <= 50], r.config) for n, r in runs.items()},
                   m.members("05", "none", "dqn"))


def test_where_the_advantage_is_lost(planned):
    runs = runs_with(planned, values)
    assert "dgpq-lq5 is ahead with the true model; its advantage is gone at a model error of ±50%" \
        in m.advantage_lost(runs, "05")
    kept = runs_with(planned, lambda n, s: values(n.replace("-e50-", "-e20-"), s))
    assert "stays ahead up to ±50%" in m.advantage_lost(kept, "05")
    even = runs_with(planned, lambda n, s: -100.0 - (s - 10) * 0.01 if "dgpq-lq5" in n or n.endswith("dqn")
                     else values(n, s))
    assert "neither dgpq-lq5 nor dqn is ahead" in m.advantage_lost(even, "05")


def test_the_section_and_its_figure(planned, tmp_path):
    runs = runs_with(planned, values)
    judged = [judge(c, runs, "report", planned) for c in CLAIMS]
    text = m.FLIGHT_05.reproduce_section(runs, tmp_path, "label", "title", judged[:10])
    assert (tmp_path / "f16-model" / "f16_model.png").stat().st_size > 10_000
    assert "f16-model/f16_model.png" in text and "GWH14's formulation" not in text.split("\n\n", 1)[1]
    assert "| lqr-e20-d3 | dgpq-lq5 | -70 [-70, -70] |" in text
    assert "nothing -140.0, pd -70.0" in text
    assert text.startswith("## How much of the model does DGPQ need? The F-16, `flight-05`") and "At episodes 91-100" in text
    assert m.GWH14.reproduce_section(runs, tmp_path, "", "", []).count("| lqr-e50-d1 |") == 3   # one draw, 3 learners
    short = {n: Run(None, r.df[r.df.episode <= 20], r.config) for n, r in runs.items()}
    assert m.window_of(short, "05") == (11, 20)
    assert "At episodes 11-20" in m.FLIGHT_05.reproduce_section(short, tmp_path, "label", "title", [])
