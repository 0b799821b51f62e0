"""The F-16's analysis (envs/f16/analysis.py): one flight for the trace figure, the figures'
data, titles and labels, and REPORT.md's section, against values worked out by hand."""
import json

import numpy as np

from trl_dgpq.analysis.claims import Claim, NoNumber
from trl_dgpq.analysis.claims import Judged as J
import pandas as pd
import pytest
import torch

from tests.test_f16 import decision_by_hand, lqr_gain_by_hand
from trl_dgpq.analysis import load_run
from trl_dgpq.envs.f16 import analysis
from trl_dgpq.envs.f16.dynamics import V_T0
from trl_dgpq.envs.f16.env import F16Env

START = np.array([20.0, 0.0, 0.01, 0.01, 0.0])  # h0, pitch0 by default


def squashed(text: str) -> str:
    """A title as written, before save() wrapped it to fit."""
    return " ".join(text.split())


# ------------------------------------------------------------ fly / flights
def test_fly_records_seed_row_0s_episode_per_decision():
    """Two seeds, 5 decisions of 2 simulator steps, no noise, each row its own actions: the
    flight is row 0's (its elevator -1, +1, 0, -1, +1), time advancing 0.1 s per decision (the
    elevator held over 2 x 0.05 s), the altitude after each decision and the summed reward."""
    env = F16Env([3, 8], noise_v=0.0, noise_alpha=0.0, decision_steps=2, max_steps=5)
    plan = iter([[0, 2], [2, 0], [1, 1], [0, 2], [2, 0]])
    flight = analysis.fly(env, lambda td: torch.tensor(next(plan)))
    x, h, total = START, [20.0], 0.0
    for e in (-1.0, 1.0, 0.0, -1.0, 1.0):
        x, r = decision_by_hand(x, e, 2)
        h.append(x[0])
        total += r
    np.testing.assert_allclose(flight["t"], [0.0, 0.1, 0.2, 0.3, 0.4, 0.5], atol=1e-12)
    np.testing.assert_allclose(flight["h"], h, rtol=1e-9)
    assert list(flight["elevator"]) == [-1, 1, 0, -1, 1]
    assert flight["reward"] == pytest.approx(total, rel=1e-9)


def test_fly_ends_with_row_0s_episode_when_it_leaves_the_envelope_first():
    """5 simulator steps per decision, 8 decisions: row 0 pulls the nose up and leaves the
    envelope after its 4th decision (h_max between its altitude errors after the 3rd and 4th,
    by hand), row 1 pushes it down and flies on inside: the flight is row 0's 4 decisions, its
    reward with the cost of the 4 decisions (20 simulator steps) left."""
    x, rewards, heights = START, [], []
    for _ in range(4):
        x, r = decision_by_hand(x, -1.0, 5)
        rewards.append(r)
        heights.append(x[0])
    h_max = (heights[2] + heights[3]) / 2
    x = START
    for _ in range(8):
        x, _ = decision_by_hand(x, 1.0, 5)
        assert abs(x[0]) < h_max and abs(x[2:]).max() < 0.5           # row 1 stays inside
    env = F16Env([3, 8], noise_v=0.0, noise_alpha=0.0, decision_steps=5, max_steps=8, h_max=h_max)
    flight = analysis.fly(env, lambda td: torch.tensor([0, 2]))
    assert list(flight["elevator"]) == [-1] * 4
    np.testing.assert_allclose(flight["t"], [0.0, 0.25, 0.5, 0.75, 1.0], atol=1e-12)
    np.testing.assert_allclose(flight["h"], [20.0, *heights], rtol=1e-9)
    assert flight["reward"] == pytest.approx(sum(rewards) - 20 * h_max / 100, rel=1e-9)


def pd_by_hand(x):
    """The PD law's command in degrees with the default gains (0.02, 0.004, 15, 5)."""
    return 0.02 * x[0] + 0.004 * V_T0 * (x[3] - x[2]) + 15.0 * x[3] + 5.0 * x[4]


