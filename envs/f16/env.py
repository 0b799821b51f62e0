"""Altitude hold of an F-16 with relaxed static stability (GWH14's second experiment;
SPEC 3.4), batched over seeds.

The model is ``dynamics.py``'s exact discretisation at ``dt`` (0.05 s, as GWH14). State,
deviations from trim: altitude error h − h_d (ft), airspeed V_T (ft/s), angle of attack
α (rad), pitch angle θ (rad), pitch rate q (rad/s). Action: elevator −1, 0, +1 (names
"nose-up", "hold", "nose-down"), each a deflection of ``elevator_deg`` degrees held over the step
(a positive elevator, trailing edge down, pitches the nose down).
After each step, Gaussian noise of s.d. ``noise_v`` (ft/s) and ``noise_alpha`` (rad) is
added to V_T and α, from the seed's own stream (GWH14: noise on airspeed and angle of
attack). Reward (GWH14): r = −|h − h_d| / 100 − |ḣ| / 100 − |elevator| after the step,
ḣ = V_T0 (θ − α).

What GWH14 do not state, chosen here (and why):
- an episode starts at h − h_d = ``h0`` (20 ft) with α = θ = ``pitch0`` (0.01 rad) and
  lasts ``max_steps`` = 200 steps (10 s). Without an attitude perturbation or noise the
  trim state is an equilibrium, and doing nothing would cost only the altitude error;
  with them, doing nothing lets the unstable mode (time constant ~10 s) grow: 120 ft
  off at the end. The scale then resembles GWH14's Figure 3, which starts at −525 and
  ends at −47: on seeds 100–107 a uniformly random elevator scores −324 on average
  (worst −458), doing nothing −135, the quantised LQR −41 and the PD controller −37
  (``baselines.py``), each with about three elevator steps per episode. (An h0 of
  100 ft was tried first: every controller then pays ~100 for the climb it cannot
  make faster, and PD and LQR scored −139 and −136, nothing like GWH14's −47.);
- the start spread (issue 28): ``h0_spread`` and ``pitch0_spread`` > 0 draw each episode's
  start uniformly around h0 and pitch0 (α = θ), from a stream keyed by the seed's episode,
  so that an episode teaches more than one trajectory; 0, the default, keeps issue 19's
  single start;
- the envelope: the episode terminates when |h − h_d| > ``h_max`` or |α|, |θ| >
  ``attitude_max`` or |q| > ``rate_max``. Leaving it costs what the remaining steps would
  at the envelope's edge (|h − h_d| = h_max, |ḣ| = 0, no elevator): ending early is
  never cheaper than flying on;
- the decision interval: GWH14's 0.05 s may be the simulator's step rather than the
  agent's. ``decision_steps`` k > 1 holds the elevator over k simulator steps and sums
  their rewards (so an episode's reward keeps GWH14's scale); ``max_steps`` counts
  decisions. The presets' "flight" (issue 28) decides every 0.25 s;
- the observation is the state divided by the envelope's half-widths (V_T by
  ``vt_scale``), so every component is in [−1, 1] while the episode runs. The state in
  its own units is in each step's TensorDict as ``state``. ``observe_climb`` (issue 28)
  appends ḣ = V_T0 (θ − α) divided by its largest value inside the envelope, 2 V_T0
  ``attitude_max``: a function of the state, so no information is added, but a metric
  can then weigh the two quantities the reward charges (h − h_d and ḣ) and nothing else;
- ``potential`` (issue 28; ``potential.py``): each step also carries Φ(s) — "lqr": the
  noiseless value of the unquantised LQR; "cost": the state's own cost paid for ever — and
  the learners shape their own rewards by it (``trl_dgpq.agents.base.learning_reward``).
  The env's reward is unchanged.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torchrl.data import Bounded, Categorical, Composite, Unbounded

from trl_dgpq.config import setting
from trl_dgpq.rng import stream_id

from ..base import SeedBatchedEnv
from .dynamics import V_T0, climb_rate, discretise, rows_times
from .potential import POTENTIALS


@dataclass
class F16Config:
    """Altitude hold of an F-16 (SPEC 3.4)."""
    dt: float = setting(0.05, "simulator time step, s (GWH14)", within="(0, 1]")
    decision_steps: int = setting(1, "simulator steps per decision: the elevator is held over them and their "
                                     "rewards summed (1: GWH14's 0.05 s per decision)", within="[1, 100]")
    elevator_deg: float = setting(1.0, "elevator deflection of actions -1 / +1, degrees", within="(0, 25]")
    h0: float = setting(20.0, "altitude error h - h_d at the start, ft", within="[-1000, 1000]")
    pitch0: float = setting(0.01, "alpha and theta at the start, rad", within="[-0.3, 0.3]")
    h0_spread: float = setting(0.0, "the start's altitude error is h0 plus a uniform draw in +-h0_spread, ft "
                                    "(0: every episode starts at h0)", within="[0, 1000)")
    pitch0_spread: float = setting(0.0, "alpha and theta at the start are pitch0 plus one uniform draw in "
                                        "+-pitch0_spread, rad", within="[0, 0.3]")
    noise_v: float = setting(0.5, "s.d. of the airspeed noise per step, ft/s", within="[0, inf)")
    noise_alpha: float = setting(5e-4, "s.d. of the angle-of-attack noise per step, rad", within="[0, inf)")
    h_max: float = setting(1000.0, "envelope: largest |h - h_d|, ft", within="(0, inf)")
    vt_scale: float = setting(100.0, "observation scale of the airspeed deviation, ft/s", within="(0, inf)")
    attitude_max: float = setting(0.5, "envelope: largest |alpha| and |theta|, rad", within="(0, 1.5]")
    rate_max: float = setting(1.0, "envelope: largest |q|, rad/s", within="(0, inf)")
    max_steps: int = setting(200, "decisions per episode (truncation)", within="[1, inf)")
    observe_climb: bool = setting(False, "append the climb rate, V_T0 (theta - alpha) / (2 V_T0 attitude_max), "
                                         "to the observation (6 coordinates): a metric can then weigh altitude "
                                         "error and climb rate alone, the two the reward charges")
    potential: str = setting("none", "each step's TensorDict carries 'potential', phi of the state, and learners "
                                     "learn from r + gamma phi(s') - phi(s) (potential-based shaping: the same optimal "
                                     "policies, a flatter Q - phi for DGPQ's envelope). lqr: the value of "
                                     "flying the unquantised LQR without noise (uses the model); cost: the state's "
                                     "own cost, |h - h_d| / 100 + |hdot| / 100 per simulator step, paid for ever (no "
                                     "model). The reward and the recorded returns stay GWH14's",
                             choices=("none", "lqr", "cost"))
    potential_gamma: float = setting(0.9, "discount per decision of the potential's sum (the learner's gamma makes it "
                                          "closest to V; any value keeps the optimal policies)", within="[0, 1)")
    potential_r: float = setting(0.1, "the potential's LQR: cost of the elevator, per degree squared",
                                 within="(0, inf)")
    potential_model_error: float = setting(0.0, "the lqr potential from a wrong model: each entry of the "
                                                "linearisation's A and B scaled by its own factor in [1 - e, 1 + e] "
                                                "(0: the true model)", within="[0, 1)")
    potential_model_draw: int = setting(0, "which fixed draw of those factors (a seed of their own)",
                                        within="[0, inf)")

    def cross_check(self) -> None:
        if self.potential_model_error and self.potential != "lqr":
            raise ValueError(f"potential_model_error {self.potential_model_error} is the lqr potential's model error; "
                             f"the potential is {self.potential!r}")
        if (abs(self.h0) + self.h0_spread >= self.h_max
                or abs(self.pitch0) + self.pitch0_spread >= self.attitude_max):
            raise ValueError(f"every start (h0 {self.h0} +- {self.h0_spread}, pitch0 {self.pitch0} +- "
                             f"{self.pitch0_spread}) must be inside the envelope (h_max {self.h_max}, "
                             f"attitude_max {self.attitude_max})")


class F16Env(SeedBatchedEnv):
    """TorchRL env, ``batch_size=[len(seeds)]``; observations float64 ``(S, 5)`` in [−1, 1]
    (``(S, 6)`` with ``observe_climb``)."""

    Config = F16Config
    action_names = ("nose-up", "hold", "nose-down")
    _state_names = ("state", "episode")
    # the start's draws, keyed by the seed's episode (uniform_at): a seed's starts never depend
    # on its batch or on how many steps its episodes took
    _streams = (("start_rng", stream_id("f16.start")),)

    def __init__(self, seeds=(0,), cfg: F16Config | None = None, device="cpu", **overrides):
        super().__init__(seeds, cfg, device, **overrides)
        ad, bd = discretise(self.cfg.dt)
        self.ad, self.bd = ad.to(self.device), bd.to(self.device)
        self.state = torch.zeros(self.num_seeds, 5, dtype=torch.float64, device=self.device)
        self.episode = torch.full((self.num_seeds,), -1, dtype=torch.long, device=self.device)  # current one
        c = self.cfg
        self.scale = torch.tensor([c.h_max, c.vt_scale, c.attitude_max, c.attitude_max, c.rate_max],
                                  dtype=torch.float64, device=self.device)
        self.potential = POTENTIALS[c.potential](c, self.device) if c.potential != "none" else None

    @classmethod
    def _specs(cls, cfg, S, device):
        f64 = dict(dtype=torch.float64, device=device)
        observation = Composite(observation=Bounded(-1.0, 1.0, shape=(S, 5 + cfg.observe_climb), **f64),
                                state=Unbounded(shape=(S, 5), **f64), shape=(S,), device=device)
        if cfg.potential != "none":
            observation["potential"] = Unbounded(shape=(S, 1), **f64)
        return observation, Categorical(3, shape=(S,), device=device), Unbounded(shape=(S, 1), **f64)

    def _observe(self):
        """The scaled observation, the state in its units by key ``state`` (for the
        scripted controllers) and, with a potential, its value by key ``potential``."""
        extra = {} if self.potential is None else dict(potential=self.potential(self.state)[:, None])
        return self._td(observation=self.observation(self.state), state=self.state.clone(), **extra)

    def observation(self, state: torch.Tensor) -> torch.Tensor:
        """The observation of states (N, 5) in the env's units."""
        obs = state / self.scale
        if self.cfg.observe_climb:  # inside the envelope |theta - alpha| <= 2 attitude_max
            climb = climb_rate(state) / (2.0 * V_T0 * self.cfg.attitude_max)
            obs = torch.cat([obs, climb[:, None]], -1)
        return obs

    def _initial(self, mask):
        c = self.cfg
        self.episode += mask
        u = 2.0 * self.start_rng.uniform_at(self.episode, 2) - 1.0                     # (S, 2) in [-1, 1)
        h, pitch = c.h0 + c.h0_spread * u[:, 0], c.pitch0 + c.pitch0_spread * u[:, 1]
        zero = torch.zeros_like(h)
        start = torch.stack([h, zero, pitch, pitch, zero], -1)
        self.state[mask] = start[mask]
        return self._observe()

    def load_state_dict(self, state: dict, strict: bool = True) -> None:
        if "episode" not in state:  # a checkpoint from before the start spread: its starts drew nothing
            state = {**state, "episode": torch.zeros_like(self.episode)}
        super().load_state_dict(state, strict)

    def elevator(self, action: torch.Tensor) -> torch.Tensor:
        """Actions 0, 1, 2 as elevator -1, 0, +1."""
        return action.to(torch.float64) - 1.0

    def _transition(self, action):
        c = self.cfg
        e = self.elevator(action)
        reward = torch.zeros_like(e)
        for _ in range(c.decision_steps):                                # the elevator held
            x = rows_times(self.state, self.ad.T) + (e * c.elevator_deg)[:, None] * self.bd
            noise = self.rng.normal(2)                                   # the seed's own stream
            x[:, 1] += c.noise_v * noise[:, 0]
            x[:, 2] += c.noise_alpha * noise[:, 1]
            self.state.copy_(x)
            reward = reward - x[:, 0].abs() / 100 - climb_rate(x).abs() / 100 - e.abs()
        outside = (x.abs() > self.scale)[:, [0, 2, 3, 4]].any(-1)       # airspeed has no envelope
        left = (self.max_steps - (self.t + 1)).to(torch.float64) * c.decision_steps  # simulator steps
        reward = torch.where(outside, reward - left * c.h_max / 100, reward)
        return self._observe(), reward, outside


Env = F16Env
