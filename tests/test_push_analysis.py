"""envs/push/analysis.py by hand, each function called at test time (the module's CLAIMS are built at
import): push.md line by line, push.png read back, the claim's words and measure, the REPORT.md
section, the camera's calls to pybullet, a world point's pixel by hand, and the animation composed
from made-up frames (pybullet, the checkpoint and the agents stubbed: the real episode is
test_evaluate's)."""
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from tests.fake_pybullet import Recorder
from trl_dgpq.analysis.claims import NoNumber
from trl_dgpq.analysis.runs import Run
from trl_dgpq.envs.push import analysis as pa


def run(rows, agent="dgpq", path="runs/p", **extra):
    """rows: (seed, episode, steps, success, fell_off) each; wall time 2 ms a step."""
    df = pd.DataFrame([dict(seed=s, episode=e, steps=n, success=w, fell_off=f, wall_s=0.002 * n,
                            distance=0.1 * n) for s, e, n, w, f in rows])
    for k, v in extra.items():
        df[k] = v
    config = {"run": {"env": "push", "agent": agent, "preset": "shaped", "seeds": sorted(set(df.seed))},
              "env": {}, "agent": {}}
    return Run(Path(path), df, config)


ROWS = [(0, 1, 50, False, False), (0, 2, 10, True, False), (0, 3, 12, True, False),
        (1, 1, 50, False, False), (1, 2, 30, False, True), (1, 3, 20, True, False),
        (2, 1, 8, True, False), (2, 2, 50, False, False), (2, 3, 50, False, False)]
HEADER = ("| run | seeds x episodes | success, last {} episodes (share of seed-episodes) | steps to goal (mean "
          "over those successes) | fell off (share) | first success (median episode over seeds) | kernel fits per "
          "seed (mean) | ms per seed-step |\n|---|---|---|---|---|---|---|---|\n")


def test_the_table_by_hand():
    """Last 2 episodes (2-3): 3 successes of 6 (10, 12 and 20 steps: 14.0), 1 fall of 6; first
    successes at 2, 3 and 1 (median 2); kernel fits 2, 4 and 0 (mean 2); 2 ms a step. A seed that
    never succeeds counts as last in the median and is counted; no success: no steps."""
    r = run(ROWS, kernel_fits=[0, 1, 2, 0, 0, 4, 0, 0, 0])
    note = "\n\nLast {} episodes of each run; steps to goal: mean over its successful ones.\n"
    assert pa.table([r], ["rbf"], 2) == HEADER.format(2) + (
        "| rbf | 3 x 3 | 50.0% | 14.0 | 16.7% | 2 | 2 | 2.00 |") + note.format(2)
    never = run([row for row in ROWS if row[0] != 2] + [(2, e, 50, False, False) for e in (1, 2, 3)])
    lost = run([(s, e, 50, False, False) for s in (0, 1) for e in (1, 2)])
    assert pa.table([never, lost], ["a", "b"], 1).splitlines()[2:4] == [
        "| a | 3 x 3 | 66.7% | 16.0 | 0.0% | 3 (1 never) | 0 | 2.00 |",
        "| b | 2 x 2 | 0.0% | – | 0.0% | never (2 never) | 0 | 2.00 |"]