def flight_by_hand(seeds, episodes_before, max_steps, act):
    """Row 0's episode after ``episodes_before`` episodes of each seed (their noise drawn, any
    actions): ``act`` picks each row's action 0/1/2 from its state, or replays a list."""
    env = F16Env(seeds, max_steps=max_steps)
    td = env.reset()
    for _ in range(episodes_before * max_steps):
        td["action"] = torch.ones(len(seeds), dtype=torch.long)
        _, td = env.step_and_maybe_reset(td)
    td = env.reset()
    h, elevator, total = [float(td["state"][0, 0])], [], 0.0
    for k in range(max_steps):
        states = td["state"].numpy()
        actions = [act(k, x) for x in states]
        td["action"] = torch.tensor(actions)
        nxt = env.step(td)["next"]
        elevator.append(actions[0] - 1)
        h.append(float(nxt["state"][0, 0]))
        total += float(nxt["reward"][0])
        td = nxt.exclude("reward", "done", "terminated", "truncated")
    return np.array(h), elevator, total


def quantise_by_hand(command):
    return int(np.clip(np.round(command), -1, 1)) + 1


def test_flights_fly_the_learner_pd_and_lqr_on_the_same_next_episode(tmp_path):
    """A DGPQ run (seeds 2 and 5, 2 episodes of 6 decisions): the learner's, PD's and LQR's
    flights are seed 2's third episode, each from the checkpoint's env (the same noise); PD and
    LQR act by their laws (worked out here), the learner's elevator replayed gives its flight."""
    from trl_dgpq.commands import train
    out = tmp_path / "run"
    assert train.main(["--env", "f16", "--agent", "dgpq", "--seeds", "2,5", "--episodes", "2", "--max-steps", "6",
                       "--out", str(out), "--no-progress"]) == 0
    got = analysis.flights(out)
    assert list(got) == ["dgpq", "pd", "lqr"]
    k = lqr_gain_by_hand(0.05)
    laws = {"pd": lambda i, x: quantise_by_hand(pd_by_hand(x)),
            "lqr": lambda i, x: quantise_by_hand(-k @ x),
            "dgpq": lambda i, x: int(got["dgpq"]["elevator"][i]) + 1}
    for name, law in laws.items():
        h, elevator, total = flight_by_hand([2, 5], 2, 6, law)
        assert list(got[name]["elevator"]) == elevator, name
        np.testing.assert_allclose(got[name]["h"], h, rtol=1e-12, err_msg=name)
        assert got[name]["reward"] == pytest.approx(total, rel=1e-12), name
        np.testing.assert_allclose(got[name]["t"], np.arange(7) * 0.05, atol=1e-12)


# ------------------------------------------------------------ the trace figure
FLIGHTS = {"dgpq": dict(t=np.array([0.0, 0.05, 0.1, 0.15]), h=np.array([20.0, 21.0, 19.5, 18.0]),
                        elevator=np.array([1, 0, -1]), reward=-12.4),
           "pd": dict(t=np.array([0.0, 0.05, 0.1, 0.15]), h=np.array([20.0, 17.0, 15.0, 14.0]),
                      elevator=np.array([-1, -1, 0]), reward=-3.6),
           "lqr": dict(t=np.array([0.0, 0.05, 0.1, 0.15]), h=np.array([20.0, 18.0, 16.0, 15.5]),
                       elevator=np.array([0, 1, 1]), reward=-7.5)}


