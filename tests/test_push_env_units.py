"""envs/push/env.py's parts by hand, pybullet replaced by a recorder: the settings' refusals at
their boundaries, the table's edges, the quiet import, one seed's world as the calls it makes
(bodies, gravity, engine settings, the pusher's constraint, the snapshot, a sweep of the pusher,
a saved and restored state), and the specs. (The physics itself: test_push.)"""
import gc
import os
import sys

import pytest
import torch

from tests.fake_pybullet import Recorder
from trl_dgpq.envs.push import env as pe
from trl_dgpq.envs.push.env import PushConfig


# ------------------------------------------------------------------ the settings
def test_the_table_is_its_half_sizes_less_a_margin_edges_included():
    assert pe._on_table((0.75, 0.5)) and pe._on_table((-0.75, -0.5)) and pe._on_table((0.0, 0.0))
    assert not pe._on_table((0.7501, 0.0)) and not pe._on_table((0.0, -0.5001))
    assert pe._on_table((0.7, 0.4), 0.05) and pe._on_table((0.65, 0.45), 0.05)
    assert not pe._on_table((0.7001, 0.0), 0.05) and not pe._on_table((0.0, 0.4501), 0.05)


def refused(words, **settings):
    with pytest.raises(ValueError) as err:
        PushConfig(**settings).cross_check()
    assert str(err.value) == words


def test_the_settings_are_refused_at_their_boundaries_in_words():
    base = PushConfig()
    base.cross_check()
    refused(f"noise must be in [0, step_size), got {base.step_size}", noise=base.step_size)
    PushConfig(noise=base.step_size * 0.999).cross_check()
    edge = (0.75 - 0.025, 0.5 - 0.025)
    PushConfig(goal=edge, block_start=(-0.3, 0.0)).cross_check()          # at the margin: on the table
    for name in ("goal", "block_start"):
        for where in ((edge[0] + 0.001, 0.0), (0.0, -edge[1] - 0.001)):
            other = {"goal": (0.5, 0.0), "block_start": (-0.3, 0.0)}
            refused(f"{name} {where} is not on the table (|x| <= {0.75 - 0.025}, |y| <= {0.5 - 0.025})",
                    **{**other, name: where})
    PushConfig(pusher_start=(0.85, -0.6)).cross_check()                  # the workspace's corner
    for where in ((0.851, 0.0), (0.0, 0.601)):
        refused(f"pusher_start {where} is outside the workspace |x| <= 0.85, |y| <= 0.6", pusher_start=where)
    bx, by = base.block_start
    touching = (bx - (0.04 + 0.025), by)
    PushConfig(pusher_start=touching).cross_check()                      # side by side: no overlap
    inside = (bx - 0.064, by + 0.01)
    refused(f"pusher_start {inside} overlaps the block at {base.block_start}", pusher_start=inside)
    gx, gy = base.goal
    refused("block_start is already at the goal", block_start=(gx - base.goal_radius, gy))
    PushConfig(block_start=(gx - base.goal_radius - 0.001, gy), pusher_start=(gx - 0.5, gy)).cross_check()
    refused("block_start is already at the goal", goal=(0.5, 0.0), goal_radius=0.125, block_start=(0.375, 0.0))
    PushConfig(goal=(0.5, 0.0), goal_radius=0.125, block_start=(0.374, 0.0)).cross_check()   # just past the rim


# ------------------------------------------------------------------ the quiet import
def test_the_import_hides_what_pybullet_writes_to_fd_2_and_gives_fd_2_back(tmp_path, monkeypatch, capfd):
    for name in ("pybullet", "pybullet_data"):
        (tmp_path / f"{name}.py").write_text(f"import os\nos.write(2, b'{name} build time\\n')\nNAME = {name!r}\n")
        monkeypatch.setitem(sys.modules, name, None)        # undone last: the real module, or none, comes back
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.syspath_prepend(str(tmp_path))
    gc.collect()
    fds = set(os.listdir("/proc/self/fd"))
    capfd.readouterr()
    pb, data = pe._quiet_import()
    assert (pb.NAME, data.NAME) == ("pybullet", "pybullet_data")
    os.write(2, b"after\n")
    assert capfd.readouterr().err == "after\n"
    gc.collect()
    assert set(os.listdir("/proc/self/fd")) == fds                                 # none left open


