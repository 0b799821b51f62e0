"""Block pushing on a table in pybullet (seed report 4.3; SPEC 3.3), batched over seeds.

One pybullet client per seed, in DIRECT mode (headless), built from pybullet_data
assets only: ``plane.urdf``, ``table/table.urdf`` (top 1.5 x 1.0 m, surface at
z = 0.625, centred on the origin), ``cube_small.urdf`` as the block (5 cm, 0.1 kg)
and ``cube.urdf`` scaled to 8 cm as the end effector: a kinematic-like pusher held
by a fixed constraint at a constant height, just above the table, and driven by
moving the constraint's target. The world never gains or loses bodies: a reset
restores a snapshot taken after building (``restoreState``), contacts included.

Actions 0..3 move the pusher's target ``step_size`` north / south / east / west
(+y / -y / +x / -x), plus uniform noise in [-noise, noise] on the moved axis from
the seed's own stream, clipped to the workspace (the table plus 0.1 m). Over the
action's ``substeps`` physics steps the target moves in a straight line, so the
pusher sweeps the path and drives the block by contact; ``settle_substeps`` more
with the target still let the pusher catch up and the block stop sliding, so the
observation (positions only) describes a state at rest.

Observation (6, float64): pusher xyz, block xyz (world frame, metres; clipped to
the spec's box); also by key, ``pusher`` and ``block`` (xyz each). Actions are named
(``action_names``: north, south, east, west). Reward: 2 at the goal (block within ``goal_radius`` of ``goal``
on the table), else 2 - |block - goal|_2 with the goal at the block's resting
height. Terminated at the goal (``success``) or when the block leaves the table
top or drops below it (``fell_off``; not a success); truncated at ``max_steps``.
``success``, ``fell_off`` and ``distance`` (block to goal, the final one) go in every
episode's CSV row.

Exact resume: every client's physics (poses, velocities, contact caches) is saved
with ``saveBullet`` and restored with ``restoreState`` into the same world; the
constraint's target is a saved tensor. A run continued from a checkpoint takes
bit-identical steps.
"""
from __future__ import annotations

import math
import os
import sys
import tempfile
from dataclasses import dataclass
from typing import Tuple

import torch
from torchrl.data import Bounded, Categorical, Composite, Unbounded

from trl_dgpq.config import setting

from ..base import SeedBatchedEnv


def _quiet_import():
    """pybullet writes its build time to stderr (fd 2, from C) when imported; not on every run's console."""
    sys.stderr.flush()
    saved, devnull = os.dup(2), os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 2)
    try:
        import pybullet
        import pybullet_data
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)
    return pybullet, pybullet_data


pb = pybullet_data = None  # imported with the first world: importing the domain needs no simulator


def _load_pybullet() -> None:
    global pb, pybullet_data
    if pb is None:
        pb, pybullet_data = _quiet_import()


MOVES = ((0.0, 1.0), (0.0, -1.0), (1.0, 0.0), (-1.0, 0.0))  # N, S, E, W
TABLE_HALF = (0.75, 0.5)     # table.urdf: a 1.5 x 1.0 top ...
TABLE_TOP = 0.625            # ... whose surface is at this height
BLOCK_HALF = 0.025           # cube_small.urdf
PUSHER_HALF = 0.04           # cube.urdf at globalScaling 2 * PUSHER_HALF
BLOCK_Z = TABLE_TOP + BLOCK_HALF
PUSHER_Z = TABLE_TOP + PUSHER_HALF + 0.003   # clear of the table, level with the block's side
ERP = 0.8                   # constraint error reduction per physics step (pybullet: 0.2)
SETTLE_STEPS = 30           # physics steps before the snapshot every episode starts from
WORKSPACE = (TABLE_HALF[0] + 0.1, TABLE_HALF[1] + 0.1)
# Observation box: the pusher stays in the workspace; the block is reported up to 0.5 m
# past the table's edge (it is terminal once off the top) and between the floor and 1 m.
OBS_LOW = (-WORKSPACE[0], -WORKSPACE[1], PUSHER_Z - 0.05, -TABLE_HALF[0] - 0.5, -TABLE_HALF[1] - 0.5, 0.0)
OBS_HIGH = (WORKSPACE[0], WORKSPACE[1], PUSHER_Z + 0.05, TABLE_HALF[0] + 0.5, TABLE_HALF[1] + 0.5, 1.0)