def test_the_figure_draws_the_final_distance_and_the_success_rate_per_episode(tmp_path, drawn, monkeypatch):
    """Upper panel: the median distance over seeds per episode (distance 0.1 x steps here), labelled
    with the seed count; lower: the share of seeds that succeeded, in the same colour; push.md is
    the table of the last 20 episodes by default; the animation only of a learner with a checkpoint."""
    import trl_dgpq.collectors.evaluate as evaluate
    a, oracle = run(ROWS, path=tmp_path / "a"), run(ROWS[:6], agent="oracle", path=tmp_path / "o")
    assert pa.figures([a, oracle], ["DGPQ", "oracle"], tmp_path, title="T") == [tmp_path / "push.png",
                                                                              tmp_path / "push.md"]
    assert (tmp_path / "push.md").read_text() == pa.table([a, oracle], ["DGPQ", "oracle"], 20)
    fig, title = drawn["push.png"]
    ax, sax = fig.axes
    assert title == "T"
    dist, odist = ax.get_lines()
    assert dist.get_label() == "DGPQ (3 seeds)" and odist.get_label() == "oracle (2 seeds)"
    assert list(dist.get_xdata()) == [1, 2, 3] and list(dist.get_ydata()) == pytest.approx([5.0, 3.0, 2.0])
    assert list(odist.get_ydata()) == pytest.approx([5.0, 2.0, 1.6])
    rate, orate = sax.get_lines()
    assert list(rate.get_xdata()) == [1, 2, 3] and list(rate.get_ydata()) == pytest.approx([1 / 3, 1 / 3, 2 / 3])
    assert list(orate.get_ydata()) == pytest.approx([0, 0.5, 1])
    assert rate.get_color() == dist.get_color() != orate.get_color() == odist.get_color()
    band = ax.collections[0].get_paths()[0].vertices                  # the IQR over 1, 3 and 5 m at episode 2
    assert sorted(set(band[band[:, 0] == 2, 1].round(9))) == [2.0, 4.0]
    assert ax.get_ylabel() == "block's final distance to the goal (m)"
    assert sax.get_ylabel() == "success rate (share of seeds)" and sax.get_xlabel() == "episode"
    assert sax.get_ylim() == (-0.03, 1.03)
    assert ax.get_legend().get_title().get_text() == "median, shaded: inter-quartile range"
    assert ax.get_title() == ("block pushing: the block's final distance to the goal, and success, per episode")
    # the looks: a square figure, distance above success at 3 : 2 on one x axis
    assert tuple(fig.get_size_inches()) == (6.4, 6.4) and ax.get_shared_x_axes().joined(ax, sax)
    assert tuple(ax.get_subplotspec().get_gridspec().get_height_ratios()) == (3, 2)
    assert rate.get_linewidth() == dist.get_linewidth() == 1.2 and ax.title.get_fontsize() == 9
    assert {t.get_fontsize() for t in [*ax.get_legend().get_texts(), ax.get_legend().get_title()]} == {8}
    assert {g.get_alpha() for a in (ax, sax) for g in a.yaxis.get_gridlines()} == {0.3}
    assert pa.figures([a], ["DGPQ"], tmp_path, last=1) and (tmp_path / "push.md").read_text() == pa.table(
        [a], ["DGPQ"], 1)
    assert drawn["push.png"][1] == ""                                     # no title by default
    # a learner with a checkpoint gets its animation; the oracle never, the first learner only
    animated = []
    monkeypatch.setattr(evaluate, "job_folders", lambda path: [path])
    monkeypatch.setattr(pa, "animation", lambda folder, out: animated.append((folder, out)) or out / "push.gif")
    b = run(ROWS, path=tmp_path / "b")
    assert pa.figures([oracle, a, b], ["o", "a", "b"], tmp_path)[-1] == tmp_path / "push.gif"
    assert animated == [(tmp_path / "a", tmp_path)]
    monkeypatch.setattr(evaluate, "job_folders", lambda path: [] if path == tmp_path / "a" else [path])
    pa.figures([oracle, a, b], ["o", "a", "b"], tmp_path)
    assert animated[-1] == (tmp_path / "b", tmp_path)


def test_the_claim_is_each_seeds_success_over_its_last_20_episodes():
    """Seed 0 succeeds in episodes 6-25 (all its last 20), seed 1 in every fifth; 25 episodes each."""
    rows = [(0, e, 10, e > 5, False) for e in range(1, 26)] + [(1, e, 10, e % 5 == 0, False) for e in range(1, 26)]
    got = pa.success("x")({"x": run(rows)})
    assert got.point == pytest.approx(0.6) and got.statistic == "IQM over 2 seeds [95 % CI]"
    rows[5] = (0, 6, 10, False, False)                   # episode 6 is in the last 20: seed 0 at 19 / 20
    assert pa.success("x")({"x": run(rows)}).point == pytest.approx((0.95 + 0.2) / 2)
    claim, = pa.declared_claims()
    assert claim.key == "push/learns" and claim.source == "the seed report" and isinstance(claim.rule, NoNumber)
    assert claim.statement == ("DGPQ reached the goal within three episodes, with very spiky performance (its code "
                               "never stepped the robot); ours: success over the last 20 episodes")
    assert claim.needs == ("push-rbf",) and claim.fmt == "{:.0%}"
    assert claim.source_model == ("reward: the block's distance to the goal (its position)",)
    assert claim.measure({"push-rbf": run(rows)}).point == pytest.approx(0.575)


