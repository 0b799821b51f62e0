"""What the analysis says about the F-16: the episode's reward. GWH14's Figure 3 goes from
about −525 to about −47 (L_Q = 5, episodes 100–200) and −113 (L_Q = 10, 900–1,000); the
references here are the quantised LQR (−136 on seeds 100–107) and PD (−139). A stable
flight: an episode's reward within 10% of PD's, −153 or better."""
from trl_dgpq.analysis import Threshold

MEASURE = ("return", "episode reward")
THRESHOLD = Threshold("return", ">=", -153, 10, "mean episode reward >= -153 (PD's -139 minus 10%) over 10 "
                                                  "episodes")
