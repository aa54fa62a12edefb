"""The scene service: one `viser.ViserServer` on 127.0.0.1 and one simulation loop.

Each tick the robot moves (at random between commands, as in snapshot capture; driven by the active
model's policy while a command is being tried), the robot model in the 3D view follows the simulation's
joints, the camera image panel is refreshed, the current frame's embedding moves on the sphere and the reward
f_I(I_t) · f_S(S_goal) is shown as a number and a small live curve. The household's data (clips, snapshots,
the active model, running runs) is re-read every few seconds in a background thread.

While a training run publishes its rollouts (`scene.live`) and no command is being tried, the view follows
the run's environment 0 instead: its camera image, its pose mirrored into the scene's world, its training
reward; when the messages stop the robot goes back to looking around on its own.
"""

import json
import os
import queue
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import viser
from viser.extras import ViserUrdf

from core.paths import data_subdir
from scene.household import ClipInfo, HouseholdView, clip_audio, load_view, model_bytes, snapshot_images
from scene.live import FOLLOW_TIMEOUT_S, LiveRollout, RolloutFeed
from scene.world import DISPLAY_URDFS, SPHERE_PLACE_DEFAULT, SPHERE_PLACES, SimWorld, world_for_robot_kind

REFRESH_S = 5.0
REWARD_HISTORY = 120
COMMAND_STEPS = 100  # one episode, as in evaluation
NO_CLIPS = "(no recordings yet)"
PALETTE = [
    (230, 57, 70),
    (42, 157, 143),
    (69, 123, 157),
    (244, 162, 97),
    (131, 56, 236),
    (255, 183, 3),
    (29, 53, 87),
    (106, 153, 78),
]
UNASSIGNED = (150, 150, 150)


@dataclass
class SphereData:
    """Points on the sphere for one model version."""

    model_id: int
    snapshot_points: np.ndarray  # (N, 3)
    snapshot_commands: list[str | None]
    clip_points: dict[int, np.ndarray]


def endpoint_file() -> Path:
    return data_subdir("scene") / "endpoint.json"


