"""One source of truth: dataclass defaults -> presets (overrides only) -> flags / --set."""
import math
import re
from dataclasses import dataclass
from typing import Optional, Tuple

import pytest

from trl_dgpq.agents import agent_class, agent_names
from trl_dgpq.bounds import box_covering, section5
from trl_dgpq.collectors.experiment import RunConfig, cli_leaves, resolve_config
from trl_dgpq.commands import train
from trl_dgpq.config import check_config, find_leaf, from_dict, leaves, nested, setting, to_dict, with_overrides
from trl_dgpq.dgpq import DGPQConfig
from trl_dgpq.envs import domains, env_class, env_configs
from trl_dgpq.envs.square.env import SquareEnv
from trl_dgpq.presets import default_preset


def cli_config(*argv):
    parser = train.make_parser()
    args = parser.parse_args(list(argv))
    return resolve_config(train.given_settings(args, parser))


def test_no_hand_written_hyperparameter_flags():
    """Every flag of train.py is a generated setting or one of the few process flags."""
    parser = train.make_parser()
    dests = {a.dest for a in parser._actions} - {"help"}
    generated = set(cli_leaves())
    assert dests - generated == set(train.PROCESS_FLAGS)
    every_leaf = {leaf.key for cls in [RunConfig] + env_configs() + [agent_class(a).Config for a in agent_names()]
                  for leaf in leaves(cls)}
    assert every_leaf <= dests
    assert all(leaf.help for leaf in cli_leaves().values())


@pytest.mark.parametrize("argv,path,value", [
    (["--gp", "exact"], ("agent", "gp", "backend"), "exact"), (["--budget", "20"], ("agent", "gp", "budget"), 20),
    (["--novelty-tol", "0.01"], ("agent", "gp", "novelty_tol"), 0.01), (["--gamma", "0.5"], ("agent", "gamma"), 0.5),
    (["--lipschitz", "2"], ("agent", "lipschitz"), 2.0), (["--v-max", "3"], ("agent", "v_max"), 3.0),
    (["--sigma-tol2", "0.2"], ("agent", "sigma_tol2"), 0.2), (["--eps1", "0.01"], ("agent", "eps1"), 0.01),
    (["--noise-var", "0.2"], ("agent", "gp", "noise_var"), 0.2), (["--lengthscale", "0.1"], ("agent", "gp", "lengthscale"), 0.1),
    (["--outputscale", "2"], ("agent", "gp", "outputscale"), 2.0), (["--metric", "l2"], ("agent", "metric"), "l2"),
    (["--gp", "exact", "--kernel", "manifold"], ("agent", "gp", "kernel"), "manifold"),
    (["--kernel-hidden", "16,16"], ("agent", "gp", "kernel_hidden"), [16, 16]),
    (["--no-kernel-skip"], ("agent", "gp", "kernel_skip"), False),
    (["--kernel-train-every", "7"], ("agent", "kernel_train_every"), 7),
    (["--kernel-lr", "0.1"], ("agent", "kernel_lr"), 0.1), (["--max-steps", "50"], ("env", "max_steps"), 50),
    (["--preset", "paper"], ("env", "reward"), "paper"), (["--seeds", "3-5"], ("run", "seeds"), [3, 4, 5]),
    (["--episodes", "7"], ("run", "episodes"), 7), (["--checkpoint-every", "3"], ("run", "checkpoint_every"), 3),
])
def test_todays_flags_keep_working(argv, path, value):
    node = cli_config(*argv)
    for p in path:
        node = node[p]
    assert node == value


def test_flags_and_set_are_the_same_setting():
    a = cli_config("--noise-var", "0.2", "--max-steps", "70")
    assert a == cli_config("--set", "noise_var=0.2", "--set", "max_steps=70")
    assert a == cli_config("--set", "gp.noise_var=0.2", "--set", "env.max_steps=70")
    assert a == cli_config("--set", "agent.gp.noise_var=0.2", "--set", "env.max_steps=70")


def test_defaults_live_in_the_dataclasses():
    cfg = cli_config()
    assert cfg == resolve_config()
    assert cfg["run"] == {**to_dict(RunConfig()), "preset": default_preset("square")}
    assert cfg["env"] == to_dict(SquareEnv.Config())
    assert cfg["agent"] == to_dict(DGPQConfig())   # "shaped" overrides nothing


