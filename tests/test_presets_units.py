"""presets.py's parts by hand: the shared DGPQ pair, names of study presets, tuned.json read and
written, and the lookup's refusals in their words."""
import json

import pytest

from trl_dgpq import presets
from trl_dgpq.envs.gym.presets import RAW


def test_rbf_and_manifold_differ_only_in_the_kernel_and_leave_their_arguments_alone():
    given = dict(gamma=0.9, lipschitz=3.0)
    assert presets.rbf_and_manifold("base", **given) == {
        "base": {"agent": {"gamma": 0.9, "lipschitz": 3.0, "gp": "exact"}},
        "manifold": {"agent": {"gamma": 0.9, "lipschitz": 3.0, "gp": "exact", "kernel": "manifold"}}}
    assert given == dict(gamma=0.9, lipschitz=3.0)
    assert presets.rbf_and_manifold("x") == {"x": {"agent": {"gp": "exact"}},
                                             "manifold": {"agent": {"gp": "exact", "kernel": "manifold"}}}


def test_a_study_preset_is_named_after_its_base():
    assert presets.tuned_name("square", "shaped") == "tuned"          # the square's default preset
    assert presets.tuned_name("square", "noisy") == "noisy-tuned"
    assert presets.tuned_name("gym:CartPole-v1", "default") == "tuned"
    assert presets.default_preset("square") == "shaped" and presets.default_preset("gym:Acrobot-v1") == "default"


@pytest.mark.parametrize("name", ["", "-a", ".a", "_a", "a b", "a/b", "ü"])
def test_a_study_preset_name_is_plain(name):
    with pytest.raises(ValueError) as err:
        presets.check_preset_name("square", "dgpq", name)
    assert str(err.value) == f"a preset name is letters, digits and _ . - (not first), got {name!r}"


def test_a_study_preset_may_not_hide_one_of_its_domain():
    for ok in ("A9", "z", "Tuned-2.b_c", "0"):
        presets.check_preset_name("square", "dgpq", ok)
    with pytest.raises(ValueError) as err:
        presets.check_preset_name("square", "dgpq", "noisy")
    assert str(err.value) == ("'noisy' is a preset of dgpq on square in its domain's presets.py: choose another "
                              "name for the study's")
    presets.check_preset_name("square", "random", "noisy")        # the square's random agent has no "noisy"
    with pytest.raises(ValueError, match="'zoo' is a preset of dqn on gym:CartPole-v1"):
        presets.check_preset_name("gym:CartPole-v1", "dqn", "zoo")
    presets.check_preset_name("gym:Pendulum-v1", "dqn", "zoo")     # an id without presets of its own
    presets.check_preset_name("square", "nobody", "shaped")        # an agent with no presets there


def test_tuned_json_is_written_whole_sorted_and_read_back(tmp_path, monkeypatch):
    path = tmp_path / "tuned.json"
    monkeypatch.setattr(presets, "tuned_file", lambda env: path)
    assert presets.tuned_entries("square") == {}                   # no file yet
    assert presets.write_tuned("square", "dqn", "b", {"agent": {"lr": 0.1}}, {"trial": 2}) == path
    presets.write_tuned("square", "dqn", "a", {"agent": {"lr": 0.2}}, {"trial": 1})
    presets.write_tuned("square:other", "dgpq", "tuned", {"env": {}}, {})
    data = {"square": {"dqn": {"a": {"preset": {"agent": {"lr": 0.2}}, "provenance": {"trial": 1}},
                               "b": {"preset": {"agent": {"lr": 0.1}}, "provenance": {"trial": 2}}}},
            "square:other": {"dgpq": {"tuned": {"preset": {"env": {}}, "provenance": {}}}}}
    assert path.read_text() == json.dumps(data, indent=2, sort_keys=True) + "\n"
    assert [p.name for p in tmp_path.iterdir()] == ["tuned.json"]  # no temporary file left
    assert presets.tuned_entries("square") == data["square"] and presets.tuned_entries("push") == {}
    table = presets.preset_table("square", "dqn")
    assert table["a"] == {"agent": {"lr": 0.2}} and table["b"] == {"agent": {"lr": 0.1}} and "shaped" in table
    assert presets.preset_overrides("square", "dqn", "a") == ("a", {"env": {}, "agent": {"lr": 0.2}})
    path.write_text("[1]")
    with pytest.raises(ValueError) as err:
        presets.tuned_entries("square")
    assert str(err.value).startswith(f"cannot read the tuned presets in {path}: ")
    path.write_text("{")
    with pytest.raises(ValueError, match="^cannot read the tuned presets in "):
        presets.tuned_entries("square")


def test_a_tuned_preset_alone_makes_a_table(tmp_path, monkeypatch):
    monkeypatch.setattr(presets, "tuned_file", lambda env: tmp_path / f"{env}.json")   # each env its file
    assert presets.preset_table("square", "nobody") is None
    assert presets.write_tuned("square", "nobody", "mine", {"agent": {"k": 1}}, {}) == tmp_path / "square.json"
    assert presets.preset_table("square", "nobody") == {"mine": {"agent": {"k": 1}}}


def test_the_lookup_refuses_in_one_line_each(tmp_path, monkeypatch):
    monkeypatch.setattr(presets, "tuned_file", lambda env: tmp_path / "tuned.json")
    refusals = [(("square", "nobody"), "no presets for agent 'nobody' on env 'square': add an entry to its "
                                       "domain's presets.py"),
                (("square", "random", "nope"), "unknown preset 'nope' for random on square; choose from "
                                               "['paper', 'shaped']")]
    for args, message in refusals:
        with pytest.raises(ValueError) as err:
            presets.preset_overrides(*args)
        assert str(err.value) == message
    presets.write_tuned("square", "random", "odd", {"agent": {}, "extra": {}, "also": 1}, {})
    with pytest.raises(ValueError) as err:
        presets.preset_overrides("square", "random", "odd")
    assert str(err.value) == "preset 'odd': sections must be 'env' and 'agent', got ['also', 'extra']"
    assert presets.preset_overrides("square", "random") == ("shaped", {"env": {}, "agent": {}})
    assert presets.preset_overrides("gym:Pendulum-v1", "dqn") == ("default", {"env": RAW, "agent": {}})
    name, sections = presets.preset_overrides("square", "random", "paper")
    sections["env"]["reward"] = "changed"                                  # a copy, not the table's own
    assert presets.preset_overrides("square", "random", "paper")[1]["env"] == {"reward": "paper"}
