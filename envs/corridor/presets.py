"""Presets of the corridor. DGPQ: rewards -1 until the goal, so Q̂ starts at V_max = 0,
undiscounted; one cell is 1 / (length - 1) = 1/9 of the unit observation and changes
the value by 1, so L_Q = 9 and a lengthscale of about a cell."""
from trl_dgpq.presets import SMALL_DQN

DEFAULT = "default"

PRESETS = {
    "dgpq": {"default": {"agent": dict(gamma=1.0, v_max=0.0, lipschitz=9.0, lengthscale=0.1)}},
    "dqn": {"default": {"agent": SMALL_DQN}},
    "random": {"default": {}},
    "constant": {"default": {"agent": dict(action="right")}},  # the optimal policy
}
