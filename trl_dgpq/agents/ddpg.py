"""DDPG (Lillicrap et al. 2016) as the course had it (SPEC 3.2): an actor (TorchRL's
``MLP``, then tanh onto the action box as its ``TanhModule`` maps it) and a critic,
the losses of TorchRL's ``DDPGLoss`` (squared TD(0) error against target networks;
the actor's -Q(s, actor(s)) with the critic held fixed; tested equal), soft target
updates (as ``SoftUpdate``), and Ornstein-Uhlenbeck exploration noise added to the
action and clipped to the box: x <- x + theta (mu - x) dt + sigma sqrt(dt) N(0, 1),
mu = 0, as TorchRL's ``OrnsteinUhlenbeckProcessModule`` (which draws from torch's
global generator; here each seed's own stream).

All seeds learn as one (``neural``: networks stacked over seeds, per-seed losses,
replay and random streams; why the losses are not ``DDPGLoss`` itself).

Per env step of the active seeds: act, store the transition, and once the memory
holds a minibatch, one gradient step on the critic (lr ``critic_lr``) and the actor
(``actor_lr``) and a soft update of both target networks.

``course`` settings reproduce the course's own agent (Udacity's finance DDPG, the seed
report's baseline), each a choice it made that the default corrects:
``ou_noise="uniform"`` (it drew U[0, 1), not N(0, 1): mean-reverting to sigma / (2 theta),
not 0), ``ou_reset=False`` (never reset between episodes), ``init="course"`` (hidden
weights uniform in +-1/sqrt(out_features) -- it took the fan-in from the wrong side --,
output layers +-3e-3), ``update="critic-then-actor"`` (the actor's step is taken
against the critic just updated) and ``start_above_batch`` (learning starts with more
than a minibatch stored).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence, Tuple

import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import Bounded
from torchrl.modules import MLP

from ..config import setting
from ..rng import SeedStreams, stream_id
from ..tuning import LogUniform, Uniform
from .neural import SeedAdam, SeedBatchedLearner, SeedStack, Target, build_per_seed, seed_mean


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
    ou_sigma: float = setting(0.2, "OU exploration noise sigma (in the action box's units)", within="[0, inf)")
    ou_dt: float = setting(1.0, "OU time step (1: x += theta (mu - x) + sigma N(0, 1))", within="(0, inf)")
    ou_noise: str = setting("normal", "OU increments: normal N(0, 1), or uniform U[0, 1) as the course drew them",
                            choices=("normal", "uniform"))
    ou_reset: bool = setting(True, "reset the OU noise to 0 at each episode's start (the course never did)")
    init: str = setting("torch", "initial weights: torch's defaults, or the course's (hidden +-1/sqrt(out_features), "
                        "output +-3e-3)", choices=("torch", "course"))
    update: str = setting("joint", "one step on both losses, or the critic's step then the actor's against the "
                          "updated critic (the course)", choices=("joint", "critic-then-actor"))
    start_above_batch: bool = setting(False, "learn once the buffer holds more than (the course), not at least, "
                                      "a minibatch")

    def cross_check(self) -> None:
        if self.buffer_size < self.batch_size:
            raise ValueError(f"need 1 <= batch_size <= buffer_size, got {self.batch_size} and {self.buffer_size}")


# What `trl-dgpq tune` searches (trl_dgpq/tuning.py).
SEARCH_SPACE = {
    "actor_lr": LogUniform(1e-5, 1e-3),
    "critic_lr": LogUniform(1e-4, 1e-2),
    "target_update": LogUniform(1e-3, 0.1),
    "ou_sigma": Uniform(0.02, 0.5),
}


class Critic(nn.Module):
    """Q(s, a): state -> hidden[0] (ReLU), concatenate the action -> hidden[1] (ReLU) -> 1."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: Tuple[int, int]):
        super().__init__()
        self.state = nn.Sequential(nn.Linear(obs_dim, hidden[0]), nn.ReLU())
        self.head = MLP(in_features=hidden[0] + act_dim, out_features=1, num_cells=[hidden[1]],
                        activation_class=nn.ReLU)

    def forward(self, observation, action):
        return self.head(torch.cat([self.state(observation), action], -1))


class Actor(nn.Module):
    """An MLP, then tanh mapped onto the box [low, high] (TorchRL's ``TanhModule``'s map)."""

    def __init__(self, mlp: nn.Module, low: torch.Tensor, high: torch.Tensor):
        super().__init__()
        self.mlp = mlp
        self.register_buffer("low", low)
        self.register_buffer("high", high)

    def forward(self, observation):
        return self.low + (self.high - self.low) * (self.mlp(observation).tanh() + 1) / 2


def course_init(net: nn.Module) -> nn.Module:
    """The course's ``reset_parameters``: each hidden layer's weights uniform in
    +-1/sqrt(weight.size(0)) (out_features), the output layer's in +-3e-3; biases left
    at torch's defaults."""
    linears = [m for m in net.modules() if isinstance(m, nn.Linear)]
    with torch.no_grad():
        for layer in linears[:-1]:
            lim = 1.0 / math.sqrt(layer.weight.size(0))
            layer.weight.uniform_(-lim, lim)
        linears[-1].weight.uniform_(-3e-3, 3e-3)
    return net


