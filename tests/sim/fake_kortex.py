"""A stand-in for the few `kortex_api` classes `sim.kortex_driver` uses, for tests only.

It behaves like a Gen3 on the other end of the link as far as the driver can tell: messages carry only the
fields the real protobuf messages have (a misspelt field raises AttributeError), actions end with a
notification from another thread, and the arm can be told to fail the next action (raise, abort, or never
finish) or to lose the link. Every message sent is recorded in `FakeArm.sent`, and every rule a real
deployment relies on (session first, poses inside the workspace box at the gripper height, a speed limit on
every move) is checked, with breaches collected in `FakeArm.violations`.
"""

import copy
import threading
from dataclasses import dataclass, field
from functools import partial
from types import SimpleNamespace
from typing import Any, ClassVar

from sim.arm import GRIPPER_HEIGHT_M, WORKSPACE_X_M, WORKSPACE_Y_M
from sim.kortex_driver import KortexApi

SINGLE_LEVEL_SERVOING = 2
REACH_JOINT_ANGLES = 7
ACTION_START, ACTION_END, ACTION_ABORT = 1, 2, 3
GRIPPER_POSITION = 3
HOME_HANDLE = 1042


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
    __slots__ = ("orientation", "translation")


class CartesianTrajectoryConstraint(_Message):
    __slots__ = ("duration", "speed")
    _nested: ClassVar[dict[str, type]] = {"speed": CartesianSpeed}


class ConstrainedPose(_Message):
    __slots__ = ("constraint", "target_pose")
    _nested: ClassVar[dict[str, type]] = {"target_pose": Pose, "constraint": CartesianTrajectoryConstraint}


class Action(_Message):
    __slots__ = ("application_data", "name", "reach_pose")
    _nested: ClassVar[dict[str, type]] = {"reach_pose": ConstrainedPose}


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


class FakeKortexError(Exception):
    """What the fake raises where kortex_api would raise KServerException / KClientException."""


@dataclass
class Sent:
    method: str
    message: Any = None


@dataclass
class FakeArm:
    """The arm's side of the link: its state, the messages it received and the rules they broke."""

    speed_ceiling_m_s: float = 0.25
    pose: list[float] = field(default_factory=lambda: [0.45, 0.0, 0.43])
    sent: list[Sent] = field(default_factory=list)
    violations: list[str] = field(default_factory=list)
    fail_next: str | None = None  # "raise", "abort" or "silent" (never finishes)
    transport_connected: bool = False
    session_open: bool = False
    link_up: bool = True
    _subscribers: dict[int, Any] = field(default_factory=dict)
    _router_error_callback: Any = None

    def api(self) -> KortexApi:
        return KortexApi(
            TCPTransport=partial(FakeTransport, self),
            RouterClient=partial(FakeRouterClient, self),
            RouterClientSendOptions=RouterClientSendOptions,
            SessionManager=partial(FakeSessionManager, self),
            BaseClient=partial(FakeBaseClient, self),
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

    def lose_link(self) -> None:
        """The cable is pulled: the router reports the error, and nothing gets through any more."""
        self.link_up = False
        if self._router_error_callback is not None:
            self._router_error_callback(FakeKortexError("connection lost"))

    # what the clients call
    def receive(self, method: str, message: Any = None, *, needs_session: bool = True) -> None:
        if not self.link_up:
            raise FakeKortexError(f"{method}: not connected")
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
            raise FakeKortexError("ExecuteAction rejected by the arm")
        if failure == "silent":
            return
        if failure is None and action is not None:
            target = action.reach_pose.target_pose
            self.pose = [target.x, target.y, target.z]
        event = ACTION_ABORT if failure == "abort" else ACTION_END
        threading.Thread(target=self._notify, args=(event,), daemon=True).start()

    def _notify(self, event: int) -> None:
        for callback in list(self._subscribers.values()):
            callback(SimpleNamespace(action_event=ACTION_START, handle=None))
            callback(SimpleNamespace(action_event=event, handle=None))

    def _check_reach(self, action: Action) -> None:
        target = action.reach_pose.target_pose
        speed = action.reach_pose.constraint.speed
        if not WORKSPACE_X_M[0] - 1e-9 <= target.x <= WORKSPACE_X_M[1] + 1e-9:
            self.violations.append(f"pose x={target.x} outside the workspace {WORKSPACE_X_M}")
        if not WORKSPACE_Y_M[0] - 1e-9 <= target.y <= WORKSPACE_Y_M[1] + 1e-9:
            self.violations.append(f"pose y={target.y} outside the workspace {WORKSPACE_Y_M}")
        if abs(target.z - GRIPPER_HEIGHT_M) > 1e-9:
            self.violations.append(f"pose z={target.z} is not the gripper height {GRIPPER_HEIGHT_M}")
        if not 0 < speed.translation <= self.speed_ceiling_m_s:
            self.violations.append(
                f"translation speed {speed.translation} outside (0, {self.speed_ceiling_m_s}]"
            )
        if speed.orientation <= 0:
            self.violations.append(f"orientation speed {speed.orientation} is not limited")


class FakeTransport:
    def __init__(self, arm: FakeArm) -> None:
        self.arm = arm

    def connect(self, ip: str, port: int) -> None:
        if not self.arm.link_up:
            raise FakeKortexError(f"no arm answers at {ip}:{port}")
        self.arm.transport_connected = True

    def disconnect(self) -> None:
        self.arm.transport_connected = False
        self.arm.session_open = False


class FakeRouterClient:
    def __init__(self, arm: FakeArm, transport: FakeTransport, error_callback: Any) -> None:
        if not isinstance(transport, FakeTransport):
            arm.violations.append("RouterClient built without the transport")
        arm._router_error_callback = error_callback
        self.arm = arm


class FakeSessionManager:
    def __init__(self, arm: FakeArm, router: FakeRouterClient) -> None:
        self.arm = arm

    def CreateSession(self, info: CreateSessionInfo) -> None:
        self.arm.receive("CreateSession", info, needs_session=False)
        if not info.username or info.connection_inactivity_timeout <= 0:
            self.arm.violations.append("session without credentials or connection timeout")
        self.arm.session_open = True

    def CloseSession(self, options: RouterClientSendOptions) -> None:
        self.arm.receive("CloseSession", options)
        self.arm.session_open = False


class FakeBaseClient:
    def __init__(self, arm: FakeArm, router: FakeRouterClient) -> None:
        self.arm = arm
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

    def GetMeasuredCartesianPose(self) -> Pose:
        self.arm.receive("GetMeasuredCartesianPose")
        pose = Pose()
        pose.x, pose.y, pose.z = self.arm.pose
        return pose

    def SendGripperCommand(self, command: GripperCommand) -> None:
        self.arm.receive("SendGripperCommand", command)
        if command.mode != GRIPPER_POSITION or not all(0 <= f.value <= 1 for f in command.gripper.finger):
            self.arm.violations.append("gripper command outside position mode [0, 1]")
