"""DDPG (Lillicrap et al. 2016) as the course had it (SPEC 3.2), assembled from TorchRL:
``DDPGLoss`` (TD(0) targets from target networks), ``SoftUpdate``, ``ReplayBuffer``
with ``LazyTensorStorage``, ``OrnsteinUhlenbeckProcessModule``, ``Actor`` (an ``MLP``
then ``TanhModule`` onto the action box) and ``ValueOperator``.

One learner per seed (``neural.PerSeedLearners``: why, and how each keeps its own
random stream).

Per step, for each active seed: act (actor + OU noise, reset at each episode's
start), store the transition, and once the buffer holds a batch, one gradient step
on the critic (lr ``critic_lr``) and the actor (``actor_lr``) and a soft update of
both target networks.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence, Tuple

import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.data import Bounded, LazyTensorStorage, ReplayBuffer
from torchrl.modules import MLP, OrnsteinUhlenbeckProcessModule, TanhModule, ValueOperator
from torchrl.objectives import DDPGLoss, SoftUpdate

from ..config import setting
from .neural import PerSeedLearners, TorchLearner


@dataclass
class DDPGConfig:
    """DDPG (SPEC 3.2: the course's sizes and hyperparameters)."""
    gamma: float = setting(0.99, "discount gamma", within="[0, 1]")
    actor_hidden: Tuple[int, ...] = setting((24, 48), "actor hidden widths (ReLU), then tanh onto the action box",
                                            within="[1, inf)", length=(1, None))
    critic_hidden: Tuple[int, int] = setting((24, 48), "critic: state -> first width, concat action -> second -> 1",
                                             within="[1, inf)", length=2)
    actor_lr: float = setting(1e-4, "actor Adam learning rate", within="(0, inf)")
    critic_lr: float = setting(1e-3, "critic Adam learning rate", within="(0, inf)")
    target_update: float = setting(1e-3, "soft target update weight tau", within="(0, 1]")
    buffer_size: int = setting(10_000, "replay buffer capacity (transitions per seed)", within="[1, inf)")
    batch_size: int = setting(128, "minibatch; learning starts once the buffer holds this many", within="[1, inf)")
    ou_theta: float = setting(0.15, "OU exploration noise theta", within="[0, inf)")
    ou_sigma: float = setting(0.2, "OU exploration noise sigma", within="[0, inf)")
    ou_dt: float = setting(1.0, "OU time step (1: x += theta (mu - x) + sigma N(0, 1))", within="(0, inf)")

    def cross_check(self) -> None:
        if self.buffer_size < self.batch_size:
            raise ValueError(f"need 1 <= batch_size <= buffer_size, got {self.batch_size} and {self.buffer_size}")


class Critic(nn.Module):
    """Q(s, a): state -> hidden[0] (ReLU), concatenate the action -> hidden[1] (ReLU) -> 1."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: Tuple[int, int]):
        super().__init__()
        self.state = nn.Sequential(nn.Linear(obs_dim, hidden[0]), nn.ReLU())
        self.head = MLP(in_features=hidden[0] + act_dim, out_features=1, num_cells=[hidden[1]],
                        activation_class=nn.ReLU)

    def forward(self, observation, action):
        return self.head(torch.cat([self.state(observation), action], -1))


class Learner(TorchLearner):
    """One seed's DDPG: networks, loss, optimisers, replay buffer and OU state."""

    def __init__(self, cfg: DDPGConfig, obs_dim: int, box: Bounded, torch_seed: int):
        super().__init__(torch_seed)
        low, high = box.space.low[0].float(), box.space.high[0].float()
        act_dim = low.numel()
        with self.own_generator():  # initial weights from this learner's generator
            net = MLP(in_features=obs_dim, out_features=act_dim, num_cells=list(cfg.actor_hidden),
                      activation_class=nn.ReLU)
            self.actor = TensorDictSequential(
                TensorDictModule(net, in_keys=["observation"], out_keys=["action_raw"]),
                TanhModule(in_keys=["action_raw"], out_keys=["action"], low=low, high=high))
            critic = ValueOperator(Critic(obs_dim, act_dim, cfg.critic_hidden), in_keys=["observation", "action"])
            self.loss = DDPGLoss(self.actor, critic, delay_actor=True, delay_value=True)
        self.loss.make_value_estimator(gamma=cfg.gamma)
        self.target = SoftUpdate(self.loss, tau=cfg.target_update)
        self.actor_optim = torch.optim.Adam(self.loss.actor_network_params.values(True, True), lr=cfg.actor_lr)
        self.critic_optim = torch.optim.Adam(self.loss.value_network_params.values(True, True), lr=cfg.critic_lr)
        self.buffer = ReplayBuffer(storage=LazyTensorStorage(cfg.buffer_size), batch_size=cfg.batch_size)
        self.ou = OrnsteinUhlenbeckProcessModule(
            Bounded(low, high, shape=(act_dim,)), theta=cfg.ou_theta, sigma=cfg.ou_sigma, dt=cfg.ou_dt,
            eps_init=1.0, eps_end=1.0)
        self.noise = TensorDict({"_ou_prev_noise": torch.zeros(1, act_dim), "_ou_steps": torch.zeros(1, dtype=torch.long)},
                                batch_size=[1])
        self.batch_size = cfg.batch_size

    def act(self, obs: torch.Tensor, new_episode: bool) -> torch.Tensor:
        """Actor + OU noise for one observation (1, obs_dim)."""
        td = TensorDict({"observation": obs, "is_init": torch.tensor([[new_episode]])}, batch_size=[1])
        td.update(self.noise)
        with self.own_generator(), torch.no_grad():
            self.ou(self.actor(td))
        self.noise = td.select("_ou_prev_noise", "_ou_steps").clone()
        return td.get("action")

    def learn(self, transition: TensorDict) -> None:
        with self.own_generator():
            self.buffer.extend(transition)
            if len(self.buffer) < self.batch_size:
                return
            losses = self.loss(self.buffer.sample())
            self.actor_optim.zero_grad()
            self.critic_optim.zero_grad()
            (losses["loss_actor"] + losses["loss_value"]).backward()
            self.actor_optim.step()
            self.critic_optim.step()
            self.target.step()
            self.updates += 1

    def state_dict(self) -> dict:
        return {"loss": self.loss.state_dict(), "actor_optim": self.actor_optim.state_dict(),
                "critic_optim": self.critic_optim.state_dict(), "buffer": self.buffer.state_dict(),
                "noise": self.noise.to_dict(), **super().state_dict()}

    def load_state_dict(self, state: dict) -> None:
        self.loss.load_state_dict(state["loss"])
        self.actor_optim.load_state_dict(state["actor_optim"])
        self.critic_optim.load_state_dict(state["critic_optim"])
        self.buffer.load_state_dict(state["buffer"])
        self.noise = TensorDict(state["noise"], batch_size=[1])
        super().load_state_dict(state)


class DDPG(PerSeedLearners):
    """S independent DDPG learners behind the runner's agent interface."""

    Config = DDPGConfig

    def __init__(self, cfg: DDPGConfig, seeds: Sequence[int], obs_dim: int, box: Bounded):
        super().__init__(seeds, lambda torch_seed: Learner(cfg, obs_dim, box, torch_seed))

    @classmethod
    def resolve_config(cls, cfg: DDPGConfig, info) -> DDPGConfig:
        info.action_box("ddpg")
        return cfg

    @classmethod
    def make(cls, cfg: DDPGConfig, info, seeds):
        return cls(cfg, seeds, info.observation_dim, info.action_box("ddpg"))

    @staticmethod
    def memory_bytes(cfg: DDPGConfig, info, num_seeds: int) -> int:
        """The replay buffers when full (observation, next observation, action, flags)."""
        dim, act = info.observation_dim, int(info.action_box("ddpg").shape[-1])
        return num_seeds * cfg.buffer_size * 4 * (2 * dim + act + 4)

    def act(self, td) -> torch.Tensor:
        return super().act(td).to(torch.float64)
