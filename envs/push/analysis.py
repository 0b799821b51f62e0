"""What the analysis says about block pushing: steps per episode, success, the block's
final distance to the goal (seed report Figure 5)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from trl_dgpq.analysis import Threshold, kernel_fits_per_seed, ms_per_seed_step

MEASURE = ("steps", "steps per episode")
MEASURE_LOWER_IS_BETTER = True  # the at-budget scores (report: IQM, P(improvement), profiles) are negated
TERMINATED = "the block reached the goal or fell off the table"
THRESHOLD = Threshold("success", ">=", 0.9, 10, "success in >= 90 % of 10 episodes")
DEFAULT_LAST = 20  # episodes at the end that the table uses
# What of the task a run is told (claims.py): the reward, 2 minus the block's distance to the goal,
# tells the learner where the goal is, as the square's shaped reward does
MODEL_KNOWLEDGE = {"run.env=push": "reward: the block's distance to the goal (its position)"}


def figures(runs, labels, out: Path, last=None, title: str = "", **_) -> list:
    """push.png: the block's distance to the goal at each episode's end (the final reward is
    2 minus it; median and IQR over seeds) -- not the return, which is larger for a 50-step
    failure than a 10-step success -- above the success rate per episode; push.md: ``table``."""
    import matplotlib.pyplot as plt

    from trl_dgpq.analysis.figures import band_plot, episode_axis, save
    fig, (ax, sax) = plt.subplots(2, 1, figsize=(6.4, 6.4), sharex=True, height_ratios=(3, 2))
    for run, label in zip(runs, labels):
        df = run.df
        line = band_plot(ax, df, df["distance"], f"{label} ({df.seed.nunique()} seeds)")
        rate = df["success"].groupby(df["episode"]).mean()
        sax.plot(rate.index, rate, color=line.get_color(), lw=1.2)
    ax.set_ylabel("block's final distance to the goal (m)")
    ax.legend(title="median, shaded: inter-quartile range", fontsize=8, title_fontsize=8)
    sax.set_ylabel("success rate (share of seeds)")
    sax.set_xlabel("episode")
    sax.set_ylim(-0.03, 1.03)
    for a in (ax, sax):
        a.grid(alpha=0.3)
    episode_axis(sax)
    ax.set_title("block pushing: the block's final distance to the goal, and success, per episode", fontsize=9)
    written = save(fig, out / "push.png", title)
    (out / "push.md").write_text(table(runs, labels, last or DEFAULT_LAST))
    from trl_dgpq.collectors.evaluate import job_folders
    learner = next((r for r in runs if r.config and r.agent != "oracle" and job_folders(r.path)), None)
    return [written, out / "push.md"] + ([animation(learner.path, out)] if learner else [])


def table(runs, labels, last: int) -> str:
    """Markdown: over the last ``last`` episodes, success rate, mean steps of the successful
    episodes, fall-offs; the first successful episode (median over seeds), kernel fits."""
    lines = [f"| run | seeds x episodes | success, last {last} episodes (share of seed-episodes) | steps to goal "
             "(mean over those successes) | fell off (share) | first success (median episode over seeds) "
             "| kernel fits per seed (mean) | ms per seed-step |",
             "|---|---|---|---|---|---|---|---|"]
    for run, label in zip(runs, labels):
        df = run.df
        tail = df[df["episode"] > df["episode"].max() - last]
        wins = tail[tail["success"]]
        first = df[df["success"]].groupby("seed")["episode"].min().reindex(df.seed.unique())
        steps = f"{wins.steps.mean():.1f}" if len(wins) else "–"
        median = first.fillna(float("inf")).median()            # a seed that never succeeded counts as last
        first_txt = ("never" if median == float("inf") else f"{median:g}") + (
            f" ({first.isna().sum()} never)" if first.isna().any() else "")
        lines.append(f"| {label} | {df.seed.nunique()} x {df.episode.max()} | {tail.success.mean():.1%} | {steps} "
                     f"| {tail.fell_off.mean():.1%} | {first_txt} | {kernel_fits_per_seed(df):g} "
                     f"| {ms_per_seed_step(df):.2f} |")
    return "\n".join(lines) + f"\n\nLast {last} episodes of each run; steps to goal: mean over its successful ones.\n"


# ------------------------------------------------------------ the reproduction (scripts/reproduce.py)
TITLE = "Block pushing (the seed report's 4.3)"
# the README's paragraph on the domain: words, no numbers (those come from the data)
SUMMARY = ('DGPQ with an RBF and with the manifold kernel pushing a block in pybullet, beside a scripted oracle;'
           " the seed report's code never stepped the robot, so there is no number to compare.")
# (seeds, episodes) at each scale; an experiment may name its own as a third item
SCALES = {"smoke": (1, 3), "quick": (3, 20), "full": (10, 100), "report": (10, 100)}
REPRODUCE = [
    ("push-rbf", dict(agent="dgpq", preset="shaped")),
    ("push-manifold", dict(agent="dgpq", preset="manifold")),
    ("push-oracle", dict(agent="oracle")),
]


def success(name: str):
    """The claim's measure: each seed's success rate over its last DEFAULT_LAST episodes."""
    def measure(runs):
        from trl_dgpq.analysis.claims import seeds_interval
        df = runs[name].df
        return seeds_interval(df[df.episode > df.episode.max() - DEFAULT_LAST].groupby("seed")["success"].mean())
    return measure


def declared_claims() -> list:
    """The seed report's push claim: its code never stepped the robot, so there is no number;
    ours beside it, DGPQ's success rate."""
    from trl_dgpq.analysis.claims import Claim, NoNumber
    return [Claim("push/learns", "the seed report", "DGPQ reached the goal within three episodes, with very spiky "
                  f"performance (its code never stepped the robot); ours: success over the last {DEFAULT_LAST} "
                  "episodes", NoNumber(), success("push-rbf"), ("push-rbf",), fmt="{:.0%}",
                  source_model=(MODEL_KNOWLEDGE["run.env=push"],))]   # the seed report's reward too


