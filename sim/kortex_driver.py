"""The real Kinova Gen3 behind `sim.arm.ArmDriver`, through Kinova's official Python API (`kortex_api`).

Safety first:
- nothing moves at import or construction: `connect()` opens the link, `home()` is the first motion;
- every target is clipped to the workspace box (`sim.arm.clip_to_workspace`) at the fixed gripper height, and
  one `move_target` shifts it by at most `max_step_m` per axis;
- every Cartesian move carries a speed constraint no faster than `max_speed_m_s` (itself capped at
  `SPEED_CEILING_M_S`);
- any error during a move (an exception, an aborted or timed-out action) sends `Stop` before it is re-raised;
  when the router reports a lost link the driver refuses further motion, and the session's short
  `connection_inactivity_timeout` lets the arm's controller drop the session too; `close()` (and leaving a
  `with` block, also through an exception) stops the arm before disconnecting.

`kortex_api` is a wheel Kinova ships from its own artifactory, not from PyPI; it is imported only on
`connect()`. Tests hand the driver a stand-in of the few Kortex classes it uses (`api=`) and of OpenCV's
`VideoCapture` (`open_capture=`): `tests/sim/kortex_standin.py`. Nothing here has run against a real arm.
"""

import collections
import collections.abc
import math
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from types import TracebackType
from typing import Any, Self

import cv2
import numpy as np

from sim.arm import GEN3_GRIPPER_HEIGHT_M, STEP_M, WORKSPACE_X_M, WORKSPACE_Y_M, clip_to_workspace

KORTEX_WHEEL = "kortex_api-2.6.0.post3-py3-none-any.whl"
KORTEX_WHEEL_URL = (
    "https://artifactory.kinovaapps.com/artifactory/generic-public/kortex/API/2.6.0/" + KORTEX_WHEEL
)
SPEED_CEILING_M_S = 0.25  # no configuration may go faster than this
DEFAULT_SPEED_M_S = 0.1
ORIENTATION_SPEED_DEG_S = 30.0
POINT_DOWN_DEG = (
    180.0,
    0.0,
    90.0,
)  # tool orientation (theta_x, theta_y, theta_z): gripper pointing at the table
HOME_XY_M = (sum(WORKSPACE_X_M) / 2, sum(WORKSPACE_Y_M) / 2)
SESSION_INACTIVITY_TIMEOUT_MS = 10_000
CONNECTION_INACTIVITY_TIMEOUT_MS = 2_000
CLOSE_SESSION_TIMEOUT_MS = 1_000


class KortexUnavailableError(ImportError):
    """`kortex_api` is not installed."""


class KortexMotionError(RuntimeError):
    """A move did not finish (aborted by the arm, timed out, or the link is gone). Stop was sent."""


class CameraError(RuntimeError):
    """The fixed camera could not be opened or read."""


@dataclass(frozen=True)
class KortexApi:
    """The parts of `kortex_api` the driver uses (a fake with the same shape stands in for it in tests)."""

    TCPTransport: Any
    RouterClient: Any
    RouterClientSendOptions: Any
    SessionManager: Any
    BaseClient: Any
    Base_pb2: Any
    Session_pb2: Any


def load_kortex_api() -> KortexApi:
    """Import Kinova's `kortex_api` now; fail with install instructions when it is missing."""
    # kortex_api (built for protobuf 3.20) still reaches for aliases Python 3.10 removed from `collections`.
    for name in ("MutableMapping", "MutableSequence", "Mapping", "Sequence"):
        if not hasattr(collections, name):
            setattr(collections, name, getattr(collections.abc, name))
    try:
        from kortex_api.autogen.client_stubs.BaseClientRpc import BaseClient
        from kortex_api.autogen.messages import Base_pb2, Session_pb2
        from kortex_api.RouterClient import RouterClient, RouterClientSendOptions
        from kortex_api.SessionManager import SessionManager
        from kortex_api.TCPTransport import TCPTransport
    except ImportError as error:
        raise KortexUnavailableError(
            "The real Kinova arm needs Kinova's Python API `kortex_api`, which is not installed "
            f"({error}). It is not on PyPI: download the wheel {KORTEX_WHEEL} from Kinova's artifactory "
            f"({KORTEX_WHEEL_URL}), then run `.venv/bin/pip install {KORTEX_WHEEL} 'protobuf==3.20.*'` "
            "(the wheel is built for protobuf 3.20). The simulated arm needs none of this."
        ) from error
    return KortexApi(
        TCPTransport=TCPTransport,
        RouterClient=RouterClient,
        RouterClientSendOptions=RouterClientSendOptions,
        SessionManager=SessionManager,
        BaseClient=BaseClient,
        Base_pb2=Base_pb2,
        Session_pb2=Session_pb2,
    )


