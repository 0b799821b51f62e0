"""envs/square/analysis.py's figure and section by hand (its claims and their measures:
test_claims and test_square_paper_tuned): REPORT.md's section with its figures stubbed, qhat.png
read back from made-up data, what it keeps of a real DGPQ run (Q̂ by Eq. 7 from the checkpoint's
pairs, the greedy episode against evaluate's), and the figures a run gets."""
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
import torch

from trl_dgpq.analysis.runs import Run
from trl_dgpq.envs.square import analysis as sq


def run(steps_per_seed, path="runs/s", max_steps=100, agent="dgpq", **extra):
    rows = [dict(seed=s, episode=e + 1, steps=n, wall_s=n * 1e-3) for s, steps in steps_per_seed.items()
            for e, n in enumerate(steps)]
    df = pd.DataFrame(rows)
    for k, v in extra.items():
        df[k] = v
    return Run(Path(path), df, {"run": {"env": "square", "agent": agent, "preset": "shaped"},
                                "env": {"max_steps": max_steps}, "agent": {}})


def test_the_section_by_hand_with_its_figures_stubbed(tmp_path, monkeypatch):
    """Two seeds alike (so each interval is its point): episode 1 at the cap of 100, episodes 3+'s
    median 17.5, the last 5 (2-6) 24.2, 2 of 12 episodes capped; one seed of one uncapped 5,000-step
    episode, with 3 kernel fits and 2 ms a step: no episode 3."""
    import trl_dgpq.analysis.figures as figures
    import trl_dgpq.collectors.evaluate as evaluate
    figured, qhat = [], []
    monkeypatch.setattr(figures, "episode_figures", lambda runs, labels, out, title: figured.append(
        (runs, labels, out, title)))
    monkeypatch.setattr(sq, "qhat_figure", lambda folder, out, title: qhat.append((folder, out, title)))
    monkeypatch.setattr(evaluate, "job_folders", lambda path: [] if path == Path("runs/shaped") else None)
    shaped = run({0: [100, 50, 20, 18, 17, 16], 1: [100, 50, 20, 18, 17, 16]}, path="runs/shaped")
    long = run({4: [5000]}, max_steps=20_000, kernel_fits=[3], wall_s=[10.0])
    runs = {"square-shaped": shaped, "square-report-nocap": long}
    judged = [SimpleNamespace(bullet=lambda: "- a verdict.")]
    text = sq.reproduce_section(runs, tmp_path, "LABEL", "TITLE", judged)
    assert (tmp_path / "square").is_dir() and (tmp_path / "square-kernels").is_dir()
    assert figured == [([shaped], ["shaped"], tmp_path / "square", "TITLE"), ([], [], tmp_path / "square-kernels",
                                                                             "TITLE")]
    assert qhat == [(None, tmp_path / "square", "TITLE")]                    # no checkpoint: figured from kept data
    assert text == (
        "## Square (seed report 4.1; GWH14's first experiment) -- Figures 2-4\n\nLABEL\n\n"
        "| run | seeds x episodes | episode 1 steps: IQM [95 % CI] over seeds | episodes 3+: each seed's median "
        "steps, IQM [95 % CI] | last 5 episodes: each seed's mean steps, IQM [95 % CI] | capped episodes (share) "
        "| kernel fits per seed (mean) | ms per seed-step |\n|---|---|---|---|---|---|---|---|\n"
        "| shaped | 2 x 6 | 100.0 | 17.5 | 24.2 | 17% | 0 | 1.00 |\n"
        "| report-nocap | 1 x 1 | 5000.0 | – | 5000.0 | 0% | 3 | 2.00 |\n\n"
        "- a verdict.\n"
        "- RBF against the manifold kernel (Figure 4; exact GP, shaped): the rows shaped-exact and shaped-manifold. "
        "sigma_tol2 is reached after one sample, so the GPs hold a point or two and the kernel barely matters here.\n\n"
        "![steps](square/steps_per_episode.png) ![time](square/time_per_step.png) "
        "![kernels](square-kernels/steps_per_episode.png)\n")
    # a checkpoint: Q̂ figured from it, and the figure named; the kernels' runs in their figure by their names
    monkeypatch.setattr(evaluate, "job_folders", lambda path: [path] if path == Path("runs/shaped") else None)
    monkeypatch.setattr(sq, "qhat_figure", lambda folder, out, title: qhat.append((folder, out, title)) or "x")
    exact, manifold, paper, report = run({0: [9]}), run({0: [8]}), run({0: [7]}), run({0: [6]})
    runs = {"square-shaped-manifold": manifold, "square-paper": paper, "square-shaped": shaped,
            "square-report": report, "square-shaped-exact": exact}
    text = sq.reproduce_section(runs, tmp_path, "L", "T", [])
    assert qhat[-1] == (Path("runs/shaped"), tmp_path / "square", "T")
    assert figured[-2] == ([shaped, report, paper], ["shaped", "report", "paper"], tmp_path / "square", "T")
    assert figured[-1] == ([exact, manifold], ["RBF (exact GP)", "manifold (exact GP)"], tmp_path / "square-kernels",
                         "T")
    assert text.endswith("![kernels](square-kernels/steps_per_episode.png) ![Q̂](square/qhat.png)\n")
    assert [line.split(" | ")[0] for line in text.splitlines() if line.startswith(("| shaped", "| paper", "| report"))
            ] == ["| shaped-manifold", "| paper", "| shaped", "| report", "| shaped-exact"]
    del runs["square-shaped"]
    sq.reproduce_section(runs, tmp_path, "L", "T", [])
    assert qhat[-1] == (None, tmp_path / "square", "T")                      # no shaped run