def test_pybullet_is_imported_once(monkeypatch):
    calls = []
    monkeypatch.setattr(pe, "_quiet_import", lambda: calls.append(1) or ("PB", "DATA"))
    monkeypatch.setattr(pe, "pb", None)
    monkeypatch.setattr(pe, "pybullet_data", None)
    pe._load_pybullet()
    pe._load_pybullet()
    assert (pe.pb, pe.pybullet_data, calls) == ("PB", "DATA", [1])


# ------------------------------------------------------------------ one world, as the calls it makes
@pytest.fixture
def fake_pb(monkeypatch):
    bodies = iter(range(10, 20))
    pb = Recorder(connect=7, loadURDF=lambda *a, **k: next(bodies), createConstraint=3, saveState=5,
                  isConnected=True, getBasePositionAndOrientation=lambda body, physicsClientId: (
                      (body, 0.5, 0.6), (0, 0, 0, 1)))
    monkeypatch.setattr(pe, "pb", pb)
    monkeypatch.setattr(pe, "pybullet_data", type("D", (), {"getDataPath": staticmethod(lambda: "/data")}))
    return pb


def test_a_world_is_built_as_the_spec_says(fake_pb):
    cfg = PushConfig(push_force=33.0, time_step=0.01, solver_iterations=17)
    world = pe._World(cfg)
    c = dict(physicsClientId=7)
    assert world.client == 7 and fake_pb.named("connect") == [((2,), {})]
    assert fake_pb.named("setAdditionalSearchPath") == [(("/data",), c)]
    assert fake_pb.named("setGravity") == [((0.0, 0.0, -9.81), c)]
    assert fake_pb.named("setPhysicsEngineParameter") == [((), dict(fixedTimeStep=0.01, numSolverIterations=17,
                                                                       deterministicOverlappingPairs=1, erp=0.8, **c))]
    start = [*cfg.pusher_start, pe.PUSHER_Z]
    assert fake_pb.named("loadURDF") == [(("plane.urdf",), c), (("table/table.urdf",), dict(useFixedBase=True, **c)),
                                         (("cube_small.urdf", [*cfg.block_start, pe.BLOCK_Z]), c),
                                         (("cube.urdf", start), dict(globalScaling=0.08, **c))]
    assert (world.block, world.pusher, world.constraint, world.force, world.start) == (12, 13, 3, 33.0, start)
    assert fake_pb.named("createConstraint") == [((13, -1, -1, -1, 4, [0, 0, 0], [0, 0, 0], start), c)]
    assert fake_pb.named("changeConstraint") == [((3, start), dict(maxForce=33.0, **c))]
    assert len(fake_pb.named("stepSimulation")) == pe.SETTLE_STEPS == 30 and world.snapshot == 5
    names = [n for n, _, _ in fake_pb.calls]
    assert names.index("changeConstraint") < names.index("stepSimulation") < names.index("saveState")
    assert world.positions() == (13, 0.5, 0.6, 12, 0.5, 0.6)                        # the pusher's, then the block's


def test_a_world_resets_sweeps_and_closes_by_its_calls(fake_pb):
    world = pe._World(PushConfig(push_force=33.0))
    fake_pb.calls.clear()
    world.reset()
    assert fake_pb.calls == [("restoreState", (5,), dict(physicsClientId=7)),
                             ("changeConstraint", (3, world.start), dict(maxForce=33.0, physicsClientId=7))]
    fake_pb.calls.clear()
    world.move([0.0, 0.0, 0.7], [0.4, -0.2, 0.9], substeps=4, settle=2)
    targets = [a[1] for a, _ in fake_pb.named("changeConstraint")]
    assert [v for t in targets for v in t] == pytest.approx([0.1, -0.05, 0.7, 0.2, -0.1, 0.7, 0.3, -0.15, 0.7,
                                                             0.4, -0.2, 0.7])
    assert all(k == dict(maxForce=33.0, physicsClientId=7) for _, k in fake_pb.named("changeConstraint"))
    assert [n for n, _, _ in fake_pb.calls] == ["changeConstraint", "stepSimulation"] * 4 + ["stepSimulation"] * 2
    world.close()
    assert fake_pb.named("disconnect") == [((7,), {})] and world.client is None
    world.close()                                                                 # once only
    assert len(fake_pb.named("disconnect")) == 1


