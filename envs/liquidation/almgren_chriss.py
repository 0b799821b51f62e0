"""The Almgren-Chriss optimal liquidation model in closed form (AC00; SPEC 3.2).

Selling X shares in N trades over T days (tau = T / N): trade k executes at
S_{k-1} - (eps sign(n_k) + (eta / tau) n_k), and each trade lowers the price
permanently by gamma n_k; between trades the price moves by sigma sqrt(tau) xi_k.
With linear impact the shortfall has mean E = eps X + gamma X^2 / 2 + (eta~ / tau)
sum n_k^2 (eta~ = eta - gamma tau / 2) and variance V = sigma^2 tau sum x_k^2
(x_k the shares held after trade k), and the schedule minimising E + lambda V is

    x_j = sinh(kappa (T - t_j)) / sinh(kappa T) X,   (2 / tau^2)(cosh kappa tau - 1) = lambda sigma^2 / eta~.

``ACModel`` holds one market and gives kappa, the optimal holdings and trades,
E*, V*, U* = E* + lambda V* (closed forms, with the lambda -> 0 limit where
kappa = 0: sell evenly), and the cost of any schedule (``cost``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class ACModel:
    shares: float            # X
    start_price: float       # S_0
    horizon: float           # T, days
    trades: int              # N
    sigma2: float            # price variance per day ($^2)
    eta: float               # temporary impact ($ per share per share/day)
    gamma: float             # permanent impact ($ per share)
    eps: float               # fixed cost per share (half the spread)
    lam: float               # risk aversion lambda

    @classmethod
    def from_config(cls, cfg) -> "ACModel":
        """The market of a ``LiquidationConfig`` (the course environment's derivations)."""
        return cls(shares=float(cfg.shares), start_price=cfg.start_price, horizon=cfg.horizon, trades=cfg.trades,
                   sigma2=(cfg.annual_volatility / math.sqrt(cfg.trading_days) * cfg.start_price) ** 2,
                   eta=cfg.spread / (0.01 * cfg.daily_volume), gamma=cfg.spread / (0.1 * cfg.daily_volume),
                   eps=cfg.spread / 2, lam=cfg.lam)

    @property
    def tau(self) -> float:
        return self.horizon / self.trades

    @property
    def eta_tilde(self) -> float:
        return self.eta - self.gamma * self.tau / 2

    @property
    def kappa(self) -> float:
        """Urgency kappa (per day): (2 / tau^2)(cosh kappa tau - 1) = lambda sigma^2 / eta~."""
        if self.eta_tilde <= 0:
            raise ValueError(f"eta~ = eta - gamma tau / 2 must be > 0, got {self.eta_tilde:g}: "
                             "more trades or a larger spread-to-volume ratio")
        return math.acosh(1 + self.lam * self.sigma2 * self.tau ** 2 / (2 * self.eta_tilde)) / self.tau

    def holdings(self, shares: float | None = None) -> torch.Tensor:
        """Optimal x_0 = X, x_1, ..., x_N = 0 (float64, N + 1), not rounded."""
        X = self.shares if shares is None else shares
        t = torch.arange(self.trades + 1, dtype=torch.float64) * self.tau
        k, T = self.kappa, self.horizon
        if k * T < 1e-9:  # lambda -> 0: sell evenly
            return X * (1 - t / T)
        return X * torch.sinh(k * (T - t)) / math.sinh(k * T)

    def trade_list(self, shares: float | None = None) -> torch.Tensor:
        """Optimal n_1, ..., n_N (float64, N)."""
        x = self.holdings(shares)
        return x[:-1] - x[1:]

    def sell_fractions(self) -> torch.Tensor:
        """n_k / x_{k-1}, k = 1..N: the optimal schedule as fractions of the remaining
        shares (independent of X; the last is 1)."""
        x = self.holdings(1.0)
        return 1 - x[1:] / x[:-1]

    # Closed forms (AC00), as quadratics in the shares so they apply to any x.
    def _coefficients(self):
        """(c_E, c_V) with E*(x) = eps x + gamma x^2 / 2 + c_E x^2 and V*(x) = c_V x^2."""
        k, T, tau = self.kappa, self.horizon, self.tau
        if k * T < 1e-9:  # the limit: n_k = x / N
            N = self.trades
            return self.eta_tilde / T, self.sigma2 * tau * sum((1 - j / N) ** 2 for j in range(1, N + 1))
        c_e = (self.eta_tilde * math.tanh(k * tau / 2) * (tau * math.sinh(2 * k * T) + 2 * T * math.sinh(k * tau))
               / (2 * tau ** 2 * math.sinh(k * T) ** 2))
        c_v = (0.5 * self.sigma2 * (tau * math.sinh(k * T) * math.cosh(k * (T - tau)) - T * math.sinh(k * tau))
               / (math.sinh(k * T) ** 2 * math.sinh(k * tau)))
        return c_e, c_v

    def expected_shortfall(self, x=None):
        """E*(x) of the optimal schedule for x shares (default X) over the full horizon."""
        x = self.shares if x is None else x
        c_e, _ = self._coefficients()
        return self.eps * x + (0.5 * self.gamma + c_e) * x * x

    def variance(self, x=None):
        """V*(x) of the optimal schedule's shortfall."""
        x = self.shares if x is None else x
        return self._coefficients()[1] * x * x

    def utility(self, x=None):
        """U*(x) = E*(x) + lambda V*(x), the optimal risk-adjusted cost."""
        return self.expected_shortfall(x) + self.lam * self.variance(x)

    def cost(self, trades) -> dict:
        """Expected shortfall, variance and E + lambda V of any schedule ``trades`` (N,)
        that sells every share, by the sums (not the closed forms); a negative trade is a buy,
        and pays the spread too (eps sign(n) n = eps |n|), as in the env."""
        n = torch.as_tensor(trades, dtype=torch.float64)
        x = n.sum() - n.cumsum(0)
        e = self.eps * n.abs().sum() + 0.5 * self.gamma * n.sum() ** 2 + self.eta_tilde / self.tau * (n * n).sum()
        v = self.sigma2 * self.tau * (x * x).sum()
        return dict(expected_shortfall=float(e), variance=float(v), utility=float(e + self.lam * v))
