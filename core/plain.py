"""Plain data: the form JSON gives back."""

import json
from typing import Any


def as_lists(value: Any) -> Any:
    """`value` with every tuple turned into a list, at any depth: what a JSON round trip gives back, and what
    `torch.load(weights_only=True)` accepts."""
    if isinstance(value, dict):
        return {key: as_lists(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [as_lists(item) for item in value]
    return value


def name_value(text: str) -> tuple[str, Any]:
    """NAME=VALUE as (NAME, VALUE), the value read as JSON where it is one (numbers, true, null, lists), else
    kept as text; refuses text without a name and an "="."""
    name, equals, value = text.partition("=")
    if not equals or not name:
        raise ValueError(f"{text!r}: write it as NAME=VALUE")
    try:
        return name, json.loads(value)
    except json.JSONDecodeError:
        return name, value