class SceneService:
    def __init__(
        self,
        household_id: int,
        robot_id: int | None = None,
        host: str = "127.0.0.1",
        port: int = 0,
        fps: float = 15.0,
        follow_timeout_s: float = FOLLOW_TIMEOUT_S,
    ) -> None:
        self.household_id = household_id
        self.robot_id = robot_id
        self.fps = fps
        self.server = viser.ViserServer(host=host, port=port, label="varbot scene", verbose=False)
        self.server.gui.configure_theme(control_width="large", dark_mode=False, show_logo=False)
        self.stop_event = threading.Event()
        self.requests: queue.Queue[tuple[str, Any]] = queue.Queue()
        self.view: HouseholdView = HouseholdView(household_id=household_id, robot=None)
        self.brain: Any = None  # scene.brain.Brain, imported lazily (torch)
        self.brain_model_id: int | None = None
        self.sphere: SphereData | None = None
        self.world: SimWorld | None = None
        self.urdf: ViserUrdf | None = None
        self.goal: tuple[ClipInfo, np.ndarray] | None = None
        self.command_steps = 0
        self.rewards: deque[float] = deque(maxlen=REWARD_HISTORY)
        self.tick_times: deque[float] = deque(maxlen=60)
        self.frames = 0
        self.feed = RolloutFeed(household_id, follow_timeout_s)
        self.following: LiveRollout | None = None  # the training rollout on show
        self._build_gui()

    # --- lifetime -------------------------------------------------------------------------------------------
    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.server.get_port()}"

    def announce(self) -> None:
        """Tell the API where the scene listens (and whose it is)."""
        payload = {"url": self.url, "household_id": self.household_id, "pid": os.getpid()}
        temporary = endpoint_file().with_suffix(".tmp")
        temporary.write_text(json.dumps(payload))
        os.replace(temporary, endpoint_file())

    def withdraw(self) -> None:
        try:
            if json.loads(endpoint_file().read_text()).get("pid") == os.getpid():
                endpoint_file().unlink()
        except (OSError, ValueError):
            pass

    def run(self) -> None:
        self.announce()
        self._refresh()  # first picture before the loop starts
        refresher = threading.Thread(target=self._refresh_forever, name="scene-refresh", daemon=True)
        refresher.start()
        self.feed.start()
        period = 1.0 / self.fps
        try:
            while not self.stop_event.is_set():
                started = time.monotonic()
                self._tick()
                self.tick_times.append(time.monotonic())
                self.stop_event.wait(max(0.0, period - (time.monotonic() - started)))
        finally:
            self.feed.stop()
            self.withdraw()
            self.server.stop()
            if self.world is not None:
                self.world.close()

    def stop(self) -> None:
        self.stop_event.set()

    @property
    def measured_fps(self) -> float:
        if len(self.tick_times) < 2:
            return 0.0
        return (len(self.tick_times) - 1) / (self.tick_times[-1] - self.tick_times[0])

    # --- the panel ------------------------------------------------------------------------------------------
    def _build_gui(self) -> None:
        gui = self.server.gui
        self.status = gui.add_markdown("Starting…")
        with gui.add_folder("Robot camera"):
            self.camera = gui.add_image(
                np.zeros((96, 96, 3), np.uint8), label="What the robot sees", format="jpeg"
            )
        with gui.add_folder("Try a command"):
            self.clip_choice = gui.add_dropdown(
                "Command", (NO_CLIPS,), hint="one of your household's recordings"
            )
            self.try_button = gui.add_button(
                "Carry it out", hint="the active model drives the robot toward it"
            )
            self.stop_button = gui.add_button("Stop", color="red")
            self.command_status = gui.add_markdown("Pick a recording and press “Carry it out”.")
        with gui.add_folder("Reward"):
            self.reward_number = gui.add_number("f_I(I_t)·f_S(goal)", 0.0, disabled=True, step=0.001)
            self.reward_plot = gui.add_uplot(
                data=(np.zeros(2), np.zeros(2)),
                series=({"label": "step"}, {"label": "reward", "stroke": "#0b57d0", "width": 2}),
                title="reward",
                aspect=2.0,
            )
        self.try_button.on_click(lambda _event: self.requests.put(("try", self.clip_choice.value)))
        self.stop_button.on_click(lambda _event: self.requests.put(("stop", None)))

    # --- household data (background thread) -----------------------------------------------------------------
    def _refresh_forever(self) -> None:
        while not self.stop_event.wait(REFRESH_S):
            try:
                self._refresh()
            except Exception as exc:  # the loop must survive a database hiccup; say what happened
                self.status.content = f"**Could not read the household's data:** {exc}"

    def _refresh(self) -> None:
        view = load_view(self.household_id, self.robot_id)
        self.view = view
        options = tuple(clip.title for clip in view.clips) or (NO_CLIPS,)
        if tuple(self.clip_choice.options) != options:
            self.clip_choice.options = options
        if self.following is None:  # while following, the run decides the world
            self._request_robot_world(view)
        model_id = view.model.id if view.model is not None else None
        if model_id != self.brain_model_id:
            self._load_brain(view)
            size = self.brain.image_size if self.brain is not None else 96
            if self.world is not None and self.world.image.shape[0] != size:
                self.requests.put(("world", self.world.world))
        if self.brain is not None and (self.sphere is None or self._sphere_stale(view)):
            self.sphere = self._sphere_for(view)
            self.requests.put(("sphere", None))
        self._update_status()

    def _request_robot_world(self, view: HouseholdView) -> None:
        if view.robot is not None and (
            self.world is None or self.world.world != world_for_robot_kind(view.robot.kind)
        ):
            self.requests.put(("world", world_for_robot_kind(view.robot.kind)))
        elif view.robot is None and self.world is None:
            self.requests.put(("world", "kuka"))

    def _load_brain(self, view: HouseholdView) -> None:
        self.brain_model_id = view.model.id if view.model is not None else None
        self.brain, self.sphere = None, None
        if view.model is None:
            return
        var_bytes, policy_bytes = model_bytes(view.model)
        if var_bytes is None:
            return
        from scene.brain import Brain

        self.brain = Brain(var_bytes, policy_bytes)

    def _sphere_stale(self, view: HouseholdView) -> bool:
        sphere = self.sphere
        assert sphere is not None
        return (
            sphere.model_id != self.brain_model_id
            or set(sphere.clip_points) != {c.id for c in view.clips}
            or len(sphere.snapshot_commands) != len(view.snapshot_ids)
        )

    def _sphere_for(self, view: HouseholdView) -> SphereData:
        """Stored embeddings where a worker wrote them; the rest computed here with the active VAR."""
        clip_points = {c.id: view.clip_vectors[c.id] for c in view.clips if c.id in view.clip_vectors}
        missing_clips = [c.id for c in view.clips if c.id not in clip_points]
        if missing_clips:
            audio = clip_audio(missing_clips)
            ids = [i for i in missing_clips if i in audio]
            for clip_id, vector in zip(
                ids, self.brain.embed_clip_bytes([audio[i] for i in ids]), strict=True
            ):
                if vector is not None:
                    clip_points[clip_id] = vector
        stored = [view.snapshot_vectors[i] for i in view.snapshot_ids if i in view.snapshot_vectors]
        missing_snapshots = [i for i in view.snapshot_ids if i not in view.snapshot_vectors]
        images = snapshot_images(missing_snapshots)
        size = self.brain.image_size
        usable = [img for img in images.values() if img.shape[:2] == (size, size)]
        computed = list(self.brain.embed_images(np.stack(usable))) if usable else []
        points = np.asarray(stored + computed, dtype=np.float32).reshape(-1, 3)
        return SphereData(
            model_id=self.brain_model_id or 0,
            snapshot_points=points,
            snapshot_commands=self._nearest_commands(points, clip_points, view),
            clip_points=clip_points,
        )

    @staticmethod
    def _nearest_commands(
        points: np.ndarray, clip_points: dict[int, np.ndarray], view: HouseholdView
    ) -> list[str | None]:
        """Each snapshot joins the command whose clips' mean direction it is closest to (its cluster)."""
        command_of = {c.id: c.command for c in view.clips}
        commands = sorted({command_of[i] for i in clip_points})
        if not commands or len(points) == 0:
            return [None] * len(points)
        centres = np.stack(
            [np.mean([clip_points[i] for i in clip_points if command_of[i] == c], axis=0) for c in commands]
        )
        centres /= np.linalg.norm(centres, axis=1, keepdims=True) + 1e-9
        nearest = np.argmax(points @ centres.T, axis=1)
        return [commands[k] for k in nearest]

    def _colour(self, command: str | None) -> tuple[int, int, int]:
        commands = self.view.commands
        if command is None or command not in commands:
            return UNASSIGNED
        return PALETTE[commands.index(command) % len(PALETTE)]

    def _update_status(self) -> None:
        view = self.view
        robot = (
            f"**{view.robot.name}** ({view.robot.kind})"
            if view.robot
            else "no robot yet (add one on the Admin page)"
        )
        if view.model is None:
            model = "no active model yet: the sphere fills in once a model is active"
        else:
            model = f"model version {view.model.id}" + (
                "" if self.brain and self.brain.policy else " (no policy)"
            )
        run = ""
        if self.following is not None:
            f = self.following
            run = f"\n\nFollowing training run {f.run_id} live ({f.stage_name}), step {f.step}"
        elif view.running_run is not None:
            r = view.running_run
            run = f"\n\nTraining run {r.id}: {r.stage}, {round(r.progress * 100)}%"
        self.status.content = f"{robot} · {model} · {self.measured_fps:.1f} frames/s{run}"

    # --- the simulation loop (main thread) ------------------------------------------------------------------
    def _tick(self) -> None:
        self._handle_requests()
        if self.world is None:
            return
        prefer = self.following.run_id if self.following is not None else None
        live = self.feed.latest(prefer) if self.goal is None else None  # a command tried takes precedence
        if live is not None:
            self._follow(live)
        else:
            if self.following is not None:
                self._back_to_own_world()
            self._simulate(self.world)
        self.frames += 1
        if self.frames % int(max(1, self.fps)) == 0:
            self._update_status()

    def _simulate(self, world: SimWorld) -> None:
        if self.goal is not None and self.brain is not None and self.brain.policy is not None:
            self._command_step(world)
        else:
            world.explore_step()
        self._show_robot(world)
        self.camera.image = world.image
        self._show_embedding(world)

    # --- following a training run ---------------------------------------------------------------------------
    def _follow(self, live: LiveRollout) -> None:
        starting = self.following is None or self.following.run_id != live.run_id
        if not starting and self.following is not None and live.sequence == self.following.sequence:
            return  # nothing new since the last frame
        if starting:
            self.rewards.clear()
        if self.world is None or self.world.world != live.world:
            self._build_world(live.world)
        world = self.world
        assert world is not None
        world.follow(live.mirror)
        self._show_robot(world)
        if starting or live.episode_ended:
            self._move_bodies(world)  # blocks and objects move only when an episode starts
        self.camera.image = live.image
        goal = self.sphere.clip_points.get(live.goal_clip_id) if self.sphere is not None else None
        self._show_markers(self._embed(live.image), goal)
        self._show_reward(live.reward)
        self.following = live
        if starting:
            self._update_status()

    def _back_to_own_world(self) -> None:
        """After following a run (or before trying a command): the robot's own world, freshly reset."""
        self.following = None
        self.rewards.clear()
        robot = self.view.robot
        home = world_for_robot_kind(robot.kind) if robot is not None else None
        if home is not None and self.world is not None and home != self.world.world:
            self._build_world(home)
        elif self.world is not None:
            self.world.reset()
        self._update_status()

    def _handle_requests(self) -> None:
        while True:
            try:
                kind, value = self.requests.get_nowait()
            except queue.Empty:
                return
            if kind == "world":
                self._build_world(value)
            elif kind == "sphere":
                self._draw_sphere()
            elif kind == "try":
                self._start_command(value)
            elif kind == "stop":
                self.goal = None
                self.command_status.content = "Stopped. The robot looks around at random."

    def _start_command(self, title: str) -> None:
        clip = next((c for c in self.view.clips if c.title == title), None)
        if clip is None:
            self.command_status.content = "Record a command first (Record page)."
            return
        if self.brain is None or self.sphere is None or clip.id not in self.sphere.clip_points:
            self.command_status.content = (
                "There is no active model yet: an admin can start training on the Admin page."
            )
            return
        if self.brain.policy is None:
            self.command_status.content = "The active model has no policy yet; run a fine-tune first."
            return
        self._back_to_own_world()
        self.goal = (clip, self.sphere.clip_points[clip.id])
        self.brain.start_episode(_goal(clip.id, self.goal[1]))
        self.command_steps = 0
        self.rewards.clear()
        self.command_status.content = f"Carrying out “{clip.title}”…"

    def _command_step(self, world: SimWorld) -> None:
        assert self.goal is not None
        embedding = self.brain.embed_images(world.image[None])[0]
        action = self.brain.act(world.image, embedding, world.state)
        ended = world.step(action)
        self.command_steps += 1
        if ended or self.command_steps >= COMMAND_STEPS:
            heard = world.info.get("heard")
            names = world.intent_names
            sees = (
                names[heard]
                if isinstance(heard, int) and 0 <= heard < len(names)
                else "nothing in particular"
            )
            title, steps = self.goal[0].title, self.command_steps
            self.command_status.content = (
                f"Done with “{title}” after {steps} steps; the robot ended at {sees}."
            )
            self.goal = None
            world.reset()

    def _build_world(self, name: str) -> None:
        image_size = self.brain.image_size if self.brain is not None else 96
        previous, self.world = self.world, SimWorld(name, image_size=image_size)
        if previous is not None:  # closed only once replaced: readers never see a closed world
            previous.close()
        self.server.scene.reset()
        self.server.scene.add_grid("/ground", width=4, height=4, cell_size=0.25, position=(0, 0, -0.13))
        self.server.scene.add_frame("/robot", show_axes=False)
        self.urdf = ViserUrdf(self.server, DISPLAY_URDFS[name], root_node_name="/robot")
        for index, shape in enumerate(self.world.other_shapes()):
            colour = tuple(int(255 * c) for c in shape.rgba[:3])
            path = f"/world/body{shape.body}_{shape.link}/shape{index}"
            position, orientation = self.world.link_pose(shape.body, shape.link)
            self.server.scene.add_frame(
                f"/world/body{shape.body}_{shape.link}",
                position=tuple(position),
                wxyz=(orientation[3], orientation[0], orientation[1], orientation[2]),
                show_axes=False,
            )
            local = shape.local_orientation
            if shape.kind == "sphere":
                self.server.scene.add_icosphere(
                    path, radius=shape.size[0], color=colour, position=shape.local_position
                )
            else:
                self.server.scene.add_box(
                    path,
                    dimensions=shape.size,
                    color=colour,
                    position=shape.local_position,
                    wxyz=(local[3], local[0], local[1], local[2]),
                )
        self._shapes = self.world.other_shapes()
        centre, radius = SPHERE_PLACES.get(name, SPHERE_PLACE_DEFAULT)
        self.sphere_radius = radius
        self.server.scene.add_frame("/sphere", position=centre, show_axes=False)
        self.server.scene.add_icosphere(
            "/sphere/surface",
            radius=radius,
            color=(170, 185, 205),
            opacity=0.25,
            subdivisions=4,
            cast_shadow=False,
        )
        self.server.scene.add_label("/sphere/title", "embedding sphere", position=(0.0, 0.0, radius * 1.25))
        self.current_marker = self.server.scene.add_icosphere(
            "/sphere/current", radius=radius * 0.06, color=(255, 255, 255), visible=False
        )
        self.goal_marker = self.server.scene.add_icosphere(
            "/sphere/goal", radius=radius * 0.08, color=(255, 200, 0), visible=False
        )
        self._draw_sphere()
        self.server.initial_camera.position = (2.2, -1.6, 1.4) if name != "turtlebot" else (3.5, -4.5, 3.5)
        self.server.initial_camera.look_at = (0.4, -0.4, 0.1) if name != "turtlebot" else (0, -1.0, 0.3)

    def _draw_sphere(self) -> None:
        if self.world is None:
            return
        radius = self.sphere_radius
        sphere = self.sphere
        scene = self.server.scene
        if sphere is None or len(sphere.snapshot_points) == 0:
            scene.add_point_cloud("/sphere/snapshots", np.zeros((0, 3)), colors=(0, 0, 0), point_size=0.02)
        else:
            colours = np.array([self._colour(c) for c in sphere.snapshot_commands], dtype=np.uint8)
            scene.add_point_cloud(
                "/sphere/snapshots",
                sphere.snapshot_points * radius,
                colors=colours,
                point_size=radius * 0.05,
                point_shape="circle",
            )
        command_of = {c.id: c.command for c in self.view.clips}
        if sphere is None or not sphere.clip_points:
            scene.add_point_cloud("/sphere/clips", np.zeros((0, 3)), colors=(0, 0, 0), point_size=0.02)
            return
        ids = list(sphere.clip_points)
        points = np.stack([sphere.clip_points[i] for i in ids]) * radius * 1.04
        colours = np.array([self._colour(command_of.get(i)) for i in ids], dtype=np.uint8)
        scene.add_point_cloud(
            "/sphere/clips", points, colors=colours, point_size=radius * 0.12, point_shape="diamond"
        )
        for command in self.view.commands:
            members = [sphere.clip_points[i] for i in ids if command_of.get(i) == command]
            if members:
                centre = np.mean(members, axis=0)
                centre = centre / (np.linalg.norm(centre) + 1e-9) * radius * 1.18
                title = (
                    command.split(":", 1)[1]
                    if command.startswith("name:")
                    else f"recording {command.split(':')[1]}"
                )
                scene.add_label(f"/sphere/commands/{abs(hash(command))}", title, position=tuple(centre))

    def _show_robot(self, world: SimWorld) -> None:
        if self.urdf is None:
            return
        position, orientation = world.robot_base()
        frame = self.server.scene
        with self.server.atomic():
            frame.add_frame("/robot", position=position, wxyz=orientation, show_axes=False)
            self.urdf.update_cfg(world.joint_values(self.urdf.get_actuated_joint_names()))
            if self.frames % 10 == 0 or self.frames < 2:
                self._move_bodies(world)

    def _move_bodies(self, world: SimWorld) -> None:
        for body, link in {(s.body, s.link) for s in self._shapes}:
            position, orientation = world.link_pose(body, link)
            self.server.scene.add_frame(
                f"/world/body{body}_{link}",
                position=tuple(position),
                wxyz=(orientation[3], orientation[0], orientation[1], orientation[2]),
                show_axes=False,
            )

    def _show_embedding(self, world: SimWorld) -> None:
        current = self._embed(world.image)
        goal = self.goal[1] if self.goal is not None else self._default_goal()
        self._show_markers(current, goal)
        if current is not None and goal is not None:
            self._show_reward(float(np.dot(current, goal)))

    def _embed(self, image: np.ndarray) -> np.ndarray | None:
        """f_I(image) with the active VAR; None without one (or for an image of another size)."""
        if self.brain is None or image.shape[:2] != (self.brain.image_size, self.brain.image_size):
            return None
        return self.brain.embed_images(image[None])[0]

    def _show_markers(self, current: np.ndarray | None, goal: np.ndarray | None) -> None:
        radius = self.sphere_radius
        if current is not None:
            self.current_marker.position = tuple(current * radius * 1.02)
        self.current_marker.visible = current is not None
        if goal is not None:
            self.goal_marker.position = tuple(goal * radius * 1.06)
        self.goal_marker.visible = goal is not None

    def _show_reward(self, value: float) -> None:
        self.rewards.append(value)
        self.reward_number.value = round(value, 3)
        if self.frames % 3 == 0 and len(self.rewards) >= 2:
            y = np.asarray(self.rewards, dtype=np.float64)
            self.reward_plot.data = (np.arange(len(y), dtype=np.float64), y)

    def _default_goal(self) -> np.ndarray | None:
        """Without a command being tried, the reward is shown for the chosen recording in the dropdown."""
        if self.sphere is None:
            return None
        clip = next((c for c in self.view.clips if c.title == self.clip_choice.value), None)
        return self.sphere.clip_points.get(clip.id) if clip is not None else None


def _goal(clip_id: int, embedding: np.ndarray) -> Any:
    from scene.brain import Goal

    return Goal(clip_id=clip_id, embedding=embedding)
