"""Presets of gymnasium's classic control (docs/domains/gym.md). DGPQ sees observations in
the unit box, DQN gymnasium's own (``observations="raw"``, as SB3 and the zoo feed their
networks). Any other discrete gymnasium id runs every agent with the preset ``DEFAULT``: no
overrides but DQN's raw observations."""
from trl_dgpq.presets import rbf_and_manifold

DEFAULT = "default"

# rl-baselines3-zoo's tuned DQN for these envs (hyperparams/dqn.yml), in Stable-Baselines3's own
# names: the "zoo" presets below are made from it, and scripts/bench_parity.py hands it to SB3
# as it is, so both sides of the parity benchmark read one table. n_timesteps is the zoo's budget.
ZOO_DQN = {
    "CartPole-v1": dict(n_timesteps=50_000, learning_rate=2.3e-3, batch_size=64, buffer_size=100_000,
                        learning_starts=1_000, gamma=0.99, target_update_interval=10, train_freq=256,
                        gradient_steps=128, exploration_fraction=0.16, exploration_final_eps=0.04,
                        net_arch=(256, 256)),
    "Acrobot-v1": dict(n_timesteps=100_000, learning_rate=6.3e-4, batch_size=128, buffer_size=50_000,
                       learning_starts=0, gamma=0.99, target_update_interval=250, train_freq=4, gradient_steps=-1,
                       exploration_fraction=0.12, exploration_final_eps=0.1, net_arch=(256, 256)),
    "MountainCar-v0": dict(n_timesteps=120_000, learning_rate=4e-3, batch_size=128, buffer_size=10_000,
                           learning_starts=1_000, gamma=0.98, target_update_interval=600, train_freq=16,
                           gradient_steps=8, exploration_fraction=0.2, exploration_final_eps=0.07,
                           net_arch=(256, 256)),
}

# What the neural agents see on every gym id: gymnasium's own observations.
RAW = dict(observations="raw")
# the presets of an agent on an id with none of its own
FALLBACK = {"dqn": {DEFAULT: {"env": RAW}}}


def zoo_dqn(env_id: str) -> dict:
    """The "zoo" preset: ZOO_DQN's settings in DQNConfig's names, over the zoo's own budget
    (epsilon falls over exploration_fraction of n_timesteps, as SB3 schedules it; SB3's
    gradient_steps = -1 is one update per env step collected, train_freq of them)."""
    from dataclasses import fields

    from trl_dgpq.agents.dqn import DQNConfig
    z = ZOO_DQN[env_id]
    agent = dict(lr=z["learning_rate"], batch_size=z["batch_size"], buffer_size=z["buffer_size"],
                 learning_starts=z["learning_starts"], gamma=z["gamma"],
                 target_update_interval=z["target_update_interval"], train_freq=z["train_freq"],
                 gradient_steps=z["train_freq"] if z["gradient_steps"] == -1 else z["gradient_steps"],
                 exploration_steps=int(z["exploration_fraction"] * z["n_timesteps"]),
                 eps_end=z["exploration_final_eps"], hidden=tuple(z["net_arch"]))
    defaults = {f.name: f.default for f in fields(DQNConfig)}  # a preset holds overrides only
    return {"env": RAW, "agent": {k: v for k, v in agent.items() if v != defaults[k]}}


# gymnasium id -> {agent: {preset: ...}}; the ids listed here are the suite's examples.
PRESETS = {
    # DGPQ: V_max = R_max / (1 - gamma) (0 where every reward is -1 until the goal), L_Q = V_max per
    # unit of L1 distance for CartPole; smaller L_Q generalise further where rewards are all -1
    # (probed: L_Q 2-200 on 4 seeds x 5,000 steps; these were the best). The exact GP in both
    # presets, so the kernel is their only difference.
    # DQN "default": rl-baselines3-zoo's tuned settings for these envs (ZOO_DQN), with epsilon's
    # decay over the zoo's exploration_fraction of the budget this suite gives them (docs/agents/neural.md
    # "DQN": 20,000 / 30,000 / 20,000 steps), as the zoo does when run with a shorter
    # n_timesteps. DQNConfig's defaults are the zoo's Acrobot-v1 settings. DQN "zoo": the zoo's
    # own budget (run it with --env-steps n_timesteps; scripts/bench_parity.py does).
    "CartPole-v1": {
        "dgpq": rbf_and_manifold(DEFAULT, gamma=0.95, v_max=20.0, lipschitz=20.0),
        "dqn": {DEFAULT: {"env": RAW, "agent": dict(
            lr=2.3e-3, batch_size=64, buffer_size=100_000, learning_starts=1_000, target_update_interval=10,
            train_freq=256, gradient_steps=128, exploration_steps=3_200, eps_end=0.04)},
                "zoo": zoo_dqn("CartPole-v1")},
    },
    "MountainCar-v0": {
        "dgpq": rbf_and_manifold(DEFAULT, gamma=0.99, v_max=0.0, lipschitz=5.0),
        "dqn": {DEFAULT: {"env": RAW, "agent": dict(
            lr=4e-3, buffer_size=10_000, learning_starts=1_000, gamma=0.98, target_update_interval=600,
            train_freq=16, gradient_steps=8, exploration_steps=6_000, eps_end=0.07)},
                "zoo": zoo_dqn("MountainCar-v0")},
    },
    "Acrobot-v1": {
        "dgpq": rbf_and_manifold(DEFAULT, gamma=0.99, v_max=0.0, lipschitz=10.0),
        "dqn": {DEFAULT: {"env": RAW, "agent": dict(exploration_steps=2_400)},
                "zoo": zoo_dqn("Acrobot-v1")},
    },
}