CLAIMS = declared_claims()


def reproduce_section(runs: dict, out: Path, label: str, title: str, judged: list) -> str:
    """REPORT.md's push section; ``runs``: {name in REPRODUCE: Run}; ``judged``: the verdicts of ``CLAIMS``."""
    (out / "push").mkdir(exist_ok=True)
    figures(list(runs.values()), ["DGPQ RBF", "DGPQ manifold", "oracle"], out / "push", DEFAULT_LAST, title=title)
    sentence = "\n".join(j.bullet() for j in judged) + " GWH14 had no robot experiment."
    return (f"## Block pushing (seed report 4.3) -- Figure 5\n\n{label}\n\n" + (out / "push" / "push.md").read_text()
            + "\n" + sentence + "\n\n![push](push/push.png)"
            + (" ![an evaluation episode](push/push.gif)" if (out / "push" / "push.gif").is_file() else "") + "\n")


# ------------------------------------------------------------ an evaluation episode, animated
# The table from its side, the push running left to right across the frame (block start at x = -0.45 to the
# goal at 0.55 span ~350 of 480 pixels; the 5 cm block ~18): from its near end, at 240 x 180, the block was
# a few pixels (issue 30).
CAMERA = dict(distance=0.6, yaw=0.0, pitch=-45.0, target=(0.0, 0.0, 0.62))
FRAME = (480, 240)  # one panel, width x height; the GIF stacks the learner's above the oracle's


def camera(width: int, height: int):
    """pybullet's (view, projection) matrices of CAMERA, column-major 4x4 lists."""
    from .env import _load_pybullet
    _load_pybullet()
    from .env import pb
    view = pb.computeViewMatrixFromYawPitchRoll(CAMERA["target"], CAMERA["distance"], CAMERA["yaw"],
                                                CAMERA["pitch"], 0.0, 2)
    return view, pb.computeProjectionMatrixFOV(60.0, width / height, 0.05, 5.0)


