"""A Kortex **stand-in** for tests: the few `kortex_api` classes `sim.kortex_driver` uses, moving the PyBullet
Gen3 (`sim.kinova_blocks`) instead of a real arm, and an OpenCV `VideoCapture` stand-in returning its rendered
camera. It is not Kinova's software and has never been compared with a real arm.

Names, signatures and message fields follow Kinova's Python API as its public repository shows it
(Kinovarobotics/Kinova-kortex2_Gen3_G3L, `api_python/examples` and `api_python/doc/markdown/references`):
- set-up as `examples/utilities.py`: `TCPTransport()`, `RouterClient(transport, error_callback)`,
  `SessionManager(router).CreateSession(Session_pb2.CreateSessionInfo)` with username, password,
  session_inactivity_timeout, connection_inactivity_timeout; `CloseSession(RouterClientSendOptions)` with
  timeout_ms; `transport.connect(ip, port)` / `disconnect()`;
- `BaseClient(router)` as `102-Movement_high_level/01-move_angular_and_cartesian.py`: SetServoingMode,
  ReadAllActions(RequestedActionType).action_list[i].name / .handle, ExecuteActionFromReference(handle),
  ExecuteAction(Action) with action.reach_pose.target_pose.{x, y, z, theta_x, theta_y, theta_z},
  OnNotificationActionTopic(callback, NotificationOptions) -> handle, Unsubscribe(handle), Stop();
- enum values from the reference pages: ServoingMode SINGLE_LEVEL_SERVOING = 2, ActionType REACH_JOINT_ANGLES
  = 7, ActionEvent ACTION_END = 1 / ACTION_ABORT = 2 / ACTION_START = 4, GripperMode GRIPPER_POSITION = 3;
  ActionNotification's fields (action_event, handle, timestamp, user_handle, abort_details, connection).

Guessed (marked GUESS below): the speed constraint's field names (`constraint.speed.translation` /
`.orientation`, from CartesianSpeed's reference page, not from an example); that `GetMeasuredCartesianPose`
returns a Pose in the base frame (examples read `BaseCyclicClient.RefreshFeedback().base.tool_pose_x`
instead: the driver does not use BaseCyclicClient or twist commands, so neither is stood in for); the
exception classes (`KClientException` for a link that is down, `KServerException` for a refused call: their
messages here are made up); that the router's error callback is called on the router's thread when the link
drops; that the arm's controller stops the arm by itself once `connection_inactivity_timeout` passes without
the client (what the session option is documented for); that the base frame is the table frame (a real arm
needs `base_in_table_m`); and when a reach ends (here: once the simulated gripper is within 0.5 mm of the
target, or after 1 s of simulated time).

As the fake it replaces, it checks the rules a deployment relies on (session first, poses inside the
workspace box at the gripper height, a speed limit on every move): breaches go to `StandInArm.violations`;
every message sent is in `StandInArm.sent`; the next action can be told to fail (raise, abort, never finish);
the link can be lost now or at the n-th move.
"""

import copy
import threading
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any, ClassVar

import cv2
import numpy as np

from sim.arm import GEN3_GRIPPER_HEIGHT_M, WORKSPACE_X_M, WORKSPACE_Y_M
from sim.kinova_blocks import KinovaBlocksEnv
from sim.kortex_driver import KortexApi

SINGLE_LEVEL_SERVOING = 2
REACH_JOINT_ANGLES = 7
ACTION_END, ACTION_ABORT, ACTION_START = 1, 2, 4
GRIPPER_POSITION = 3
HOME_HANDLE = 1042  # GUESS: a real arm's handle is an ActionHandle message; the driver only passes it back
REACHED_WITHIN_M = 5e-4  # a reach ends once the simulated gripper is this close to its target ...
MAX_REACH_PERIODS = 60  # ... or after this many control periods (1 s of simulated time)
WEBCAM_WIDTH_PAD = 1 / 6  # each side: the stand-in's frames are 4:3 like a webcam's, the render in the middle


class _Message:
    """Only the declared fields exist, like a protobuf message; nested messages are created with it."""

    __slots__ = ()
    _nested: ClassVar[dict[str, type]] = {}

    def __init__(self) -> None:
        for name in self.__slots__:
            setattr(self, name, self._nested[name]() if name in self._nested else 0)