XY = "(-inf, inf)"  # finite coordinates


def _on_table(xy, margin: float = 0.0) -> bool:
    return abs(xy[0]) <= TABLE_HALF[0] - margin and abs(xy[1]) <= TABLE_HALF[1] - margin


@dataclass
class PushConfig:
    """Block pushing in pybullet (SPEC 3.3)."""
    max_steps: int = setting(50, "step cap per episode (truncation, not termination)", within="(0, inf)")
    step_size: float = setting(0.1, "length of a pusher move, metres", within="(0, inf)")
    noise: float = setting(0.01, "uniform noise on the moved axis, in [-noise, noise] metres (< step_size)",
                           within="[0, inf)")
    goal: Tuple[float, ...] = setting((0.55, 0.0), "goal x,y on the table (the far end)", within=XY, length=2)
    goal_radius: float = setting(0.1, "terminated (success) with the block within this distance of the goal",
                                 within="(0, inf)")
    block_start: Tuple[float, ...] = setting((-0.45, 0.0), "block's start x,y", within=XY, length=2)
    pusher_start: Tuple[float, ...] = setting((-0.55, 0.0), "pusher's start x,y (behind the block)", within=XY,
                                              length=2)
    substeps: int = setting(24, "physics steps per action in which the pusher's target moves", within="(0, inf)")
    settle_substeps: int = setting(8, "physics steps after them with the target still, so the pusher "
                                      "reaches it and the block stops: the observation is a state at rest",
                                   within="[0, inf)")
    time_step: float = setting(1.0 / 120.0, "physics time step, seconds (24 x 1/120: 0.2 s, 0.5 m/s a move)",
                               within="(0, inf)")
    solver_iterations: int = setting(20, "Bullet's constraint-solver iterations per physics step",
                                     within="(0, inf)")
    push_force: float = setting(50.0, "largest force of the constraint holding the pusher, newtons",
                                within="(0, inf)")

    def cross_check(self) -> None:
        if self.noise >= self.step_size:
            raise ValueError(f"noise must be in [0, step_size), got {self.noise}")
        for name in ("goal", "block_start"):
            if not _on_table(getattr(self, name), BLOCK_HALF):
                raise ValueError(f"{name} {getattr(self, name)} is not on the table "
                                 f"(|x| <= {TABLE_HALF[0] - BLOCK_HALF}, |y| <= {TABLE_HALF[1] - BLOCK_HALF})")
        if not all(abs(v) <= w for v, w in zip(self.pusher_start, WORKSPACE)):
            raise ValueError(f"pusher_start {self.pusher_start} is outside the workspace |x| <= {WORKSPACE[0]}, "
                             f"|y| <= {WORKSPACE[1]}")
        gap = max(abs(a - b) for a, b in zip(self.pusher_start, self.block_start))
        if gap < PUSHER_HALF + BLOCK_HALF:
            raise ValueError(f"pusher_start {self.pusher_start} overlaps the block at {self.block_start}")
        if math.dist(self.block_start, self.goal) <= self.goal_radius:
            raise ValueError("block_start is already at the goal")


