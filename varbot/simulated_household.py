"""A simulated household that teaches a tiny model, for the worker tests and the launcher's bench.

Each command word said by two espeak-ng voices (the family), a 16 px random VAR with a policy after one tiny
PPO update installed as the kuka base model, and a `Household` that records those clips, captures views of a
simulated Kuka and answers every is / is-not pair with the simulator's ground truth, through the real API."""

import subprocess
from dataclasses import dataclass
from pathlib import Path

import httpx

from varbot.services import wait_until

IMAGE = 16
WORDS = ["zero", "one", "two", "three"]
VOICES = ["en", "en-us"]
# A fine-tune run small enough for a test: seconds per stage on one core.
TINY = {
    "var_epochs": 3,
    "var_batch_size": 16,
    "policy_steps": 48,
    "eval_episodes": 4,
    "held_out_fraction": 0.25,
    "replay_fraction": 0.0,  # the tiny VAR learnt from no corpus: nothing to replay
}


def spoken_commands(folder: Path) -> dict[tuple[str, str], bytes]:
    """Each command word said by each voice (Debian package espeak-ng)."""
    folder.mkdir(parents=True, exist_ok=True)
    wavs = {}
    for word in WORDS:
        for voice in VOICES:
            path = folder / f"{word}-{voice}.wav"
            subprocess.run(["espeak-ng", "-v", voice, "-w", str(path), word], check=True)
            wavs[(word, voice)] = path.read_bytes()
    return wavs


def install_tiny_base_model(
    wavs: dict[tuple[str, str], bytes], build_dir: Path, base_models_dir: Path
) -> Path:
    """A 16 px random VAR and a policy after one tiny PPO update, installed as the kuka base model."""
    import numpy as np
    import torch

    from learning.audio import features_from_bytes
    from learning.rl.ppo import PPOConfig
    from learning.rl.rewards import ClipBank
    from learning.rl.run import train_run
    from learning.var.checkpoint import save_var
    from learning.var.model import VAR, VARConfig
    from worker.base_models import write_base

    torch.manual_seed(0)
    var_path = save_var(VAR(VARConfig(image_size=IMAGE)).eval(), build_dir / "var.pt")
    features = np.stack([features_from_bytes(w) for w in wavs.values()])
    intents = np.array([WORDS.index(word) for word, _ in wavs], dtype=np.int64)
    config = PPOConfig(
        world="kuka", image_size=IMAGE, policy_image_size=IMAGE, max_episode_steps=5, num_envs=2,
        num_steps=12, num_minibatches=2, update_epochs=1, checkpoint_every=1, total_steps=24, seed=1,
    )  # fmt: skip
    policy_dir = build_dir / "policy"
    train_run(config, policy_dir, var_path, goals=ClipBank(features, intents), progress=False)
    record = {"world": "kuka", "image_size": IMAGE, "feature_kind": "speech", "note": "tiny test base model"}
    return write_base("kuka", var_path, policy_dir / "checkpoint.pt", base_models_dir, record)


@dataclass
class Household:
    client: httpx.Client  # signed in as a member of the household, base_url the API's root
    household_id: int
    clip_ids: dict[tuple[str, str], int]

    @classmethod
    def sign_in(
        cls, api_url: str, username: str, password: str, household_id: int, wavs: dict[tuple[str, str], bytes]
    ) -> "Household":
        """Signs in and records every clip of `wavs`."""
        client = httpx.Client(base_url=api_url, timeout=30)
        token = client.post("/api/v1/auth/token", data={"username": username, "password": password})
        assert token.status_code == 200, token.text
        client.headers["Authorization"] = f"Bearer {token.json()['access_token']}"
        clip_ids = {}
        for (word, voice), wav in wavs.items():
            response = client.post(
                "/api/v1/clips", files={"file": (f"{word}.wav", wav, "audio/wav")}, data={"name": word}
            )
            assert response.status_code == 201, response.text
            clip_ids[(word, voice)] = response.json()["id"]
        return cls(client, household_id, clip_ids)

    def new_robot(self, name: str, views: int = 60, kind: str = "kuka-sim") -> int:
        """A simulated robot (a Kuka unless `kind` says) with `views` captured snapshots, every one answered
        as a person would."""
        response = self.client.post("/api/v1/robots", json={"name": name, "kind": kind})
        assert response.status_code == 201, response.text
        robot_id = response.json()["id"]
        response = self.client.post(f"/api/v1/robots/{robot_id}/snapshots:capture", json={"count": views})
        assert response.status_code == 202, response.text

        def captured() -> list[dict] | None:
            found = self.snapshots(robot_id)
            return found if len(found) >= views else None

        snapshots = wait_until(captured, 120, "captured snapshots")
        for snapshot in snapshots:
            self.answer(snapshot)
        return robot_id

    def snapshots(self, robot_id: int) -> list[dict]:
        response = self.client.get("/api/v1/snapshots", params={"robot_id": robot_id, "limit": 500})
        assert response.status_code == 200, response.text
        return response.json()

    def answer(self, snapshot: dict) -> None:
        """Ground truth plays the person: 'is' for the word in view, 'is not' for another word; with nothing
        in view, 'is not' for every word ("nothing I said")."""
        heard = snapshot["meta"].get("sim_heard")  # a real camera's view has no ground truth: nothing heard
        voice = VOICES[snapshot["id"] % 2]
        if heard is None:
            pairs = [(self.clip_ids[(word, voice)], "is_not") for word in WORDS]
        else:
            other = WORDS[(heard + 1 + snapshot["id"] % 3) % 4]
            pairs = [
                (self.clip_ids[(WORDS[heard], voice)], "is"),
                (self.clip_ids[(WORDS[heard], VOICES[1 - VOICES.index(voice)])], "is"),
                (self.clip_ids[(other, voice)], "is_not"),
            ]
        for clip_id, verdict in pairs:
            response = self.client.post(
                "/api/v1/labels", json={"snapshot_id": snapshot["id"], "clip_id": clip_id, "verdict": verdict}
            )
            assert response.status_code == 201, response.text

    def robot_task(self, robot_id: int, ask: str, status: str, body: dict, what: str) -> dict:
        """POST …/robots/{id}/`ask` (202), then follow GET …/robots/{id}/`status`/{task_id} until the task
        ends: what the POST answered, with the task's end as "status"."""
        robot = f"/api/v1/robots/{robot_id}"
        response = self.client.post(f"{robot}/{ask}", json=body)
        assert response.status_code == 202, response.text
        queued = response.json()

        def ended() -> dict | None:
            found = self.client.get(f"{robot}/{status}/{queued['task_id']}").json()
            return found if found["state"] in ("done", "refused", "failed") else None

        return {**queued, "status": wait_until(ended, 180, what, interval=0.5)}

    def start_run(self, robot_id: int, kind: str = "finetune", **params: object) -> dict:
        body = {"robot_id": robot_id, "kind": kind, "preset": "quick", "params": params}
        response = self.client.post("/api/v1/runs", json=body)
        assert response.status_code == 201, response.text
        return response.json()

    def run(self, run_id: int) -> dict:
        return self.client.get(f"/api/v1/runs/{run_id}").json()

    def wait_run(self, run_id: int, timeout: float = 180) -> dict:
        def ended() -> dict | None:
            run = self.run(run_id)
            return run if run["status"] in ("succeeded", "failed", "cancelled") else None

        return wait_until(ended, timeout, f"run {run_id} to end", interval=0.5)

    def versions(self, robot_id: int) -> list[dict]:
        response = self.client.get(f"/api/v1/robots/{robot_id}/models")
        assert response.status_code == 200, response.text
        return response.json()