def centre_crop_resize(frame_bgr: np.ndarray, image_size: int) -> np.ndarray:
    """The camera frame as the simulated worlds see theirs: centre square crop, resized, RGB uint8."""
    height, width = frame_bgr.shape[:2]
    side = min(height, width)
    top, left = (height - side) // 2, (width - side) // 2
    square = frame_bgr[top : top + side, left : left + side]
    interpolation = cv2.INTER_AREA if side > image_size else cv2.INTER_LINEAR
    resized = cv2.resize(square, (image_size, image_size), interpolation=interpolation)
    return cv2.cvtColor(resized, cv2.COLOR_BGR2RGB)


VideoCaptureFactory = Callable[[int | str], Any]  # cv2.VideoCapture, or what has its isOpened/read/release


class FixedCamera:
    """A camera OpenCV can open (a device index such as 0, or a stream URL / file), opened on demand."""

    def __init__(
        self, source: int | str, image_size: int = 96, open_capture: VideoCaptureFactory = cv2.VideoCapture
    ) -> None:
        if not isinstance(source, int | str) or isinstance(source, bool):
            raise ValueError(f"camera source must be a device index or a stream URL, got {source!r}")
        if not 8 <= image_size <= 1024:
            raise ValueError(f"image_size must be between 8 and 1024 pixels, got {image_size}")
        self.source = source
        self.image_size = image_size
        self._open_capture = open_capture
        self._capture: Any = None

    def open(self) -> None:
        if self._capture is not None:
            return
        capture = self._open_capture(self.source)
        if not capture.isOpened():
            capture.release()
            raise CameraError(
                f"could not open camera {self.source!r}: check the device index (ls /dev/video*) "
                "or that the stream URL plays in a video player"
            )
        self._capture = capture

    def grab(self) -> np.ndarray:
        self.open()
        assert self._capture is not None
        ok, frame = self._capture.read()
        if not ok or frame is None:
            raise CameraError(f"camera {self.source!r} returned no frame (unplugged, or the stream ended?)")
        return centre_crop_resize(frame, self.image_size)

    def release(self) -> None:
        if self._capture is not None:
            self._capture.release()
            self._capture = None


