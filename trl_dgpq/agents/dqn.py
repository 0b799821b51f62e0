"""DQN (Mnih et al. 2015) assembled from TorchRL, with Stable-Baselines3's schedule:
``QValueActor`` over an ``MLP`` (ReLU), ``EGreedyModule`` (epsilon annealed linearly
from ``eps_init`` to ``eps_end`` over ``exploration_steps`` env steps), ``DQNLoss``
(Huber, TD(0) targets from a target network), ``HardUpdate`` (the target copies the
online network every ``target_update_interval`` env steps), ``ReplayBuffer`` with
``LazyTensorStorage``, Adam with gradient norm clipped at ``max_grad_norm``.

One learner per seed (``neural.PerSeedLearners``). Per env step of an active seed:
act epsilon-greedily, store the transition, count the step towards epsilon and the
target update; once ``learning_starts`` steps are stored, every ``train_freq``-th step
makes ``gradient_steps`` updates on minibatches of ``batch_size``.

Observations are the env's (the gym envs' are already in the unit box); a discrete
action spec is required (liquidation: ``action_levels`` > 0).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence, Tuple

import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictSequential
from torch import nn
from torchrl.data import Categorical, LazyTensorStorage, ReplayBuffer
from torchrl.modules import MLP, EGreedyModule, QValueActor
from torchrl.objectives import DQNLoss, HardUpdate

from ..config import setting
from .neural import PerSeedLearners, TorchLearner


@dataclass
class DQNConfig:
    """DQN (defaults: rl-baselines3-zoo's tuned Acrobot-v1 settings; presets per env)."""
    gamma: float = setting(0.99, "discount gamma", within="[0, 1]")
    hidden: Tuple[int, ...] = setting((256, 256), "Q-network hidden widths (ReLU)", within="[1, inf)",
                                      length=(1, None))
    lr: float = setting(6.3e-4, "Adam learning rate", within="(0, inf)")
    buffer_size: int = setting(50_000, "replay buffer capacity (transitions per seed)", within="[1, inf)")
    batch_size: int = setting(128, "minibatch size", within="[1, inf)")
    learning_starts: int = setting(0, "env steps before the first update (and at least a minibatch stored)",
                                   within="[0, inf)")
    train_freq: int = setting(4, "update every this many env steps", within="[1, inf)")
    gradient_steps: int = setting(4, "updates each time", within="[1, inf)")
    target_update_interval: int = setting(250, "env steps between copies of the online network to the target",
                                          within="[1, inf)")
    eps_init: float = setting(1.0, "initial exploration epsilon", within="[0, 1]")
    eps_end: float = setting(0.1, "final exploration epsilon", within="[0, 1]")
    exploration_steps: int = setting(12_000, "env steps over which epsilon falls linearly to eps_end",
                                     within="[1, inf)")
    max_grad_norm: float = setting(10.0, "gradient norm clip", within="(0, inf)")

    def cross_check(self) -> None:
        if self.buffer_size < self.batch_size:
            raise ValueError(f"need 1 <= batch_size <= buffer_size, got {self.batch_size} and {self.buffer_size}")
        if self.eps_end > self.eps_init:
            raise ValueError(f"need 0 <= eps_end <= eps_init <= 1, got {self.eps_end} and {self.eps_init}")


class Learner(TorchLearner):
    """One seed's DQN: Q-network and its target, loss, optimiser, replay buffer, epsilon."""

    def __init__(self, cfg: DQNConfig, obs_dim: int, n_actions: int, torch_seed: int):
        super().__init__(torch_seed)
        spec = Categorical(n_actions)
        with self.own_generator():  # initial weights from this learner's generator
            net = MLP(in_features=obs_dim, out_features=n_actions, num_cells=list(cfg.hidden),
                      activation_class=nn.ReLU)
            self.actor = QValueActor(net, in_keys=["observation"], spec=spec)
            self.loss = DQNLoss(self.actor, loss_function="smooth_l1", delay_value=True, action_space=spec)
        self.loss.make_value_estimator(gamma=cfg.gamma)
        # HardUpdate copies on the (interval + 1)-th call of step(), then every interval + 1
        self.target = HardUpdate(self.loss, value_network_update_interval=cfg.target_update_interval - 1)
        self.explore = EGreedyModule(spec, eps_init=float(cfg.eps_init), eps_end=float(cfg.eps_end),
                                     annealing_num_steps=cfg.exploration_steps)
        self.policy = TensorDictSequential(self.actor, self.explore)
        self.params = list(self.loss.value_network_params.values(True, True))  # the online network's
        self.optim = torch.optim.Adam(self.params, lr=cfg.lr)
        self.buffer = ReplayBuffer(storage=LazyTensorStorage(cfg.buffer_size), batch_size=cfg.batch_size)
        self.cfg, self.steps = cfg, 0

    def act(self, obs: torch.Tensor, new_episode: bool) -> torch.Tensor:
        with self.own_generator(), torch.no_grad():
            return self.policy(TensorDict({"observation": obs}, batch_size=[1])).get("action")

    def learn(self, transition: TensorDict) -> None:
        cfg = self.cfg
        with self.own_generator():
            self.buffer.extend(transition)
            self.steps += 1
            self.explore.step()
            # from learning_starts on, once a minibatch is stored (SB3 samples with replacement before)
            ready = self.steps >= cfg.learning_starts and len(self.buffer) >= cfg.batch_size
            if ready and self.steps % cfg.train_freq == 0:
                for _ in range(cfg.gradient_steps):
                    loss = self.loss(self.buffer.sample())["loss"]
                    self.optim.zero_grad()
                    loss.backward()
                    nn.utils.clip_grad_norm_(self.params, cfg.max_grad_norm)
                    self.optim.step()
                    self.updates += 1
            self.target.step()  # counts env steps; copies every target_update_interval-th

    def state_dict(self) -> dict:
        return {"loss": self.loss.state_dict(), "optim": self.optim.state_dict(), "buffer": self.buffer.state_dict(),
                "eps": self.explore.eps.clone(), "target_counter": self.target.counter, "steps": self.steps,
                **super().state_dict()}

    def load_state_dict(self, state: dict) -> None:
        self.loss.load_state_dict(state["loss"])
        self.optim.load_state_dict(state["optim"])
        self.buffer.load_state_dict(state["buffer"])
        self.explore.eps.copy_(state["eps"])
        self.target.counter = int(state["target_counter"])
        self.steps = int(state["steps"])
        super().load_state_dict(state)


class DQN(PerSeedLearners):
    """S independent DQN learners behind the runner's agent interface."""

    Config = DQNConfig

    def __init__(self, cfg: DQNConfig, seeds: Sequence[int], obs_dim: int, n_actions: int):
        super().__init__(seeds, lambda torch_seed: Learner(cfg, obs_dim, n_actions, torch_seed))

    @classmethod
    def resolve_config(cls, cfg: DQNConfig, info) -> DQNConfig:
        info.num_actions("dqn")
        return cfg

    @classmethod
    def make(cls, cfg: DQNConfig, info, seeds):
        return cls(cfg, seeds, info.observation_dim, info.num_actions("dqn"))

    @staticmethod
    def memory_bytes(cfg: DQNConfig, info, num_seeds: int) -> int:
        """The replay buffers when full (observation, next observation, action, reward, flags)."""
        return num_seeds * cfg.buffer_size * (4 * (2 * info.observation_dim + 1) + 8 + 2)