DRAWN = dict(q=[[[0.1 * (i + 2 * j) + a for a in range(3)] for j in range(4)] for i in range(4)],
             names=["N", "S", "E"], pairs=[[[0.1, 0.2], [0.3, 0.4]], [], [[0.5, 0.5]]],
             path=[[0.0, 0.0], [0.1, 0.0], [0.1, 0.1]], goal=[0.9, 0.8], radius=0.15, seed=3, run="square-shaped")


def test_the_qhat_figure_reads_back_as_drawn(tmp_path, monkeypatch, saved_figures):
    """Three actions: three Q̂ panels on one colour scale (each with its pairs as dots), the greedy
    value, the greedy action; every panel with the goal's circle and the greedy path; kept as data."""
    from trl_dgpq.analysis.figures import load_drawn
    monkeypatch.setattr(sq, "qhat_drawn", lambda folder: DRAWN if folder == Path("run") else None)
    assert sq.qhat_figure(Path("run"), tmp_path, "T") == tmp_path / "qhat.png"
    assert load_drawn(tmp_path / "qhat.json.xz", fresh=True) == DRAWN
    fig = saved_figures["qhat.png"]
    q = np.asarray(DRAWN["q"])
    panels = [ax for ax in fig.axes if ax.get_images()]
    assert len(panels) == 5
    for a, ax in enumerate(panels[:3]):
        im, = ax.get_images()
        assert (np.asarray(im.get_array()) == q[:, :, a]).all() and im.origin == "lower"
        assert im.get_extent() == [0, 1, 0, 1] and im.get_clim() == (q.min(), q.max())
        assert im.get_cmap().name == "viridis"
        dots = ax.get_lines()[0]
        assert dots.get_linestyle() == "None" and dots.get_marker() == "."
        assert list(dots.get_xdata()) == [p[0] for p in DRAWN["pairs"][a]]
        assert list(dots.get_ydata()) == [p[1] for p in DRAWN["pairs"][a]]
        assert ax.get_title() == f"Q̂({DRAWN['names'][a]}): {len(DRAWN['pairs'][a])} pairs"
    value, action = panels[3].get_images()[0], panels[4].get_images()[0]
    assert (np.asarray(value.get_array()) == q.max(-1)).all() and panels[3].get_title() == "greedy value max_a Q̂"
    assert (np.asarray(action.get_array()) == q.argmax(-1)).all() and action.get_clim() == (-0.5, 2.5)
    assert panels[4].get_title() == "greedy action (ties: lowest index)"
    assert [t.get_text() for t in panels[4].get_legend().get_texts()] == ["N", "S", "E"]
    for ax in panels:
        circle, = ax.patches
        assert tuple(circle.center) == (0.9, 0.8) and circle.radius == 0.15 and not circle.get_fill()
        path = ax.get_lines()[-1] if ax in panels[3:] else ax.get_lines()[1]
        assert list(path.get_xdata()) == [0.0, 0.1, 0.1] and list(path.get_ydata()) == [0.0, 0.0, 0.1]
        assert ax.get_xlim() == (0, 1) and ax.get_ylim() == (0, 1) and ax.get_xlabel() == "x"
    assert panels[0].get_ylabel() == "y" and panels[1].get_ylabel() == ""
    assert len(fig.axes) == 7                                                 # two colour bars
    assert fig._suptitle.get_text() == ("T: seed 3 after square-shaped's training; dots: Q̂'s pairs; red: the goal "
                                        "and a greedy evaluation episode (2 steps)")
    for ax in panels[3:]:
        im, = ax.get_images()
        assert im.origin == "lower" and im.get_extent() == [0, 1, 0, 1]
    assert value.get_cmap().name == "viridis" and value.get_clim() == (q.max(-1).min(), q.max(-1).max())
    assert action.get_cmap().name == "tab10" and action.get_cmap().N == 3
    assert [(h.get_marker(), h.get_color()) for h in panels[4].get_legend().legend_handles] == [
        ("s", action.get_cmap()(a)) for a in range(3)]
    legend = panels[4].get_legend()
    assert legend._loc == 4 and {t.get_fontsize() for t in legend.get_texts()} == {7}   # lower right
    # the colour bars: the Q̂ panels' shared scale beside the last of them, the greedy value's beside it
    bars = [ax for ax in fig.axes if ax not in panels]
    assert [b.get_ylim() for b in bars] == [(q.min(), q.max()), value.get_clim()]
    for bar, parent, nxt in zip(bars, (panels[2], panels[3]), (panels[3], panels[4])):
        box, p = bar.get_position(), parent.get_position()
        assert p.x1 < box.x0 < nxt.get_position().x0
    for ax in panels:
        assert ax.title.get_fontsize() == 9
        circle, = ax.patches
        assert circle.get_edgecolor() == (1.0, 0.0, 0.0, 1.0) and circle.get_linewidth() == 1.2
        path = ax.get_lines()[-1]
        assert (path.get_linestyle(), path.get_color(), path.get_linewidth()) == ("-", "r", 1.0)
    for ax in panels[:3]:
        dots = ax.get_lines()[0]
        assert (dots.get_color(), dots.get_markersize(), dots.get_alpha()) == ("w", 2, 0.7)
    assert fig._suptitle.get_fontsize() == 9 and tuple(fig.get_size_inches()) == pytest.approx((15.5, 3.3))
    assert type(fig.get_layout_engine()).__name__ == "ConstrainedLayoutEngine"
    from PIL import Image
    assert Image.open(tmp_path / "qhat.png").size == (1705, 363)                    # 110 dpi
    assert saved_figures.problems("qhat.png") == []
    sq.qhat_figure(Path("run"), tmp_path)
    assert saved_figures["qhat.png"]._suptitle.get_text().startswith("seed 3 after")
    assert sq.qhat_figure(Path("another"), tmp_path / "x") is None           # an agent without Q̂
    assert not (tmp_path / "x" / "qhat.json.xz").exists()


