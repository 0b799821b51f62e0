"""What the neural-network agents (DDPG, DQN) share: one learner per seed.

Why not one learner whose parameters carry a seed dimension (``torch.vmap``):
TorchRL's losses, replay buffers and exploration modules draw from torch's global
generator and hold one set of parameters, so stacking would mean re-implementing
them functionally; per-seed learners keep every part stock and make "seed i alone
= seed i in a batch" hold by construction. The price is a Python loop over seeds
(S small networks instead of one batched one). Each learner owns a torch generator
state: it is swapped into torch's global generator (``fork_rng``) around everything
the learner does, so initial weights, replay sampling and exploration form a
per-seed stream, saved with the learner.
"""
from __future__ import annotations

import contextlib
from typing import Sequence

import torch
from tensordict import TensorDict

from ..rng import LEARNER_STREAM, SeedStreams


class TorchLearner:
    """Base of one seed's learner: its generator, and a count of gradient updates."""

    def __init__(self, torch_seed: int):
        self.generator_state = torch.Generator().manual_seed(torch_seed).get_state()
        self.updates = 0

    @contextlib.contextmanager
    def own_generator(self):
        """Torch's global generator is this learner's for the duration (and is put back after)."""
        with torch.random.fork_rng(devices=[]):
            torch.set_rng_state(self.generator_state)
            try:
                yield
            finally:
                self.generator_state = torch.get_rng_state()

    def act(self, obs: torch.Tensor, new_episode: bool) -> torch.Tensor:
        raise NotImplementedError

    def learn(self, transition: TensorDict) -> None:
        raise NotImplementedError

    def state_dict(self) -> dict:
        return {"generator": self.generator_state.clone(), "updates": self.updates}

    def load_state_dict(self, state: dict) -> None:
        self.generator_state = state["generator"].clone()
        self.updates = int(state["updates"])


class PerSeedLearners:
    """Agent base: S independent ``TorchLearner``s behind the runner's agent interface.
    Observations, rewards (and continuous actions) reach the learners as float32."""

    def __init__(self, seeds: Sequence[int], make_learner):
        torch_seeds = SeedStreams(seeds, LEARNER_STREAM).seed_for_torch()
        self.learners = [make_learner(s) for s in torch_seeds]
        self.new_episode = torch.ones(len(seeds), dtype=torch.bool)

    def act(self, td) -> torch.Tensor:
        obs = td.get("observation").to(torch.float32)
        return torch.cat([learner.act(obs[i:i + 1], bool(self.new_episode[i]))
                          for i, learner in enumerate(self.learners)])

    def observe(self, td, active=None) -> None:
        nxt = td.get("next")
        S = len(self.learners)
        active = torch.ones(S, dtype=torch.bool) if active is None else active
        f32 = lambda t: t.to(torch.float32) if t.is_floating_point() else t  # noqa: E731
        batch = TensorDict({
            "observation": f32(td.get("observation")), "action": f32(td.get("action")),
            "next": {"observation": f32(nxt.get("observation")), "reward": f32(nxt.get("reward")),
                     "done": nxt.get("done"), "terminated": nxt.get("terminated")}}, batch_size=[S])
        for i in active.nonzero()[:, 0].tolist():
            self.learners[i].learn(batch[i:i + 1])
        self.new_episode = nxt.get("done").reshape(S).clone()

    def episode_stats(self) -> dict:
        return {"updates": torch.tensor([learner.updates for learner in self.learners])}

    def state_dict(self) -> dict:
        return {"learners": [learner.state_dict() for learner in self.learners],
                "new_episode": self.new_episode.clone()}

    def load_state_dict(self, state: dict) -> None:
        if len(state["learners"]) != len(self.learners):
            raise ValueError(f"{type(self).__name__.lower()} state is for {len(state['learners'])} seeds, "
                             f"not {len(self.learners)}")
        for learner, s in zip(self.learners, state["learners"]):
            learner.load_state_dict(s)
        self.new_episode.copy_(state["new_episode"])
