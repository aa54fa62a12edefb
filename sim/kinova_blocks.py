"""The block task with a Kinova Gen3 (7 DOF; its tool flange is the "gripper").

`SimulatedGen3` implements `sim.arm.ArmDriver`, like the real Kortex driver, so whatever drives one arm
drives the other. A visual-only 0.18 m tool stands in for a gripper, so the camera sees where the arm points.
The arm stands on the table behind the blocks, centred on the workspace, where its reach covers the whole
workspace with the tool pointing down.
"""

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from sim.arm import GEN3_GRIPPER_HEIGHT_M
from sim.blocks import TABLE_TOP_Z_M, BlocksEnv
from sim.bullet_arm import BulletArm

GEN3_DIR = Path(__file__).resolve().parent / "assets" / "kinova_gen3"
GEN3_URDF = GEN3_DIR / "gen3_7dof.urdf"
GEN3_BASE_POSITION_M = (0.2, 0.05, TABLE_TOP_Z_M)
TOOL_DOWN_EULER = (np.pi, 0.0, 0.0)
# Kinova's own "home" posture, the start of every inverse-kinematics solve after a reset.
GEN3_HOME_JOINTS = (0.0, 0.26, 3.14, -2.27, 0.0, 0.96, 1.57)
GEN3_TOOL_LENGTH_M = 0.18  # tool_link's cylinder in gen3_7dof.urdf
GEN3_JOINT_LIMITS = {1: 2.24, 3: 2.57, 5: 2.09}  # the bounded joints (index: ±limit); the others turn freely


class SimulatedGen3(BulletArm):
    gripper_link = 7  # end_effector_link, the tool flange
    arm_joints = tuple(range(7))
    rest_pose = GEN3_HOME_JOINTS
    ray_start_below_gripper_m = GEN3_TOOL_LENGTH_M + 0.01  # below the tool
    gripper_height_m = GEN3_GRIPPER_HEIGHT_M
    motor_force = 200.0
    position_gain = 0.03
    velocity_gain = 1.0

    def _load(self) -> int:
        body = self.client.loadURDF(
            str(self.model_file(GEN3_URDF)), list(GEN3_BASE_POSITION_M), useFixedBase=True
        )
        self._down = self.client.getQuaternionFromEuler(TOOL_DOWN_EULER)
        return body

    def _solve_ik(self, position: Sequence[float]) -> Sequence[float]:
        solution = np.array(
            self.client.calculateInverseKinematics(
                self.body,
                self.gripper_link,
                list(position),
                self._down,
                maxNumIterations=50,
                residualThreshold=1e-5,
            )[: len(self.arm_joints)]
        )
        for joint, limit in GEN3_JOINT_LIMITS.items():
            solution[joint] = np.clip(solution[joint], -limit, limit)
        return solution.tolist()

    def _hold_other_joints(self) -> None:
        """The Gen3 has no gripper: every joint is an arm joint."""


class KinovaBlocksEnv(BlocksEnv):
    arm_class = SimulatedGen3