def test_trace_figure_draws_each_flights_altitude_and_elevator(tmp_path, monkeypatch, saved_figures):
    """f16_trace.png from three flights: altitude error against time on top (each labelled with
    its episode reward, the zero line), each elevator as a step line below, offset by -0.08, 0,
    +0.08 so that overlaps show, ticked -1 (nose up) / 0 / +1 (nose down); the label in the
    panel's title, the run's title above."""
    seen = []
    monkeypatch.setattr(analysis, "flights", lambda folder: seen.append(folder) or FLIGHTS)
    path = analysis.trace_figure(tmp_path / "run", tmp_path, title="smoke scale", label="dgpq-lq5")
    assert path == tmp_path / "f16_trace.png" and path.is_file() and seen == [tmp_path / "run"]
    fig = saved_figures["f16_trace.png"]
    ax, bx = fig.axes
    assert ax.get_shared_x_axes().joined(ax, bx)
    *flights, zero = ax.get_lines()
    assert [line.get_label() for line in flights] == ["dgpq: episode reward -12", "pd: episode reward -4",
                                                      "lqr: episode reward -8"]
    for line, f in zip(flights, FLIGHTS.values()):
        np.testing.assert_array_equal(line.get_xdata(), f["t"])
        np.testing.assert_array_equal(line.get_ydata(), f["h"])
    assert list(zero.get_ydata()) == [0, 0] and zero.get_color() == "k"          # the reference, not a flight
    assert [t.get_text() for t in ax.get_legend().get_texts()] == [line.get_label() for line in flights]
    steps = bx.get_lines()
    assert [line.get_label() for line in steps] == ["dgpq", "pd", "lqr"]
    for line, f, offset in zip(steps, FLIGHTS.values(), (-0.08, 0.0, 0.08)):
        assert line.get_drawstyle() == "steps-post"
        np.testing.assert_array_equal(line.get_xdata(), f["t"][:-1])
        np.testing.assert_allclose(line.get_ydata(), f["elevator"] + offset, atol=1e-12)
    assert list(bx.get_yticks()) == [-1, 0, 1]
    assert [t.get_text() for t in bx.get_yticklabels()] == ["-1 (nose up)", "0", "+1 (nose down)"]
    assert ax.get_ylabel() == "altitude error h - h_d (ft)"
    assert bx.get_ylabel() == "elevator (lines offset to show overlaps)" and bx.get_xlabel() == "time (s)"
    assert squashed(ax.get_title()) == "one episode after training (dgpq-lq5), the same noise for all"
    assert squashed(fig._suptitle.get_text()) == "smoke scale"
    assert saved_figures.problems("f16_trace.png") == []
    analysis.trace_figure(tmp_path / "run", tmp_path)                    # no label, no title
    fig = saved_figures["f16_trace.png"]
    assert squashed(fig.axes[0].get_title()) == "one episode after training, the same noise for all"
    assert fig._suptitle is None
    # without the checkpoint: in a publication (a folder beside its data/) drawn again from what was
    # kept; anywhere else the file could be another run's, so nothing is drawn from it
    seen.clear()
    assert analysis.trace_figure(None, tmp_path) is None and seen == []
    pub = tmp_path / "pub" / "f16"
    pub.mkdir(parents=True)
    (tmp_path / "pub" / "data").mkdir()
    (tmp_path / "pub" / "data" / "manifest.json").write_text("{}")
    (tmp_path / "f16_trace.json.xz").rename(pub / "f16_trace.json.xz")
    assert analysis.trace_figure(None, pub) == pub / "f16_trace.png" and seen == []
    again = saved_figures["f16_trace.png"].axes[0].get_lines()
    for line, f in zip(again, FLIGHTS.values()):
        np.testing.assert_array_equal(line.get_ydata(), f["h"])
    assert analysis.trace_figure(None, tmp_path / "pub" / "elsewhere") is None      # nothing kept there


# ------------------------------------------------------------ the reward figure
def run_folder(folder, agent, returns, lipschitz=None):
    """A run of ``agent`` with {seed: [return per episode]} (``lipschitz`` in its agent config)."""
    folder.mkdir(parents=True)
    pd.DataFrame([dict(seed=s, episode=i + 1, steps=200, **{"return": r}, terminated=False, wall_s=0.2, cpu_s=0.2,
                       us_per_step=1e3) for s, rs in returns.items() for i, r in enumerate(rs)]
                 ).to_csv(folder / "episodes.csv", index=False)
    agent_cfg = {} if lipschitz is None else {"lipschitz": lipschitz}
    (folder / "config.json").write_text(json.dumps({"run": {"env": "f16", "agent": agent, "preset": "default"},
                                                    "env": {}, "agent": agent_cfg}))
    return load_run(folder)


