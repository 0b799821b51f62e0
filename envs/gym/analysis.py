"""What the analysis says about gymnasium envs: curves of the return; thresholds per id."""
from trl_dgpq.analysis import Threshold

THRESHOLDS = {
    "CartPole-v1": Threshold("return", ">=", 195, 10, "mean return >= 195 over 10 episodes"),
    "MountainCar-v0": Threshold("terminated", ">=", 1, 1, "an episode reaches the flag"),
    "Acrobot-v1": Threshold("return", ">=", -100, 10, "mean return >= -100 over 10 episodes"),
}
