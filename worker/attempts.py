"""The robot tries the household's recorded commands (the robot queue's `try_commands`): for each attempt,
the active policy (or the world's base model) plays one episode with a recorded command as its goal (the
command's clip embedding), and the final view becomes a snapshot to judge on the Label page ("did it do
what I said?"), with a few frames before it as a short replay (blobs named in `meta["attempt"]["frames"]`).
A share of random-exploration views joins them for the "nothing" case (`worker.capture`).

Every episode runs its full length (success rule "final"): no simulator ground truth chooses or filters the
views; `meta["sim_heard"]` is kept for scoring only, as capture does."""

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from sqlalchemy import select

from backend import models
from backend.blobs import BlobStore
from backend.db import get_session_factory
from backend.deps import get_blob_store
from backend.services import model_versions
from backend.services.attempts import (
    ATTEMPT_SOURCE,
    Command,
    commands_with_an_is_answer,
    household_commands,
    write_status,
)
from backend.services.snapshots import create_snapshot
from core.paths import data_subdir
from core.robots import world_of_kind
from core.rooms import room_of
from worker.base_models import BaseModelMissing, find_base
from worker.capture import capture_views, fresh_seed, png
from worker.run_context import materialise

REPLAY_FRAMES = 6  # frames of the replay, the final view last, spread over the attempt's second half
MakeEnv = Callable[[int, int | None], Any]  # (image_size, max_steps) -> the robot's Gymnasium env
Capture = Callable[[int, int, int, str | None, int | None], dict]  # (robot, household, count, task, seed)


class AttemptRefused(ValueError):
    """What cannot be attempted, saying why and what to do."""


@dataclass(frozen=True)
class RobotModel:
    var_path: Path
    policy_path: Path
    version_id: int | None  # None: the world's base model (the robot has no active version yet)


@dataclass(frozen=True)
class Attempt:
    frames: list[np.ndarray]  # the replay, the final view last
    state: list[float]  # the robot's state at the final view
    sim_heard: int | None  # the simulator's account of the final view: scoring only


def try_commands(
    robot_id: int,
    household_id: int,
    attempts: int,
    random_views: int,
    commands: list[str],
    task_id: str | None = None,
    make_env: MakeEnv | None = None,
    capture: Capture = capture_views,
    seed: int | None = None,
) -> dict[str, Any]:
    """`attempts` attempts spread evenly over the command keys `commands` (none: every command, those with no
    *is* answer yet favoured, `attempt_cycle`), then `random_views` random views.
    `seed` (default: a fresh one) decides which clip each attempt plays, where each starts and the random
    views: with the same model, commands and answers so far, the same attempts come back (a bench compares
    two fine-tunes on the same labels that way).
    Raises AttemptRefused for a robot with no model, a household with no recordings, a command with none.
    A simulated robot plays in its world; a real one (`worker.real_arm`) passes its `make_env` and
    `capture`."""
    import torch

    from learning.var.checkpoint import front_end_of, load_var

    torch.set_num_threads(1)
    blobs = get_blob_store()
    report = _reporter(task_id, robot_id, random_views)
    with get_session_factory()() as session:
        robot = _robot(session, robot_id, household_id, simulated=make_env is None)
        world = world_of_kind(robot.kind)
        asked = _commands(session, household_id, commands)
        if not commands:  # the household left the choice to the robot
            asked = attempt_cycle(asked, commands_with_an_is_answer(session, robot.id))
        model = robot_model(session, blobs, robot, world)
        var = load_var(model.var_path).eval()
        commands_once = list(dict.fromkeys(asked))
        goals = _goal_embeddings(session, blobs, commands_once, var, front_end_of(model.var_path), world)
        seed = fresh_seed() if seed is None else seed
        rng = np.random.default_rng(seed)
        created = []
        report("running", f"trying {attempts} times: {', '.join(c.name for c in commands_once)}", 0)
        with policy_player(model.policy_path, var, world, room_of(robot.settings or {}), make_env) as play:
            for index in range(attempts):
                command = asked[index % len(asked)]
                clip_id = int(rng.choice(command.clip_ids))
                attempt = play(goals[clip_id], int(rng.integers(2**31 - 1)))
                created.append(_store(session, blobs, robot, command, clip_id, attempt, model, task_id).id)
                report("running", f"{len(created)} of {attempts} attempts stored", len(created))
    if random_views:
        capture(robot_id, household_id, random_views, task_id, seed + 1)
    report(
        "done", f"{len(created)} attempts and {random_views} random views are ready to label", len(created)
    )
    return {
        "robot_id": robot_id,
        "created": len(created),
        "random_views": random_views,
        "snapshot_ids": created,
    }