class Pose(_Message):
    __slots__ = ("theta_x", "theta_y", "theta_z", "x", "y", "z")


class CartesianSpeed(_Message):
    __slots__ = ("orientation", "translation")  # GUESS: from the reference page, not an example


class CartesianTrajectoryConstraint(_Message):
    __slots__ = ("duration", "speed")
    _nested: ClassVar[dict[str, type]] = {"speed": CartesianSpeed}


class ConstrainedPose(_Message):
    __slots__ = ("constraint", "target_pose")
    _nested: ClassVar[dict[str, type]] = {"target_pose": Pose, "constraint": CartesianTrajectoryConstraint}


class Action(_Message):
    __slots__ = ("application_data", "handle", "name", "reach_pose")
    _nested: ClassVar[dict[str, type]] = {"reach_pose": ConstrainedPose}


class ActionNotification(_Message):
    __slots__ = ("abort_details", "action_event", "connection", "handle", "timestamp", "user_handle")


class Finger(_Message):
    __slots__ = ("finger_identifier", "value")


class RepeatedFinger(list):
    def add(self) -> Finger:
        finger = Finger()
        self.append(finger)
        return finger


class Gripper(_Message):
    __slots__ = ("finger",)
    _nested: ClassVar[dict[str, type]] = {"finger": RepeatedFinger}


class GripperCommand(_Message):
    __slots__ = ("duration", "gripper", "mode")
    _nested: ClassVar[dict[str, type]] = {"gripper": Gripper}


class ServoingModeInformation(_Message):
    __slots__ = ("servoing_mode",)


class RequestedActionType(_Message):
    __slots__ = ("action_type",)


class NotificationOptions(_Message):
    __slots__ = ()


class CreateSessionInfo(_Message):
    __slots__ = ("connection_inactivity_timeout", "password", "session_inactivity_timeout", "username")


class RouterClientSendOptions(_Message):
    __slots__ = ("andForget", "delay_ms", "timeout_ms")


class KClientException(Exception):
    """GUESS: what kortex_api raises when the client side fails (no link)."""


class KServerException(Exception):
    """GUESS: what kortex_api raises when the arm refuses a call."""


@dataclass
class Sent:
    method: str
    message: Any = None


