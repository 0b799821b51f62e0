"""What the analysis says about the corridor: steps per episode; the optimum expects
(length - 1) / (1 - 2 slip) = 11.25 with the defaults."""
from trl_dgpq.analysis import Threshold

MEASURE = ("steps", "steps per episode")
MEASURE_LOWER_IS_BETTER = True  # the at-budget scores (report: IQM, P(improvement), profiles) are negated
TERMINATED = "reached the goal"
THRESHOLD = Threshold("steps", "<=", 13, 10, "mean steps per episode <= 13 over 10 episodes")