def attempt_cycle(commands: list[Command], answered: set[str]) -> list[Command]:
    """The order attempts take the commands in, round and round: commands that no view has an *is* answer
    for yet come first and twice per round, since an attempt that ends at its command gives that command its
    first positive (and until every command has one, the robot's success cannot be measured)."""
    missing = [command for command in commands if command.key not in answered]
    return missing + commands


def _reporter(task_id: str | None, robot_id: int, random_views: int) -> Callable[[str, str, int], None]:
    def report(state: str, message: str, created: int) -> None:
        if task_id is not None:
            with contextlib.suppress(Exception):  # best effort: the snapshots are the truth
                write_status(task_id, {"state": state, "message": message, "created": created,
                                       "random_views": random_views, "robot_id": robot_id})  # fmt: skip

    return report


def report_refusal(task_id: str | None, robot_id: int, state: str, message: str) -> None:
    """The task's end when it could not run: refused (with what to do) or failed."""
    _reporter(task_id, robot_id, 0)(state, message, 0)


def _robot(session: Any, robot_id: int, household_id: int, simulated: bool) -> models.Robot:
    robot = session.get(models.Robot, robot_id)
    if robot is None or robot.household_id != household_id:
        raise AttemptRefused(f"robot {robot_id} of household {household_id} does not exist")
    if models.RobotKind(robot.kind).simulated != simulated:
        raise AttemptRefused(
            f"robot {robot_id} is a {robot.kind}: its attempts are made "
            + ("by simulated robots" if simulated else "on a real arm (worker.real_arm)")
        )
    return robot


def _commands(session: Any, household_id: int, keys: list[str]) -> list[Command]:
    commands = household_commands(session, household_id)
    if not commands:
        raise AttemptRefused("your household has no recorded commands: record some on the Record page first")
    gone = [key for key in keys if key not in commands]
    if gone:
        raise AttemptRefused(
            f"no recording of {', '.join(key.removeprefix('name:') for key in gone)} any more: record it on "
            "the Record page first, or ask for the other commands"
        )
    return [commands[key] for key in keys] or list(commands.values())


def robot_model(session: Any, blobs: BlobStore, robot: models.Robot, world: str) -> RobotModel:
    """The robot's active version, or the world's base model when it has none yet."""
    active = model_versions.active_version(session, robot.id)
    if active is not None:
        if active.policy_key is None or active.var_key is None:
            raise AttemptRefused(
                f"the active version {active.id} of robot {robot.id} has no policy to act with: activate "
                "a version that has one (Admin page), or train one"
            )
        folder = data_subdir("attempts", f"version-{active.id}")
        return RobotModel(
            materialise(blobs, active.var_key, folder / "var.pt"),
            materialise(blobs, active.policy_key, folder / "policy.pt"),
            active.id,
        )
    try:
        base = find_base(world)
    except BaseModelMissing as missing:
        raise AttemptRefused(
            f"robot {robot.id} has no model to act with: train or pick a base model first ({missing})"
        ) from missing
    return RobotModel(base.var_path, base.policy_path, None)


