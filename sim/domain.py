"""Domain-shift knobs: make a world look like an unseen room (used to show fine-tuning).

The description is the household's (`core.rooms`), so that the API can check a robot's room without
importing the simulator; the worlds render it.
"""

from core.rooms import DomainShift

__all__ = ["DomainShift"]