def pixel(xyz, view, projection, width: int, height: int):
    """Where a world point lands in the image: (column, row)."""
    v, p = (np.array(m).reshape(4, 4).T for m in (view, projection))  # pybullet's are column-major
    clip = p @ v @ np.array([*xyz, 1.0])
    x, y = clip[:2] / clip[3]
    return (x + 1) / 2 * width, (1 - y) / 2 * height


def frame(env, row: int, width: int, height: int) -> np.ndarray:
    """Seed row ``row``'s world as RGB (height, width, 3), by pybullet's TinyRenderer (no display)."""
    from .env import pb
    view, projection = camera(width, height)
    _, _, rgba, _, _ = pb.getCameraImage(width, height, view, projection, renderer=pb.ER_TINY_RENDERER,
                                         physicsClientId=env.worlds[row].client)
    return np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[..., :3]


def episode_frames(env, policy, row: int = 0, width: int = FRAME[0], height: int = FRAME[1]) -> list:
    """Frames of seed row ``row``'s next episode under ``policy`` (td -> actions)."""
    from trl_dgpq.collectors.evaluate import episode_steps
    td = env.reset()
    frames = [frame(env, row, width, height)]
    frames += [frame(env, row, width, height) for _ in episode_steps(env, policy, td, row)]
    return frames


def animation(folder: Path, out: Path, width: int = FRAME[0], height: int = FRAME[1]) -> Path:
    """push.gif: the first seed's first evaluation episode of the learner in ``folder`` (its
    last checkpoint, exploration off) above the scripted oracle's on the same episode; the
    goal marked in red."""
    from PIL import Image, ImageDraw, ImageFont

    from trl_dgpq.agents import agent_class
    from trl_dgpq.collectors.evaluate import Frozen, jobs, restore
    config, env, agent, _ = restore(jobs(folder)[0])
    cls = agent_class("oracle", config["run"]["env"])
    oracle = cls.make(cls.Config(), env.info, list(config["run"]["seeds"]))
    clips = []
    for name, policy in ((config["run"]["agent"], Frozen(agent).act), ("oracle", oracle.act)):
        env.for_evaluation()  # re-keyed: both play the same first evaluation episode
        clips.append((name, episode_frames(env, policy, 0, width, height)))
    view, projection = camera(width, height)
    (gx, gy), (ex, _), (_, ny) = (pixel((x, y, 0.625), view, projection, width, height) for x, y in (
        env.cfg.goal, (env.cfg.goal[0] + env.cfg.goal_radius, env.cfg.goal[1]),
        (env.cfg.goal[0], env.cfg.goal[1] + env.cfg.goal_radius)))
    rx, ry = abs(ex - gx), abs(ny - gy)  # the goal's radius, in perspective
    n = max(len(f) for _, f in clips)
    font = ImageFont.load_default(size=max(12, height // 15))
    images = []
    for k in range(n):
        panels = []
        for name, frames in clips:
            img = Image.fromarray(frames[min(k, len(frames) - 1)])
            draw = ImageDraw.Draw(img)
            draw.ellipse((gx - rx, gy - ry, gx + rx, gy + ry), outline=(220, 0, 0), width=2)
            done = " (done)" if k >= len(frames) - 1 else ""
            draw.text((6, 4), f"{name}: step {min(k, len(frames) - 1)}{done}", fill=(0, 0, 0), font=font)
            panels.append(img)
        both = Image.new("RGB", (width, height * len(panels)), "white")
        for i, img in enumerate(panels):
            both.paste(img, (0, i * height))
        images.append(both.quantize(256, method=Image.Quantize.FASTOCTREE))  # a few red and black pixels kept
    path = out / "push.gif"
    images[0].save(path, save_all=True, append_images=images[1:], duration=120, loop=0)
    return path