def _goal_embeddings(
    session: Any, blobs: BlobStore, commands: list[Command], var: Any, front_end: str, world: str
) -> dict[int, Any]:
    """Each recording's f_S embedding: the goal the policy is given."""
    import torch

    from learning.audio import features_from_bytes

    clip_ids = sorted({clip_id for command in commands for clip_id in command.clip_ids})
    clips = {c.id: c for c in session.scalars(select(models.Clip).where(models.Clip.id.in_(clip_ids)))}
    kind = feature_kind(world)
    features = np.stack([features_from_bytes(blobs.get(clips[i].wav_key), kind, front_end) for i in clip_ids])
    with torch.inference_mode():
        embedded = var.encode_sound(torch.from_numpy(features.astype(np.float32)))
    return {clip_id: (embedded[row], features[row]) for row, clip_id in enumerate(clip_ids)}


def feature_kind(world: str) -> str:
    try:
        return find_base(world).feature_kind
    except BaseModelMissing:
        return "speech"


@contextlib.contextmanager
def policy_player(
    policy_path: Path, var: Any, world: str, room: Any, make_env: MakeEnv | None = None
) -> Iterator[Callable[[Any, int], Attempt]]:
    """A function playing one deterministic episode of the policy toward a goal, in the robot's room (or,
    with `make_env`, in the env it makes: a real arm)."""
    import torch

    from learning.rl.envs import make_env_fn, world_id
    from learning.rl.ppo import load_policy

    policy, payload = load_policy(policy_path)
    policy.eval()
    config, run_config = policy.config, payload["config"]
    max_steps = run_config.get("max_episode_steps")
    image_size = int(run_config["image_size"])
    if make_env is not None:
        env = make_env(image_size, max_steps)
    else:
        env = make_env_fn(world_id(world), image_size, "final", max_steps, None, room)()

    @torch.inference_mode()
    def play(goal: tuple[Any, np.ndarray], seed: int) -> Attempt:
        embedding, features = goal
        goal_input = embedding[None] if config.goal_encoder == "var" else torch.from_numpy(features[None])
        goal_features = policy.encode_goal(goal_input)
        observation, info = env.reset(seed=seed)
        hidden, start = policy.initial_state(1), torch.ones(1)
        frames = [observation["image"]]
        done = False
        while not done:
            image = torch.from_numpy(np.asarray(observation["image"])[None])
            seen = var.encode_image(image) if config.var_dim else torch.zeros(1, 0)
            state = torch.from_numpy(np.asarray(observation["state"], dtype=np.float32)[None])
            mean, _, hidden = policy.step(policy.view_of(image), seen, state, goal_features, hidden, start)
            observation, _, terminated, truncated, info = env.step(mean.clamp(-1.0, 1.0)[0].numpy())
            frames.append(observation["image"])
            start, done = torch.zeros(1), bool(terminated or truncated)
        heard = info["heard"]  # None on a real arm (no ground truth), -1 for nothing in a simulated one
        return Attempt(
            _replay(frames), [float(v) for v in np.asarray(observation["state"]).ravel()],
            None if heard is None or heard < 0 else int(heard),
        )  # fmt: skip

    try:
        yield play
    finally:
        env.close()


def _replay(frames: list[np.ndarray]) -> list[np.ndarray]:
    picks = np.unique(np.linspace(len(frames) // 2, len(frames) - 1, REPLAY_FRAMES).round().astype(int))
    return [frames[i] for i in picks]


def _store(
    session: Any,
    blobs: BlobStore,
    robot: models.Robot,
    command: Command,
    clip_id: int,
    attempt: Attempt,
    model: RobotModel,
    task_id: str | None,
) -> models.Snapshot:
    meta = {
        "attempt": {
            "command": command.key,
            "clip_id": clip_id,
            "frames": [blobs.put(png(frame)) for frame in attempt.frames],
            "model_version_id": model.version_id,
        },
        "world": world_of_kind(robot.kind),
        "sim_heard": attempt.sim_heard,
        "task_id": task_id,
    }
    return create_snapshot(
        session, blobs, robot, png(attempt.frames[-1]), attempt.state, ATTEMPT_SOURCE, meta
    )
