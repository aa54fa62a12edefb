"""The real Kinova Gen3 (`kinova-real` robots): snapshot capture from its camera and the household's commands
tried with the active policy (robot-queue tasks), and policy self-improvement on the arm (a run's
policy_improve stage: PPO on the arm's one env, in the worker's process, for the run's `policy_steps`, with
the run's cancel and progress), all over `sim.kinova_real.KinovaRealEnv` and the Kortex driver. None of this
has run against a real arm: it is tested with a Kortex stand-in (tests/sim/kortex_standin.py).

Where a real arm's settings come from:
- the robot's settings (Admin page, `robots.settings`): `arm_ip` (required), `arm_port` (10000),
  `camera` (an OpenCV device index such as 0, or a stream URL; 0 by default), `max_speed_m_s` (0.1, at
  most the driver's ceiling 0.25) and `image_size` of captured views (96);
- the robot worker's environment: `VARBOT_KORTEX_USERNAME` and `VARBOT_KORTEX_PASSWORD` (Kinova's factory
  `admin` / `admin` when unset), so no password is stored in the database.

The worker that serves the robot queue must reach the arm's IP and have the camera plugged in, and Kinova's
`kortex_api` wheel installed (`sim.kortex_driver` says how).
"""

import os
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np

from backend import models
from backend.db import get_session_factory
from backend.deps import get_blob_store
from backend.services.snapshots import create_snapshot
from core.robots import RobotKind, world_of_kind
from sim.arm import ArmDriver
from sim.kinova_real import KinovaRealEnv
from sim.kortex_driver import DEFAULT_SPEED_M_S, KortexArmDriver
from worker.capture import fresh_seed, png

USERNAME_VARIABLE = "VARBOT_KORTEX_USERNAME"
PASSWORD_VARIABLE = "VARBOT_KORTEX_PASSWORD"
CAPTURE_SOURCE = "camera"
CAPTURE_IMAGE_SIZE = 96
WALK_STEPS_PER_VIEW = 8  # random steps of at most one STEP_M per axis between two captured views


class ArmNotConfigured(ValueError):
    """The robot is not a real arm, or its settings do not say where the arm is."""


@dataclass(frozen=True)
class ArmSettings:
    ip: str
    port: int
    camera: int | str
    max_speed_m_s: float
    image_size: int
    username: str
    password: str

    @classmethod
    def of(cls, settings: Mapping[str, Any], environ: Mapping[str, str] = os.environ) -> "ArmSettings":
        if not settings.get("arm_ip"):
            raise ArmNotConfigured(
                "this real arm has no arm_ip in its settings: set the arm's IP address (Admin page)"
            )
        camera = settings.get("camera", 0)
        return cls(
            ip=str(settings["arm_ip"]),
            port=int(settings.get("arm_port", 10000)),
            camera=int(camera) if str(camera).isdigit() else str(camera),
            max_speed_m_s=float(settings.get("max_speed_m_s", DEFAULT_SPEED_M_S)),
            image_size=int(settings.get("image_size") or CAPTURE_IMAGE_SIZE),
            username=environ.get(USERNAME_VARIABLE, "admin"),
            password=environ.get(PASSWORD_VARIABLE, "admin"),
        )


Connect = Callable[[ArmSettings, int], ArmDriver]  # (settings, image size) -> a driver, not yet connected


def kortex_driver(settings: ArmSettings, image_size: int, **driver_options: Any) -> KortexArmDriver:
    """The Kortex driver for the arm; `driver_options` reach `KortexArmDriver` (tests: a stand-in's `api`
    and `open_capture`)."""
    return KortexArmDriver(
        settings.ip,
        port=settings.port,
        username=settings.username,
        password=settings.password,
        camera=settings.camera,
        image_size=image_size,
        max_speed_m_s=settings.max_speed_m_s,
        **driver_options,
    )


connect_arm: Connect = kortex_driver  # how a run's policy stage reaches the arm (tests: the Kortex stand-in)


def is_real_arm(robot_id: int) -> bool:
    with get_session_factory()() as session:
        robot = session.get(models.Robot, robot_id)
        return robot is not None and robot.kind == RobotKind.KINOVA_REAL


