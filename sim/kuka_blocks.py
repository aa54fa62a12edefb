"""The reference task: a Kuka iiwa with its two-finger gripper (pybullet_data's `kuka_with_gripper2.sdf`)."""

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pybullet_data

from sim.blocks import BlocksEnv
from sim.bullet_arm import BulletArm

KUKA_SDF = "kuka_iiwa/kuka_with_gripper2.sdf"
KUKA_BASE_POSITION_M = (-0.1, 0.0, 0.07)
GRIPPER_DOWN_EULER = (0.0, -np.pi, 0.0)
FINGER_JOINTS_AND_FORCES = ((7, 500.0), (8, 2.0), (11, 2.0), (10, 2.0), (13, 2.0))


class SimulatedKuka(BulletArm):
    """The reference's Kuka: joint 6 is the wrist it positions; gains and forces as in the reference."""

    gripper_link = 6
    arm_joints = tuple(range(7))
    rest_pose = (0.0, 0.4, 0.0, -1.57, 0.0, 1.1, 0.0)
    ray_start_below_gripper_m = 0.2
    motor_force = 500.0
    position_gain = 0.03
    velocity_gain = 1.0

    def _load(self) -> int:
        body = self.client.loadSDF(str(self.model_file(Path(pybullet_data.getDataPath()) / KUKA_SDF)))[0]
        self.client.resetBasePositionAndOrientation(body, list(KUKA_BASE_POSITION_M), [0, 0, 0, 1])
        self._down = self.client.getQuaternionFromEuler(GRIPPER_DOWN_EULER)
        return body

    def _solve_ik(self, position: Sequence[float]) -> Sequence[float]:
        # The reference passes 7-long null-space lists, which PyBullet ignores for this 12-DOF body:
        # what it really runs is plain IK with orientation, so that is what we run.
        solution = self.client.calculateInverseKinematics(
            self.body, self.gripper_link, list(position), self._down
        )
        return solution[: len(self.arm_joints)]

    def _hold_other_joints(self) -> None:
        for joint, force in FINGER_JOINTS_AND_FORCES:
            self.client.resetJointState(self.body, joint, 0.0)
            self.client.setJointMotorControl2(
                self.body, joint, self.client.POSITION_CONTROL, targetPosition=0.0, force=force
            )


class KukaBlocksEnv(BlocksEnv):
    arm_class = SimulatedKuka