LQ5 = {0: [-100.0, -80.0, -60.0, -40.0], 1: [-120.0, -100.0, -50.0, -30.0], 2: [-90.0, -70.0, -80.0, -20.0]}
# blocks of 2: seeds' means -90, -110, -80 (median -90, quartiles -100, -85) then -50, -40, -50
# (median -50, quartiles -50, -45); drawn at the blocks' middle episodes 1.5 and 3.5


def test_reward_figure_draws_blocks_references_and_gwh14s_marks(tmp_path, saved_figures):
    runs = [run_folder(tmp_path / "a", "dgpq", LQ5, lipschitz=5.0),
            run_folder(tmp_path / "b", "dgpq", {0: [-10.0] * 4}, lipschitz=5.0),     # the same L_Q: no marks again
            run_folder(tmp_path / "c", "dgpq", {0: [-20.0] * 4, 1: [-30.0] * 4}, lipschitz=10.0),
            run_folder(tmp_path / "d", "dqn", {0: [-5.0, -7.0, -9.0, -11.0]}),
            run_folder(tmp_path / "e", "pd", {0: [-36.0, -38.0], 1: [-37.0, -37.2]}),
            run_folder(tmp_path / "f", "lqr", {0: [-41.0]}),
            run_folder(tmp_path / "g", "constant", {0: [-135.0]}),
            run_folder(tmp_path / "h", "random", {0: [-324.0]})]
    labels = ["lq5", "lq5 again", "lq10", "dqn", "pd", "lqr", "nothing", "random"]
    path = analysis.reward_figure(runs, labels, tmp_path, block=2, title="quick scale")
    assert path == tmp_path / "f16_reward.png" and path.is_file()
    fig = saved_figures["f16_reward.png"]
    (ax,) = fig.axes
    data = [line for line in ax.get_lines() if line.get_transform() == ax.transData]
    references = [line for line in ax.get_lines() if line.get_transform() != ax.transData]
    # the learners' medians, each followed by its marks (L_Q 5's first run and L_Q 10's)
    lq5, x5, bar5, again, lq10, x10, bar10, dqn, legend_only = data
    assert lq5.get_label() == "lq5 (3 seeds)" and again.get_label() == "lq5 again (1 seeds)"
    assert lq10.get_label() == "lq10 (2 seeds)" and dqn.get_label() == "dqn (1 seeds)"
    np.testing.assert_array_equal(lq5.get_xdata(), [1.5, 3.5])
    np.testing.assert_allclose(lq5.get_ydata(), [-90.0, -50.0])
    np.testing.assert_allclose(dqn.get_ydata(), [-6.0, -10.0])
    band = ax.collections[0].get_paths()[0].vertices
    for x, lo, hi in ((1.5, -100.0, -85.0), (3.5, -50.0, -45.0)):
        assert set(np.round(band[band[:, 0] == x, 1], 9)) == {lo, hi}
    assert len(ax.collections) == 4                                    # one band per learner
    for band_, line in zip(ax.collections, (lq5, again, lq10, dqn)):
        np.testing.assert_allclose(band_.get_facecolor()[0][:3], matplotlib_rgb(line.get_color()))
        assert band_.get_alpha() == 0.25
    for line, (x, y, bar, level, median) in ((x5, (1, -525, bar5, -47, lq5)), (x10, (1, -514, bar10, -113, lq10))):
        assert line.get_marker() == "x" and line.get_linestyle() == "None"
        assert list(line.get_xdata()) == [x] and list(line.get_ydata()) == [y]
        assert line.get_color() == median.get_color() == bar.get_color()
        assert list(bar.get_ydata()) == [level, level]
    assert list(bar5.get_xdata()) == [100, 200] and list(bar10.get_xdata()) == [900, 1000]
    assert bar5.get_linewidth() == 3 and x5.get_markersize() == 8
    assert legend_only.get_marker() == "x" and legend_only.get_color() == "k" and len(legend_only.get_xdata()) == 0
    # the scripted agents: their mean as a line across, in four styles told apart in grey
    assert [line.get_label() for line in references] == ["pd (mean -37)", "lqr (mean -41)", "nothing (mean -135)",
                                                         "random (mean -324)"]
    assert [line.get_ydata()[0] for line in references] == pytest.approx([-37.05, -41.0, -135.0, -324.0])
    assert [(line.get_linestyle(), line.get_color()) for line in references] == [
        (":", "k"), ("--", "0.4"), ("-.", "0.6"), (":", "0.7")]
    texts = [t.get_text() for t in ax.get_legend().get_texts()]
    assert set(texts) == {"lq5 (3 seeds)", "lq5 again (1 seeds)", "lq10 (2 seeds)", "dqn (1 seeds)", "pd (mean -37)",
                          "lqr (mean -41)", "nothing (mean -135)", "random (mean -324)",
                          "GWH14 Fig. 3: start (x) and episodes 100-200 / 900-1000 (bar)"}
    assert ax.get_xscale() == "log" and ax.get_yscale() == "linear"
    assert ax.get_xlabel() == "episode (log axis; blocks of 2)"
    assert ax.get_ylabel() == "episode reward (median of seeds; band: IQR)"
    assert squashed(ax.get_title()) == "F-16 altitude hold: episode reward per block of episodes"
    assert squashed(fig._suptitle.get_text()) == "quick scale"
    assert saved_figures.problems("f16_reward.png") == []
    analysis.reward_figure(runs[3:4], ["dqn"], tmp_path, block=1)     # episodes 1-4: no tick at 1.5 or 2.5
    assert saved_figures.problems("f16_reward.png") == []