def test_the_section_by_hand_with_its_figures_stubbed(tmp_path, monkeypatch):
    called = []

    def figures(runs, labels, out, last, title):
        called.append((runs, labels, out, last, title))
        (out / "push.md").write_text("TABLE\n")
    monkeypatch.setattr(pa, "figures", figures)
    runs = {"push-rbf": 1, "push-manifold": 2, "push-oracle": 3}
    judged = [SimpleNamespace(bullet=lambda: "- a claim."), SimpleNamespace(bullet=lambda: "- another.")]
    text = pa.reproduce_section(runs, tmp_path, "LABEL", "TITLE", judged)
    assert called == [([1, 2, 3], ["DGPQ RBF", "DGPQ manifold", "oracle"], tmp_path / "push", 20, "TITLE")]
    assert text == ("## Block pushing (seed report 4.3) -- Figure 5\n\nLABEL\n\nTABLE\n\n- a claim.\n- another. GWH14 "
                    "had no robot experiment.\n\n![push](push/push.png)\n")
    (tmp_path / "push" / "push.gif").write_bytes(b"")
    assert pa.reproduce_section(runs, tmp_path, "L", "T", judged).endswith(
        "![push](push/push.png) ![an evaluation episode](push/push.gif)\n")


# ------------------------------------------------------------------ the animation's pieces
def test_a_world_points_pixel_through_column_major_matrices_by_hand():
    """Identity projection, a view that moves x by 0.5 (column-major: the translation is entries
    12-14): the origin lands at x = 0.5, pixel 0.75 w; a projection with w = 2 halves both."""
    eye = np.eye(4)
    view = eye.copy()
    view[3, 0] = 0.5                                          # row-major [3, 0]: the flat list's 12th entry
    view = view.reshape(-1).tolist()
    assert pa.pixel((0.0, 0.0, 0.0), view, eye.reshape(-1).tolist(), 400, 200) == pytest.approx((300.0, 100.0))
    assert pa.pixel((0.0, 0.5, 0.0), view, eye.reshape(-1).tolist(), 400, 200) == pytest.approx((300.0, 50.0))
    half = np.diag([1.0, 1.0, 1.0, 2.0]).reshape(-1).tolist()
    assert pa.pixel((0.0, 0.5, 0.0), view, half, 400, 200) == pytest.approx((250.0, 75.0))


@pytest.fixture
def fake_pb(monkeypatch):
    """The camera's matrices as names; a made-up RGBA image rendered."""
    from trl_dgpq.envs.push import env
    pb = Recorder(computeViewMatrixFromYawPitchRoll="VIEW", computeProjectionMatrixFOV="PROJECTION",
                  getCameraImage=lambda width, height, *_, **__: (
                      width, height, (np.arange(width * height * 4) % 251).tolist(), None, None))
    monkeypatch.setattr(env, "pb", pb)
    return pb


def test_the_camera_looks_at_the_table_from_its_side(fake_pb):
    assert pa.camera(480, 240) == ("VIEW", "PROJECTION")
    assert fake_pb.named("computeViewMatrixFromYawPitchRoll") == [(((0.0, 0.0, 0.62), 0.6, 0.0, -45.0, 0.0, 2), {})]
    assert fake_pb.named("computeProjectionMatrixFOV") == [((60.0, 2.0, 0.05, 5.0), {})] and len(fake_pb.calls) == 2


def test_a_frame_is_the_rows_world_as_rgb(fake_pb):
    env = SimpleNamespace(worlds=[SimpleNamespace(client=4), SimpleNamespace(client=9)])
    got = pa.frame(env, 1, 6, 3)
    assert fake_pb.named("getCameraImage") == [((6, 3, "VIEW", "PROJECTION"), dict(renderer=7, physicsClientId=9))]
    want = (np.arange(6 * 3 * 4) % 251).reshape(3, 6, 4)[..., :3]
    assert got.dtype == np.uint8 and got.shape == (3, 6, 3) and (got == want).all()


def test_an_episodes_frames_are_the_start_and_one_per_step_of_its_row(monkeypatch):
    import trl_dgpq.collectors.evaluate as evaluate
    env = SimpleNamespace(reset=lambda: "TD")
    seen = []
    monkeypatch.setattr(pa, "frame", lambda e, row, w, h: seen.append((e, row, w, h)) or len(seen))
    monkeypatch.setattr(evaluate, "episode_steps", lambda e, policy, td, row: iter(
        [(td, policy, row)] * 3 if (e, td, row) == (env, "TD", 1) else []))
    assert pa.episode_frames(env, "POLICY", 1, 20, 10) == [1, 2, 3, 4]
    assert seen == [(env, 1, 20, 10)] * 4
    assert pa.episode_frames(env, "POLICY", 1) == [5, 6, 7, 8] and seen[-1] == (env, 1, *pa.FRAME)
    assert pa.episode_frames(env, "POLICY") == [9] and seen[-1] == (env, 0, *pa.FRAME)   # row 0 by default


