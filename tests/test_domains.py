"""The contract every registered domain keeps, checked on its ``example`` (``envs/domain.py``):
TorchRL's spec check, a rollout, seeds independent of their batch, an exact state round
trip, what EnvInfo promises, and settings outside their declared range refused in one
line. A new domain folder is picked up here with no edit; one without an example fails."""
import math
import subprocess
import sys

import pytest
import torch
from torchrl.envs.utils import check_env_specs

from conftest import through_disk
from trl_dgpq.config import leaves, with_overrides
from trl_dgpq.envs import DOMAINS, domains, env_class

DOMAIN_LIST = domains()


def example_env(domain, seeds):
    name = domain.examples()[0]
    cls = env_class(name)
    return cls(seeds, with_overrides(cls.Config(), domain.example))


def actions(env, seeds, t):
    """A fixed action per (seed, step), whatever else is in the batch: discrete indices cycle,
    continuous actions walk over the box."""
    info = env.info
    s = torch.tensor(seeds)
    if info.action_spec.__class__.__name__ == "Categorical":
        return (s + t) % info.num_actions()
    box = info.action_box()
    low, high = box.space.low[0], box.space.high[0]
    frac = (((s + t) % 5).to(torch.float64) / 4)[:, None]
    return (low + (high - low) * frac).to(box.dtype)


def trajectory(env, seeds, steps, td=None):
    """Observations, rewards and done flags of ``steps`` steps (resetting finished seeds)."""
    td = env.reset() if td is None else td
    out = []
    for t in range(steps):
        td["action"] = actions(env, seeds, t)
        step, td = env.step_and_maybe_reset(td)
        nxt = step["next"]
        out.append((nxt["observation"].clone(), nxt["reward"].clone(), nxt["done"].clone()))
    return out, td


def test_every_domain_has_an_example():
    """The contract needs one per domain: a domain without it is not checked, so it fails here."""
    assert [d.name for d in DOMAIN_LIST] == list(DOMAINS)
    assert all(d.example is not None for d in DOMAIN_LIST), [d.name for d in DOMAIN_LIST if d.example is None]


@pytest.fixture(params=DOMAIN_LIST, ids=lambda d: d.name)
def domain(request):
    if request.param.example is None:
        pytest.fail(f"domain {request.param.name} has no example (Domain(..., example=dict(...)))")
    return request.param


def test_specs_and_a_rollout(domain):
    env = example_env(domain, [0, 1])
    check_env_specs(env, seed=None)
    roll = env.rollout(10, break_when_any_done=False)
    assert roll.batch_size[:1] == torch.Size([2]) and torch.isfinite(roll["next", "reward"]).all()
    env.close()


def test_env_info_describes_the_env_without_building_one(domain):
    """EnvInfo from the class and config equals what the built env says, and every key it
    promises is in the TensorDicts."""
    name = domain.examples()[0]
    cls = env_class(name)
    info = cls.describe(with_overrides(cls.Config(), domain.example))
    env = example_env(domain, [0, 3])
    one = example_env(domain, [3])
    assert info.config == env.cfg and env.info == info
    assert info.observation_spec == one.observation_spec and info.action_spec == one.action_spec
    assert info.observation_dim == env.observation_spec["observation"].shape[-1]
    one.close()
    td = env.reset()
    assert set(info.keys) <= set(td.keys()) and "observation" in td.keys()
    if info.action_names:
        assert len(info.action_names) == info.num_actions()
    env.close()


def test_an_id_is_taken_only_by_a_family(domain):
    from trl_dgpq.envs import domain as lookup
    with pytest.raises(ValueError, match="needs an id" if domain.takes_id else "takes no id"):
        lookup(domain.name if domain.takes_id else f"{domain.name}:x")


def test_a_seed_does_not_depend_on_its_batch(domain):
    alone = example_env(domain, [3])
    batch = example_env(domain, [1, 3, 5])
    a, _ = trajectory(alone, [3], 15)
    b, _ = trajectory(batch, [1, 3, 5], 15)
    for (oa, ra, da), (ob, rb, db) in zip(a, b):
        assert torch.equal(oa[0], ob[1]) and torch.equal(ra[0], rb[1]) and torch.equal(da[0], db[1])
    alone.close()
    batch.close()


