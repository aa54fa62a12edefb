"""The block task on a real Kinova Gen3: a Gymnasium env over an `sim.arm.ArmDriver` (on a real arm,
`sim.kortex_driver.KortexArmDriver`), with the simulated Gen3's observation and action contract
(`sim.kinova_blocks.KinovaBlocksEnv`): observation {"image": (S, S, 3) uint8 from the fixed camera,
"state": gripper (x, y) float32}, action (dx, dy) in [-1, 1] scaled by `STEP_M`.

- The driver's safety limits hold for every step (workspace box, step length, speed: see the driver).
- Every exception during reset or step (the driver's, the camera's, a KeyboardInterrupt) stops the arm
  before it is re-raised.
- `reset` connects if needed and homes the arm: every episode starts from the same pose. Where the blocks
  lie is up to the person at the table.
- A real arm has no ground truth: `info["heard"]` is None and `info["success"]` False (a person judges the
  attempt's final view instead); there is no sparse task reward (0.0).
"""

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np

from sim.arm import STEP_M, ArmDriver
from sim.blocks import EPISODE_STEPS, INTENT_NAMES, NUM_INTENTS


class KinovaRealEnv(gym.Env[dict, np.ndarray]):
    metadata: ClassVar[dict] = {"render_modes": ["rgb_array"], "render_fps": 15}
    num_intents = NUM_INTENTS
    intent_names = INTENT_NAMES

    def __init__(self, driver: ArmDriver, image_size: int = 96, max_steps: int | None = None) -> None:
        if max_steps is not None and max_steps < 1:
            raise ValueError(f"max_steps must be a positive number of steps, got {max_steps}")
        self.driver = driver
        self.image_size = image_size
        self.max_steps = EPISODE_STEPS if max_steps is None else int(max_steps)
        self.observation_space = gym.spaces.Dict(
            {
                "image": gym.spaces.Box(0, 255, (image_size, image_size, 3), np.uint8),
                "state": gym.spaces.Box(-np.inf, np.inf, (2,), np.float32),
            }
        )
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.intent = 0
        self.steps = 0
        self.target_xy: tuple[float, float] | None = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[dict, dict]:
        super().reset(seed=seed)
        options = dict(options or {})
        intent = options.pop("intent", None)
        if options:
            raise ValueError(f"unknown reset options {sorted(options)}; the only option is 'intent'")
        self.intent = int(self.np_random.integers(NUM_INTENTS)) if intent is None else _intent(intent)
        with self._stop_on_error():
            connect = getattr(self.driver, "connect", None)
            if connect is not None:
                connect()
            self.driver.home()
            self.target_xy = self.driver.gripper_xy()
            observation = self._observe()
        self.steps = 0
        return observation, self._info()

    def step(self, action: np.ndarray) -> tuple[dict, float, bool, bool, dict]:
        action = np.asarray(action, dtype=np.float64).reshape(-1)
        if action.shape != (2,) or not np.all(np.isfinite(action)):
            raise ValueError(f"action must be 2 finite numbers (dx, dy) in [-1, 1], got {action!r}")
        dx, dy = np.clip(action, -1.0, 1.0) * STEP_M
        with self._stop_on_error():
            self.target_xy = self.driver.move_target(float(dx), float(dy))
            observation = self._observe()
        self.steps += 1
        return observation, 0.0, False, self.steps >= self.max_steps, self._info()

    def render(self) -> np.ndarray:
        with self._stop_on_error():
            return self.driver.grab_frame()

    def close(self) -> None:
        self.driver.close()

    @contextmanager
    def _stop_on_error(self) -> Iterator[None]:
        try:
            yield
        except BaseException:
            self.driver.stop()
            raise

    def _observe(self) -> dict:
        image = np.asarray(self.driver.grab_frame(), dtype=np.uint8)
        if image.shape != (self.image_size, self.image_size, 3):
            raise ValueError(
                f"the camera gives {image.shape} frames but this env observes "
                f"({self.image_size}, {self.image_size}, 3): give the driver image_size={self.image_size}"
            )
        return {"image": image, "state": np.asarray(self.driver.gripper_xy(), dtype=np.float32)}

    def _info(self) -> dict:
        return {
            "intent": self.intent,
            "heard": None,
            "success": False,
            "on_target": False,
            "hold_streak": 0,
            "target_xy": self.target_xy,
        }


def _intent(intent: Any) -> int:
    if isinstance(intent, bool) or not isinstance(intent, int | np.integer) or not 0 <= intent < NUM_INTENTS:
        raise ValueError(f"options['intent'] must be an int in 0..{NUM_INTENTS - 1}, got {intent!r}")
    return int(intent)