@pytest.mark.parametrize("domain", domains(), ids=lambda d: d.name)
def test_presets_hold_only_overrides_of_known_settings(domain):
    for env, agent, table in domain.preset_tables():
        assert default_preset(env) in table, (env, agent)
        for name, preset in table.items():
            for section, owner in (("env", env_class(env).Config), ("agent", agent_class(agent, env).Config)):
                for key, value in preset.get(section, {}).items():
                    leaf = find_leaf(owner, key)
                    assert leaf is not None, (env, agent, name, key)
                    assert value != leaf.default, f"{env}/{agent}/{name}: {key}={value!r} is the default"
            resolve_config(env=env, agent=agent, preset=name, seeds=[0])


def test_section5_is_derived_when_eps_or_delta_is_given():
    """eps = 1, delta = 0.9, R_max = 2 on "shaped" (L_Q = 1, gamma = 0.01, 4 actions): eps1 =
    0.33; the unit box under L1 at r = 0.33 needs ceil(1/0.33)^2 = 16 balls."""
    agent = cli_config("--eps", "1", "--delta", "0.9", "--r-max", "2")["agent"]
    assert agent["eps1"] == pytest.approx(0.33)
    assert box_covering([0, 0], [1, 1], "l1")(0.33) == 16
    expect = section5(1.0, 0.9, 0.01, 2.0, 1.0, 4, 0.1, lambda r: 16)[1]
    assert agent["sigma_tol2"] == pytest.approx(expect, rel=1e-12)
    assert cli_config("--eps", "1", "--delta", "0.9", "--r-max", "2", "--eps1", "0.5")["agent"]["eps1"] == 0.5


def test_int_settings_refuse_non_integral_floats():
    for value in (2.5, 1.9999):
        with pytest.raises(ValueError, match="episodes must be an integer"):
            resolve_config(seeds=[0], episodes=value)        # JSON (config.json) gives floats, not text
        with pytest.raises(ValueError, match="qhat_capacity must be an integer"):
            with_overrides(DGPQConfig(), {"qhat_capacity": value})
    assert resolve_config(seeds=[0], episodes=3.0)["run"]["episodes"] == 3   # integral floats are fine


def test_user_overrides_beat_the_preset():
    """Preset "paper" sets gamma=1, lipschitz=9, reward=paper; the user's values must win,
    and the preset's other values stay."""
    cfg = resolve_config(preset="paper", seeds=[0], gamma=0.5, reward="shaped")
    assert cfg["agent"]["gamma"] == 0.5 and cfg["env"]["reward"] == "shaped"
    assert cfg["agent"]["lipschitz"] == 9.0 and cfg["agent"]["v_max"] == 0.0


@dataclass
class Inner:
    """inner"""
    width: Tuple[int, ...] = setting((1, 2), "widths")
    on: bool = setting(True, "switch")


@dataclass
class Outer:
    """outer"""
    rate: float = setting(0.5, "a rate")
    tol: Optional[float] = setting(None, "a tolerance")
    mode: str = setting("a", "a mode", choices=("a", "b"))
    count: int = setting(3, "a count")
    inner: Inner = nested(Inner)


def test_values_are_parsed_against_the_field_types():
    cfg = with_overrides(Outer(), {"rate": "1e-3", "tol": "none", "mode": "b", "count": "4", "width": "3, 4",
                                   "inner.on": "no"})
    assert (cfg.rate, cfg.tol, cfg.mode, cfg.count, cfg.inner.width, cfg.inner.on) == (1e-3, None, "b", 4, (3, 4), False)
    assert from_dict(Outer, to_dict(cfg)) == cfg                          # JSON round trip
    assert with_overrides(Outer(), {"rate": "inf"}).rate == math.inf
    for key, value, words in (("rate", "fast", "rate must be a number"), ("count", "1.5", "count must be an integer"),
                              ("count", True, "count must be an integer"), ("mode", "c", "mode must be one of"),
                              ("inner.on", "maybe", "on must be true or false"), ("width", "1,x", "width must be"),
                              ("nope", 1, "unknown setting 'nope'")):
        with pytest.raises(ValueError, match=words):
            with_overrides(Outer(), {key: value})
    with pytest.raises(ValueError, match="unknown Outer settings"):
        from_dict(Outer, {"rate": 1.0, "speed": 2})