class _World:
    """One seed's pybullet client: the bodies, the pusher's constraint and the
    snapshot every episode starts from."""

    def __init__(self, cfg: PushConfig):
        _load_pybullet()
        self.client = pb.connect(pb.DIRECT)
        if self.client < 0:
            raise RuntimeError("pybullet could not open a DIRECT client")
        try:
            self._build(cfg)
        except BaseException:
            self.close()
            raise

    def _build(self, cfg: PushConfig) -> None:
        c = self.client
        pb.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=c)
        pb.setGravity(0.0, 0.0, -9.81, physicsClientId=c)
        # deterministicOverlappingPairs: contact order independent of memory layout. erp: at
        # pybullet's 0.2 the pusher trails its moving target by ~17 mm and creeps after it for
        # many steps; at 0.8 it keeps within ~1 mm and stops with its target.
        pb.setPhysicsEngineParameter(fixedTimeStep=cfg.time_step, numSolverIterations=cfg.solver_iterations,
                                     deterministicOverlappingPairs=1, erp=ERP, physicsClientId=c)
        pb.loadURDF("plane.urdf", physicsClientId=c)
        pb.loadURDF("table/table.urdf", useFixedBase=True, physicsClientId=c)
        self.block = pb.loadURDF("cube_small.urdf", [*cfg.block_start, BLOCK_Z], physicsClientId=c)
        start = [*cfg.pusher_start, PUSHER_Z]
        self.pusher = pb.loadURDF("cube.urdf", start, globalScaling=2 * PUSHER_HALF, physicsClientId=c)
        self.constraint = pb.createConstraint(self.pusher, -1, -1, -1, pb.JOINT_FIXED, [0, 0, 0], [0, 0, 0],
                                              start, physicsClientId=c)
        self.force, self.start = cfg.push_force, start
        self.hold(start)
        # Let the block settle on the table first: the snapshot then holds the contacts every
        # episode starts with (a snapshot of the unstepped world made the first episode differ).
        for _ in range(SETTLE_STEPS):
            pb.stepSimulation(physicsClientId=c)
        self.snapshot = pb.saveState(physicsClientId=c)

    def hold(self, target) -> None:
        """Set the constraint's target (xyz), where the pusher is held."""
        pb.changeConstraint(self.constraint, target, maxForce=self.force, physicsClientId=self.client)

    def reset(self) -> None:
        pb.restoreState(self.snapshot, physicsClientId=self.client)
        self.hold(self.start)

    def move(self, start, end, substeps: int, settle: int) -> None:
        """Sweep the pusher's target from ``start`` to ``end`` (xyz lists) in ``substeps``
        physics steps, then hold it there for ``settle`` more."""
        c, cid, force = self.client, self.constraint, self.force
        change, step = pb.changeConstraint, pb.stepSimulation
        (x0, y0, z), (x1, y1, _) = start, end
        for k in range(1, substeps + 1):
            f = k / substeps
            change(cid, (x0 + f * (x1 - x0), y0 + f * (y1 - y0), z), maxForce=force, physicsClientId=c)
            step(physicsClientId=c)
        for _ in range(settle):
            step(physicsClientId=c)

    def positions(self):
        c = self.client
        return (*pb.getBasePositionAndOrientation(self.pusher, physicsClientId=c)[0],
                *pb.getBasePositionAndOrientation(self.block, physicsClientId=c)[0])

    def save(self) -> torch.Tensor:
        """The physics state as the bytes of a .bullet file (uint8 tensor)."""
        with tempfile.TemporaryDirectory() as folder:
            path = os.path.join(folder, "state.bullet")
            pb.saveBullet(path, physicsClientId=self.client)
            with open(path, "rb") as f:
                data = f.read()
        if not data:
            raise RuntimeError("pybullet saved an empty state")
        return torch.frombuffer(bytearray(data), dtype=torch.uint8)

    def load(self, data: torch.Tensor, target) -> None:
        with tempfile.TemporaryDirectory() as folder:
            path = os.path.join(folder, "state.bullet")
            with open(path, "wb") as f:
                f.write(data.numpy().tobytes())
            pb.restoreState(fileName=path, physicsClientId=self.client)
        self.hold(target)

    def close(self) -> None:
        if self.client is not None and pb.isConnected(self.client):
            pb.disconnect(self.client)
        self.client = None