def matplotlib_rgb(color):
    import matplotlib.colors
    return matplotlib.colors.to_rgb(color)


def test_figures_draw_the_reward_and_the_trace_of_the_first_learner_with_a_checkpoint(tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(analysis, "reward_figure", lambda *a, **k: calls.append(("reward", a, k)) or "r.png")
    monkeypatch.setattr(analysis, "trace_figure", lambda *a, **k: calls.append(("trace", a, k)) or "t.png")
    runs = [run_folder(tmp_path / "pd", "pd", {0: [-37.0]}), run_folder(tmp_path / "dqn", "dqn", {0: [-50.0]}),
            run_folder(tmp_path / "lq5", "dgpq", {0: [-40.0]}), run_folder(tmp_path / "lq10", "dgpq", {0: [-60.0]})]
    for name in ("pd", "lq5", "lq10"):                    # PD's checkpoint does not count, nor DQN's absence
        (tmp_path / name / "checkpoint.pt").write_bytes(b"")
    labels = ["pd", "dqn", "lq5", "lq10"]
    assert analysis.figures(runs, labels, tmp_path / "out", title="T", last=3) == ["r.png", "t.png"]
    (_, (runs_, labels_, out), kw), trace = calls
    assert runs_ is runs and labels_ is labels and out == tmp_path / "out" and kw == dict(block=10, title="T")
    assert trace == ("trace", (tmp_path / "lq5", tmp_path / "out", "T"), dict(label="lq5"))
    calls.clear()
    # no learner's checkpoint: the trace from what an earlier drawing kept, if any (trace_figure says None if not)
    assert analysis.figures(runs[:2], labels[:2], tmp_path / "out", block=4) == ["r.png", "t.png"]
    (_, (runs_, labels_, out), kw), trace = calls
    assert [r.agent for r in runs_] == ["pd", "dqn"] and labels_ == ["pd", "dqn"] and kw == dict(block=4, title="")
    assert trace == ("trace", (None, tmp_path / "out", ""), dict(label=""))


# ------------------------------------------------------------ the report's row and section
def returns_by_episode(episodes, value):
    """Returns for episodes 1..``episodes`` as ``value(episode)``."""
    return [float(value(e)) for e in range(1, episodes + 1)]


def timed(df, ms):
    """Rows whose wall time makes ``ms`` milliseconds per seed-step (200 steps each)."""
    return df.assign(wall_s=ms * 1e-3 * df["steps"])


def test_the_row_shows_each_window_of_the_run(tmp_path):
    """Seed 0's return is -100 minus ten times the episode number (it never meets the threshold,
    -41), seed 1's -100 up to episode 10 and -30 after it: it meets it at episode 19 (episodes
    10-19: (-100 - 9 x 30) / 10 = -37; 9-18: -44). Every window's mean by hand."""
    seed0 = returns_by_episode(200, lambda e: -100 - 10 * e)
    seed1 = returns_by_episode(200, lambda e: -100 if e <= 10 else -30)
    df = timed(run_folder(tmp_path / "a", "dgpq", {0: seed0, 1: seed1}).df, 1.25)
    cells = [c.strip() for c in analysis.row("f16-dgpq-lq5", df).strip("|").split("|")]
    assert cells == ["dgpq-lq5", "2 x 200",
                     f"{(-155 - 100) / 2:.0f}",                       # episodes 1-10: seed 0 -155, seed 1 -100
                     f"{(-1600 - 30) / 2:.0f}",                       # 100-200: seed 0 -1,600
                     f"{(-2055 - 30) / 2:.0f} (191-200)",
                     "1 of 2, median 19", "1.25"]
    assert analysis.row("f16-pd", df.assign(**{"return": -37.0})).endswith(" | 2 of 2, median 10 | 1.25 |")
    short = df[df.episode <= 199]                                       # 100-200 is not whole
    assert analysis.row("f16-x", short).split(" | ")[3] == "- (not run to 200)"
    never = df[df.seed == 0]
    assert analysis.row("f16-x", never) == "| x | 1 x 200 | -155 | -1600 | -2055 (191-200) | 0 of 1 | 1.25 |"
    longer = timed(run_folder(tmp_path / "b", "dgpq", {0: returns_by_episode(250, lambda e: -2 * e)}).df, 1.0)
    assert analysis.row("f16-x", longer).split(" | ")[3] == "-300"       # episodes 100-200 of 250, no more


def test_the_late_window_is_gwh14s_or_the_last_ten_episodes():
    assert analysis.late_window(5) == (1, 5) and analysis.late_window(10) == (1, 10)
    assert analysis.late_window(11) == (2, 11) and analysis.late_window(999) == (990, 999)
    assert analysis.late_window(1000) == (901, 1000) and analysis.late_window(1500) == (901, 1000)


def fake(df, agent):
    return type("Run", (), dict(df=df, agent=agent))()


def test_the_report_section_against_gwh14_by_hand(tmp_path, monkeypatch):
    """L_Q 5: 2 seeds x 200 episodes, -70.5 in episodes 100-200 -- exactly 1.5 x GWH14's -47, the
    edge of "within" --, seed 0 stable at episode 20 (-100 - 10 e up to episode 10, -30 after);
    L_Q 10: 1 seed x 1,000 episodes, -113 in 900-1000 (GWH14's own); PD: a row, no sentence."""
    drawn = []
    monkeypatch.setattr(analysis, "figures", lambda *a, **k: drawn.append((a, k)))
    lq5 = timed(run_folder(tmp_path / "lq5", "dgpq", {
        0: returns_by_episode(200, lambda e: -100 - 10 * e if e <= 10 else -30 if e < 100 else -70.5),
        1: returns_by_episode(200, lambda e: -100 - 10 * e if e <= 10 else -70.5)}).df, 2.0)
    lq10 = timed(run_folder(tmp_path / "lq10", "dgpq", {0: returns_by_episode(1000, lambda e: -113 if e >= 900 else
                                                                             -200)}).df, 0.5)
    pd_ = timed(run_folder(tmp_path / "pd", "pd", {0: [-37.0] * 20}).df, 0.25)
    runs = {"f16-dgpq-lq5": fake(lq5, "dgpq"), "f16-dgpq-lq10": fake(lq10, "dgpq"), "f16-pd": fake(pd_, "pd")}
    out = tmp_path / "report"
    out.mkdir()
    judged = [J(Claim("k", "GWH14", "a claim", NoNumber(), None, ("f16-dgpq-lq5",)), "agrees", "ours")]
    text = analysis.reproduce_section(runs, out, "quick scale: 2 seeds", "the title", judged)
    assert (out / "f16").is_dir()
    assert drawn == [(([runs["f16-dgpq-lq5"], runs["f16-dgpq-lq10"], runs["f16-pd"]], ["dgpq-lq5", "dgpq-lq10", "pd"],
                       out / "f16"), dict(block=10, title="the title"))]
    assert text == (
        "## Aircraft altitude hold (GWH14's second experiment) -- Figure 3\n\nquick scale: 2 seeds\n\n"
        "| agent | seeds x episodes | episode reward, episodes 1-10 (mean over seed-episodes) | 100-200 (mean) "
        "| late (episodes; mean) | seeds flying stably (median first episode) | ms per seed-step |\n"
        "|---|---|---|---|---|---|---|\n"
        f"| dgpq-lq5 | 2 x 200 | -155 | {-70.5:.0f} | {-70.5:.0f} (191-200) | 1 of 2, median 20 | 2.00 |\n"
        "| dgpq-lq10 | 1 x 1000 | -200 | -200 | -113 (901-1000) | 0 of 1 | 0.50 |\n"
        "| pd | 1 x 20 | -37 | - (not run to 200) | -37 (11-20) | 1 of 1, median 10 | 0.25 |\n\n"
        "- GWH14: a claim (the source gives no number). Ours: ours -- **agrees**.\n\n"
        "![reward](f16/f16_reward.png)\n")      # no trace drawn: none linked


# ------------------------------------------------------------ optimism (issue 28)
def test_lqr_q_is_the_settings_reward_then_the_lqrs_discounted_by_hand():
    """No noise, decisions of 5 steps, gamma 0.9 and tol 0.85 (a horizon of 2 decisions): Q of
    each setting is its decision's reward plus 0.9 times the reward of the LQR's next decision
    (the gain from scipy's Riccati solver, r = 0.1), at two states."""
    from trl_dgpq.envs.f16.env import F16Config
    cfg = F16Config(noise_v=0.0, noise_alpha=0.0, decision_steps=5, max_steps=40)
    states = np.array([START, [-35.0, 2.0, 0.02, -0.01, 0.05]])
    q = analysis.lqr_q(cfg, torch.tensor(states), 0.9, rollouts=2, r=0.1, tol=0.85)
    k = lqr_gain_by_hand(0.25, r=0.1)
    for i, x0 in enumerate(states):
        for a, e in enumerate((-1.0, 0.0, 1.0)):
            x1, r0 = decision_by_hand(x0, e, 5)
            _, r1 = decision_by_hand(x1, float(quantise_by_hand(-k @ x1)) - 1.0, 5)
            assert float(q[i, a]) == pytest.approx(r0 + 0.9 * r1, rel=1e-7), (i, a)  # RK4 by hand


def test_visited_states_are_the_noise_free_flights_by_hand():
    from trl_dgpq.envs.f16.env import F16Config
    cfg = F16Config(noise_v=0.0, noise_alpha=0.0, decision_steps=5, max_steps=3)
    k = lqr_gain_by_hand(0.25, r=0.1)
    for policy, law in (("hold", lambda x: 0.0), ("lqr", lambda x: float(quantise_by_hand(-k @ x)) - 1.0)):
        got = analysis.visited(cfg, policy, episodes=2).numpy()
        x, want = START, []
        for _ in range(3):
            want.append(x)
            x, _ = decision_by_hand(x, law(x), 5)
        assert got.shape == (6, 5)
        np.testing.assert_allclose(got, np.repeat(np.array(want), 2, axis=0), rtol=1e-8, atol=1e-10, err_msg=policy)


def test_optimism_compares_qhat_with_the_lower_bound_per_seed(tmp_path, monkeypatch):
    """A DGPQ run whose Q̂ is all V_max = 0 at some states: against a lower bound of -1 nothing is
    below it; against +1 everything is, short by 1 where Q̂ is 0."""
    from trl_dgpq.commands import train
    out = tmp_path / "run"
    assert train.main(["--env", "f16", "--agent", "dgpq", "--seeds", "2,5", "--episodes", "1", "--max-steps", "2",
                       "--out", str(out), "--no-progress"]) == 0
    for bound, share in ((-1e6, 0.0), (1e6, 1.0)):
        monkeypatch.setattr(analysis, "lqr_q", lambda cfg, s, gamma, rollouts: torch.full((len(s), 3), bound))
        df = analysis.optimism(out, "hold", episodes=3, rollouts=1)
        assert df.seed.tolist() == [2, 5] and (df.L_Q == 5.0).all()
        for n in ("up", "hold", "down"):
            assert (df[f"below_{n}"] == share).all(), (bound, n)
        assert all(sum(g) == 6 for g in df.greedy)           # 3 episodes x 2 decisions
        assert df.q_start.tolist() == [[bound] * 3] * 2
        assert list(df.attrs["slopes"].index) == ["up", "hold", "down"]
    # above Q̂ at 2 of the 6 states: a share of exactly 1/3 (float64, not float32's 0.33333334)
    monkeypatch.setattr(analysis, "lqr_q", lambda cfg, s, gamma, rollouts:
                        torch.where(torch.arange(len(s))[:, None] % 3 == 0, 1e6, -1e6).expand(-1, 3))
    df = analysis.optimism(out, "hold", episodes=3, rollouts=1)
    assert df.below_up.tolist() == [1 / 3, 1 / 3]


def test_optimism_of_a_shaped_run_compares_qhat_with_q_minus_the_potential(tmp_path, monkeypatch):
    """The "cost" potential at the start (h 20 ft, hdot 0): -0.2 per step x 10 steps / (1 - 0.9) = -20, so a
    lower bound of -30 on Q is one of -10 on Q - phi: the shaped run's Q̂ is compared with that."""
    from trl_dgpq.commands import train
    out = tmp_path / "run"
    assert train.main(["--env", "f16", "--agent", "dgpq", "--preset", "flight-05-cost-shaped", "--seeds", "2",
                       "--episodes", "1", "--max-steps", "2", "--out", str(out), "--no-progress"]) == 0
    monkeypatch.setattr(analysis, "lqr_q", lambda cfg, s, gamma, rollouts: torch.full((len(s), 3), -30.0))
    df = analysis.optimism(out, "hold", episodes=1, rollouts=1)
    assert df.q_start.tolist() == [[-10.0] * 3] * len(df) and len(df) == 2   # --seeds 2: seeds 0 and 1


def test_optimism_refuses_a_run_without_qhat(tmp_path):
    from trl_dgpq.commands import train
    out = tmp_path / "run"
    assert train.main(["--env", "f16", "--agent", "pd", "--seeds", "2", "--episodes", "1", "--max-steps", "2",
                       "--out", str(out), "--no-progress"]) == 0
    with pytest.raises(ValueError, match="not a DGPQ run"):
        analysis.optimism(out)


def test_slopes_are_the_quantiles_of_q_differences_over_l1_distances():
    """Three states on a line at 0, 1 and 3 with Q of action 0 at 0, 2 and 3: the pair slopes
    are 2, 1 and 1/2 (median 1, max 2); action 1 flat (0); pairs closer than 0.05 left out."""
    f = torch.tensor([[0.0, 0.0], [1.0, 0.0], [2.0, 1.0], [2.0, 1.01]], dtype=torch.float64)
    q = torch.tensor([[0.0, 5.0, 0.0], [2.0, 5.0, 0.0], [3.0, 5.0, 9.0], [3.0, 5.0, 0.0]], dtype=torch.float64)
    got = analysis.slopes(f[:3], q[:3])
    assert got.loc["up", "max"] == pytest.approx(2.0) and got.loc["up", "median"] == pytest.approx(1.0)
    assert got.loc["hold", "max"] == 0.0
    assert analysis.slopes(f, q).loc["down", "max"] == pytest.approx(9.0 / 2.0)   # 0.01 apart: left out