@dataclass
class Declared:
    share: float = setting(0.5, "a share", within="[0, 1]")
    rate: Optional[float] = setting(1.0, "a rate", within="(0, inf)")
    widths: Tuple[int, ...] = setting((4,), "widths", within="[1, inf)", length=(1, 3))
    xy: Tuple[float, ...] = setting((0.0, 0.0), "a point", within="(-inf, inf)", length=2)
    low: float = setting(0.0, "low")
    high: float = setting(1.0, "high")
    inner: Inner = nested(Inner)

    def cross_check(self):
        if self.low >= self.high:
            raise ValueError("need low < high")


@pytest.mark.parametrize("key, value, words", [
    ("share", 1.5, "share must be in [0, 1], got 1.5"), ("share", -0.0001, "share must be in [0, 1]"),
    ("share", math.nan, "share must be in [0, 1], got nan"), ("rate", 0.0, "rate must be > 0, got 0"),
    ("rate", math.inf, "rate must be > 0, got inf"), ("widths", (4, 0), "widths must each be >= 1, got [4, 0]"),
    ("widths", (), "widths needs 1 to 3 values, got []"), ("widths", (1, 2, 3, 4), "widths needs 1 to 3 values"),
    ("xy", (0.0, math.inf), "xy must each be finite"), ("xy", (1.0,), "xy needs 2 values, got [1.0]"),
    ("low", 2.0, "need low < high"),
])
def test_declared_constraints_refuse_values_outside_them_in_one_line(key, value, words):
    """Ranges hold for a number or each item of a tuple, NaN is never inside one, an infinite
    value only where the range is closed there; the class's cross_check runs after them."""
    with pytest.raises(ValueError, match=re.escape(words)) as err:
        with_overrides(Declared(), {key: value})
    assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match=re.escape(words)):
        check_config(Declared(**{key: value}))                    # built directly: the same check
    assert check_config(Declared(rate=None, share=1.0, widths=(1, 2, 3))).share == 1.0   # edges and None pass


def test_constraints_of_nested_configs_and_choices_are_checked():
    @dataclass
    class Leaf:
        n: int = setting(1, "n", within="[1, inf)")
        mode: str = setting("a", "mode", choices=("a", "b"))

    @dataclass
    class Root:
        leaf: Leaf = nested(Leaf)
    with pytest.raises(ValueError, match="n must be >= 1, got 0"):
        check_config(Root(Leaf(n=0)))
    with pytest.raises(ValueError, match="mode must be one of"):
        check_config(Root(Leaf(mode="c")))


@pytest.mark.parametrize("config_class", sorted({cls for cls in [RunConfig] + env_configs()
                                                 + [agent_class(a).Config for a in agent_names()]},
                                                key=lambda c: c.__name__), ids=lambda c: c.__name__)
def test_every_settings_default_meets_its_own_constraints(config_class):
    check_config(config_class())


def test_help_gives_each_configs_default_for_a_shared_flag():
    """--gamma is DGPQ's (0.01) and the neural agents' (0.99); --reward is the square's and liquidation's."""
    text = " ".join(train.make_parser().format_help().split())
    assert "[DGPQ: 0.01; DDPG: 0.99; TD3: 0.99; DQN: 0.99]" in text
    square, liquidation = text.split("--reward REWARD ")[1].split(" --")[0].split("; Liquidation: ")
    assert square.startswith("Square: shaped: 2 - |goal - s|_2 per step") and square.endswith("[shaped] {shaped, paper}")
    assert liquidation.startswith("shortfall: minus each trade's") and liquidation.replace("- ", "-").endswith(
        "[shortfall] {shortfall, impact, utility-ratio}")


def test_an_old_dotted_path_names_the_setting_it_is_now():
    """The kernel-training settings moved from gp to DGPQConfig: --set gp.kernel_lr=... is unknown
    now, and the error says which name to use."""
    with pytest.raises(ValueError, match=re.escape("unknown setting 'gp.kernel_lr'") + ".*did you mean 'kernel_lr'"):
        resolve_config(**{"gp.kernel_lr": 0.1})
    assert resolve_config(kernel_lr=0.1)["agent"]["kernel_lr"] == 0.1


