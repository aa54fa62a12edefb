"""Trying a command: the active model's policy drives the simulated robot toward one of the household's
recordings for one episode (as in evaluation), then says where the robot ended."""

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from scene.household import ClipInfo, HouseholdView
from scene.sphere import SphereData, command_title, nearest_commands
from scene.world import SimWorld

if TYPE_CHECKING:
    from scene.brain import Brain

COMMAND_STEPS = 100  # one episode, as in evaluation
NO_MODEL = "There is no active model yet: an admin can start training on the Admin page."


def command_choices(view: HouseholdView) -> list[str]:
    """ "Try a command" offers each of the household's commands once, in its own words."""
    return [command_title(command) for command in view.commands]


def clip_for(choice: str, view: HouseholdView) -> ClipInfo | None:
    """The recording that stands for the command chosen (its first one)."""
    return next((c for c in view.clips if command_title(c.command) == choice), None)


def why_not(choice: str, view: HouseholdView, brain: "Brain | None", sphere: SphereData | None) -> str | None:
    """What stands in the way of trying the command chosen; None when it can be tried."""
    clip = clip_for(choice, view)
    if clip is None:
        return "Record a command first (Record page)."
    if brain is None or sphere is None or clip.id not in sphere.clip_points:
        return NO_MODEL
    return model_cannot_drive(brain)


def model_cannot_drive(brain: "Brain | None") -> str | None:
    """Why the active model cannot drive the robot toward a goal; None when it can."""
    if brain is None:
        return NO_MODEL
    if brain.policy is None:
        return "The active model has no policy yet; run a fine-tune first."
    return None


class CommandTrial:
    """One episode of the policy carrying out the command in `words`, whose embedding is `goal`; at the end,
    `closest(final view's embedding)` names the household's command that view is closest to."""

    def __init__(
        self,
        words: str,
        goal: np.ndarray,
        brain: "Brain",
        closest: Callable[[np.ndarray], str | None],
        clip_id: int | None = None,
    ) -> None:
        from scene.brain import Goal

        self.goal, self.brain, self.closest = goal, brain, closest
        self.subject = f"“{words}”"  # how the messages name what is carried out
        self.steps = 0
        self.final_embedding: np.ndarray | None = None
        brain.start_episode(Goal(clip_id=clip_id, embedding=goal))

    @property
    def started(self) -> str:
        return f"Carrying out {self.subject}…"

    def step(self, world: SimWorld) -> str | None:
        """One step of the policy in `world`; when the episode is over, what happened (the world is reset)."""
        embedding = self.brain.embed_images(world.image[None])[0]
        ended = world.step(self.brain.act(world.image, embedding, world.state))
        self.steps += 1
        if not ended and self.steps < COMMAND_STEPS:
            return None
        self.final_embedding = self.brain.embed_images(world.image[None])[0]
        world.reset()
        return f"Done with {self.subject} after {self.steps} steps: {self.where_it_ended()}"

    def where_it_ended(self) -> str:
        """Where the robot stopped, in the household's words (as the active model sees the final view)."""
        sees = self.closest(self.final_embedding) if self.final_embedding is not None else None
        if sees is None:
            return "the model cannot tell which of your commands its last view shows."
        return f"what the robot sees at the end looks most like “{sees}”."


def closest_command(vector: np.ndarray, sphere: SphereData | None, view: HouseholdView) -> str | None:
    """The household's command (in its words) whose recordings lie closest to `vector` on the sphere."""
    if sphere is None or not sphere.clip_points:
        return None
    command = nearest_commands(np.asarray(vector, dtype=np.float32)[None], sphere.clip_points, view)[0]
    return command_title(command) if command is not None else None
