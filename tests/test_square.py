import pandas as pd
import pytest
import torch
from torchrl.envs.utils import check_env_specs

from trl_dgpq.collectors.experiment import TIMING_COLUMNS, resolve_config, run_experiment
from trl_dgpq.collectors.online import OnlineCollector
from trl_dgpq.envs.square.env import SquareEnv

def test_specs_and_dynamics():
    env = SquareEnv(seeds=[0, 1, 2])
    check_env_specs(env)
    td = env.reset()
    assert torch.equal(td["observation"], torch.zeros(3, 2, dtype=torch.float64))
    td["action"] = torch.tensor([0, 2, 1])  # north, east, south (clipped at 0)
    nxt = env.step(td)["next"]
    obs = nxt["observation"]
    assert 0.09 <= obs[0, 1] <= 0.11 and obs[0, 0] == 0
    assert 0.09 <= obs[1, 0] <= 0.11 and obs[1, 1] == 0
    assert torch.equal(obs[2], torch.zeros(2, dtype=torch.float64))
    d = torch.linalg.vector_norm(torch.tensor([1.0, 1.0], dtype=torch.float64) - obs, dim=-1)
    torch.testing.assert_close(nxt["reward"][:, 0], 2 - d)


def test_goal_terminates_and_cap_truncates():
    env = SquareEnv(seeds=[0], max_steps=30)
    td = env.reset()
    for i in range(30):
        td["action"] = torch.tensor([0 if i % 2 else 2])  # zig-zag to (1, 1)
        td = env.step(td)
        if td["next", "done"].item():
            break
        td = td["next"]
    assert td["next", "terminated"].item() and not td["next", "truncated"].item()
    env = SquareEnv(seeds=[0], max_steps=3, reward="paper")
    td = env.rollout(10, break_when_any_done=True)
    assert td.shape[-1] == 3 and td["next", "truncated"][0, -1].item() and not td["next", "terminated"].any()
    assert (td["next", "reward"] == -1).all()


def test_partial_reset_touches_only_masked_seeds():
    env = SquareEnv(seeds=[0, 1])
    td = env.reset()
    td["action"] = torch.tensor([0, 0])
    td = env.step_mdp(env.step(td))
    before = env.pos.clone()
    td["_reset"] = torch.tensor([[True], [False]])
    out = env.reset(td)
    assert torch.equal(env.pos[0], torch.zeros(2, dtype=torch.float64))
    assert torch.equal(env.pos[1], before[1]) and torch.equal(out["observation"][1], before[1])


def test_invalid_actions_are_refused_with_a_clear_error():
    env = SquareEnv(seeds=[0, 1], noise=0.0)
    td = env.reset()
    for bad, msg in ((torch.tensor([0, -1]), r"in \[0, 4\)"), (torch.tensor([4, 0]), r"in \[0, 4\)"),
                     (torch.tensor([0.5, 1.0]), "non-integral"), (torch.tensor([True, False]), "dtype"),
                     (torch.nn.functional.one_hot(torch.tensor([0, 1]), 4), "one-hot"),
                     (torch.tensor([[0], [1]]), "shape")):
        td["action"] = bad
        with pytest.raises(ValueError, match=msg):
            env.step(td)
    assert torch.equal(env.pos, torch.zeros(2, 2, dtype=torch.float64))  # nothing moved
    td["action"] = torch.tensor([2.0, 0.0])                              # integral floats are cast
    obs = env.step(td)["next", "observation"]
    assert obs.tolist() == [[0.1, 0.0], [0.0, 0.1]]


def test_goal_radius_and_step_cap_defaults():
    """SPEC 3.1: terminal within 0.15 of (1, 1); truncated at 200 steps."""
    env = SquareEnv(seeds=[0, 1], noise=0.0)
    td = env.reset()
    env.pos.copy_(torch.tensor([[1.0, 0.751], [1.0, 0.749]], dtype=torch.float64))
    td["action"] = torch.tensor([0, 0])                                  # north to distance 0.149 / 0.151
    nxt = env.step(td)["next"]
    assert nxt["terminated"][:, 0].tolist() == [True, False]
    env = SquareEnv(seeds=[0])
    td = env.rollout(1000, policy=lambda td: td.set("action", torch.tensor([3])), break_when_any_done=True)
    assert td.shape[-1] == 200 and td["next", "truncated"][0, -1].item() and not td["next", "terminated"].any()


