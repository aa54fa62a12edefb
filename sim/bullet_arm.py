"""Arms simulated in PyBullet behind the robot-facing `sim.arm.ArmDriver` interface.

A simulated arm follows its gripper target with joint position control; the target moves in the table plane
at its arm's fixed height (`gripper_height_m`) and inverse kinematics turn it into joint targets.
`move_target` advances the simulation by one control period (16 physics steps of 1/240 s): the time a real
arm gets to follow one command before the next frame is taken.
"""

from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import pybullet as p
from pybullet_utils.bullet_client import BulletClient

from sim.arm import GRIPPER_HEIGHT_M, WORKSPACE_X_M, WORKSPACE_Y_M, clip_to_workspace
from sim.lowpoly import lowpoly_model

PHYSICS_DT_S = 1.0 / 240.0
PHYSICS_STEPS_PER_COMMAND = 16
HOME_XY_M = (float(np.mean(WORKSPACE_X_M)), float(np.mean(WORKSPACE_Y_M)))
TELEPORT_IK_ITERATIONS = 8
VISUAL_DETAILS = ("fast", "full")
FAST_VISUAL_CELL_M = 0.01  # about 2/3 of a pixel at the arm: see sim/lowpoly.py and bench/env_speed.py


def configure_physics(client: BulletClient) -> None:
    """One `stepSimulation` call = one control period of 16 physics steps of 1/240 s (as the reference)."""
    client.setGravity(0, 0, -9.8)
    client.setPhysicsEngineParameter(
        fixedTimeStep=PHYSICS_DT_S * PHYSICS_STEPS_PER_COMMAND,
        numSubSteps=PHYSICS_STEPS_PER_COMMAND,
        numSolverIterations=30,
        deterministicOverlappingPairs=1,
    )


class BulletArm(ABC):
    """Common behaviour of the simulated arms; subclasses say which robot and how to solve its kinematics."""

    gripper_link: int
    arm_joints: Sequence[int]
    rest_pose: Sequence[float]
    ray_start_below_gripper_m: (
        float  # so that the "what is under the gripper" ray starts below the gripper itself
    )
    motor_force: float
    position_gain: float
    velocity_gain: float
    gripper_height_m: float = GRIPPER_HEIGHT_M  # where the gripper link moves in the table plane

    def __init__(
        self,
        client: BulletClient,
        camera: Callable[[], np.ndarray] | None = None,
        visual_detail: str = "fast",
    ) -> None:
        if visual_detail not in VISUAL_DETAILS:
            raise ValueError(f"visual_detail must be one of {VISUAL_DETAILS}, got {visual_detail!r}")
        self.client = client
        self._camera = camera
        self.visual_detail = visual_detail
        self.body = self._load()
        self._target = np.array(HOME_XY_M)
        self.reset_to(*HOME_XY_M)

    def model_file(self, original: Path) -> Path:
        """The robot description to load: the original, or its copy with simplified visual meshes."""
        return original if self.visual_detail == "full" else lowpoly_model(original, FAST_VISUAL_CELL_M)

    @abstractmethod
    def _load(self) -> int:
        """Load the robot into `self.client`, fixed at its base pose; return its body id."""

    @abstractmethod
    def _solve_ik(self, position: Sequence[float]) -> Sequence[float]:
        """Joint positions for `arm_joints` that put the gripper at `position`, pointing down."""

    @abstractmethod
    def _hold_other_joints(self) -> None:
        """Put and keep the joints outside `arm_joints` (fingers, if any) at rest."""

    # --- ArmDriver -------------------------------------------------------------------------------------
    def home(self) -> None:
        self.reset_to(*HOME_XY_M)

    def move_target(self, dx: float, dy: float) -> tuple[float, float]:
        if not (np.isfinite(dx) and np.isfinite(dy)):
            raise ValueError(f"move_target needs finite offsets in metres, got ({dx}, {dy})")
        self._target = np.array(clip_to_workspace(self._target[0] + dx, self._target[1] + dy))
        self._drive_joints(self._solve_ik(self._target_position()))
        self.client.stepSimulation()
        return float(self._target[0]), float(self._target[1])

    def gripper_xy(self) -> tuple[float, float]:
        x, y, _ = self.gripper_position()
        return float(x), float(y)

    def grab_frame(self) -> np.ndarray:
        if self._camera is None:
            raise RuntimeError(
                "this simulated arm was created without a camera; pass camera=... to grab frames"
            )
        return self._camera()

    def stop(self) -> None:
        """Hold the joints where they are now and forget the old target."""
        joints = [self.client.getJointState(self.body, j)[0] for j in self.arm_joints]
        self._drive_joints(joints)
        self._target = np.array(clip_to_workspace(*self.gripper_xy()))

    def close(self) -> None:
        self.stop()

    # --- simulation only -------------------------------------------------------------------------------
    @property
    def target_xy(self) -> tuple[float, float]:
        return float(self._target[0]), float(self._target[1])

    def reset_to(self, x: float, y: float) -> None:
        """Put the gripper above (x, y) at once (no motion), at rest, with the target there."""
        self._target = np.array(clip_to_workspace(x, y))
        for joint, angle in zip(self.arm_joints, self.rest_pose, strict=True):
            self.client.resetJointState(self.body, joint, angle)
        for _ in range(TELEPORT_IK_ITERATIONS):  # IK starts from the current pose: iterate to converge
            joints = self._solve_ik(self._target_position())
            for joint, angle in zip(self.arm_joints, joints, strict=True):
                self.client.resetJointState(self.body, joint, angle)
        self._drive_joints(joints)
        self._hold_other_joints()

    def gripper_position(self) -> np.ndarray:
        state = self.client.getLinkState(self.body, self.gripper_link, computeForwardKinematics=True)
        return np.asarray(state[4], dtype=np.float64)

    def body_under_gripper(self, down_to_z: float) -> int:
        """The body id the vertical ray below the gripper hits first, -1 for none."""
        x, y, z = self.gripper_position()
        start = (x, y, z - self.ray_start_below_gripper_m)
        return int(self.client.rayTest(start, (x, y, down_to_z))[0][0])

    def _target_position(self) -> list[float]:
        return [float(self._target[0]), float(self._target[1]), self.gripper_height_m]

    def _drive_joints(self, positions: Sequence[float]) -> None:
        count = len(self.arm_joints)
        self.client.setJointMotorControlArray(
            self.body,
            list(self.arm_joints),
            p.POSITION_CONTROL,
            targetPositions=list(positions),
            targetVelocities=[0.0] * count,
            forces=[self.motor_force] * count,
            positionGains=[self.position_gain] * count,
            velocityGains=[self.velocity_gain] * count,
        )
