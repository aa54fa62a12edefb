// Commands as a household thinks of them: recordings grouped by what was said, and what each robot can be asked.

/** The command a clip records: its name ignoring case and surrounding spaces, or the clip alone
 * (the same rule as core/labels.py command_key). */
export function commandKey(clip) {
  const name = (clip.name || "").trim();
  return name ? `name:${name.toLocaleLowerCase()}` : `clip:${clip.id}`;
}

const firstId = (command) => Math.min(...command.clips.map((clip) => clip.id));

/** The household's commands, most recorded first, then in the order they were first recorded: [{key, name, clips: [clip], bySpeaker: Map(id → count)}]. */
export function groupCommands(clips) {
  const commands = new Map();
  for (const clip of clips) {
    const key = commandKey(clip);
    if (!commands.has(key)) commands.set(key, { key, name: clip.name ? clip.name.trim() : `recording ${clip.id} (no name)`, named: Boolean(clip.name), clips: [], bySpeaker: new Map() });
    const command = commands.get(key);
    command.clips.push(clip);
    command.bySpeaker.set(clip.speaker_id, (command.bySpeaker.get(clip.speaker_id) || 0) + 1);
  }
  return [...commands.values()].sort((a, b) => b.clips.length - a.clips.length || firstId(a) - firstId(b));
}

// What each kind of robot can be sent to (sim/blocks.py INTENT_NAMES, sim/turtlebot_arena.py OBJECTS).
const BLOCKS = "four red blocks in a row on a table; each command should name one of them, counted from the left as the robot's camera sees them (for example “zero”, “one”, “two”, “three”)";
const TARGETS = {
  "kuka-sim": { count: 4, what: BLOCKS },
  "kinova-sim": { count: 4, what: BLOCKS },
  "kinova-real": { count: 4, what: BLOCKS },
  "turtlebot-sim": { count: 4, what: "four objects on the floor: a red cube, a green sphere, a blue cone and a yellow cylinder; each command should name one of them" },
};

/** A sentence on what the robot knows, e.g. "kitchen arm knows 4 targets: …", or "" for an unknown kind. */
export function targetsSentence(robot) {
  const targets = robot && TARGETS[robot.kind];
  return targets ? `${robot.name} knows ${targets.count} targets: ${targets.what}.` : "";
}

export function targetCount(robot) {
  return (robot && TARGETS[robot.kind] && TARGETS[robot.kind].count) || 0;
}

/** "2 recordings (Alice 1, Bob 1)" */
export function describeCounts(total, noun, bySpeaker, names) {
  const people = [...bySpeaker.entries()].map(([id, n]) => `${names.get(id) || `member ${id}`} ${n}`).join(", ");
  return `${total} ${noun}${total === 1 ? "" : "s"}${people ? ` (${people})` : ""}`;
}
