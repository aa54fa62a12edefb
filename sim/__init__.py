"""Simulated worlds (PyBullet, Gymnasium) and robot drivers. Importing `sim` registers the env ids."""

from gymnasium.envs.registration import register, registry, spec

KUKA_BLOCKS = "varbot/KukaBlocks-v0"
KINOVA_BLOCKS = "varbot/KinovaBlocks-v0"
TURTLEBOT_ARENA = "varbot/TurtleBotArena-v0"
WORLDS = {"kuka": KUKA_BLOCKS, "kinova": KINOVA_BLOCKS, "turtlebot": TURTLEBOT_ARENA}

_ENTRY_POINTS = {
    KUKA_BLOCKS: "sim.kuka_blocks:KukaBlocksEnv",
    KINOVA_BLOCKS: "sim.kinova_blocks:KinovaBlocksEnv",
    TURTLEBOT_ARENA: "sim.turtlebot_arena:TurtleBotArenaEnv",
}

for _env_id, _entry_point in _ENTRY_POINTS.items():
    if _env_id not in registry:  # entry points are strings: nothing heavy is imported until make()
        register(id=_env_id, entry_point=_entry_point)


def world_id(world: str) -> str:
    """The Gymnasium id of a world name ("kuka", "kinova", "turtlebot")."""
    try:
        return WORLDS[world]
    except KeyError:
        raise ValueError(f"unknown world {world!r}: choose one of {', '.join(WORLDS)}") from None


def world_class(world: str) -> type:
    """The env class of a world, without making one: what a world can do is checked before rendering."""
    from gymnasium.envs.registration import load_env_creator

    return load_env_creator(spec(world_id(world)).entry_point)


def has_blocks(world: str) -> bool:
    """Whether a world has blocks to place the gripper around (the arm worlds, not the TurtleBot's arena)."""
    return hasattr(world_class(world), "slot_position")