def test_truncation_is_not_terminal_for_the_learner():
    class Spy:
        def __init__(self):
            self.terminal, self.obs, self.next_obs = [], [], []

        def act(self, td):
            return torch.zeros(td.shape[0], dtype=torch.long)

        def observe(self, td, active):
            self.terminal.append(td["next", "terminated"][:, 0].clone())
            self.obs.append(td["observation"].clone())
            self.next_obs.append(td["next", "observation"].clone())

        def episode_stats(self):
            return {}

    spy = Spy()
    df = OnlineCollector(SquareEnv(seeds=[0, 1], max_steps=4), spy, episodes=2, progress=False).run()
    assert len(spy.terminal) == 8 and not torch.stack(spy.terminal).any()
    assert (df.steps == 4).all() and not df.terminated.any() and len(df) == 4
    # s' of the truncating step is where the 4th move north led (y = 0.4 +- 0.04), not the reset state
    for k in (3, 7):  # the truncating steps
        assert ((spy.next_obs[k][:, 1] - 0.4).abs() <= 0.04).all() and (spy.next_obs[k][:, 0] == 0).all()
    assert torch.equal(spy.obs[4], torch.zeros(2, 2, dtype=torch.float64))  # the next episode starts at (0, 0)


def test_return_is_per_episode():
    """r = -1 per step, truncated after 3: every episode's return is -3 (not -3, -6, -9)."""
    class West:
        def act(self, td):
            return torch.full((td.shape[0],), 3)

        def observe(self, td, active):
            pass

        def episode_stats(self):
            return {}

    df = OnlineCollector(SquareEnv(seeds=[0, 1], max_steps=3, reward="paper"), West(), episodes=3,
                         progress=False).run()
    assert df["return"].tolist() == [-3.0] * 6 and df.steps.tolist() == [3] * 6


def small(seeds, episodes=6, **settings):
    return resolve_config(preset="shaped", seeds=seeds, episodes=episodes, **settings)


def drop_timing(df):
    return df.drop(columns=list(TIMING_COLUMNS))


def test_tiny_rollout_learns_and_records_every_episode():
    df = run_experiment(small([0, 1, 2, 3]), progress=False)
    assert len(df) == 24 and set(df.seed) == {0, 1, 2, 3}
    for col in ("seed", "episode", "steps", "return", "terminated", "wall_s", "cpu_s", "qhat_size", "qhat_updates"):
        assert col in df
    assert df.terminated.all() and (df.steps < 200).all()
    assert df[df.episode >= 3].steps.median() <= 25  # learns the ~17-step path fast
    # "shaped": one sample leaves variance 1/11 < sigma_tol2 = 0.1 and Q̂ - mean >= dist/1.1 > 2 eps1
    # away from the goal, so every step adds a point and overwrites Q̂, which empties the GPs
    # (so the next step's GP is empty again): gp_adds = steps so far; in episode 1 every step
    # overwrites; later some states are already tight.
    cum_steps = df.groupby("seed").steps.cumsum()
    assert (df.gp_adds == cum_steps).all()
    first = df[df.episode == 1]
    assert (first.qhat_updates == first.steps).all() and (df.gp_size == 0).all()
    assert (df.qhat_updates <= cum_steps).all() and (df.qhat_size <= df.qhat_updates).all()
    assert (df.groupby("seed").qhat_updates.diff().dropna() > 0).all()


def test_determinism_and_batch_composition_invariance():
    a = drop_timing(run_experiment(small(list(range(8))), progress=False))
    b = drop_timing(run_experiment(small(list(range(8))), progress=False))
    pd.testing.assert_frame_equal(a, b)
    alone = drop_timing(run_experiment(small([3]), progress=False)).reset_index(drop=True)
    within = a[a.seed == 3].reset_index(drop=True)
    pd.testing.assert_frame_equal(alone, within, check_exact=False, rtol=0, atol=1e-9)


