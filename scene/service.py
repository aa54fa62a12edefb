"""The scene service: one `viser.ViserServer` on 127.0.0.1, open to the app's proxy only (`scene.access`), and
one simulation loop.

Each tick the robot moves (at random between commands, as in snapshot capture; driven by the active model's
policy while a command is tried, `scene.trial`), the 3D view follows the simulation (`scene.world_view`), the
camera image and the reward are shown in the panel (`scene.panel`) and the current frame's embedding moves on
the sphere (`scene.sphere`). The household's data is re-read in a background thread (`scene.refresh`); what
changed is handed to the loop as requests, so that only the loop touches the simulated world.

While a training run publishes its rollouts and no command is tried, the view follows the run's environment 0
instead (`scene.following`); when its messages stop the robot goes back to looking around on its own.

What the app asks (`scene.inbox`): re-read the household's data at once (a model was activated), show another
of its robots, or carry out what a member just said ("try it now", `scene.voice_try`).
"""

import queue
import threading
import time
from collections import deque
from typing import Any

import numpy as np

from backend import scene_requests
from core.robots import world_of_kind
from scene import endpoint
from scene.access import LOOPBACK, guarded_viser_server, new_secret
from scene.active_model import ActiveModel
from scene.following import RunFollowing
from scene.household import HouseholdView
from scene.inbox import SceneInbox
from scene.legend import SphereLegend
from scene.live import FOLLOW_TIMEOUT_S, LiveRollout
from scene.panel import Panel, status_line
from scene.refresh import HouseholdRefresh
from scene.sphere import SphereData, SphereView, command_title, reward, sphere_for
from scene.trial import CommandTrial, clip_for, closest_command, command_choices, why_not
from scene.voice_try import TryReports, VoiceTrial, VoiceTry, accepted, voice_trial
from scene.world import SimWorld
from scene.world_view import WorldView

DEFAULT_WORLD = "kuka"  # shown while the household has no robot yet


