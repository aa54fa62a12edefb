"""The panel beside the 3D view: the status line, the robot's camera image, "Try a command" and the reward
f_I(I_t) · f_S(S_goal) (shown in plain words: how close what the robot sees is to the command) as a number
and a small live curve."""

from collections import deque
from collections.abc import Callable, Sequence

import numpy as np
import viser

from backend.broker import COACHING_STAGE
from scene.household import HouseholdView
from scene.live import LiveRollout
from scene.sphere import SphereData

NO_CLIPS = "(no commands recorded yet)"
REWARD_LABEL = "How close to the command"
REWARD_HINT = (
    "how close what the robot sees is to the command, as the active model hears it (higher is closer)"
)
REWARD_HISTORY = 120
PLOT_EVERY = 3  # redraw the curve on every third reward: the browser need not re-plot 15 times a second


class Panel:
    """The panel's controls; `on_try(title)` and `on_stop()` are called from Viser's thread."""

    def __init__(self, gui: viser.GuiApi, on_try: Callable[[str], None], on_stop: Callable[[], None]) -> None:
        self.status = gui.add_markdown("Starting…")
        with gui.add_folder("Robot camera"):
            self.camera = gui.add_image(
                np.zeros((96, 96, 3), np.uint8), label="What the robot sees", format="jpeg"
            )
        with gui.add_folder("Try a command"):
            self.clip_choice = gui.add_dropdown(
                "Command", (NO_CLIPS,), hint="one of your household's commands"
            )
            self.try_button = gui.add_button(
                "Carry it out", hint="the active model drives the robot toward it"
            )
            self.stop_button = gui.add_button("Stop", color="red")
            self.command_status = gui.add_markdown("Pick a command and press “Carry it out”.")
        with gui.add_folder("Reward"):
            self.reward_number = gui.add_number(
                REWARD_LABEL, 0.0, disabled=True, step=0.001, hint=REWARD_HINT
            )
            self.reward_plot = gui.add_uplot(
                data=(np.zeros(2), np.zeros(2)),
                series=({"label": "step"}, {"label": "reward", "stroke": "#0b57d0", "width": 2}),
                title="reward",
                aspect=2.0,
            )
        self.rewards: deque[float] = deque(maxlen=REWARD_HISTORY)
        self.rewards_shown = 0
        self.try_button.on_click(lambda _event: on_try(self.clip_choice.value))
        self.stop_button.on_click(lambda _event: on_stop())

    def offer_clips(self, titles: Sequence[str]) -> None:
        options = tuple(titles) or (NO_CLIPS,)
        if tuple(self.clip_choice.options) != options:
            self.clip_choice.options = options

    @property
    def chosen_clip(self) -> str:
        return self.clip_choice.value

    def show_reward(self, value: float) -> None:
        self.rewards.append(value)
        self.rewards_shown += 1
        self.reward_number.value = round(value, 3)
        if self.rewards_shown % PLOT_EVERY == 0 and len(self.rewards) >= 2:
            y = np.asarray(self.rewards, dtype=np.float64)
            self.reward_plot.data = (np.arange(len(y), dtype=np.float64), y)

    def clear_rewards(self) -> None:
        self.rewards.clear()


def _following_words(rollout: LiveRollout) -> str:
    if rollout.stage == COACHING_STAGE:
        return "Following a coaching session by voice live"
    return f"Following training run {rollout.run_id} live ({rollout.stage_name})"


def status_line(
    view: HouseholdView,
    has_policy: bool,
    on_sphere: SphereData | None,
    following: LiveRollout | None,
    frames_per_s: float,
) -> str:
    """Whose robot, which model, what is drawn on the sphere, the loop's frame rate, and the training run on
    show (or running)."""
    if view.robot:
        robot = f"**{view.robot.name}** ({view.robot.kind})"
    else:
        robot = "no robot yet (add one on the Admin page)"
    if view.model is None:
        model = "no active model yet: the sphere fills in once a model is active"
    else:
        model = f"model version {view.model.id}" + ("" if has_policy else " (no policy)")
    sphere = ""
    if on_sphere is not None:
        views, recordings = len(on_sphere.snapshot_points), len(on_sphere.clip_points)
        sphere = f" · {views} views and {recordings} recordings on the sphere"
    run = ""
    if following is not None:
        run = f"\n\n{_following_words(following)}, step {following.step}"
    elif view.running_run is not None:
        r = view.running_run
        run = f"\n\nTraining run {r.id}: {r.stage}, {round(r.progress * 100)}%"
    return f"{robot} · {model}{sphere} · {frames_per_s:.1f} frames/s{run}"
