"""Where the policy's goal comes from: the VAR's goal embedding (the method) or the baselines' own encoder of
the clip's MFCC. Either way the update sees the goal features the rollout acted on."""

import numpy as np
import torch

from learning.rl.goals import EpisodeGoals, LearnedGoal, VarGoal, goal_source
from learning.rl.policy import Policy, PolicyConfig
from learning.rl.rewards import ClipBank


def bank() -> ClipBank:
    rng = np.random.default_rng(0)
    clips = ClipBank(rng.normal(size=(4, 100, 40)).astype(np.float32), np.array([0, 0, 1, 1]))
    embeddings = torch.from_numpy(rng.normal(size=(4, 3))).float()
    clips.embeddings = torch.nn.functional.normalize(embeddings, dim=-1)
    return clips


def policy(goal_encoder: str) -> Policy:
    torch.manual_seed(0)
    var_dim = 3 if goal_encoder == "var" else 0
    config = PolicyConfig(image_size=16, state_dim=2, policy_image_size=16, var_dim=var_dim,
                          goal_encoder=goal_encoder)  # fmt: skip
    return Policy(config).eval()


def test_the_var_goal_is_the_clips_embedding_and_the_rollout_stores_it() -> None:
    clips = bank()
    source = goal_source("var", clips)
    assert isinstance(source, VarGoal) and source.input_shape == (3,)
    picked = np.array([2, 0])
    inputs = source.inputs(picked)
    assert torch.equal(inputs, clips.embeddings[[2, 0]])
    assert torch.equal(source.stored(picked, inputs), inputs)
    assert source.allocate(5, 2).shape == (5, 2, 3)
    net = policy("var")
    with torch.no_grad():
        assert torch.equal(source.features(net, inputs), net.encode_goal(clips.embeddings[[2, 0]]))


def test_the_learned_goal_stores_clip_indices_and_encodes_each_distinct_clip_once_in_the_update() -> None:
    clips = bank()
    source = goal_source("learned", clips)
    assert isinstance(source, LearnedGoal) and source.input_shape == (100, 40)
    picked = np.array([3, 1])
    assert torch.equal(source.inputs(picked), torch.from_numpy(clips.features[[3, 1]]))
    stored = source.allocate(3, 2)
    assert stored.dtype == torch.int64 and stored.shape == (3, 2)
    for t in range(3):
        stored[t] = source.stored(picked, source.inputs(picked))
    net = policy("learned")
    with torch.no_grad():
        features = source.features(net, stored)
        one_by_one = net.encode_goal(torch.from_numpy(clips.features[[3, 1]]))
    assert features.shape == (3, 2, net.goal_feature_size)
    for t in range(3):
        torch.testing.assert_close(features[t], one_by_one, rtol=0, atol=1e-6)


def test_each_new_episode_draws_a_goal_clip_of_its_target_and_encodes_it_once() -> None:
    clips, net = bank(), policy("var")
    goals = EpisodeGoals(goal_source("var", clips), clips, num_envs=3, feature_size=net.goal_feature_size)
    with torch.no_grad():
        goals.draw(np.array([0, 2]), np.array([1, 0]), np.random.default_rng(0), net)
        assert clips.intents[goals.clip[0]] == 1 and clips.intents[goals.clip[2]] == 0
        assert torch.equal(goals.features[1], torch.zeros(net.goal_feature_size))  # env 1 not started yet
        assert torch.equal(goals.features[[0, 2]], net.encode_goal(clips.embeddings[goals.clip[[0, 2]]]))
        assert torch.equal(goals.stored(slice(0, 1)), clips.embeddings[goals.clip[[0]]])
