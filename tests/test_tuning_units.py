"""tuning.py's parts not reached by a study's run: the tuning seeds' refusal, an agent without a
search space or with one naming no setting, and weights' factors drawn log-uniform."""
import optuna
import pytest

from trl_dgpq.agents import agent_class
from trl_dgpq.agents import dqn as dqn_module
from trl_dgpq.tuning import Factors, check_tuning_seeds, search_space


def test_reporting_seeds_as_tuning_seeds_are_refused_with_the_default_range_as_the_example():
    check_tuning_seeds([1000, 1004, 5000])
    with pytest.raises(ValueError) as err:
        check_tuning_seeds([1000, 7])
    assert str(err.value).startswith("tuning seeds [7] are reporting seeds: ")
    assert str(err.value).endswith("; use e.g. 1000-1004")


def test_an_agent_without_a_search_space_or_naming_no_setting_is_refused():
    with pytest.raises(ValueError) as err:
        search_space(agent_class("random"))
    module = agent_class("random").Config.__module__
    assert str(err.value) == (f"{agent_class('random').__name__} has nothing to tune: declare SEARCH_SPACE beside its "
                              f"config in {module}")
    space = dict(dqn_module.SEARCH_SPACE)
    assert search_space(agent_class("dqn")) == space
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(dqn_module, "SEARCH_SPACE", {**space, "nope": space["lr"], "nor": space["lr"]})
        with pytest.raises(ValueError) as err:
            search_space(agent_class("dqn"))
    assert str(err.value) == (f"SEARCH_SPACE of {dqn_module.__name__} names ['nope', 'nor'], not settings of "
                              f"{agent_class('dqn').Config.__name__}")


def test_each_nonzero_weight_gets_its_own_log_uniform_factor():
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    trial = optuna.create_study().ask()
    weights = Factors(0.5, 4.0, (2.0, 0.0, 3.0)).suggest(trial, "w", 0)
    assert sorted(trial.distributions) == ["w_0", "w_2"] and weights[1] == 0.0
    assert all(trial.distributions[k] == optuna.distributions.FloatDistribution(0.5, 4.0, log=True)
               for k in ("w_0", "w_2"))
    assert weights == (2.0 * trial.params["w_0"], 0.0, 3.0 * trial.params["w_2"])