def test_what_the_qhat_figure_keeps_of_a_real_run(tmp_path):
    """A DGPQ run of 2 seeds: Q̂ on the grid is Eq. 7 over seed row 0's pairs of the checkpoint
    (min(V_max, mu + L_Q |s - s_i|_1), L1 distance); its pairs are the finite ones; the greedy path
    starts where evaluation starts and has the steps of evaluate's first episode of the first seed."""
    from trl_dgpq.collectors.evaluate import evaluate, restore
    from trl_dgpq.commands import train
    out = tmp_path / "run"
    assert train.main(["--seeds", "5,2", "--episodes", "3", "--out", str(out), "--no-progress"]) == 0
    got = sq.qhat_drawn(out)
    config, env, agent, state = restore(out)
    mu, s = state["agent"]["qhat"]["mu"][0], state["agent"]["qhat"]["s"][0]           # (A, capacity[, 2])
    q = np.asarray(got["q"])
    xs = np.linspace(0, 1, 41)
    for i, j in ((0, 0), (40, 3), (17, 29), (40, 40)):
        x = torch.tensor([xs[j], xs[i]], dtype=torch.float64)
        envelope = (mu + agent.cfg.lipschitz * (s - x).abs().sum(-1)).amin(-1).clamp_max(agent.cfg.v_max)
        assert q[i, j].tolist() == pytest.approx(envelope.tolist(), abs=1e-12)
    assert q.shape == (41, 41, 4)
    assert [len(p) for p in got["pairs"]] == torch.isfinite(mu).sum(-1).tolist() and sum(map(len, got["pairs"])) > 0
    for a, pairs in enumerate(got["pairs"]):
        assert pairs == s[a][torch.isfinite(mu[a])].tolist()
    assert got["names"] == list(env.action_names) and got["goal"] == list(env.cfg.goal)
    assert (got["radius"], got["seed"], got["run"]) == (env.cfg.goal_radius, 5, "run")
    ev = evaluate(out, episodes=1)
    path = np.asarray(got["path"])
    assert len(path) - 1 == int(ev[ev.seed == 5].steps.iloc[0])
    env.for_evaluation()
    assert path[0].tolist() == env.reset()["observation"][0].tolist()
    assert ((path >= 0) & (path <= 1)).all() and (np.abs(np.diff(path, axis=0)) < 0.2).all()   # one move a step
    assert sq.greedy_path(env, agent, row=1).shape[1] == 2