class PushEnv(SeedBatchedEnv):
    """TorchRL env, ``batch_size=[len(seeds)]``, one pybullet client per seed;
    observations are float64 ``(S, 6)``. ``close()`` disconnects every client."""

    Config = PushConfig
    action_names = ("north", "south", "east", "west")  # MOVES: +y, -y, +x, -x
    _state_names = ("target",)
    episode_info = ("success", "fell_off", "distance")

    def __init__(self, seeds=(0,), cfg: PushConfig | None = None, device="cpu", **overrides):
        super().__init__(seeds, cfg, device, **overrides)
        cfg = self.cfg
        f64 = dict(dtype=torch.float64, device=self.device)
        self.worlds = []
        try:
            for _ in self.seeds:
                self.worlds.append(_World(cfg))
        except BaseException:           # no client outlives a failed construction
            self.close()
            raise
        self.start = torch.tensor([*cfg.pusher_start, PUSHER_Z], **f64)
        self.target = self.start.repeat(self.num_seeds, 1)          # the constraint's target, (S, 3)
        self.goal = torch.tensor([*cfg.goal, BLOCK_Z], **f64)
        self.moves = torch.tensor(MOVES, **f64)
        self.workspace = torch.tensor(WORKSPACE, **f64)
        self.obs_low, self.obs_high = torch.tensor(OBS_LOW, **f64), torch.tensor(OBS_HIGH, **f64)

    @classmethod
    def _specs(cls, cfg, S, device):
        low = torch.tensor(OBS_LOW, dtype=torch.float64).expand(S, 6)
        high = torch.tensor(OBS_HIGH, dtype=torch.float64).expand(S, 6)
        box = lambda part: Bounded(low[:, part], high[:, part], shape=(S, 3), dtype=torch.float64,  # noqa: E731
                                   device=device)
        flag = Categorical(2, shape=(S,), dtype=torch.bool, device=device)
        observation = Composite(
            observation=Bounded(low, high, shape=(S, 6), dtype=torch.float64, device=device),
            pusher=box(slice(0, 3)), block=box(slice(3, 6)), success=flag.clone(), fell_off=flag.clone(),
            distance=Unbounded(shape=(S,), dtype=torch.float64, device=device), shape=(S,), device=device)
        return (observation, Categorical(len(MOVES), shape=(S,), device=device),
                Unbounded(shape=(S, 1), dtype=torch.float64, device=device))

    def _out(self, obs, **extra):
        return self._td(observation=obs, pusher=obs[:, :3], block=obs[:, 3:], distance=self._distance(obs), **extra)

    def _observe(self) -> torch.Tensor:
        obs = torch.tensor([w.positions() for w in self.worlds], dtype=torch.float64, device=self.device)
        return torch.maximum(torch.minimum(obs, self.obs_high), self.obs_low)

    def _initial(self, mask):
        for i in mask.nonzero()[:, 0].tolist():
            self.worlds[i].reset()
        self.target[mask] = self.start
        false = torch.zeros(self.num_seeds, dtype=torch.bool, device=self.device)
        return self._out(self._observe(), success=false, fell_off=false.clone())

    def _distance(self, obs) -> torch.Tensor:
        return torch.linalg.vector_norm(obs[:, 3:] - self.goal, dim=-1)

    def _transition(self, action):
        cfg = self.cfg
        jitter = (2.0 * self.rng.uniform(1) - 1.0) * cfg.noise            # (S, 1), the seed's own stream
        start = self.target.clone()
        xy = start[:, :2] + self.moves[action] * (cfg.step_size + jitter)
        self.target[:, :2] = torch.maximum(torch.minimum(xy, self.workspace), -self.workspace)
        for world, a, b in zip(self.worlds, start.tolist(), self.target.tolist()):
            world.move(a, b, cfg.substeps, cfg.settle_substeps)
        obs = self._observe()
        block = obs[:, 3:]
        off = ((block[:, 0].abs() > TABLE_HALF[0]) | (block[:, 1].abs() > TABLE_HALF[1])
               | (block[:, 2] < TABLE_TOP))
        out = self._out(obs, success=~off & (torch.linalg.vector_norm(block[:, :2] - self.goal[:2], dim=-1)
                                             <= cfg.goal_radius), fell_off=off)
        success = out.get("success")
        reward = torch.where(success, 2.0, 2.0 - out.get("distance"))
        return out, reward, success | off

    # ------------------------------------------------------------- state
    def state_dict(self, *args, **kwargs) -> dict:
        return {**super().state_dict(), "bullet": [w.save() for w in self.worlds]}

    def load_state_dict(self, state: dict, strict: bool = True) -> None:
        super().load_state_dict(state, strict)
        for world, data, target in zip(self.worlds, state["bullet"], self.target.tolist()):
            world.load(data, target)

    def num_bodies(self) -> list:
        """Bodies in each client's world (constant: resets never add any)."""
        return [pb.getNumBodies(physicsClientId=w.client) for w in self.worlds]

    def close(self, *, raise_if_closed: bool = True) -> None:
        for world in getattr(self, "worlds", ()):
            world.close()
        super().close(raise_if_closed=raise_if_closed)


Env = PushEnv