@dataclass
class StandInArm:
    """The arm's side of the link: a simulated Gen3 over the block table, the messages it received and the
    rules they broke."""

    image_size: int = 32
    seed: int = 0  # where the blocks lie (a person laid them out before the session)
    speed_ceiling_m_s: float = 0.25
    sent: list[Sent] = field(default_factory=list)
    violations: list[str] = field(default_factory=list)
    fail_next: str | None = None  # "raise", "abort" or "silent" (never finishes)
    link_up: bool = True
    transport_connected: bool = False
    session_open: bool = False
    connection_inactivity_timeout_ms: int = 0
    stopped_by_controller: bool = False  # the arm stopped itself: the link was down past the session timeout
    moves_until_disconnect: int | None = None  # the link drops at that ExecuteAction (1: the next one)
    _subscribers: dict[int, Any] = field(default_factory=dict)
    _router_error_callback: Any = None

    def __post_init__(self) -> None:
        self.world = KinovaBlocksEnv(image_size=self.image_size)
        self.world.reset(seed=self.seed)
        self.world.arm.home()

    def api(self) -> KortexApi:
        return KortexApi(
            TCPTransport=lambda: TCPTransport(self),
            RouterClient=RouterClient,
            RouterClientSendOptions=RouterClientSendOptions,
            SessionManager=SessionManager,
            BaseClient=BaseClient,
            Base_pb2=SimpleNamespace(
                Action=Action,
                GripperCommand=GripperCommand,
                ServoingModeInformation=ServoingModeInformation,
                RequestedActionType=RequestedActionType,
                NotificationOptions=NotificationOptions,
                SINGLE_LEVEL_SERVOING=SINGLE_LEVEL_SERVOING,
                REACH_JOINT_ANGLES=REACH_JOINT_ANGLES,
                ACTION_START=ACTION_START,
                ACTION_END=ACTION_END,
                ACTION_ABORT=ACTION_ABORT,
                GRIPPER_POSITION=GRIPPER_POSITION,
            ),
            Session_pb2=SimpleNamespace(CreateSessionInfo=CreateSessionInfo),
        )

    def video_capture(self, source: int | str) -> "StandInVideoCapture":
        """What the driver gets for `cv2.VideoCapture(source)`: the simulated camera."""
        return StandInVideoCapture(self, source)

    def close(self) -> None:
        self.world.close()

    # what tests look at
    def methods(self) -> list[str]:
        return [entry.method for entry in self.sent]

    def motions(self) -> list[Sent]:
        return [
            entry for entry in self.sent if entry.method in ("ExecuteAction", "ExecuteActionFromReference")
        ]

    def reach_targets(self) -> list[tuple[float, float, float]]:
        return [
            (
                entry.message.reach_pose.target_pose.x,
                entry.message.reach_pose.target_pose.y,
                entry.message.reach_pose.target_pose.z,
            )
            for entry in self.sent
            if entry.method == "ExecuteAction"
        ]

    def under_gripper(self) -> int | None:
        """The block under the gripper now (the simulator's ground truth: tests only)."""
        return self.world.heard()

    def lose_link(self) -> None:
        """The cable is pulled: the router reports the error, nothing gets through any more, and the arm's
        controller stops the arm once the session's connection inactivity timeout has passed."""
        self.link_up = False
        if self.session_open and self.connection_inactivity_timeout_ms > 0:
            self.world.arm.stop()
            self.stopped_by_controller = True
        if self._router_error_callback is not None:
            self._router_error_callback(KClientException("connection lost"))

    # what the clients call
    def receive(self, method: str, message: Any = None, *, needs_session: bool = True) -> None:
        if not self.link_up:
            raise KClientException(f"{method}: not connected")
        self.sent.append(Sent(method, copy.deepcopy(message)))
        if not self.transport_connected:
            self.violations.append(f"{method} sent before the transport was connected")
        if needs_session and not self.session_open:
            self.violations.append(f"{method} sent outside a session")

    def execute(self, action: Action | None) -> None:
        if action is not None:
            self._check_reach(action)
        failure, self.fail_next = self.fail_next, None
        if failure == "raise":
            raise KServerException("ExecuteAction rejected by the arm")
        if failure == "silent":
            return
        if failure is None:
            self._move(action)
        event = ACTION_ABORT if failure == "abort" else ACTION_END
        threading.Thread(target=self._notify, args=(event,), daemon=True).start()

    def count_down_to_disconnect(self) -> None:
        if self.moves_until_disconnect is None:
            return
        self.moves_until_disconnect -= 1
        if self.moves_until_disconnect <= 0:
            self.moves_until_disconnect = None
            self.lose_link()
            raise KClientException("ExecuteAction: connection lost")

    def _move(self, action: Action | None) -> None:
        """The simulated Gen3 follows the action: "Home" is its stored joint pose, a reach its target."""
        arm = self.world.arm
        if action is None:
            arm.home()
            return
        target = np.array([action.reach_pose.target_pose.x, action.reach_pose.target_pose.y])
        arm.move_target(*(target - arm.target_xy))
        for _ in range(MAX_REACH_PERIODS):
            if np.linalg.norm(np.asarray(arm.gripper_xy()) - target) < REACHED_WITHIN_M:
                return
            arm.move_target(0.0, 0.0)

    def _notify(self, event: int) -> None:
        for callback in list(self._subscribers.values()):
            for kind in (ACTION_START, event):
                notification = ActionNotification()
                notification.action_event = kind
                callback(notification)

    def _check_reach(self, action: Action) -> None:
        target = action.reach_pose.target_pose
        speed = action.reach_pose.constraint.speed
        if not WORKSPACE_X_M[0] - 1e-9 <= target.x <= WORKSPACE_X_M[1] + 1e-9:
            self.violations.append(f"pose x={target.x} outside the workspace {WORKSPACE_X_M}")
        if not WORKSPACE_Y_M[0] - 1e-9 <= target.y <= WORKSPACE_Y_M[1] + 1e-9:
            self.violations.append(f"pose y={target.y} outside the workspace {WORKSPACE_Y_M}")
        if abs(target.z - GEN3_GRIPPER_HEIGHT_M) > 1e-9:
            self.violations.append(f"pose z={target.z} is not the gripper height {GEN3_GRIPPER_HEIGHT_M}")
        if not 0 < speed.translation <= self.speed_ceiling_m_s:
            self.violations.append(
                f"translation speed {speed.translation} outside (0, {self.speed_ceiling_m_s}]"
            )
        if speed.orientation <= 0:
            self.violations.append(f"orientation speed {speed.orientation} is not limited")


