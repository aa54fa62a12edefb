"""Policy checkpoints carry a format version: today's and the unversioned older ones load (acting exactly as
they did when saved), a newer one is refused with a message that says what to do."""

from pathlib import Path

import pytest
import torch

from core.paths import REPO_ROOT
from learning.rl.checkpoints import (
    CHECKPOINT_KIND,
    FORMAT_VERSION,
    LEGACY_RUN_OPTIONS,
    compact_policy_checkpoint,
    load_policy,
    read_policy_checkpoint,
)
from learning.rl.policy import Policy, PolicyConfig
from learning.rl.ppo import PPOConfig

SHIPPED_KUKA_POLICY = REPO_ROOT / "worker" / "base_models" / "kuka" / "policy.pt"
# the Kuka policy shipped until 2026-12-02, written before checkpoints had a format version
UNVERSIONED_KUKA_POLICY = Path(__file__).parent / "checkpoints" / "unversioned_kuka_policy.pt"


def fixed_inputs(image_size: int, batch: int = 4) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    unit = lambda rows: torch.nn.functional.normalize(torch.randn(rows, 3, generator=g), dim=-1)  # noqa: E731
    goal = unit(batch)
    return {
        "goal": goal,
        "images": torch.randint(0, 256, (batch, image_size, image_size, 3), dtype=torch.uint8, generator=g),
        "var_embedding": unit(batch),
        "state": torch.rand(batch, 2, generator=g),
    }


def act(policy: Policy, x: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    with torch.no_grad():
        goal = policy.encode_goal(x["goal"])
        batch, view = len(goal), policy.view_of(x["images"])
        mean, value, _ = policy.step(
            view, x["var_embedding"], x["state"], goal, policy.initial_state(batch), torch.ones(batch)
        )
    return mean, value


def test_a_checkpoint_of_a_newer_format_is_refused_with_a_clear_message(tmp_path: Path) -> None:
    policy = Policy(PolicyConfig(image_size=16, state_dim=2, policy_image_size=16))
    path = tmp_path / "future.pt"
    payload = {
        "kind": CHECKPOINT_KIND,
        "format_version": FORMAT_VERSION + 1,
        "policy_config": policy.config.to_dict(),
        "policy": policy.state_dict(),
    }
    torch.save(payload, path)
    message = rf"format {FORMAT_VERSION + 1}, but this code reads formats 1 to {FORMAT_VERSION}.*newer varbot"
    with pytest.raises(ValueError, match=message):
        load_policy(path)


def test_a_file_that_is_not_a_policy_checkpoint_is_refused(tmp_path: Path) -> None:
    torch.save({"kind": "varbot-var"}, tmp_path / "var.pt")
    with pytest.raises(ValueError, match="not a varbot policy checkpoint"):
        read_policy_checkpoint(tmp_path / "var.pt")


def test_an_unversioned_checkpoint_from_before_the_newer_options_loads_as_it_was_trained(
    tmp_path: Path,
) -> None:
    torch.manual_seed(0)
    old = Policy(PolicyConfig(image_size=16, state_dim=2, policy_image_size=16, goal_fusion="core",
                              bounded_mean=False))  # fmt: skip
    saved_config = {k: v for k, v in old.config.to_dict().items() if k not in LEGACY_RUN_OPTIONS}
    path = tmp_path / "old.pt"
    stats = {"returns": [1.0, 2.0], "lengths": [5, 5], "successes": [0.0, 1.0]}  # intents not logged yet
    payload = {"kind": CHECKPOINT_KIND, "config": {"world": "kuka", "seed": 4}, "policy_config": saved_config,
               "policy": old.state_dict(), "stats": stats}  # fmt: skip
    torch.save(payload, path)
    x = fixed_inputs(16)
    loaded, upgraded = load_policy(path)
    assert upgraded["format_version"] == FORMAT_VERSION
    assert (loaded.config.goal_fusion, loaded.config.bounded_mean, loaded.config.goal_match) == (
        "core", False, False,
    )  # fmt: skip
    for ours, theirs in zip(act(loaded, x), act(old.eval(), x), strict=True):
        assert torch.equal(ours, theirs)
    run = PPOConfig.from_dict(upgraded["config"])
    assert (run.world, run.seed, run.goal_fusion, run.hard_target_share) == ("kuka", 4, "core", 0.0)
    assert upgraded["stats"]["intents"] == [-1, -1]


def test_the_old_shipped_kuka_policy_loads_and_acts_as_before_checkpoints_had_versions() -> None:
    policy, payload = load_policy(UNVERSIONED_KUKA_POLICY)
    assert "format_version" not in torch.load(UNVERSIONED_KUKA_POLICY, map_location="cpu", weights_only=False)
    assert (policy.config.goal_fusion, policy.config.bounded_mean) == ("image", True)
    mean, value = act(policy, fixed_inputs(policy.config.policy_image_size))
    # what the code before this format version computed for the same inputs (`learning/rl/ppo.py` @ 062d7cb)
    expected_mean = [
        [-0.9998645186424255, -0.7446476221084595],
        [-0.9988415241241455, 0.983357310295105],
        [-0.9974455237388611, 0.4022662341594696],
        [-0.9990378022193909, -0.9998857975006104],
    ]
    expected_value = [3.776144504547119, 3.9241979122161865, 3.7838869094848633, 3.070319652557373]
    torch.testing.assert_close(mean, torch.tensor(expected_mean), rtol=0, atol=1e-6)
    torch.testing.assert_close(value, torch.tensor(expected_value), rtol=0, atol=1e-5)
    assert PPOConfig.from_dict(payload["config"]).goal_fusion == "image"


def test_a_compacted_policy_keeps_the_current_format_and_acts_the_same(tmp_path: Path) -> None:
    compact = compact_policy_checkpoint(SHIPPED_KUKA_POLICY, tmp_path / "policy.pt")
    stored = torch.load(compact, map_location="cpu", weights_only=False)
    assert stored["format_version"] == FORMAT_VERSION, "a compacted file says which format it is"
    assert not {"optimizer", "rng", "stats"} & set(stored), "only what acting and improving need"
    inputs = fixed_inputs(load_policy(SHIPPED_KUKA_POLICY)[0].config.image_size)  # as rendered
    for before, after in zip(
        act(load_policy(SHIPPED_KUKA_POLICY)[0], inputs), act(load_policy(compact)[0], inputs), strict=True
    ):
        assert torch.equal(before, after)
