"""The recurrent policy: its state is cleared where an episode starts; the update sees what rollouts saw; the
goal meets the current view (new policies) or only the recurrent core (policies saved before that)."""

from dataclasses import fields
from pathlib import Path

import pytest
import torch

from learning.rl.checkpoints import CHECKPOINT_KIND, load_policy
from learning.rl.policy import Policy, PolicyConfig, downsample_images
from learning.rl.ppo import PPOConfig

T, B = 12, 3


def make_inputs(seed: int = 0) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return {
        "images": torch.randint(0, 256, (T, B, 16, 16, 3), dtype=torch.uint8, generator=g),
        "var_embedding": torch.randn(T, B, 3, generator=g),
        "state": torch.randn(T, B, 2, generator=g),
        "goal": torch.randn(B, 3, generator=g),
    }


@pytest.fixture(params=["image", "core"])
def goal_fusion(request: pytest.FixtureRequest) -> str:
    return request.param


def make_policy(goal_fusion: str = "image") -> Policy:
    torch.manual_seed(0)
    config = PolicyConfig(
        image_size=16, state_dim=2, policy_image_size=16, goal_fusion=goal_fusion, bounded_mean=True
    )
    return Policy(config).eval()


def test_an_episode_start_clears_the_recurrent_state(goal_fusion: str) -> None:
    net, x = make_policy(goal_fusion), make_inputs()
    goal = net.encode_goal(x["goal"])
    busy = torch.randn(B, net.config.hidden)
    with torch.no_grad():
        mean_fresh, value_fresh, h_fresh = net.step(
            x["images"][0], x["var_embedding"][0], x["state"][0], goal, net.initial_state(B), torch.zeros(B)
        )
        mean_reset, value_reset, h_reset = net.step(
            x["images"][0], x["var_embedding"][0], x["state"][0], goal, busy, torch.ones(B)
        )
        mean_busy, _, _ = net.step(
            x["images"][0], x["var_embedding"][0], x["state"][0], goal, busy, torch.zeros(B)
        )
    assert torch.equal(h_fresh, h_reset) and torch.equal(mean_fresh, mean_reset)
    assert torch.equal(value_fresh, value_reset)
    assert not torch.allclose(mean_busy, mean_fresh)  # the state does matter when it is kept


def test_sequence_evaluation_matches_step_by_step_rollout_with_resets_mid_sequence(goal_fusion: str) -> None:
    net, x = make_policy(goal_fusion), make_inputs(1)
    starts = torch.zeros(T, B)
    starts[0] = 1
    starts[5, 0] = 1  # env 0 starts a new episode at t = 5, env 2 at t = 9
    starts[9, 2] = 1
    goal = net.encode_goal(x["goal"])
    hidden = torch.randn(B, net.config.hidden)
    means, values = [], []
    with torch.no_grad():
        h = hidden
        for t in range(T):
            mean, value, h = net.step(
                x["images"][t], x["var_embedding"][t], x["state"][t], goal, h, starts[t]
            )
            means.append(mean)
            values.append(value)
        seq_mean, seq_value, _ = net.evaluate_sequences(
            x["images"], x["var_embedding"], x["state"], goal.expand(T, B, -1), hidden, starts
        )
    assert torch.allclose(seq_mean, torch.stack(means), atol=1e-5)
    assert torch.allclose(seq_value, torch.stack(values), atol=1e-5)


def test_what_happened_before_an_episode_start_does_not_leak_into_the_new_episode(goal_fusion: str) -> None:
    net, x = make_policy(goal_fusion), make_inputs(2)
    starts = torch.zeros(T, B)
    starts[6] = 1
    goal = net.encode_goal(x["goal"]).expand(T, B, -1)
    other = make_inputs(3)
    with torch.no_grad():
        a, _, _ = net.evaluate_sequences(
            x["images"], x["var_embedding"], x["state"], goal, net.initial_state(B), starts
        )
        mixed = {k: v.clone() for k, v in x.items()}
        for key in ("images", "var_embedding", "state"):
            mixed[key][:6] = other[key][:6]  # a different first episode
        b, _, _ = net.evaluate_sequences(
            mixed["images"],
            mixed["var_embedding"],
            mixed["state"],
            goal,
            torch.randn(B, net.config.hidden),
            starts,
        )
    assert torch.allclose(a[6:], b[6:], atol=1e-6)
    assert not torch.allclose(a[:6], b[:6])


def test_downsampling_keeps_uint8_channels_last_images() -> None:
    images = torch.full((2, 32, 32, 3), 200, dtype=torch.uint8)
    small = downsample_images(images, 16)
    assert small.shape == (2, 16, 16, 3) and small.dtype == torch.uint8
    assert (small == 200).all()


