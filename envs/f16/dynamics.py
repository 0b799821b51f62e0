"""The F-16's linearised longitudinal dynamics (SPEC 3.4; Stevens & Lewis), exactly
discretised.

The standard published linearisation at h = 0 ft, V_T = 502 ft/s, x_cg = 0.35 c̄:
state (V_T ft/s, α rad, θ rad, q rad/s), elevator in degrees; open-loop eigenvalues
−1.912, −0.151 ± 0.115i and +0.098 (relaxed static stability: one unstable mode).
Altitude is appended as the first state, ḣ = V_T0 (θ − α), so the model is 5-D:
(h, V_T, α, θ, q), all deviations from trim. Discretised with a zero-order hold on
the elevator: exp([[A, B], [0, 0]] dt) gives (A_d, B_d) exactly.
"""
from __future__ import annotations

import torch

V_T0 = 502.0  # trim airspeed, ft/s

A = torch.tensor([[-1.9311e-02, 8.8157e+00, -3.2170e+01, -5.7499e-01],
                  [-2.5389e-04, -1.0189e+00, 0.0, 9.0506e-01],
                  [0.0, 0.0, 0.0, 1.0],
                  [2.9465e-12, 8.2225e-01, 0.0, -1.0774e+00]], dtype=torch.float64)
B = torch.tensor([1.7370e-01, -2.1499e-03, 0.0, -1.7555e-01], dtype=torch.float64)

STATE = ("h", "v_t", "alpha", "theta", "q")  # the 5-D model's order


def perturbed(error: float, draw: int) -> tuple:
    """(A, B) with each entry scaled by its own factor, uniform in [1 - ``error``, 1 + ``error``],
    from a generator seeded by ``draw`` alone: a fixed, recorded wrong model (a zero stays zero;
    altitude's row, ḣ = V_T0 (θ − α), is kinematics, not a model, and ``continuous`` keeps it).
    ``error`` 0: the true linearisation itself."""
    if error == 0:
        return A, B
    g = torch.Generator().manual_seed(int(draw))
    factors = 1 + error * (2 * torch.rand(4 * 4 + 4, generator=g, dtype=torch.float64) - 1)
    return A * factors[:16].view(4, 4), B * factors[16:]


def continuous(model=None) -> tuple:
    """(A, B) of the 5-D model (h, V_T, α, θ, q) with ḣ = V_T0 (θ − α); ``model``: the 4-D (A, B)
    it is built on (default: the true linearisation)."""
    a4, b4 = model if model is not None else (A, B)
    a = torch.zeros(5, 5, dtype=torch.float64)
    a[1:, 1:] = a4
    a[0, 2], a[0, 3] = -V_T0, V_T0
    b = torch.zeros(5, dtype=torch.float64)
    b[1:] = b4
    return a, b


def discretise(dt: float, model=None) -> tuple:
    """(A_d, B_d): x_{k+1} = A_d x_k + B_d u_k for an elevator u_k (degrees) held over dt (of
    ``model``'s 4-D (A, B); default: the true linearisation)."""
    a, b = continuous(model)
    m = torch.zeros(6, 6, dtype=torch.float64)
    m[:5, :5], m[:5, 5] = a, b
    e = torch.linalg.matrix_exp(m * dt)
    return e[:5, :5].clone(), e[:5, 5].clone()


def climb_rate(state: torch.Tensor) -> torch.Tensor:
    """ḣ (ft/s) of states (..., 5)."""
    return V_T0 * (state[..., 3] - state[..., 2])


def rows_times(x: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
    """``x @ m`` for a batch of rows (seeds), each row's result independent of the others
    bit for bit: a matrix product's kernel (and so its rounding) can change with the number
    of rows, which made a seed's flight depend on its batch on some CPUs."""
    out = x[:, 0, None] * m[0]
    for j in range(1, x.shape[1]):
        out = out + x[:, j, None] * m[j]
    return out
