""" "Try it now" with a live voice: a member holds a button on the Record or Scene page, says a command, lets
go, and the robot carries out what was just said. The clip comes through the scene's inbox
(`backend.scene_requests`), is embedded with the active VAR (f_S of the live voice is the goal) and is kept
nowhere. Progress and the outcome are written back, in the household's command words, for the page to show.
"""

import base64
import binascii
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from backend import scene_requests
from backend.scene_requests import TryState
from scene.trial import COMMAND_STEPS, CommandTrial, model_cannot_drive
from scene.world import SimWorld

if TYPE_CHECKING:
    from scene.brain import Brain

REPORT_EVERY = 5  # steps between progress reports: a page polling twice a second sees it move


@dataclass(frozen=True)
class VoiceTry:
    try_id: str
    household_id: int
    robot_id: int | None
    wav: bytes
    asked_at: float  # Unix time the API queued it

    @classmethod
    def from_request(cls, request: dict[str, Any], household_id: int) -> "VoiceTry":
        """The inbox's "try" request; ValueError (naming what is wrong) for one that cannot be read."""
        try:
            return cls(
                try_id=str(request["try_id"]),
                household_id=household_id,
                robot_id=None if request.get("robot_id") is None else int(request["robot_id"]),
                wav=base64.b64decode(request["wav_b64"], validate=True),
                asked_at=float(request["at"]),
            )
        except (KeyError, TypeError, ValueError, binascii.Error) as error:
            raise ValueError(f"unreadable try request: {type(error).__name__}: {error}") from error

    @property
    def too_old(self) -> bool:
        return time.time() - self.asked_at > scene_requests.TRY_STALE_S


class TryReports:
    """Writes tries' statuses to Redis from a thread of its own, so that the simulation loop never waits
    for Redis; a status that cannot be written is dropped (the page then says the scene went quiet)."""

    def __init__(self) -> None:
        self.pending: queue.Queue[tuple[VoiceTry, TryState, str, int]] = queue.Queue()
        threading.Thread(target=self._forever, name="scene-try-reports", daemon=True).start()

    def say(self, voice: VoiceTry, state: TryState, message: str, step: int = 0) -> None:
        self.pending.put((voice, state, message, step))

    def _forever(self) -> None:
        while True:
            voice, state, message, step = self.pending.get()
            try:
                scene_requests.write_try(
                    voice.try_id, voice.household_id, state, message, step, COMMAND_STEPS
                )
            except scene_requests.SceneUnreachable:
                continue


class VoiceTrial(CommandTrial):
    """One episode of the policy carrying out a live voice; reports its progress as it goes."""

    def __init__(self, voice: VoiceTry, heard_as: str | None, *args: Any, reports: TryReports) -> None:
        super().__init__("what you said", *args)
        self.subject = f"what you said (it sounds most like “{heard_as}”)" if heard_as else "what you said"
        self.voice, self.reports = voice, reports
        self.reports.say(voice, "running", self.started)

    def step(self, world: SimWorld) -> str | None:
        done = super().step(world)
        if done is not None:
            self.reports.say(self.voice, "done", done, self.steps)
        elif self.steps % REPORT_EVERY == 0:
            message = f"{self.started} step {self.steps} of at most {COMMAND_STEPS}"
            self.reports.say(self.voice, "running", message, self.steps)
        return done

    def interrupted(self, why: str) -> None:
        self.reports.say(self.voice, "failed", why, self.steps)


def accepted(voice: VoiceTry, reports: TryReports) -> bool:
    """False (and the page told why) for a try the scene took too late to carry out."""
    if voice.too_old:
        reports.say(voice, "refused", "Too late: the scene took too long to start. Try again.")
        return False
    reports.say(voice, "starting", "Heard you: the robot is about to start…")
    return True


def voice_trial(
    voice: VoiceTry,
    brain: "Brain | None",
    closest: Callable[[np.ndarray], str | None],
    reports: TryReports,
) -> VoiceTrial | None:
    """The episode carrying out `voice` with the active model; None (and the page told why) when it cannot."""
    refusal = model_cannot_drive(brain)
    if refusal is not None or brain is None:
        reports.say(voice, "refused", refusal or "")
        return None
    goal = brain.embed_clip_bytes([voice.wav])[0]  # f_S(live voice)
    if goal is None:
        reports.say(voice, "refused", "The recording could not be read; hold the button while you speak.")
        return None
    return VoiceTrial(voice, closest(goal), goal, brain, closest, reports=reports)