def test_new_policies_fuse_the_goal_with_the_current_view() -> None:
    net, x = make_policy("image"), make_inputs(4)
    goal = net.encode_goal(x["goal"][:1]).expand(B, -1)  # one goal for all three views
    core = torch.zeros(B, net.config.hidden)  # same recurrent state: only the current view differs
    with torch.no_grad():
        inputs = net.encode_inputs(x["images"][0], x["var_embedding"][0], x["state"][0])
        mean, _ = net.heads(core, inputs, goal, x["var_embedding"][0])
        late = make_policy("core")
        late_goal = late.encode_goal(x["goal"][:1]).expand(B, -1)
        late_mean, _ = late.heads(core, inputs, late_goal, x["var_embedding"][0])
    assert not torch.allclose(mean[0], mean[1])  # the goal's contribution depends on what is in view
    assert torch.allclose(late_mean[0], late_mean[1])  # "core": only h_t carries the view


def test_a_policy_saved_before_goal_fusion_and_bounded_means_loads_as_it_was_trained(tmp_path: Path) -> None:
    old = make_policy("core")
    newer_fields = ("goal_fusion", "bounded_mean")
    saved_config = {k: v for k, v in old.config.to_dict().items() if k not in newer_fields}
    path = tmp_path / "old.pt"
    torch.save({"kind": CHECKPOINT_KIND, "policy_config": saved_config, "policy": old.state_dict()}, path)
    loaded, _ = load_policy(path)  # strict: the same layers, no fusion MLP
    assert loaded.config.goal_fusion == "core"
    assert loaded.config.bounded_mean is False
    legacy_run = PPOConfig.from_dict({"world": "kuka"})  # its run settings, likewise
    assert (legacy_run.goal_fusion, legacy_run.bounded_mean) == ("core", False)
    assert legacy_run.hard_target_share == 0.0  # and it drew its targets uniformly
    assert (PPOConfig().goal_fusion, PPOConfig().bounded_mean) == ("image", True)  # new runs


def test_the_action_mean_stays_inside_the_action_range_however_large_the_head_output() -> None:
    bounded = make_policy("image")
    with torch.no_grad():
        bounded.actor_mean[-1].bias.fill_(50.0)  # a head that has drifted far to one side
    x = make_inputs(5)
    goal = bounded.encode_goal(x["goal"])
    with torch.no_grad():
        inputs = (x["images"][0], x["var_embedding"][0], x["state"][0])
        mean, _, _ = bounded.step(*inputs, goal, bounded.initial_state(B), torch.ones(B))
    assert mean.abs().max() <= 1.0
    samples = bounded.distribution(mean).sample((2000,)).clamp(-1.0, 1.0)
    assert (samples < 0.99).float().mean() > 0.3  # clipped samples still differ: the noise still explores


def test_with_goal_match_the_fusion_sees_how_well_the_view_matches_the_goal() -> None:
    torch.manual_seed(0)
    shape = {"image_size": 16, "state_dim": 2, "policy_image_size": 16}
    config = PolicyConfig(**shape, goal_fusion="image", bounded_mean=True, goal_match=True)
    net, x = Policy(config).eval(), make_inputs(6)
    goal_embedding = torch.nn.functional.normalize(x["goal"][:1], dim=-1).expand(B, -1)
    goal = net.encode_goal(goal_embedding)
    assert goal.shape == (B, net.goal_feature_size)
    core, inputs = torch.zeros(B, net.config.hidden), torch.zeros(B, net.config.hidden)
    with torch.no_grad():
        on_goal, _ = net.heads(core, inputs, goal, goal_embedding)  # the view embeds as the goal does
        opposite, _ = net.heads(core, inputs, goal, -goal_embedding)
    assert not torch.allclose(on_goal, opposite)  # only the match term differs between the two calls
    with pytest.raises(ValueError, match="goal_match"):
        Policy(PolicyConfig(**shape, goal_fusion="core", goal_match=True))


def test_a_policy_config_built_directly_is_the_network_a_new_run_builds() -> None:
    direct = PolicyConfig(image_size=96, state_dim=2)
    run = PPOConfig()
    network_options = {f.name for f in fields(PolicyConfig)} & {f.name for f in fields(PPOConfig)}
    assert network_options >= {"goal_fusion", "bounded_mean", "goal_match", "policy_image_size"}
    for name in sorted(network_options - {"image_size"}):  # the rendered size is the VAR's, not the net's
        assert getattr(direct, name) == getattr(run, name), name
    assert (direct.goal_fusion, direct.bounded_mean) == ("image", True)
