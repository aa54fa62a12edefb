"""Plain data: the form JSON gives back."""

from typing import Any


def as_lists(value: Any) -> Any:
    """`value` with every tuple turned into a list, at any depth: what a JSON round trip gives back, and what
    `torch.load(weights_only=True)` accepts."""
    if isinstance(value, dict):
        return {key: as_lists(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [as_lists(item) for item in value]
    return value