class SceneService:
    def __init__(
        self,
        household_id: int,
        robot_id: int | None = None,
        port: int = 0,
        fps: float = 15.0,
        follow_timeout_s: float = FOLLOW_TIMEOUT_S,
        idle_stop_s: float | None = None,
    ) -> None:
        self.household_id = household_id
        self.idle_stop_s = idle_stop_s  # None: runs until stopped, watched or not
        self.last_watched = time.monotonic()
        self.fps = fps
        self.secret = new_secret()
        self.server = guarded_viser_server(self.secret, port)
        self.server.gui.configure_theme(
            control_width="large", dark_mode=False, show_logo=False, show_share_button=False
        )  # Viser's share button offers a public link; the scene is shown through the app only
        self.stop_event = threading.Event()
        self.requests: queue.Queue[tuple[str, Any]] = queue.Queue()
        self.view = HouseholdView(household_id=household_id, robot=None)
        self.model = ActiveModel()
        self.sphere: SphereData | None = None
        self.world: SimWorld | None = None
        self.trial: CommandTrial | None = None
        self.tick_times: deque[float] = deque(maxlen=60)
        self.frames = 0
        self.run_following = RunFollowing(household_id, follow_timeout_s)
        self.refresh = HouseholdRefresh(
            household_id, robot_id, self.apply, self._refresh_failed, self.stop_event
        )
        self.panel = Panel(
            self.server.gui,
            on_try=lambda title: self.requests.put(("try", title)),
            on_stop=lambda: self.requests.put(("stop", None)),
        )
        self.world_view = WorldView(self.server)
        self.sphere_view = SphereView(self.server.scene)
        self.legend = SphereLegend(self.server.gui, after=self.panel.status)
        self.inbox = SceneInbox(household_id, self._on_request, self.stop_event)
        self.try_reports = TryReports()

    # --- lifetime -------------------------------------------------------------------------------------------
    @property
    def url(self) -> str:
        return f"http://{LOOPBACK}:{self.server.get_port()}"

    @property
    def following(self) -> LiveRollout | None:
        """The training rollout on show; None while the robot looks around on its own."""
        return self.run_following.current

    def run(self) -> None:
        endpoint.announce(self.url, self.household_id, self.secret)
        self.refresh.once()  # first picture before the loop starts
        self.refresh.start()
        self.inbox.start()
        self.run_following.start()
        period = 1.0 / self.fps
        try:
            while not self.stop_event.is_set() and not self._unwatched_for_too_long():
                started = time.monotonic()
                self._tick()
                self.tick_times.append(time.monotonic())
                self.stop_event.wait(max(0.0, period - (time.monotonic() - started)))
        finally:
            self.run_following.stop()
            endpoint.withdraw(self.household_id)
            scene_requests.write_shown_robot(self.household_id, None)  # the next scene starts on the default
            self.server.stop()
            if self.world is not None:
                self.world.close()

    def stop(self) -> None:
        self.stop_event.set()

    def _unwatched_for_too_long(self) -> bool:
        if self.server.get_clients() or self.trial is not None:  # a try from the Record page counts too
            self.last_watched = time.monotonic()
        return self.idle_stop_s is not None and time.monotonic() - self.last_watched > self.idle_stop_s

    @property
    def measured_fps(self) -> float:
        if len(self.tick_times) < 2:
            return 0.0
        return (len(self.tick_times) - 1) / (self.tick_times[-1] - self.tick_times[0])

    def show_status(self) -> None:
        self.panel.status.content = status_line(
            self.view, self.model.has_policy, self.sphere_view.drawn, self.following, self.measured_fps
        )

    # --- household data (refresh thread) --------------------------------------------------------------------
    def apply(self, view: HouseholdView) -> None:
        """Take in freshly read household data: new recordings, another robot or model, new sphere points."""
        self.view = view
        self._tell_shown_robot(view)
        self.panel.offer_clips(command_choices(view))
        self.legend.show(view.commands)
        if self.following is None:  # while following, the run decides the world
            self._ask_for_robot_world(view)
        if self.model.follow(view.model):
            self.sphere = None
            if self.world is not None and self.world.image.shape[0] != self.model.image_size:
                self.requests.put(("world", self.world.world))
        brain = self.model.brain
        if brain is not None and (self.sphere is None or self.sphere.is_stale(self.model.version_id, view)):
            self.sphere = sphere_for(view, brain, self.model.version_id)
            self.requests.put(("sphere", None))
        self.show_status()

    def _tell_shown_robot(self, view: HouseholdView) -> None:
        """The Scene page's robot choice shows which robot this is."""
        scene_requests.write_shown_robot(self.household_id, view.robot.id if view.robot else None)

    def _refresh_failed(self, error: Exception) -> None:
        self.panel.status.content = f"**Could not read the household's data:** {error}"

    def _ask_for_robot_world(self, view: HouseholdView) -> None:
        if view.robot is not None:
            home = world_of_kind(view.robot.kind)
            if self.world is None or self.world.world != home:
                self.requests.put(("world", home))
        elif self.world is None:
            self.requests.put(("world", DEFAULT_WORLD))

    # --- the simulation loop (main thread) ------------------------------------------------------------------
    def _tick(self) -> None:
        self._handle_requests()
        if self.world is None:
            return
        live = self.run_following.newest() if self.trial is None else None  # a command tried comes first
        if live is not None:
            self._follow(live)
        else:
            if self.following is not None:
                self._back_to_own_world()
            self._simulate(self.world)
        self.frames += 1
        if self.frames % int(max(1, self.fps)) == 0:
            self.show_status()

    def _handle_requests(self) -> None:
        while True:
            try:
                kind, value = self.requests.get_nowait()
            except queue.Empty:
                return
            if kind == "world":
                self._build_world(value)
            elif kind == "sphere" and self.world is not None:
                self.sphere_view.draw(self.sphere, self.view)
                self.show_status()  # after the points: a status naming them comes once they are drawn
            elif kind == "try":
                self._start_trial(value)
            elif kind == "voice":
                self._start_voice_trial(value)
            elif kind == "stop":
                self._replace_trial(None)
                self.panel.command_status.content = "Stopped. The robot looks around at random."

    def _build_world(self, name: str) -> None:
        previous, self.world = self.world, SimWorld(name, image_size=self.model.image_size)
        if previous is not None:  # closed only once replaced: readers never see a closed world
            previous.close()
        self.world_view.build(self.world)
        self.sphere_view.place(name)
        self.sphere_view.draw(self.sphere, self.view)

    def _simulate(self, world: SimWorld) -> None:
        if self.trial is not None:
            done = self.trial.step(world)
            if done is not None:
                self.trial = None
                self.panel.command_status.content = done
        else:
            world.explore_step()
        self.world_view.pose_robot(world, self.frames)
        self.panel.camera.image = world.image
        current = self.model.embed(world.image)
        goal = self.trial.goal if self.trial is not None else self._chosen_clip_point()
        self.sphere_view.show_markers(current, goal)
        if current is not None and goal is not None:
            self.panel.show_reward(reward(current, goal))

    def _chosen_clip_point(self) -> np.ndarray | None:
        """Without a command being tried, the reward is shown for the recording chosen in the dropdown."""
        if self.sphere is None:
            return None
        clip = clip_for(self.panel.chosen_clip, self.view)
        return self.sphere.clip_points.get(clip.id) if clip is not None else None

    # --- trying a command -----------------------------------------------------------------------------------
    def _start_trial(self, title: str) -> None:
        refusal = why_not(title, self.view, self.model.brain, self.sphere)
        if refusal is not None:
            self.panel.command_status.content = refusal
            return
        assert self.model.brain is not None and self.sphere is not None
        clip = clip_for(title, self.view)
        assert clip is not None
        goal = self.sphere.clip_points[clip.id]
        self._begin(CommandTrial(command_title(clip.command), goal, self.model.brain, self._closest, clip.id))

    def _closest(self, vector: np.ndarray) -> str | None:
        return closest_command(vector, self.sphere, self.view)

    def _begin(self, trial: CommandTrial) -> None:
        self._back_to_own_world()
        self._replace_trial(trial)
        self.panel.clear_rewards()
        self.panel.command_status.content = trial.started

    def _replace_trial(self, trial: CommandTrial | None) -> None:
        """A live voice's try that is cut short says so on its page."""
        if isinstance(self.trial, VoiceTrial) and self.trial is not trial:
            self.trial.interrupted("Stopped before the end: someone pressed Stop or tried another command.")
        self.trial = trial

    # --- "try it now" with a live voice -------------------------------------------------------------------
    def _on_request(self, request: dict[str, Any]) -> None:
        """What the app asks (the inbox's thread): re-read now, show another robot, or try a live voice."""
        kind = request.get("type")
        if kind == "refresh":
            self.refresh.wake()
        elif kind == "show_robot":
            self.refresh.show_robot(int(request["robot_id"]))
        elif kind == "try":
            self._take_voice(VoiceTry.from_request(request, self.household_id))

    def _take_voice(self, voice: VoiceTry) -> None:
        self.last_watched = time.monotonic()  # a member uses the scene, watched or not
        if not accepted(voice, self.try_reports):
            return
        shown = self.view.robot.id if self.view.robot is not None else None
        if voice.robot_id is not None and voice.robot_id != shown:
            self.refresh.show_robot(voice.robot_id)  # its model and world come before the try, in order
        self.requests.put(("voice", voice))

    def _start_voice_trial(self, voice: VoiceTry) -> None:
        trial = voice_trial(voice, self.model.brain, self._closest, self.try_reports)
        if trial is not None:
            self._begin(trial)

    # --- following a training run ---------------------------------------------------------------------------
    def _follow(self, live: LiveRollout) -> None:
        following = self.run_following
        if not following.is_new(live):
            return  # nothing new since the last frame
        starting = following.starts_with(live)
        if starting:
            self.panel.clear_rewards()
        if self.world is None or self.world.world != live.world:
            self._build_world(live.world)
        world = self.world
        assert world is not None
        world.follow(live.mirror)
        self.world_view.pose_robot(world, self.frames)
        if starting or live.episode_ended:
            self.world_view.move_bodies(world)  # blocks and objects move only when an episode starts
        self.panel.camera.image = live.image
        goal = self.sphere.clip_points.get(live.goal_clip_id) if self.sphere is not None else None
        self.sphere_view.show_markers(self.model.embed(live.image), goal)
        self.panel.show_reward(live.reward)
        following.current = live
        if starting:
            self.show_status()

    def _back_to_own_world(self) -> None:
        """After following a run (or before trying a command): the robot's own world, freshly reset."""
        self.run_following.current = None
        self.panel.clear_rewards()
        robot = self.view.robot
        home = world_of_kind(robot.kind) if robot is not None else None
        if home is not None and self.world is not None and home != self.world.world:
            self._build_world(home)
        elif self.world is not None:
            self.world.reset()
        self.show_status()