def test_section5_by_hand_away_from_the_degenerate_values():
    """GWH14 Section 5 at eps 0.5, delta 0.2, gamma 0.1, R_max 3, L_Q 2, 3 actions, noise 0.2 and a
    covering of 7 balls (at r = 0.5 x 0.9 / 6 = 0.075): eps1 = 0.15; kappa = 3 x 7 x (9 / (0.81 x
    0.5) + 1) = 487.667; sigma_tol2 = 2 x 0.2 x 0.25 x 0.6561 / (81 ln(6 x 3 x 7 x 488.667 / 0.2))."""
    radii = []
    eps1, tol = section5(0.5, 0.2, 0.1, 3.0, 2.0, 3, 0.2, lambda r: radii.append(r) or 7)
    assert radii == [pytest.approx(0.075)] and eps1 == pytest.approx(0.15)
    kappa = 3 * 7 * (9 / (0.81 * 0.5) + 1)
    assert kappa == pytest.approx(487.6666667)
    assert tol == pytest.approx(2 * 0.2 * 0.25 * 0.6561 / (81 * math.log(6 * 3 * 7 * (1 + kappa) / 0.2)), rel=1e-12)
    assert section5(0.5, 0.2, 0.0, 3.0, 2.0, 1, 0.2, lambda r: 7)[0] == pytest.approx(0.5 / 3)  # gamma 0, 1 action


@pytest.mark.parametrize("args, message", [
    ((0.0, 0.2, 0.1, 3.0, 2.0, 3, 0.2), r"^eps must be > 0, got 0.0$"),
    ((0.5, 0.0, 0.1, 3.0, 2.0, 3, 0.2), r"^delta must be in \(0, 1\), got 0.0$"),
    ((0.5, 1.0, 0.1, 3.0, 2.0, 3, 0.2), r"^delta must be in \(0, 1\), got 1.0$"),
    ((0.5, 1.5, 0.1, 3.0, 2.0, 3, 0.2), r"^delta must be in \(0, 1\), got 1.5$"),
    ((0.5, 0.2, -0.1, 3.0, 2.0, 3, 0.2), r"^Section 5 needs 0 <= gamma < 1 \(got -0.1\); set sigma_tol2 and eps1"),
    ((0.5, 0.2, 0.1, 0.0, 2.0, 3, 0.2), r"^Section 5 needs r_max > 0, lipschitz > 0, noise_var > 0 and >= 1 action$"),
    ((0.5, 0.2, 0.1, 3.0, 0.0, 3, 0.2), r"^Section 5 needs r_max > 0, lipschitz > 0, noise_var > 0 and >= 1 action$"),
    ((0.5, 0.2, 0.1, 3.0, 2.0, 3, 0.0), r"^Section 5 needs r_max > 0, lipschitz > 0, noise_var > 0 and >= 1 action$"),
    ((0.5, 0.2, 0.1, 3.0, 2.0, 0, 0.2), r"^Section 5 needs r_max > 0, lipschitz > 0, noise_var > 0 and >= 1 action$")])
def test_section5_refuses_where_its_formulas_are_undefined(args, message):
    with pytest.raises(ValueError, match=message):
        section5(*args, lambda r: 7)


def test_box_covering_counts_cubes_of_each_width_and_refuses_a_box_that_is_not_finite():
    """[2, 5] x [1, 1] under L1 at r 0.5: cubes of side 2 x 0.5 / 2 = 0.5, ceil(3 / 0.5) = 6 along
    the first side, 1 along the flat one."""
    assert box_covering([2.0, 1.0], [5.0, 1.0], "l1")(0.5) == 6
    for low, high in (([0.0], [math.inf]), ([0.0], [-1.0]), ([], [])):
        with pytest.raises(ValueError, match=r"^the state box must be finite, got low=\[.*\], high=\[.*\]$"):
            box_covering(low, high, "l1")
    with pytest.raises(ValueError, match=r"^metric must be one of \['l1', 'l2', 'linf'\], got 'l3'$"):
        box_covering([0.0], [1.0], "l3")
