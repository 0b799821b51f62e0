"""Presets of block pushing (SPEC 3.3; docs/domains/push.md)."""
from trl_dgpq.presets import SMALL_DQN, rbf_and_manifold

DEFAULT = "shaped"
# State scaled to a box of side 1: the table's 1.5 x 1.0 m top maps to [-0.5, 0.5]^2 (only
# distances matter) for the pusher's and the block's x, y; the heights are dropped (constant
# while the block is on the table).
PUSH_SCALE = (1 / 1.5, 1.0, 0.0, 1 / 1.5, 1.0, 0.0)

PRESETS = {
    # L_Q = 1.5: the reward changes by 1 per metre of the block, 1.5 per unit of scaled x (with the
    # square's L_Q = 1, Q̂ undercuts the true Q and no seed learnt the task in 40 episodes). Both
    # presets use the exact GP, so the kernel is their only difference.
    "dgpq": rbf_and_manifold(DEFAULT, state_scale=PUSH_SCALE, lipschitz=1.5),
    "oracle": {"shaped": {}},
    "dqn": {"shaped": {"agent": dict(SMALL_DQN, gamma=0.9)}},
    "random": {"shaped": {}},
}
