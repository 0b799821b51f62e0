"""Presets of the F-16 altitude hold (SPEC 3.4; issue 19).

DGPQ: GWH14's two Lipschitz constants, L_Q = 5 ("default") and 10 ("lq10"). The rest is
not stated in GWH14 and is chosen here, not yet probed: every reward is ≤ 0, so Q̂ starts
at V_max = 0 (optimism); γ = 0.9, a horizon of ~10 steps (0.5 s), over which the
elevator's effect on the reward shows; the observation is the state over the envelope's
half-widths, in [−1, 1]⁵, with the L1 metric. The GP is sized like the square's "shaped":
the per-step reward moves by ~0.1 with the state noise, so noise_var 0.01, and Q̂ moves
once the posterior variance is under σ_tol² = 0.005.
"""
from trl_dgpq.presets import SMALL_DQN

DEFAULT = "default"

F16_DGPQ = dict(gamma=0.9, v_max=0.0, lengthscale=0.1, noise_var=0.01, sigma_tol2=0.005, eps1=0.05)

PRESETS = {
    "dgpq": {"default": {"agent": dict(F16_DGPQ, lipschitz=5.0)},
             "lq10": {"agent": dict(F16_DGPQ, lipschitz=10.0)}},
    "dqn": {"default": {"agent": dict(SMALL_DQN, gamma=0.9)}},
    "random": {"default": {}},
    "lqr": {"default": {}},
    "pd": {"default": {}},
}
