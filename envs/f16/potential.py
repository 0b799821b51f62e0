"""Potentials for reward shaping on the F-16 (issue 28): ``lqr``, Φ(x) the value of flying the
unquantised LQR from x without noise; ``cost``, Φ(x) the cost the reward charges for the state
x, as if it were paid for ever (no model).

Shaping by a potential (Ng, Harada & Russell 1999) — learning from r + γΦ(s') − Φ(s) instead
of r — leaves every policy's ranking unchanged, for any Φ and the learner's own γ, but what
a learner must represent becomes Q − Φ. For DGPQ that is what matters: its envelope Q̂ needs
L_Q at least Q's slope in the state metric, and on the F-16 that slope (~40 per unit where
the aircraft flies, from the state's value) is far above the differences between the
elevator's settings (~1.4-3.7) that flying rests on. With Φ close to V, Q − Φ is about the
advantage, whose slope is small. ``lqr`` uses the model (the LQR of the linearised
dynamics), knowledge GWH14's model-free agent does not have; ``cost`` uses only the reward's
own terms. Both are documented variants, off by default.

The closed loop is linear, so along the noiseless trajectory every cost term of every
simulator step is |g · x₀| for a fixed row g: Φ(x) = −Σ w |G x| with the rows G and the
discounts w computed once.
"""
from __future__ import annotations

import math

import torch

from .baselines import LQR_WEIGHTS, lqr_gain
from .dynamics import V_T0, climb_rate, discretise, perturbed, rows_times


def horizon(gamma: float, tail: float = 1e-3) -> int:
    """Decisions t = 0, 1, ... while γᵗ ≥ ``tail`` (1 at γ = 0)."""
    return 1 if gamma == 0 else max(1, math.ceil(math.log(tail) / math.log(gamma)))


def lqr_rows(dt: float, decision_steps: int, elevator_deg: float, r: float, gamma: float,
             tail: float = 1e-3, model=None) -> tuple:
    """(G, w): rows (N, 5) and weights (N,) with Φ(x) = −Σ_n w_n |G_n · x|, over decisions
    until γᵗ < ``tail``. Each decision holds u = −K x (K: the LQR for a decision of
    ``dt · decision_steps``, elevator cost ``r``) over its simulator steps, each costing
    |h|/100 + |ḣ|/100 + |u|/elevator_deg as the env's reward does. ``model``: the 4-D (A, B)
    the designer believes (``dynamics.perturbed``): the gain and the flight are both its."""
    ad, bd = discretise(dt, model)
    gain = lqr_gain(*discretise(dt * decision_steps, model), LQR_WEIGHTS, r)
    decisions = horizon(gamma, tail)
    m, rows, weights = torch.eye(5, dtype=torch.float64), [], []
    for t in range(decisions):
        u = -gain @ m                                     # the decision's command, as a row on x₀
        for _ in range(decision_steps):
            m = ad @ m + torch.outer(bd, u)
            rows += [m[0] / 100, V_T0 * (m[3] - m[2]) / 100, u / elevator_deg]
            weights += [gamma ** t] * 3
    return torch.stack(rows), torch.tensor(weights, dtype=torch.float64)


class LQRPotential:
    """Φ of states (S, 5) in the env's units, (S,); each row independent of the others bit for bit."""

    def __init__(self, cfg, device="cpu"):
        model = perturbed(cfg.potential_model_error, cfg.potential_model_draw)   # the true one at error 0
        g, w = lqr_rows(cfg.dt, cfg.decision_steps, cfg.elevator_deg, cfg.potential_r, cfg.potential_gamma,
                        model=model)
        self.rows_t, self.weights = g.T.contiguous().to(device), w.to(device)

    def __call__(self, state: torch.Tensor) -> torch.Tensor:
        return -(rows_times(state, self.rows_t).abs() * self.weights).sum(-1)


class CostPotential:
    """Φ(x) = −(|h − h_d| / 100 + |ḣ| / 100) · decision_steps / (1 − γ): the state's own cost per
    simulator step (the reward's terms without the elevator's), paid at every step for ever."""

    def __init__(self, cfg, device="cpu"):
        self.factor = cfg.decision_steps / (1.0 - cfg.potential_gamma)

    def __call__(self, state: torch.Tensor) -> torch.Tensor:
        return -(state[:, 0].abs() / 100 + climb_rate(state).abs() / 100) * self.factor


POTENTIALS = {"lqr": LQRPotential, "cost": CostPotential}
