"""Trying a command: the active model's policy drives the simulated robot toward one of the household's
recordings for one episode (as in evaluation), then says where the robot ended."""

from typing import TYPE_CHECKING

import numpy as np

from scene.household import ClipInfo, HouseholdView
from scene.sphere import SphereData, command_title
from scene.world import SimWorld

if TYPE_CHECKING:
    from scene.brain import Brain

COMMAND_STEPS = 100  # one episode, as in evaluation


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
        return "There is no active model yet: an admin can start training on the Admin page."
    if brain.policy is None:
        return "The active model has no policy yet; run a fine-tune first."
    return None


class CommandTrial:
    """One episode of the policy carrying out `clip`, whose embedding is `goal`."""

    def __init__(self, clip: ClipInfo, goal: np.ndarray, brain: "Brain") -> None:
        from scene.brain import Goal

        self.clip, self.goal, self.brain = clip, goal, brain
        self.steps = 0
        brain.start_episode(Goal(clip_id=clip.id, embedding=goal))

    @property
    def started(self) -> str:
        return f"Carrying out “{command_title(self.clip.command)}”…"

    def step(self, world: SimWorld) -> str | None:
        """One step of the policy in `world`; when the episode is over, what happened (the world is reset)."""
        embedding = self.brain.embed_images(world.image[None])[0]
        ended = world.step(self.brain.act(world.image, embedding, world.state))
        self.steps += 1
        if not ended and self.steps < COMMAND_STEPS:
            return None
        heard = world.info.get("heard")
        names = world.intent_names
        sees = names[heard] if isinstance(heard, int) and 0 <= heard < len(names) else "nothing in particular"
        world.reset()
        command = command_title(self.clip.command)
        return f"Done with “{command}” after {self.steps} steps; the robot ended at {sees}."
