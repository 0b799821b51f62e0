"""What the analysis says about gymnasium envs: curves of the return; thresholds per id."""
from trl_dgpq.analysis import Threshold

# What the agent sees ("unit" for DGPQ, "raw" for the neural learners) is its side of the
# task: DGPQ and DQN on one gym id share a table.
AGENT_SIDE_SETTINGS = ("observations",)
THRESHOLDS = {
    "CartPole-v1": Threshold("return", ">=", 195, 10, "mean return >= 195 over 10 episodes"),
    "MountainCar-v0": Threshold("terminated", ">=", 1, 1, "an episode reaches the flag"),
    "Acrobot-v1": Threshold("return", ">=", -100, 10, "mean return >= -100 over 10 episodes"),
}

# what "terminated" (gymnasium's, not the step cap) means per id, for the summary line
TERMINATED = {
    "CartPole-v1": "the pole fell or the cart left the track",
    "MountainCar-v0": "reached the flag",
    "Acrobot-v1": "swung the tip above the line",
}
