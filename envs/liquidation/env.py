"""Optimal liquidation in the Almgren-Chriss market (AC00; seed report 4.4; SPEC 3.2),
batched over seeds.

Sell ``shares`` in ``trades`` trades over ``horizon`` days. Action: the fraction of
the remaining shares to sell, in [0, 1] (rounded to whole shares); the last trade
sells everything. Trade k executes at S_{k-1} - (eps sign(n_k) + (eta / tau) n_k)
(no price noise before the first trade); then S_k = S_{k-1} + sigma sqrt(tau) xi_k
- gamma n_k. The episode terminates when no shares are left.

Observation (8): the last six log-returns log(S_k / S_{k-1}), trades left / N,
shares left / X; with ``pace`` (9) also (shares left / X) / trades left. Also in every step's TensorDict, by key: ``trades_left`` (a count)
and ``shares_left`` (shares), for agents that follow a schedule, and, as running totals of the
episode (the runner puts their final values in the episode's CSV row):
``implementation_shortfall`` = X S_0 - sum n_k exec_k and ``ac_cost`` = shortfall +
lambda sigma^2 tau sum x_k^2 (x_k held after trade k), whose expectation for the
AC schedule is U*. Per episode (constant over it): ``optimal_ac_cost``, the ac_cost the AC
schedule (``ac-optimal``, rounded as trades are) has on this episode's price path; and
``cost_ratio`` = 1 + (ac_cost - optimal_ac_cost) / U*, final at the episode's end: an
estimate of E[ac_cost] / U* paired with the optimum on the same prices. The price noise
moves a single ac_cost by ~2.5 U* (s.d.), far more than policies differ; it moves the
difference to the optimum on the same path far less, so means of ``cost_ratio`` over a
few hundred episodes separate policies that means of ``ac_cost`` over thousands do not.
``noise_free_ac_cost``: the ac_cost of the episode's trades had the price not moved (its
impact and risk terms, what the "impact" reward pays), and ``noise_free_cost_ratio`` = 1 +
(that - the AC schedule's expected ac_cost) / U*. ac_cost = noise_free_ac_cost - sigma sqrt(tau)
sum_k xi_k x_k, and x_k is held before xi_k is revealed (xi_k first moves the price after trade
k), so the two have the same mean for every agent that does not read the episode's
``optimal_ac_cost`` or ``cost_ratio`` (which know its whole path): E[ac_cost] / U* is the mean of
either ratio. For an agent whose trades never depend on prices (DGPQ with the "impact" reward on
a state without the log-returns: presets ``steady``, ``flat``) the noise-free ratio is exactly
the expected cost of the trades it played, with no price noise at all: a block's mean moves
only when the policy does.

Rewards:
  "shortfall" (default): r_k = -[n_k (S_0 - exec_k) + lambda sigma^2 tau x_k^2] / reward_scale,
      so the return is -ac_cost / reward_scale and its expectation is maximised
      exactly by the AC schedule (rewards in $M with the default scale).
  "impact": r_k = -[n_k (eps + (eta / tau) n_k) + gamma n_k x_k + lambda sigma^2 tau x_k^2] / reward_scale,
      what trade k costs in impact (spread, temporary impact, its permanent impact on the x_k
      still held) and risk, with no price noise: the return is -(ac_cost + sigma sqrt(tau)
      sum_k xi_k x_k) / reward_scale, and as x_k is chosen before xi_k the sum has mean zero
      for every policy, so the expected return, and the best policy, are the shortfall's. Each
      reward is a function of (x_{k-1}, n_k): a learner whose state is (trades left, shares
      left) meets a deterministic MDP (docs/domains/liquidation.md, "Drift").
  "utility-ratio" (the seed report's): (|U(x_{k-1})| - |U(x_k)|) / |U(x_{k-1})| with
      U(x) = E*(x) + lambda V*(x) over the full horizon. Not aligned with the
      objective: selling everything at once earns the largest single reward.

Common random numbers: the xi of seed s's episode e are draw e of the seed's price
stream (``SeedStreams.uniform_at``), so every agent meets the same price paths,
whatever it does and whoever shares its batch.

Actions: ``action_levels`` = 0 gives a continuous action (``Bounded`` [0, 1], shape
(S, 1)); n >= 2 gives n discrete levels 0, 1/(n-1), ..., 1 (``Categorical``), for
agents that need discrete actions (DGPQ: the seed report used 101). With levels,
``level_noise`` > 0 adds Ornstein-Uhlenbeck noise (theta ``level_noise_theta``,
dt = 1, reset every episode) to the chosen fraction, from the seed's env stream.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torchrl.data import Bounded, Categorical, Composite, Unbounded

from trl_dgpq.config import setting
from trl_dgpq.rng import box_muller

from ..base import SeedBatchedEnv
from .almgren_chriss import ACModel

REWARDS = ("shortfall", "impact", "utility-ratio")
RETURNS = 6  # log-returns in the observation
PRICE_STREAM = 5  # the price noise's stream id (trl_dgpq.rng: ids 1-7 are taken)


@dataclass
class LiquidationConfig:
    """Almgren-Chriss liquidation (SPEC 3.2; defaults: the course environment)."""
    reward: str = setting("shortfall", "shortfall: minus each trade's risk-adjusted cost / reward_scale; "
                                       "impact: the same without the price noise's term (mean zero); "
                                       "utility-ratio: the seed report's", choices=REWARDS)
    reward_scale: float = setting(1e6, "dollars per unit of the shortfall reward", within="(0, inf)")
    shares: int = setting(1_000_000, "shares to sell, X", within="(0, inf)")
    start_price: float = setting(50.0, "S_0, dollars", within="(0, inf)")
    annual_volatility: float = setting(0.12, "annual volatility of the price", within="(0, inf)")
    trading_days: float = setting(250.0, "trading days per year", within="(0, inf)")
    spread: float = setting(0.125, "bid-ask spread, dollars (fixed cost eps = spread / 2)", within="(0, inf)")
    daily_volume: float = setting(5e6, "daily volume, shares (eta = spread / (0.01 volume), "
                                       "gamma = spread / (0.1 volume))", within="(0, inf)")
    horizon: float = setting(60.0, "liquidation time T, days", within="(0, inf)")
    trades: int = setting(60, "number of trades N (the episode's length at most)", within="(0, inf)")
    lam: float = setting(1e-6, "risk aversion lambda", within="[0, inf)")
    price_noise: bool = setting(True, "random price moves (off: the price moves only by impact; "
                                      "sigma still sets kappa and the risk term)")
    action_levels: int = setting(0, "0: continuous sell fraction in [0, 1]; n >= 2: n levels 0, 1/(n-1), .., 1",
                                 within="[0, inf)")
    level_noise: float = setting(0.0, "sigma of OU noise on the chosen level's fraction (0: none)",
                                 within="[0, inf)")
    level_noise_theta: float = setting(0.15, "theta of that OU noise", within="[0, inf)")
    pace: bool = setting(False, "append the pace, (shares left / X) / trades left, to the observation: the "
                                "optimal cost-to-go is 2.5-Lipschitz (L1, $M) in (shares left, pace) and "
                                "69-Lipschitz in (trades left, shares left)")

    @property
    def max_steps(self) -> int:
        return self.trades

    def cross_check(self) -> None:
        if self.action_levels == 1:
            raise ValueError(f"action_levels must be 0 (continuous) or >= 2, got {self.action_levels}")
        if self.level_noise > 0 and self.action_levels == 0:
            raise ValueError("level_noise applies to discrete levels: set action_levels >= 2")
        ACModel.from_config(self).kappa  # eta~ > 0


class LiquidationEnv(SeedBatchedEnv):
    """TorchRL env, ``batch_size=[len(seeds)]``; observations float64 ``(S, 8)``, ``(S, 9)``
    with ``pace``."""

    Config = LiquidationConfig
    action_hint = "liquidation: action_levels=0 gives a continuous sell fraction, >= 2 discrete levels"
    episode_info = ("implementation_shortfall", "ac_cost", "optimal_ac_cost", "cost_ratio", "noise_free_ac_cost",
                    "noise_free_cost_ratio")
    _streams = (("price_rng", PRICE_STREAM),)  # keyed by episode (uniform_at): its counter never moves
    _state_names = ("x", "price", "returns", "shortfall", "ac_cost", "episode", "ou", "xi", "optimal_ac_cost",
                    "noise_free_ac_cost")

    def __init__(self, seeds=(0,), cfg: LiquidationConfig | None = None, device="cpu", **overrides):
        super().__init__(seeds, cfg, device, **overrides)
        cfg = self.cfg
        self.model = ACModel.from_config(cfg)
        S, f64 = self.num_seeds, dict(dtype=torch.float64, device=self.device)
        self.x = torch.full((S,), float(cfg.shares), **f64)          # shares held
        self.price = torch.full((S,), cfg.start_price, **f64)        # S_{k-1}: the next trade's price
        self.returns = torch.zeros(S, RETURNS, **f64)
        self.shortfall = torch.zeros(S, **f64)
        self.ac_cost = torch.zeros(S, **f64)
        self.episode = torch.full((S,), -1, dtype=torch.long, device=self.device)  # index of the current episode
        self.ou = torch.zeros(S, **f64)
        self.xi = torch.zeros(S, cfg.trades, **f64)  # the current episode's price noise
        self.optimal_ac_cost = torch.zeros(S, **f64)  # the AC schedule's ac_cost on that noise
        self.noise_free_ac_cost = torch.zeros(S, **f64)  # ac_cost without the price noise's term
        self.u_star = self.model.utility()
        self.optimal_trades = self._schedule_trades(self.model.sell_fractions())
        # the AC schedule's expected ac_cost (rounded as trades are: U* up to the rounding)
        self.optimal_noise_free = self.path_cost(self.optimal_trades, torch.zeros(1, cfg.trades, **f64))[0]
        self.levels = torch.linspace(0, 1, cfg.action_levels, **f64) if cfg.action_levels else None

    @classmethod
    def _specs(cls, cfg, S, device):
        f64 = dict(dtype=torch.float64, device=device)
        observation = Composite(
            observation=Unbounded(shape=(S, RETURNS + 2 + cfg.pace), **f64),
            trades_left=Bounded(0.0, float(cfg.trades), shape=(S,), **f64),
            shares_left=Bounded(0.0, float(cfg.shares), shape=(S,), **f64),
            implementation_shortfall=Unbounded(shape=(S,), **f64),
            ac_cost=Unbounded(shape=(S,), **f64),
            optimal_ac_cost=Unbounded(shape=(S,), **f64),
            cost_ratio=Unbounded(shape=(S,), **f64),
            noise_free_ac_cost=Unbounded(shape=(S,), **f64),
            noise_free_cost_ratio=Unbounded(shape=(S,), **f64),
            shape=(S,), device=device)
        if cfg.action_levels:
            action = Categorical(cfg.action_levels, shape=(S,), device=device)
        else:
            action = Bounded(0.0, 1.0, shape=(S, 1), **f64)
        return observation, action, Unbounded(shape=(S, 1), **f64)

    def _observation(self, trades_done):
        cfg = self.cfg
        left = (cfg.trades - trades_done).to(torch.float64)
        held = self.x / cfg.shares
        obs = [self.returns, (left / cfg.trades)[:, None], held[:, None]]
        if cfg.pace:  # what each trade left would sell, evenly: where the cost-to-go's slopes are moderate
            obs.append((held / left.clamp_min(1.0))[:, None])
        obs = torch.cat(obs, -1)
        return self._td(observation=obs, trades_left=left, shares_left=self.x.clone(),
                        implementation_shortfall=self.shortfall.clone(), ac_cost=self.ac_cost.clone(),
                        optimal_ac_cost=self.optimal_ac_cost.clone(),
                        cost_ratio=1 + (self.ac_cost - self.optimal_ac_cost) / self.u_star,
                        noise_free_ac_cost=self.noise_free_ac_cost.clone(),
                        noise_free_cost_ratio=1 + (self.noise_free_ac_cost - self.optimal_noise_free) / self.u_star)

    def _initial(self, mask):
        self.x[mask] = float(self.cfg.shares)
        self.price[mask] = self.cfg.start_price
        for name in ("returns", "shortfall", "ac_cost", "ou", "noise_free_ac_cost"):
            getattr(self, name)[mask] = 0.0
        self.episode += mask
        # xi of (seed, episode): draw ``episode`` of the seed's price stream, whatever happened before.
        u = self.price_rng.uniform_at(self.episode, 2 * self.cfg.trades).view(-1, 2, self.cfg.trades)
        self.xi[mask] = box_muller(u[:, 0], u[:, 1])[mask] * float(self.cfg.price_noise)
        self.optimal_ac_cost[mask] = self.path_cost(self.optimal_trades, self.xi[mask])
        return self._observation(self.t)

    def load_state_dict(self, state: dict, strict: bool = True) -> None:
        if "optimal_ac_cost" not in state:  # a checkpoint from before the column: its episode's xi says it
            state = {**state, "optimal_ac_cost": self.path_cost(self.optimal_trades, state["xi"])}
        if "noise_free_ac_cost" not in state:  # from before it: known at an episode's start only
            state = {**state, "noise_free_ac_cost": torch.where(state["t"] == 0, 0.0, float("nan")).to(self.x)}
        super().load_state_dict(state, strict)

    def _shares_to_sell(self, fraction, x, last):
        """Whole shares of ``fraction`` of the ``x`` held, everything at the ``last`` trade."""
        return torch.where(last, x, torch.round(fraction * x).clamp(min=0.0).minimum(x))

    def _schedule_trades(self, fractions: torch.Tensor) -> torch.Tensor:
        """n_1..n_N (N,) of selling ``fractions[k]`` of the rest at trade k + 1, rounded as ``step``
        rounds (so ``path_cost`` is ac-optimal's ac_cost, not the unrounded schedule's)."""
        x, trades = torch.tensor(float(self.cfg.shares), dtype=torch.float64), []
        for k, fraction in enumerate(fractions):
            n = self._shares_to_sell(fraction, x, torch.tensor(k + 1 >= self.cfg.trades))
            trades.append(n)
            x = x - n
        return torch.stack(trades)

    def path_cost(self, trades: torch.Tensor, xi: torch.Tensor) -> torch.Tensor:
        """ac_cost (B,) of selling ``trades`` (N,) on price noise ``xi`` (B, N), as ``step`` adds it
        up: trade k at S_{k-1} - eps sign(n_k) - (eta / tau) n_k, S_k = S_{k-1} + sigma sqrt(tau)
        xi_k - gamma n_k, plus lambda sigma^2 tau x_k^2."""
        m, s0 = self.model, self.cfg.start_price
        before = lambda v: torch.cumsum(v, -1) - v  # noqa: E731  (sum over j < k)
        price = s0 + math.sqrt(m.sigma2 * m.tau) * before(xi) - m.gamma * before(trades)
        exec_price = price - m.eps * torch.sign(trades) - (m.eta / m.tau) * trades
        held = self.cfg.shares - torch.cumsum(trades, 0)
        return (trades * (s0 - exec_price)).sum(-1) + m.lam * m.sigma2 * m.tau * (held * held).sum()

    def _fraction(self, action):
        if self.levels is None:
            return action[:, 0].to(torch.float64)
        fraction = self.levels[action]
        cfg = self.cfg
        if cfg.level_noise > 0:
            self.ou.mul_(1 - cfg.level_noise_theta).add_(cfg.level_noise * self.rng.normal())
            fraction = (fraction + self.ou).clamp(0.0, 1.0)
        return fraction

    def _transition(self, action):
        cfg, m = self.cfg, self.model
        x = self.x
        last = self.t + 1 >= cfg.trades
        n = self._shares_to_sell(self._fraction(action), x, last)
        exec_price = self.price - m.eps * torch.sign(n) - (m.eta / m.tau) * n
        trade_cost = n * (cfg.start_price - exec_price)
        x_new = x - n
        risk = m.lam * m.sigma2 * m.tau * x_new * x_new
        impact = n * (m.eps * torch.sign(n) + (m.eta / m.tau) * n) + m.gamma * n * x_new
        if cfg.reward == "shortfall":
            reward = -(trade_cost + risk) / cfg.reward_scale
        elif cfg.reward == "impact":
            reward = -(impact + risk) / cfg.reward_scale
        else:
            u_prev, u_now = m.utility(x).abs(), m.utility(x_new).abs()
            reward = (u_prev - u_now) / u_prev
        xi = self.xi.gather(1, self.t.clamp_max(cfg.trades - 1)[:, None])[:, 0]
        new_price = self.price + math.sqrt(m.sigma2 * m.tau) * xi - m.gamma * n
        self.returns.copy_(torch.cat([self.returns[:, 1:], torch.log(new_price / self.price)[:, None]], -1))
        self.price.copy_(new_price)  # (in place: assigning a tensor attribute of a Module is slow)
        self.x.copy_(x_new)
        self.shortfall.add_(trade_cost)
        self.ac_cost.add_(trade_cost + risk)
        self.noise_free_ac_cost.add_(impact + risk)
        return self._observation(self.t + 1), reward, x_new <= 0  # (the base advances t after this)


Env = LiquidationEnv