def test_state_round_trip_continues_exactly(domain):
    a = example_env(domain, [0, 2])
    _, td = trajectory(a, [0, 2], 7)
    b = example_env(domain, [0, 2])
    b.reset()
    b.load_state_dict(through_disk(a.state_dict()))
    rest_a, _ = trajectory(a, [0, 2], 10, td.clone())
    rest_b, _ = trajectory(b, [0, 2], 10, td.clone())
    for x, y in zip(rest_a, rest_b):
        assert all(torch.equal(u, v) for u, v in zip(x, y))
    a.close()
    b.close()


def outside(leaf):
    """A value just outside the leaf's declared range (None: it declares none)."""
    within = leaf.field.metadata.get("within")
    if within is None:
        return None
    if math.isfinite(within.low):
        bad = within.low - 1 if within.closed_low else within.low
    elif math.isfinite(within.high):
        bad = within.high + 1 if within.closed_high else within.high
    else:
        bad = math.inf
    if isinstance(leaf.default, tuple):
        return (bad,) + tuple(leaf.default[1:]) if leaf.default else None
    return int(bad) if leaf.type is int and math.isfinite(bad) else bad


def test_settings_outside_their_range_are_refused_in_one_line(domain):
    cls = env_class(domain.examples()[0])
    checked = 0
    for leaf in leaves(cls.Config):
        bad = outside(leaf)
        if bad is None:
            continue
        with pytest.raises(ValueError, match=leaf.key) as err:
            with_overrides(cls.Config(), {leaf.key: bad})
        assert "\n" not in str(err.value)
        checked += 1
    assert checked > 0, f"{domain.name}: no setting declares its range"


def test_importing_the_core_imports_no_simulator():
    """DGPQ, the registries and the domains' declarations import neither pybullet nor gymnasium;
    the block-push gymnasium id is registered only when gymnasium imports its module."""
    code = ("import sys, trl_dgpq, trl_dgpq.dgpq, trl_dgpq.agents, trl_dgpq.envs, trl_dgpq.presets\n"
            "from trl_dgpq.envs import domains\n"
            "[d.examples() for d in domains()]\n"
            "print('pybullet' in sys.modules, 'gymnasium' in sys.modules)\n"
            "import gymnasium\n"
            "print('trl_dgpq/BlockPush-v0' in gymnasium.registry)\n"
            "from trl_dgpq.envs.push.env import PushEnv\n"
            "print('pybullet' in sys.modules)\n"
            "env = gymnasium.make('trl_dgpq.envs.push.gym_adapter:trl_dgpq/BlockPush-v0', max_steps=3)\n"
            "print('pybullet' in sys.modules, env.reset(seed=0)[0].shape)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split("\n")[:4] == ["False False", "False", "False", "True (6,)"]


def test_the_worked_examples_corridor_and_constant():
    """The docs' worked examples (docs/domains/corridor.md, docs/architecture.md). Without slip, always "right" takes length - 1 steps, by hand;
    with slip 0.25 a step advances 1 - 2 (0.25) = 0.5 cells on average: about 2 (length - 1).
    The constant agent finds its action by the env's name for it, and refuses what it cannot do."""
    from trl_dgpq.collectors.experiment import resolve_config, run_experiment
    df = run_experiment(resolve_config(env="corridor", agent="constant", length=6, slip=0.0, seeds=[0, 1],
                                       episodes=3), progress=False)
    assert (df.steps == 5).all() and df.terminated.all() and (df["return"] == -4).all()
    df = run_experiment(resolve_config(env="corridor", agent="constant", length=11, slip=0.25, max_steps=200,
                                       seeds=list(range(8)), episodes=10), progress=False)
    assert 16 < df.steps.mean() < 24
    # (the constant agent's refusals: test_random_constant)
