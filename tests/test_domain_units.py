"""envs/domain.py on two made-up domains written by the test: one with every optional part
(``full``), one with none (``bare``), so each default and each hook is checked by hand."""
import sys

import pytest

from trl_dgpq.envs.domain import Domain

FULL = {
    "__init__.py": "",
    "env.py": "class Env:\n    class Config:\n        pass\n",
    "presets.py": "DEFAULT = 'base'\nPRESETS = {'dqn': {'base': {}, 'fast': {'agent': {'lr': 1.0}}}, 'dgpq': {'base': {}}}\n",
    "baselines.py": "class Hold:\n    pass\n",
    "analysis.py": ("MEASURE = ('cost', 'cost per episode')\nOTHER_MEASURES = {'quiet_cost': 'cost without noise'}\n"
                    "MEASURE_FORMAT = '{:.2f}'\nMEASURE_LOWER_IS_BETTER = 1\nAGENT_SIDE_SETTINGS = ['grid']\n"
                    "MODEL_KNOWLEDGE = {'env.reward=impact': 'the impact model', 'agent.phi=3': 'a potential'}\n"
                    "THRESHOLD = 'a threshold'\nTERMINATED = 'sold out'\n"),
}
BARE = {"__init__.py": "", "presets.py": "DEFAULT = 'only'\nPRESETS = {}\n"}


@pytest.fixture
def made(tmp_path, monkeypatch):
    for package, files in (("dom_full", FULL), ("dom_bare", BARE)):
        (tmp_path / "madeup" / package).mkdir(parents=True)
        for name, text in files.items():
            (tmp_path / "madeup" / package / name).write_text(text)
    (tmp_path / "madeup" / "__init__.py").write_text("")
    monkeypatch.syspath_prepend(str(tmp_path))
    yield Domain("madeup.dom_full", baselines={"hold": "baselines:Hold"}, example={"x": 1}), Domain("madeup.dom_bare")
    for name in [m for m in sys.modules if m.startswith("madeup")]:
        del sys.modules[name]


def test_a_domain_is_named_by_its_packages_last_part_and_keeps_what_it_is_given(made):
    full, bare = made
    assert (full.package, full.name, full.example) == ("madeup.dom_full", "dom_full", {"x": 1})
    assert full.baseline_paths == {"hold": "baselines:Hold"} and bare.baseline_paths == {} and bare.example is None
    assert Domain("a.b.c.deep").name == "deep" and Domain("flat").name == "flat"
    given = {"hold": "baselines:Hold"}
    assert Domain("x", baselines=given).baseline_paths is not given                     # a copy


def test_its_parts_come_from_its_modules(made):
    full, bare = made
    assert full.env_class().__name__ == "Env" and full.config_class().__name__ == "Config"
    assert full.baseline("hold").__name__ == "Hold" and full.baseline("hold").__module__ == "madeup.dom_full.baselines"
    assert full.presets("dqn") == {"base": {}, "fast": {"agent": {"lr": 1.0}}} and full.presets("td3") is None
    assert full.default_preset() == "base" and bare.default_preset() == "only"
    assert list(full.preset_tables()) == [("dom_full", "dqn", {"base": {}, "fast": {"agent": {"lr": 1.0}}}),
                                          ("dom_full", "dgpq", {"base": {}})]
    assert full.examples() == ("dom_full",)
    assert full.analysis().__name__ == "madeup.dom_full.analysis" and bare.analysis() is None
    with pytest.raises(ModuleNotFoundError):
        bare.module("analysis")                                     # optional only when asked
    with pytest.raises(ModuleNotFoundError):
        bare.env_class()


def test_the_analysis_hooks_and_their_defaults(made):
    full, bare = made
    assert full.measure() == ("cost", "cost per episode") and full.measure(None, "cost") == ("cost", "cost per episode")
    assert full.measure(None, "quiet_cost") == ("quiet_cost", "cost without noise")
    with pytest.raises(ValueError) as err:
        full.measure(None, "return")
    assert str(err.value) == "dom_full has no measure 'return': its measures are cost, quiet_cost"
    assert bare.measure() == ("return", "return per episode")
    with pytest.raises(ValueError) as err:
        bare.measure(None, "cost")
    assert str(err.value) == "dom_bare has no measure 'cost': its measures are return"
    assert full.format_measure(1.23456) == "1.23" and bare.format_measure(1.23456) == "1.235"
    assert bare.format_measure(123456.0) == "1.235e+05"
    assert full.lower_is_better() is True and bare.lower_is_better() is False
    assert full.agent_side_settings() == ("grid",) and bare.agent_side_settings() == ()
    assert full.threshold() == "a threshold" and bare.threshold() is None
    assert full.terminated_means() == "sold out" and bare.terminated_means() == "ended by the env, not the step cap"


def test_model_knowledge_names_each_entry_a_config_matches(made):
    full, bare = made
    config = {"run": {}, "env": {"reward": "impact"}, "agent": {"phi": 3}}
    assert full.model_knowledge(config) == ["the impact model", "a potential"]
    assert full.model_knowledge({"env": {"reward": "shortfall"}, "agent": {"phi": 3.5}}) == []
    assert full.model_knowledge({"agent": {"phi": 3}}) == ["a potential"]            # a section missing
    assert bare.model_knowledge(config) == []


def test_an_id_is_refused_where_none_is_taken_and_required_where_one_is(made):
    full, _ = made
    full.check_id(None)
    with pytest.raises(ValueError) as err:
        full.check_id("v1")
    assert str(err.value) == "unknown env 'dom_full:v1': dom_full takes no id"

    class Family(Domain):
        takes_id = True
    family = Family("madeup.dom_bare")
    family.check_id("v1")
    for missing in (None, ""):
        with pytest.raises(ValueError) as err:
            family.check_id(missing)
    assert str(err.value) == "unknown env 'dom_bare:': dom_bare needs an id, dom_bare:ID"
    with pytest.raises(ValueError) as err:
        family.check_id(None)
    assert str(err.value) == "unknown env 'dom_bare': dom_bare needs an id, dom_bare:ID"
