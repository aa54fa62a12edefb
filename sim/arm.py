"""The robot-facing interface shared by the simulated Kinova Gen3 and the real arm (Kortex driver).

A policy trained in simulation drives either one: it moves the gripper target in the table plane at a fixed
height, reads where the gripper is, and sees frames from a fixed camera.
"""

from typing import Protocol

import numpy as np

GRIPPER_HEIGHT_M = 0.22  # the Kuka's gripper link: its fingers end just above the blocks
# The Gen3's tool flange: its 0.18 m tool ends 2 cm above the blocks' tops, so the camera sees the tool touch
# the block it is at. At 0.22 m the tool hovered 11 cm above them and no Kinova policy learnt (README).
GEN3_GRIPPER_HEIGHT_M = 0.113
STEP_M = 0.02
WORKSPACE_X_M = (0.45, 0.75)
WORKSPACE_Y_M = (-0.25, 0.35)


class ArmDriver(Protocol):
    def home(self) -> None:
        """Move to the home pose above the middle of the workspace and wait until it is reached."""

    def move_target(self, dx: float, dy: float) -> tuple[float, float]:
        """Shift the gripper target by (dx, dy) metres at the fixed height, clipped to the workspace.

        Returns the clipped target (x, y) that was commanded.
        """

    def gripper_xy(self) -> tuple[float, float]:
        """Where the gripper is now, in the table frame (metres)."""

    def grab_frame(self) -> np.ndarray:
        """The fixed camera's current view as uint8 RGB (H, W, 3)."""

    def stop(self) -> None:
        """Stop all motion now. Safe to call at any time, also after an error."""

    def close(self) -> None:
        """Stop, then release the connection and the camera."""


def clip_to_workspace(x: float, y: float) -> tuple[float, float]:
    return (
        float(np.clip(x, *WORKSPACE_X_M)),
        float(np.clip(y, *WORKSPACE_Y_M)),
    )