def test_what_a_run_without_qhat_keeps_is_nothing(tmp_path):
    from trl_dgpq.commands import train
    out = tmp_path / "random"
    assert train.main(["--agent", "random", "--seeds", "1", "--episodes", "1", "--out", str(out),
                       "--no-progress"]) == 0
    assert sq.qhat_drawn(out) is None and sq.qhat_figure(out, tmp_path) is None


def test_the_figures_of_a_run_are_the_episode_figures_and_the_first_dgpq_runs_qhat(tmp_path, monkeypatch):
    import trl_dgpq.analysis.figures as figures
    import trl_dgpq.collectors.evaluate as evaluate
    monkeypatch.setattr(figures, "episode_figures", lambda runs, labels, out, title: [f"episodes {title}"])
    monkeypatch.setattr(evaluate, "job_folders", lambda path: [] if path.name == "none" else [path])
    asked = []
    monkeypatch.setattr(sq, "qhat_figure", lambda folder, out, title: asked.append(folder) or (
        None if folder.name == "nothing" else out / f"qhat {title}.png"))
    dqn, none, dgpq, other = (run({0: [1]}, path=p, agent=a) for p, a in (
        ("runs/dqn", "dqn"), ("runs/none", "dgpq"), ("runs/dgpq", "dgpq"), ("runs/other", "dgpq")))
    assert sq.figures([dqn, none, dgpq, other], list("abcd"), tmp_path, title="T") == ["episodes T",
                                                                                     tmp_path / "qhat T.png"]
    assert asked == [Path("runs/dgpq")]                                       # the first with a checkpoint only
    nothing = run({0: [1]}, path="runs/nothing")
    assert sq.figures([nothing, dgpq], list("ab"), tmp_path) == ["episodes "] and asked[-1] == Path("runs/nothing")
    unconfigured = Run(Path("runs/dgpq"), dgpq.df, None)
    assert sq.figures([unconfigured], ["u"], tmp_path) == ["episodes "] and len(asked) == 2