class StandInVideoCapture:
    """`cv2.VideoCapture`'s isOpened / read / release over the simulated table camera: BGR frames, 4:3, the
    world's render in the middle (so the driver's centre crop gives back exactly what the simulator sees)."""

    def __init__(self, arm: StandInArm, source: int | str) -> None:
        self.arm, self.source, self.opened = arm, source, True

    def isOpened(self) -> bool:
        return self.opened

    def read(self) -> tuple[bool, np.ndarray | None]:
        if not self.opened:
            return False, None
        render = cv2.cvtColor(self.arm.world.render(), cv2.COLOR_RGB2BGR)
        pad = round(render.shape[1] * WEBCAM_WIDTH_PAD)
        return True, cv2.copyMakeBorder(render, 0, 0, pad, pad, cv2.BORDER_CONSTANT, value=(40, 40, 40))

    def release(self) -> None:
        self.opened = False


class TCPTransport:
    def __init__(self, arm: StandInArm) -> None:
        self.arm = arm

    def connect(self, ip: str, port: int) -> None:
        if not self.arm.link_up:
            raise KClientException(f"no arm answers at {ip}:{port}")
        self.arm.transport_connected = True

    def disconnect(self) -> None:
        self.arm.transport_connected = False
        self.arm.session_open = False


class RouterClient:
    def __init__(self, transport: TCPTransport, error_callback: Any) -> None:
        self.arm = transport.arm
        self.arm._router_error_callback = error_callback


class SessionManager:
    def __init__(self, router: RouterClient) -> None:
        self.arm = router.arm

    def CreateSession(self, info: CreateSessionInfo) -> None:
        self.arm.receive("CreateSession", info, needs_session=False)
        if not info.username or info.connection_inactivity_timeout <= 0:
            self.arm.violations.append("session without credentials or connection timeout")
        self.arm.connection_inactivity_timeout_ms = info.connection_inactivity_timeout
        self.arm.session_open = True

    def CloseSession(self, options: RouterClientSendOptions) -> None:
        self.arm.receive("CloseSession", options)
        self.arm.session_open = False


class BaseClient:
    def __init__(self, router: RouterClient) -> None:
        self.arm = router.arm
        self._next_subscription = 1

    def SetServoingMode(self, mode: ServoingModeInformation) -> None:
        self.arm.receive("SetServoingMode", mode)

    def ReadAllActions(self, requested: RequestedActionType) -> Any:
        self.arm.receive("ReadAllActions", requested)
        home = SimpleNamespace(name="Home", handle=HOME_HANDLE)
        other = SimpleNamespace(name="Retract", handle=7)
        return SimpleNamespace(
            action_list=[other, home] if requested.action_type == REACH_JOINT_ANGLES else []
        )

    def ExecuteActionFromReference(self, handle: Any) -> None:
        self.arm.receive("ExecuteActionFromReference", handle)
        self.arm.execute(None)

    def ExecuteAction(self, action: Action) -> None:
        self.arm.count_down_to_disconnect()
        self.arm.receive("ExecuteAction", action)
        self.arm.execute(action)

    def OnNotificationActionTopic(self, callback: Any, options: NotificationOptions) -> int:
        self.arm.receive("OnNotificationActionTopic", options)
        handle = self._next_subscription
        self._next_subscription += 1
        self.arm._subscribers[handle] = callback
        return handle

    def Unsubscribe(self, handle: int) -> None:
        self.arm.receive("Unsubscribe", handle)
        self.arm._subscribers.pop(handle, None)

    def Stop(self) -> None:
        self.arm.receive("Stop")
        self.arm.world.arm.stop()

    def GetMeasuredCartesianPose(self) -> Pose:
        self.arm.receive("GetMeasuredCartesianPose")
        pose = Pose()
        pose.x, pose.y, pose.z = (float(v) for v in self.arm.world.arm.gripper_position())
        return pose

    def SendGripperCommand(self, command: GripperCommand) -> None:
        self.arm.receive("SendGripperCommand", command)
        if command.mode != GRIPPER_POSITION or not all(0 <= f.value <= 1 for f in command.gripper.finger):
            self.arm.violations.append("gripper command outside position mode [0, 1]")
