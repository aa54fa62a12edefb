"""The triplet loss of the paper and the matching accuracy (is the positive closer than the negative?)."""

import torch


def squared_distances(anchor: torch.Tensor, positive: torch.Tensor, negative: torch.Tensor):
    """‖a − p‖² and ‖a − n‖², row by row."""
    return (anchor - positive).pow(2).sum(dim=1), (anchor - negative).pow(2).sum(dim=1)


def triplet_losses(
    anchor: torch.Tensor, positive: torch.Tensor, negative: torch.Tensor, margin: float = 1.0
) -> torch.Tensor:
    """max(0, ‖v_i − v+‖² − ‖v_i − v−‖² + α) per triplet."""
    to_positive, to_negative = squared_distances(anchor, positive, negative)
    return torch.relu(to_positive - to_negative + margin)


def triplet_loss(
    anchor: torch.Tensor, positive: torch.Tensor, negative: torch.Tensor, margin: float = 1.0
) -> torch.Tensor:
    """The batch mean of `triplet_losses`."""
    return triplet_losses(anchor, positive, negative, margin).mean()


def triplet_correct(anchor: torch.Tensor, positive: torch.Tensor, negative: torch.Tensor) -> torch.Tensor:
    """Boolean per triplet: ‖v_i − v+‖ < ‖v_i − v−‖."""
    to_positive, to_negative = squared_distances(anchor, positive, negative)
    return to_positive < to_negative