def test_the_animation_stacks_the_learner_above_the_oracle_with_the_goal_ringed(tmp_path, monkeypatch):
    """Made-up frames: the learner's 3 (grey levels 50, 100, 150), the oracle's 2 (blue); 3 GIF frames
    of 120 ms, looping; a panel that has ended holds its last frame and says so; the goal's ring from
    its centre and radius through ``pixel``; each panel labelled with its agent and step."""
    from PIL import Image, ImageDraw

    import trl_dgpq.agents as agents
    import trl_dgpq.collectors.evaluate as evaluate
    W, H = 64, 240
    goal, radius = (0.3, 0.1), 0.05
    evaluated = []
    env = SimpleNamespace(info="INFO", for_evaluation=lambda: evaluated.append(1),
                          cfg=SimpleNamespace(goal=goal, goal_radius=radius))
    agent = SimpleNamespace(exploit=lambda td: "LEARNER", act=lambda td: "EXPLORING")
    made = []

    class Oracle:
        Config = dict

        @classmethod
        def make(cls, cfg, info, seeds):
            made.append((cfg, info, seeds))
            return SimpleNamespace(act=lambda td: "ORACLE")
    monkeypatch.setattr(evaluate, "jobs", lambda folder: [folder / "job"])
    config = {"run": {"agent": "dgpq", "env": "push", "seeds": [5, 6]}}
    monkeypatch.setattr(evaluate, "restore", lambda job: (config, env, agent, None)
                        if job == tmp_path / "run" / "job" else None)
    monkeypatch.setattr(agents, "agent_class", lambda name, env_name: Oracle if (name, env_name) == (
        "oracle", "push") else None)

    def frames(e, policy, row, width, height):
        assert (e, row, width, height, len(evaluated)) == (env, 0, W, H, 1 + (policy(None) == "ORACLE"))
        if policy(None) == "LEARNER":
            return [np.full((H, W, 3), g, np.uint8) for g in (50, 100, 150)]
        return [np.tile(np.array([0, 0, 200], np.uint8), (H, W, 1))] * 2
    monkeypatch.setattr(pa, "episode_frames", frames)
    monkeypatch.setattr(pa, "camera", lambda w, h: ("V", "P") if (w, h) == (W, H) else None)
    # the goal's centre at (40, 120), its edge 6 pixels east and 4 south: the ring's box 34-46 x 116-124
    where = {(0.3, 0.1): (40.0, 120.0), (0.35, 0.1): (46.0, 120.0), (0.3, 0.15): (40.0, 124.0)}
    monkeypatch.setattr(pa, "pixel", lambda xyz, v, p, w, h: where[(round(xyz[0], 9), round(xyz[1], 9))]
                        if (xyz[2], v, p, w, h) == (0.625, "V", "P", W, H) else None)
    texts, rings = [], []
    text, ellipse = ImageDraw.ImageDraw.text, ImageDraw.ImageDraw.ellipse
    monkeypatch.setattr(ImageDraw.ImageDraw, "text", lambda self, xy, s, **kw: texts.append(
        (xy, s, kw["fill"], kw["font"].size)) or text(self, xy, s, **kw))
    monkeypatch.setattr(ImageDraw.ImageDraw, "ellipse", lambda self, box, **kw: rings.append((box, kw))
                        or ellipse(self, box, **kw))
    path = pa.animation(tmp_path / "run", tmp_path, W, H)
    assert path == tmp_path / "push.gif" and made == [({}, "INFO", [5, 6])]
    assert [s for _, s, _, _ in texts] == ["dgpq: step 0", "oracle: step 0", "dgpq: step 1", "oracle: step 1 (done)",
                                        "dgpq: step 2 (done)", "oracle: step 1 (done)"]
    assert {(xy, fill, size) for xy, _, fill, size in texts} == {((6, 4), (0, 0, 0), 16)}   # 240 // 15 pixels
    assert rings == [((34.0, 116.0, 46.0, 124.0), dict(outline=(220, 0, 0), width=2))] * 6
    gif = Image.open(path)
    assert gif.size == (W, 2 * H) and gif.n_frames == 3 and gif.info["loop"] == 0
    for k, grey in enumerate((50, 100, 150)):
        gif.seek(k)
        assert gif.info["duration"] == 120
        rgb = np.asarray(gif.convert("RGB")).astype(int)
        assert (np.abs(rgb[H - 5, 5] - grey) <= 4).all()                         # the learner on top
        assert (np.abs(rgb[2 * H - 5, 5] - [0, 0, 200]) <= 4).all()              # the oracle below
        for row in (120, H + 120):                                               # the ring's west edge, red
            assert rgb[row, 34, 0] > 150 and rgb[row, 34, 1] < 60 and rgb[row, 38, 0] < 160

