"""bench/told_position.py: the policy is handed its position shifted by (dx, dy), and nothing else changes."""

import pytest
import told_position as bench
import torch

from learning.rl.policy import Policy, PolicyConfig


def test_the_policy_is_told_its_x_and_y_shifted_and_its_heading_as_it_is() -> None:
    torch.manual_seed(0)
    policy = Policy(PolicyConfig(image_size=16, state_dim=4, policy_image_size=16)).eval()
    images = torch.randint(0, 255, (2, 16, 16, 3), dtype=torch.uint8)
    var_embedding, goal = torch.randn(2, 3), policy.encode_goal(torch.randn(2, 3))
    state = torch.tensor([[0.5, -0.2, 0.6, 0.8], [0.4, 0.1, 0.0, 1.0]])
    hidden, start = policy.initial_state(2), torch.ones(2)
    with torch.inference_mode():
        expected = policy.step(
            images, var_embedding, state + torch.tensor([0.03, -0.01, 0, 0]), goal, hidden, start
        )
        bench.told_off_by(policy, 0.03, -0.01)
        told = policy.step(images, var_embedding, state, goal, hidden, start)
    for mine, theirs in zip(told, expected, strict=True):
        torch.testing.assert_close(mine, theirs)
    assert torch.equal(state[0], torch.tensor([0.5, -0.2, 0.6, 0.8])), "the caller's state is left alone"


def test_offsets_are_dx_dy_pairs_and_anything_else_says_how_to_write_them() -> None:
    assert bench.offsets("0/0,0.03/0") == [(0.0, 0.0), (0.03, 0.0)]
    with pytest.raises(SystemExit, match="dx/dy pairs in metres"):
        bench.offsets("0.03")