def test_the_greedy_path_is_its_rows_positions_until_that_row_is_done(monkeypatch):
    """Evaluation streams, then the row's start and its position after each step of an episode
    played until that row ends (not every row)."""
    import trl_dgpq.collectors.evaluate as evaluate
    calls = []
    obs = lambda k: {"observation": torch.tensor([[0.1 * k, 0.0], [0.0, 0.1 * k]])}  # noqa: E731
    env = SimpleNamespace(for_evaluation=lambda: calls.append("evaluation"), reset=lambda: calls.append("reset") or
                          obs(0))
    agent = SimpleNamespace(exploit=lambda td: "greedy", act=lambda td: "exploring")

    def steps(e, policy, td, row):
        calls.append(("steps", row, policy(td)))
        return iter([(None, obs(k), None) for k in (1, 2)])
    monkeypatch.setattr(evaluate, "episode_steps", steps)
    assert np.allclose(sq.greedy_path(env, agent, 1), [[0.0, 0.0], [0.0, 0.1], [0.0, 0.2]])
    assert calls == ["evaluation", "reset", ("steps", 1, "greedy")]
    assert np.allclose(sq.greedy_path(env, agent), [[0.0, 0.0], [0.1, 0.0], [0.2, 0.0]])
    assert calls[-1] == ("steps", 0, "greedy")


def test_the_claims_words_rules_and_runs():
    """GWH14's two claims on each reward (its own, capped far out, and the seed report's shaped one:
    a variant), the seed report's own episode-1 claim."""
    from trl_dgpq.analysis.claims import Agrees
    claims = {c.key: c for c in sq.declared_claims()}
    assert list(claims) == ["square/paper/episode-1", "square/paper/episodes-3+", "square/shaped/episode-1",
                            "square/shaped/episodes-3+", "square/report/episode-1"]
    paper = "GWH14's reward, -1 per step (`paper`), capped at 20,000 steps"
    shaped = "the seed report's shaped reward (`shaped`)"
    for key, reward, name, base in (("paper", paper, "square-paper-nocap", "square-random-paper"),
                                    ("shaped", shaped, "square-shaped", "square-random")):
        one, later = claims[f"square/{key}/episode-1"], claims[f"square/{key}/episodes-3+"]
        assert one.statement == f"DGPQ reaches the goal in ~100 steps in episode 1; run on {reward}"
        assert later.statement == ("~20 steps per episode (the optimum ~17) within 2-3 episodes: each seed's median "
                                   f"from episode 3 on; run on {reward}")
        assert one.rule == Agrees(100, 3, higher_is_better=False) and later.rule == Agrees(20, 1.5,
                                                                                           higher_is_better=False)
        assert one.source == later.source == "GWH14" and one.needs == later.needs == (name,)
        assert one.baseline is None and later.baseline == base
    report = claims["square/report/episode-1"]
    assert report.source == "the seed report" and report.needs == ("square-report-nocap",)
    assert report.statement == ("its settings (exact GP, Section 5's values, L_Q 9) take 1,000-5,000 steps in "
                                "episode 1; run capped at 20,000 steps")
    assert report.rule == Agrees(5000 ** 0.5 * 1000 ** 0.5, 5 ** 0.5, higher_is_better=False)
    assert report.rule.band() == pytest.approx((1000, 5000))
    assert report.source_model == ("reward: the distance to the goal (its position)",)