def test_a_world_that_cannot_connect_or_build_says_so_and_leaves_no_client(fake_pb):
    fake_pb.answers["connect"] = -1
    with pytest.raises(RuntimeError, match="^pybullet could not open a DIRECT client$"):
        pe._World(PushConfig())
    fake_pb.answers["connect"] = 0                                                 # client 0 is a client
    assert pe._World(PushConfig()).client == 0
    fake_pb.answers["setGravity"] = lambda *a, **k: 1 / 0
    fake_pb.calls.clear()
    with pytest.raises(ZeroDivisionError):
        pe._World(PushConfig())
    assert fake_pb.named("disconnect") == [((0,), {})]


def test_a_worlds_state_is_the_bytes_of_a_bullet_file_and_comes_back_from_them(fake_pb):
    world = pe._World(PushConfig(push_force=33.0))
    written = {}

    def save(path, physicsClientId):
        assert os.path.basename(path) == "state.bullet" and physicsClientId == 7
        assert os.path.isabs(path) and os.path.isdir(os.path.dirname(path))          # in a folder of its own
        with open(path, "wb") as f:
            f.write(b"\x01\x02state")
    fake_pb.answers["saveBullet"] = save
    data = world.save()
    assert data.dtype == torch.uint8 and bytes(data.numpy()) == b"\x01\x02state"

    def restore(fileName, physicsClientId):
        with open(fileName, "rb") as f:
            written["bytes"], written["name"] = f.read(), os.path.basename(fileName)
        written["absolute"] = os.path.isabs(fileName)
    fake_pb.answers["restoreState"] = restore
    fake_pb.calls.clear()
    world.load(data, [0.1, 0.2, 0.3])
    assert written == {"bytes": b"\x01\x02state", "name": "state.bullet", "absolute": True}
    assert fake_pb.named("changeConstraint") == [((3, [0.1, 0.2, 0.3]), dict(maxForce=33.0, physicsClientId=7))]
    fake_pb.answers["saveBullet"] = lambda path, physicsClientId: open(path, "wb").close()
    with pytest.raises(RuntimeError, match="^pybullet saved an empty state$"):
        world.save()


# ------------------------------------------------------------------ the specs
def test_the_specs_by_hand():
    obs, action, reward = pe.PushEnv._specs(PushConfig(), 3, "cpu")
    o = obs["observation"]
    assert o.shape == (3, 6) and o.dtype == torch.float64
    assert o.space.low[0].tolist() == list(pe.OBS_LOW) and o.space.high[2].tolist() == list(pe.OBS_HIGH)
    for name, part in (("pusher", slice(0, 3)), ("block", slice(3, 6))):
        box = obs[name]
        assert box.shape == (3, 3) and box.dtype == torch.float64
        assert box.space.low[1].tolist() == list(pe.OBS_LOW[part]) and box.space.high[0].tolist() == list(
            pe.OBS_HIGH[part])
    for name in ("success", "fell_off"):
        assert obs[name].shape == (3,) and obs[name].dtype == torch.bool and obs[name].space.n == 2
    assert obs["distance"].shape == (3,) and obs["distance"].dtype == torch.float64 and obs.shape == (3,)
    assert action.shape == (3,) and action.space.n == 4
    assert reward.shape == (3, 1) and reward.dtype == torch.float64
    assert pe.OBS_LOW == (-0.85, -0.6, pe.PUSHER_Z - 0.05, -1.25, -1.0, 0.0)
    assert pe.OBS_HIGH == (0.85, 0.6, pe.PUSHER_Z + 0.05, 1.25, 1.0, 1.0)