def arm_settings(session: Any, robot_id: int, household_id: int) -> tuple[models.Robot, ArmSettings]:
    robot = session.get(models.Robot, robot_id)
    if robot is None or robot.household_id != household_id:
        raise ArmNotConfigured(f"robot {robot_id} of household {household_id} does not exist")
    if robot.kind != RobotKind.KINOVA_REAL:
        raise ArmNotConfigured(f"robot {robot_id} is a {robot.kind}, not a real arm")
    return robot, ArmSettings.of(robot.settings or {})


def capture_arm_views(
    robot_id: int,
    household_id: int,
    count: int,
    task_id: str | None = None,
    seed: int | None = None,
    connect: Connect = kortex_driver,
) -> dict:
    """`count` views from the arm's camera: the arm homes, then walks at random (the driver's limits on every
    step) and each view is stored as it is taken, so views taken before a failure are kept."""
    blobs = get_blob_store()
    seed = fresh_seed() if seed is None else seed
    rng = np.random.default_rng(seed)
    created = []
    with get_session_factory()() as session:
        robot, settings = arm_settings(session, robot_id, household_id)
        env = KinovaRealEnv(connect(settings, settings.image_size), settings.image_size)
        try:
            observation, _ = env.reset(seed=seed)
            for index in range(count):
                for _ in range(WALK_STEPS_PER_VIEW):
                    observation, *_ = env.step(rng.uniform(-1.0, 1.0, 2).astype(np.float32))
                snapshot = create_snapshot(
                    session,
                    blobs,
                    robot,
                    png(observation["image"]),
                    [float(v) for v in observation["state"]],
                    CAPTURE_SOURCE,
                    meta={"world": world_of_kind(robot.kind), "arm": settings.ip, "seed": seed,
                          "index": index, "task_id": task_id},
                )  # fmt: skip
                created.append(snapshot.id)
        finally:
            env.close()
    return {"robot_id": robot_id, "created": len(created), "snapshot_ids": created}


def try_arm_commands(
    robot_id: int,
    household_id: int,
    attempts: int,
    random_views: int,
    commands: list[str],
    task_id: str | None = None,
    connect: Connect = kortex_driver,
    seed: int | None = None,
) -> dict[str, Any]:
    """`worker.attempts.try_commands` on the arm: each attempt is one episode of the active policy on the
    arm (homed first), its final view a snapshot to judge; then `random_views` views from the camera."""
    from worker.attempts import AttemptRefused, try_commands

    with get_session_factory()() as session:
        try:
            _, settings = arm_settings(session, robot_id, household_id)
        except ArmNotConfigured as refusal:
            raise AttemptRefused(str(refusal)) from refusal

    def make_env(image_size: int, max_steps: int | None) -> KinovaRealEnv:
        return KinovaRealEnv(connect(settings, image_size), image_size, max_steps)

    capture = partial(capture_arm_views, connect=connect)
    return try_commands(
        robot_id, household_id, attempts, random_views, commands, task_id, make_env, capture, seed
    )


@contextmanager
def arm_env_context(context: Any) -> Iterator[str | None]:
    """For a run of a real arm (`worker.run_context.RunContext`): the arm's env registered for PPO
    (`learning.rl.env_groups.in_process_env`), yielding the env_context to train with; None for a simulated
    robot. The env connects and homes the arm at its first reset; the trainer closes it (Stop, then the
    session ends) however the stage ends."""
    if not is_real_arm(context.robot_id):
        yield None
        return
    from learning.rl.env_groups import in_process_env
    from learning.rl.ppo import read_policy_checkpoint

    policy_config = read_policy_checkpoint(context.start_policy)["config"]
    image_size, max_steps = int(policy_config["image_size"]), policy_config.get("max_episode_steps")
    with get_session_factory()() as session:
        _, settings = arm_settings(session, context.robot_id, context.household_id)

    def make_env() -> KinovaRealEnv:
        return KinovaRealEnv(connect_arm(settings, image_size), image_size, max_steps)

    with in_process_env(f"robot-{context.robot_id}", make_env) as env_context:
        yield env_context