class DDPG(SeedBatchedLearner):
    """DDPG for S seeds: stacked actor and critic with their targets, two loss terms, two optimisers."""

    Config = DDPGConfig

    def __init__(self, cfg: DDPGConfig, seeds: Sequence[int], obs_dim: int, box: Bounded):
        super().__init__(seeds, cfg.buffer_size)
        self.cfg, self.batch_size = cfg, cfg.batch_size
        self.low, self.high = box.space.low[0].float(), box.space.high[0].float()
        act_dim = self.low.numel()
        init = course_init if cfg.init == "course" else (lambda net: net)

        def actor_and_critic():  # in this order from each seed's generator, as before
            actor = init(MLP(in_features=obs_dim, out_features=act_dim, num_cells=list(cfg.actor_hidden),
                             activation_class=nn.ReLU))
            return nn.ModuleList([actor, init(Critic(obs_dim, act_dim, cfg.critic_hidden))])
        pairs = build_per_seed(actor_and_critic, self.seeds)
        actor = Actor(SeedStack([p[0] for p in pairs]), self.low, self.high)
        critic = SeedStack([p[1] for p in pairs])
        self.nets = nn.ModuleDict(dict(actor=actor, critic=critic, target_actor=Target(actor),
                                       target_critic=Target(critic)))
        self.actor, self.critic = actor, critic
        self.actor_optim = SeedAdam(actor.mlp, lr=cfg.actor_lr)
        self.critic_params = list(critic.parameters())
        self.critic_optim = SeedAdam(critic, lr=cfg.critic_lr)
        self.optimizers = [self.actor_optim, self.critic_optim]
        self.noise = torch.zeros(len(self.seeds), act_dim)
        self.noise_rng = SeedStreams(self.seeds, stream_id("ddpg.ou"))

    def ou_step(self) -> torch.Tensor:
        """The next OU noise (S, act_dim): from 0 at each seed's new episode (if ``ou_reset``)."""
        cfg = self.cfg
        if cfg.ou_reset:
            self.noise[self.new_episode] = 0.0
        draw = (self.noise_rng.uniform(self.noise.shape[1]) if cfg.ou_noise == "uniform"
                else self.noise_rng.normal(self.noise.shape[1])).to(torch.float32)
        self.noise = (self.noise + cfg.ou_theta * (0.0 - self.noise) * cfg.ou_dt
                      + cfg.ou_sigma * math.sqrt(cfg.ou_dt) * draw)
        return self.noise

    def exploit(self, td) -> torch.Tensor:
        """The actor's action, no noise (evaluation), float64 (S, act_dim)."""
        with torch.no_grad():
            return self.actor(td.get("observation").to(torch.float32)).clamp(self.low, self.high).to(torch.float64)

    def act(self, td) -> torch.Tensor:
        """Actor + OU noise, clipped to the action box, float64 (S, act_dim)."""
        with torch.no_grad():
            action = self.actor(td.get("observation").to(torch.float32))
        return (action + self.ou_step()).clamp(self.low, self.high).to(torch.float64)

    def wants_update(self) -> int:
        stored = len(self.replay)
        return int(stored > self.batch_size if self.cfg.start_above_batch else stored >= self.batch_size)

    def value_loss(self, batch: TensorDict) -> torch.Tensor:
        """Per element (S, B): (Q(s, a) - (r + gamma (1 - terminated) Q'(s', actor'(s'))))^2."""
        nxt = batch["next"]
        with torch.no_grad():
            q_next = self.nets["target_critic"](nxt["observation"], self.nets["target_actor"](nxt["observation"]))
            y = nxt["reward"] + self.cfg.gamma * (~nxt["terminated"]) * q_next
        return (self.critic(batch["observation"], batch["action"]) - y).pow(2).squeeze(-1)

    def actor_loss(self, batch: TensorDict) -> torch.Tensor:
        """Per element (S, B): -Q(s, actor(s)), the critic held fixed (its parameters get no gradient)."""
        obs = batch["observation"]
        for p in self.critic_params:
            p.requires_grad_(False)
        try:
            return -self.critic(obs, self.actor(obs)).squeeze(-1)
        finally:
            for p in self.critic_params:
                p.requires_grad_(True)

    def update(self, batch: TensorDict) -> None:
        if self.cfg.update == "critic-then-actor":
            self._step(self.critic_optim, seed_mean(self.value_loss(batch)))
            self._step(self.actor_optim, seed_mean(self.actor_loss(batch)))
        else:
            self.actor_optim.zero_grad()
            self.critic_optim.zero_grad()
            (seed_mean(self.actor_loss(batch)) + seed_mean(self.value_loss(batch))).backward()
            self.actor_optim.step()
            self.critic_optim.step()
        for name in ("actor", "critic"):
            self.nets[f"target_{name}"].soft_update_(self.cfg.target_update)

    @staticmethod
    def _step(optim, loss) -> None:
        optim.zero_grad()
        loss.backward()
        optim.step()

    def state_dict(self) -> dict:
        return {**super().state_dict(), "noise": self.noise.clone(), "noise_rng": self.noise_rng.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        super().load_state_dict(state)
        self.noise = state["noise"].clone()
        self.noise_rng.load_state_dict(state["noise_rng"])

    @classmethod
    def resolve_config(cls, cfg: DDPGConfig, info) -> DDPGConfig:
        info.action_box("ddpg")
        return cfg

    @classmethod
    def make(cls, cfg: DDPGConfig, info, seeds):
        return cls(cfg, seeds, info.observation_dim, info.action_box("ddpg"))

    @staticmethod
    def memory_bytes(cfg: DDPGConfig, info, num_seeds: int) -> int:
        """The replay memory when full (observation, next observation, action, reward, flags)."""
        dim, act = info.observation_dim, int(info.action_box("ddpg").shape[-1])
        return num_seeds * cfg.buffer_size * (4 * (2 * dim + act + 1) + 2)
