"""Domain-shift knobs: make a world look like an unseen room, or draw a room per episode from training ranges.

The description is the household's (`core.rooms`), so that the API can check a robot's room without
importing the simulator; the worlds render it.
"""

from core.rooms import DomainShift, RoomRanges, sample_room

__all__ = ["DomainShift", "RoomRanges", "room_and_ranges", "sample_room"]


def room_and_ranges(domain: object) -> tuple[DomainShift, RoomRanges | None]:
    """A world's `domain` argument read: one room (a DomainShift; None: the training room), or RoomRanges,
    which start in the training room and draw a new room at every reset."""
    if domain is None or isinstance(domain, DomainShift):
        return domain or DomainShift(), None
    if isinstance(domain, RoomRanges):
        return DomainShift(), domain
    raise TypeError(
        f"domain must be a DomainShift (one room), RoomRanges (a room per episode) or None, "
        f"got {type(domain).__name__}"
    )