@pytest.mark.parametrize("gp", ["exact", "sparse"])
def test_backends_run_the_report_and_paper_presets(gp):
    """Both cap episode 1 (SPEC 3.1). "report": Section 5's sigma_tol2 = 3e-4 needs ~330
    samples at a point, so Q̂ is never overwritten; "paper": -1 per step."""
    report = run_experiment(resolve_config(preset="report", seeds=[0], episodes=1, gp=gp, budget=20), progress=False)
    assert report.steps[0] == 200 and not report.terminated[0] and report.qhat_updates[0] == 0
    paper = run_experiment(resolve_config(preset="paper", seeds=[0], episodes=1, gp=gp, budget=20), progress=False)
    assert paper.steps[0] == 200 and paper["return"][0] == -200 and paper.qhat_updates[0] > 0


def test_reward_noise_is_gaussian_and_leaves_the_moves_alone():
    """With reward_noise 0.3, reward - (2 - |goal - s|) has mean ~0 and s.d. ~0.3 over 4,000
    seed-steps, and positions equal the noise-free env's (the noise has its own stream); seed 1's
    noise is the same alone as beside seed 0."""
    quiet, noisy, alone = SquareEnv([0, 1]), SquareEnv([0, 1], reward_noise=0.3), SquareEnv([1], reward_noise=0.3)
    for env in (quiet, noisy, alone):
        env.reset()
    gen = torch.Generator().manual_seed(0)
    residuals = []
    for _ in range(2000):
        a = torch.randint(4, (2,), generator=gen)
        q = quiet.step(quiet._td(action=a))["next"]
        n = noisy.step(noisy._td(action=a))["next"]
        s = alone.step(alone._td(action=a[1:]))["next"]
        assert torch.equal(q["observation"], n["observation"])
        assert torch.equal(n["reward"][1], s["reward"][0])
        residuals.append(n["reward"][:, 0] - q["reward"][:, 0])
        for env in (quiet, noisy, alone):
            env.pos.zero_()  # stay away from the goal: no episode ends
    r = torch.cat(residuals)
    assert abs(r.mean().item()) < 0.03 and r.std().item() == pytest.approx(0.3, rel=0.05)
    with pytest.raises(ValueError, match="reward_noise"):
        SquareEnv([0], reward_noise=-0.1)


def test_figures_titles_fit_and_a_narrow_log_axis_gets_three_labels(tmp_path, saved_figures):
    """steps_per_episode.png and time_per_step.png with reproduce's long title: each title inside
    the image (issue 30: cut at both edges); steps between 17 and 40 on the log axis labelled at
    least three times (20 and 30 alone before), whole episodes on the x axis of a 4-episode run."""
    from tests.test_report import fake_run
    from trl_dgpq.analysis import load_run
    from trl_dgpq.envs.square.analysis import figures
    run = fake_run(tmp_path / "sq", "square", {0: [40, 25, 18, 17], 1: [35, 30, 19, 17]}, agent="dqn")
    figures([load_run(run)], ["dqn p"], tmp_path, title="quick scale (fewer seeds and episodes than the seed report)")
    for name in ("steps_per_episode.png", "time_per_step.png"):
        assert saved_figures.problems(name) == [], name


def test_an_evaluation_with_one_capped_episode_is_drawn_on_a_log_axis(tmp_path, saved_figures):
    """eval_returns.png: 39 episodes of 17-20 steps and one of 200 (the cap) squashed the box
    into the bottom 2 % of a linear axis; on a log axis, labelled, every episode inside it."""
    from tests.test_report import fake_run
    from trl_dgpq.analysis import load_run
    from trl_dgpq.analysis.figures import evaluation_figure
    run = fake_run(tmp_path / "sq", "square", {0: [20]})
    steps = [17, 18, 19, 20] * 9 + [17, 18, 19, 200]
    pd.DataFrame({"seed": [0, 1, 2, 3] * 10, "episode": [e for e in range(1, 11) for _ in range(4)],
                  "steps": steps}).to_csv(run / "eval.csv", index=False)
    assert evaluation_figure([load_run(run)], ["dgpq"], tmp_path, "steps", "steps per episode") is not None
    ax = saved_figures["eval_returns.png"].axes[0]
    assert ax.get_yscale() == "log" and saved_figures.problems("eval_returns.png") == []