class KortexArmDriver:
    """`sim.arm.ArmDriver` for a real Kinova Gen3: gripper target moves at a fixed height over the table."""

    def __init__(
        self,
        ip: str = "192.168.1.10",
        *,
        port: int = 10000,
        username: str = "admin",
        password: str = "admin",
        camera: int | str = 0,
        image_size: int = 96,
        max_speed_m_s: float = DEFAULT_SPEED_M_S,
        max_step_m: float = STEP_M,
        move_timeout_s: float = 20.0,
        base_in_table_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
        tool_orientation_deg: tuple[float, float, float] = POINT_DOWN_DEG,
        gripper_position: float | None = 1.0,
        api: KortexApi | None = None,
        open_capture: VideoCaptureFactory = cv2.VideoCapture,
    ) -> None:
        if not 0.0 < max_speed_m_s <= SPEED_CEILING_M_S:
            raise ValueError(f"max_speed_m_s must be in (0, {SPEED_CEILING_M_S}] m/s, got {max_speed_m_s}")
        if not 0.0 < max_step_m <= 5 * STEP_M:
            raise ValueError(f"max_step_m must be in (0, {5 * STEP_M}] m, got {max_step_m}")
        if move_timeout_s <= 0:
            raise ValueError(f"move_timeout_s must be positive, got {move_timeout_s}")
        if gripper_position is not None and not 0.0 <= gripper_position <= 1.0:
            raise ValueError(
                f"gripper_position must be in [0, 1] (0 open, 1 closed) or None, got {gripper_position}"
            )
        self.ip, self.port, self._credentials = ip, port, (username, password)
        self.max_speed_m_s = max_speed_m_s
        self.max_step_m = max_step_m
        self.move_timeout_s = move_timeout_s
        self.base_in_table_m = tuple(float(v) for v in base_in_table_m)
        self.tool_orientation_deg = tuple(float(v) for v in tool_orientation_deg)
        self.gripper_position = gripper_position
        self.camera = FixedCamera(camera, image_size, open_capture)
        self._api = api
        self._transport: Any = None
        self._router: Any = None
        self._session: Any = None
        self._base: Any = None
        self._target: tuple[float, float] | None = None
        self._link_lost = threading.Event()

    # ------------------------------------------------------------------ connection

    @property
    def connected(self) -> bool:
        return self._base is not None and not self._link_lost.is_set()

    def connect(self) -> None:
        """Open the TCP link and a session, and the camera. Moves nothing."""
        if self._base is not None:
            return
        api = self._api or load_kortex_api()
        self._api = api
        self._link_lost.clear()
        self._transport = api.TCPTransport()
        self._router = api.RouterClient(self._transport, self._on_router_error)
        try:
            self._transport.connect(self.ip, self.port)
            session_info = api.Session_pb2.CreateSessionInfo()
            session_info.username, session_info.password = self._credentials
            session_info.session_inactivity_timeout = SESSION_INACTIVITY_TIMEOUT_MS
            session_info.connection_inactivity_timeout = CONNECTION_INACTIVITY_TIMEOUT_MS
            self._session = api.SessionManager(self._router)
            self._session.CreateSession(session_info)
            self._base = api.BaseClient(self._router)
            self.camera.open()
        except BaseException:
            self.close()
            raise

    def _on_router_error(self, error: Exception) -> None:
        """Called by the Kortex router (on its own thread) when the link fails: no more motion from here."""
        self._link_lost.set()

    def close(self) -> None:
        """Stop, then end the session, disconnect and release the camera. Safe to call more than once."""
        try:
            if self._base is not None:
                self.stop()
            if self._session is not None and not self._link_lost.is_set():
                options = self._api.RouterClientSendOptions()
                options.timeout_ms = CLOSE_SESSION_TIMEOUT_MS
                with suppress(Exception):  # best effort: a session that never opened cannot be closed
                    self._session.CloseSession(options)
        finally:
            if self._transport is not None:
                self._transport.disconnect()
            self.camera.release()
            self._transport = self._router = self._session = self._base = None
            self._target = None

    def __enter__(self) -> Self:
        self.connect()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, traceback: TracebackType | None
    ) -> None:
        self.close()

    # ------------------------------------------------------------------ ArmDriver

    def stop(self) -> None:
        """Stop all motion now; never raises (it is what runs after an error)."""
        if self._base is None or self._link_lost.is_set():
            return
        try:
            self._base.Stop()
        except Exception:  # stopping must not hide the error that made us stop
            self._link_lost.set()

    def home(self) -> None:
        """Go to the arm's stored "Home" joint pose, then point down above the middle of the workspace."""
        base_pb2 = self._require_connection().Base_pb2
        with self._stop_on_error():
            servo_mode = base_pb2.ServoingModeInformation()
            servo_mode.servoing_mode = base_pb2.SINGLE_LEVEL_SERVOING
            self._base.SetServoingMode(servo_mode)
            self._run(lambda: self._base.ExecuteActionFromReference(self._stored_home_handle()), "Home")
            self._reach(HOME_XY_M)
            if self.gripper_position is not None:
                self._set_gripper(self.gripper_position)
        self._target = HOME_XY_M

    def move_target(self, dx: float, dy: float) -> tuple[float, float]:
        if not (math.isfinite(dx) and math.isfinite(dy)):
            raise ValueError(f"dx and dy must be finite metres, got ({dx}, {dy})")
        self._require_connection()
        if self._target is None:
            raise RuntimeError("call home() before move_target(): the arm's starting pose is unknown")
        step_x = float(np.clip(dx, -self.max_step_m, self.max_step_m))
        step_y = float(np.clip(dy, -self.max_step_m, self.max_step_m))
        target = clip_to_workspace(self._target[0] + step_x, self._target[1] + step_y)
        with self._stop_on_error():
            self._reach(target)
        self._target = target
        return target

    def gripper_xy(self) -> tuple[float, float]:
        self._require_connection()
        with self._stop_on_error():
            pose = self._base.GetMeasuredCartesianPose()
        return pose.x + self.base_in_table_m[0], pose.y + self.base_in_table_m[1]

    def grab_frame(self) -> np.ndarray:
        return self.camera.grab()

    # ------------------------------------------------------------------ moves

    def _require_connection(self) -> KortexApi:
        if self._base is None:
            raise RuntimeError(
                "the arm is not connected: call connect() (or use `with KortexArmDriver(...)`)"
            )
        if self._link_lost.is_set():
            raise KortexMotionError(f"the link to the arm at {self.ip} was lost; reconnect before moving it")
        assert self._api is not None
        return self._api

    @contextmanager
    def _stop_on_error(self) -> Iterator[None]:
        """Send Stop when the block raises (KeyboardInterrupt included), then let the error through."""
        try:
            yield
        except BaseException:
            self.stop()
            raise

    def _stored_home_handle(self) -> Any:
        base_pb2 = self._api.Base_pb2
        requested = base_pb2.RequestedActionType()
        requested.action_type = base_pb2.REACH_JOINT_ANGLES
        for action in self._base.ReadAllActions(requested).action_list:
            if action.name == "Home":
                return action.handle
        raise KortexMotionError("the arm has no stored 'Home' action; create one in Kinova's Web App")

    def _reach(self, table_xy: tuple[float, float]) -> None:
        """One Cartesian pose action to `table_xy` at the gripper height, speed-limited; waits until done."""
        x, y = clip_to_workspace(*table_xy)
        action = self._api.Base_pb2.Action()
        action.name = "varbot reach"
        pose = action.reach_pose.target_pose
        pose.x = x - self.base_in_table_m[0]
        pose.y = y - self.base_in_table_m[1]
        pose.z = GEN3_GRIPPER_HEIGHT_M - self.base_in_table_m[2]
        pose.theta_x, pose.theta_y, pose.theta_z = self.tool_orientation_deg
        speed = action.reach_pose.constraint.speed
        speed.translation = self.max_speed_m_s
        speed.orientation = ORIENTATION_SPEED_DEG_S
        self._run(lambda: self._base.ExecuteAction(action), f"reach ({x:.3f}, {y:.3f})")

    def _set_gripper(self, position: float) -> None:
        base_pb2 = self._api.Base_pb2
        command = base_pb2.GripperCommand()
        command.mode = base_pb2.GRIPPER_POSITION
        finger = command.gripper.finger.add()
        finger.finger_identifier = 1
        finger.value = position
        self._base.SendGripperCommand(command)

    def _run(self, execute: Callable[[], Any], description: str) -> None:
        """Execute an action and wait for the arm's END notification (ABORT or a timeout is an error)."""
        base_pb2 = self._api.Base_pb2
        finished = threading.Event()
        outcome: list[int] = []

        def on_action(notification: Any) -> None:
            if notification.action_event in (base_pb2.ACTION_END, base_pb2.ACTION_ABORT):
                outcome.append(notification.action_event)
                finished.set()

        subscription = self._base.OnNotificationActionTopic(on_action, base_pb2.NotificationOptions())
        try:
            execute()
            if not finished.wait(self.move_timeout_s):
                raise KortexMotionError(
                    f"{description}: the arm did not finish within {self.move_timeout_s} s"
                )
        except Exception as error:
            if self._link_lost.is_set():  # the library's own error says less than this
                raise KortexMotionError(self._lost_during(description)) from error
            raise
        finally:
            if not self._link_lost.is_set():  # nothing gets through a lost link: do not mask the error
                self._base.Unsubscribe(subscription)
        if self._link_lost.is_set():
            raise KortexMotionError(self._lost_during(description))
        if outcome[0] == base_pb2.ACTION_ABORT:
            raise KortexMotionError(
                f"{description}: the arm aborted the move (protection zone, joint limit, e-stop?)"
            )

    def _lost_during(self, description: str) -> str:
        return (
            f"{description}: the link to the arm at {self.ip} was lost during the move (its controller stops "
            f"the arm {CONNECTION_INACTIVITY_TIMEOUT_MS / 1000:g} s after losing the session)"
        )
