"""The block-push oracle (envs/push/baselines.py) by hand, without pybullet: its refusals at their
boundaries, what ``make`` hands it, and each branch of its decision table on made-up positions
(the whole oracle reaching the goal in pybullet is test_push's)."""
from types import SimpleNamespace

import pytest
import torch
from tensordict import TensorDict

from trl_dgpq.envs.push.baselines import CONTACT, OracleConfig, OraclePusher

E, N, W, S = 0, 1, 2, 3          # action indices of this test's own table
NAMES = {"east": E, "north": N, "west": W, "south": S}


def info(step_size=0.05, goal_radius=0.1, goal=(0.3, 0.2)):
    config = SimpleNamespace(step_size=step_size, goal_radius=goal_radius, goal=goal)
    return SimpleNamespace(config=config, action_index=NAMES.__getitem__)


def test_contact_is_the_pushers_and_blocks_half_widths():
    assert CONTACT == pytest.approx(0.04 + 0.025)


def test_the_oracle_needs_moves_that_fit_its_goal_and_its_line():
    """A push moves the block about a move: the goal's box (goal_radius / sqrt 2 each way) must span
    half a move, and 2 align_tol a move; each refusal says what it needs, at its boundary."""
    cfg = OracleConfig()
    assert OraclePusher.resolve_config(cfg, info(step_size=0.05, goal_radius=0.0354)) is cfg
    exact = 2 ** 0.5 * 0.05                                         # its box spans exactly half a move of 0.1
    assert exact / 2 ** 0.5 == 0.1 / 2 and OraclePusher.resolve_config(cfg, info(step_size=0.1, goal_radius=exact))
    with pytest.raises(ValueError, match=r"^oracle pushes in moves of 0\.05: it needs goal_radius >= 0\.0354 "
                                         r"\(step_size / sqrt 2\), got 0\.035$"):
        OraclePusher.resolve_config(cfg, info(step_size=0.05, goal_radius=0.035))
    assert OraclePusher.resolve_config(OracleConfig(align_tol=0.025), info(step_size=0.05)).align_tol == 0.025
    with pytest.raises(ValueError, match=r"^oracle lines up in moves of 0\.05: it needs align_tol >= 0\.025, got "
                                         r"0\.024 \(and align_tol < 0\.065, so step_size <= 0\.13\)$"):
        OraclePusher.resolve_config(OracleConfig(align_tol=0.024), info(step_size=0.05))


def test_make_hands_it_the_goal_in_float64_its_box_and_the_moves_along_each_axis():
    agent = OraclePusher.make(OracleConfig(), info(goal_radius=0.1, goal=(0.3, 0.2)), seeds=[0])
    assert agent.goal.dtype == torch.float64 and agent.goal.tolist() == [0.3, 0.2]
    assert agent.tol == 0.1 / 2 ** 0.5
    assert agent.plus.tolist() == [E, N] and agent.minus.tolist() == [W, S]
    given = OraclePusher(OracleConfig(), torch.tensor([0.3, 0.2]), 0.05, agent.plus, agent.minus)
    assert given.goal.dtype == torch.float64                           # a float32 goal is made float64


def acts(pushers, blocks, goal=(1.0, 0.0), tol=0.05, align_tol=0.055):
    """The oracle's actions for each (pusher, block) position pair, one seed each (float32 in, as the env's)."""
    agent = OraclePusher(OracleConfig(align_tol=align_tol), torch.tensor(goal), tol, torch.tensor([E, N]),
                         torch.tensor([W, S]))
    td = TensorDict({"pusher": torch.tensor([[*p, 0.0] for p in pushers], dtype=torch.float32),
                     "block": torch.tensor([[*b, 0.0] for b in blocks], dtype=torch.float32)},
                    batch_size=[len(pushers)])
    return agent.act(td).tolist()


def test_each_branch_of_the_decision_table():
    """Block at the origin, goal east along x (|to goal x| > tol: x first, sign +). Behind the block
    by contact and lined up: push east; well behind but off the line: slide onto it (south from
    above, north from below); in front and not clear of it: move away across (north, south from
    below); in front and clear beside it: go back west."""
    c = CONTACT
    pushers = [(-c, 0.0), (-c - 0.05, 0.1), (-c - 0.05, -0.1), (0.3, 0.0), (0.3, -0.01), (0.3, c + 0.05)]
    assert acts(pushers, [(0.0, 0.0)] * 6) == [E, S, N, N, S, W]


def test_the_tables_boundaries():
    """Touching within 0.01 of contact (lined up: push), not within it (away across); well behind
    from 0.01 past contact (slide onto the line, here south); lined up within align_tol 0.055; clear
    beside from contact + 0.02 (touching but off the line and not well behind: away across, north);
    pushing on y once x is within tol of the goal; the sign of an exact 0 taken as +."""
    c = CONTACT
    pushers = [(-c + 0.009, 0.0), (-c + 0.011, 0.0),            # touching or not, lined up
               (-c - 0.011, 0.06), (-c - 0.009, 0.06),          # well behind or not, off the line
               (-c, 0.054), (-c, 0.056),                        # lined up or not, touching
               (0.3, c + 0.021), (0.3, c + 0.019)]              # clear beside or not, in front
    assert acts(pushers, [(0.0, 0.0)] * 8) == [E, N, S, N, E, N, W, N]
    # y: the goal 0.049 east (within tol 0.05) and 1 south: push south from above
    assert acts([(0.0, c)], [(0.0, 0.0)], goal=(0.049, -1.0)) == [S]
    assert acts([(0.0, c)], [(0.0, 0.0)], goal=(0.051, -1.0)) == [N]       # x still first: away across
    at_tol = float(torch.tensor(0.05))                                     # the goal's float32 0.05 exactly
    assert acts([(0.0, c)], [(0.0, 0.0)], goal=(0.05, -1.0), tol=at_tol) == [S]   # within tol: y
    assert acts([(0.0, -c)], [(0.0, 0.0)], goal=(0.0, 0.0)) == [N]         # to goal 0 on y: sign +, push north


def test_pushing_west_measures_ahead_by_the_goals_side():
    """The goal west of the block: a pusher 0.005 past contact east of it is touching (ahead -0.07),
    off the line (0.06) and not well behind: it moves away across, north; were "ahead" scaled by
    more than the sign, it would read well behind and slide south. A side exactly align_tol off the
    line (a float32 value the config holds exactly) is lined up: push west."""
    c = CONTACT
    assert acts([(c + 0.005, 0.06)], [(0.0, 0.0)], goal=(-1.0, 0.0)) == [N]
    at = float(torch.tensor(0.055))
    assert acts([(c, at)], [(0.0, 0.0)], goal=(-1.0, 0.0), align_tol=at) == [W]
