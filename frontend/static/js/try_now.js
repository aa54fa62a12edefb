// "Try it now": what a member just said goes to the household's scene, where the robot carries it out; the clip
// is not kept. The page says "Starting…" at once, then the scene's progress and outcome in the household's words.
import { api } from "./api.js";
import { say } from "./shell.js";

const POLL_MS = 400;
const QUIET_FOR_MS = 180_000; // no end by then: the scene went away

const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

const KINDS = { done: "ok", refused: "warn", failed: "error" };

const MIN_SECONDS = 0.3; // as the API's clips

/** While the member talks (`open`: the microphone is listening): never the last try's outcome. */
export function listening(message, open = true) {
  message.dataset.tryState = "listening";
  say(message, open ? "Listening… let go and the robot carries it out." : "Opening the microphone…");
}

/** A take too short to be a command is not sent: say how to do it instead. */
export function tooShort(take, message) {
  if (take.seconds >= MIN_SECONDS) return false;
  message.dataset.tryState = "failed";
  say(message, `That was only ${take.seconds.toFixed(1)} s: hold the button (or key) while you say the whole command.`, "warn");
  return true;
}

/** The try ends before it reached the robot (no microphone, a refused upload…): say why. */
export function tryFailed(message, text) {
  message.dataset.tryState = "failed";
  say(message, text, "error");
}

function show(message, status) {
  message.dataset.tryState = status.state;
  say(message, status.message, KINDS[status.state] || "");
}

/** Sends `wav` to the scene for `robotId` (null: the scene's own) and follows it to its end; the last status. */
export async function tryItNow(wav, robotId, message) {
  message.dataset.tryState = "sending";
  say(message, "Starting… sending what you said to the robot.");
  const form = new FormData();
  form.append("file", wav, "try-it-now.wav");
  if (robotId) form.append("robot_id", String(robotId));
  let status;
  try {
    status = await api("/scene/tries", { method: "POST", form });
  } catch (error) {
    tryFailed(message, `The robot could not try it: ${error.message}`);
    return null;
  }
  const giveUpAt = Date.now() + QUIET_FOR_MS;
  show(message, status);
  while (!status.finished && Date.now() < giveUpAt) {
    await sleep(POLL_MS);
    try {
      status = await api(`/scene/tries/${status.try_id}`);
    } catch (error) {
      tryFailed(message, `Lost track of the robot's try: ${error.message}`);
      return null;
    }
    show(message, status);
  }
  if (!status.finished) tryFailed(message, "The scene went quiet before the robot finished. Open the Scene page to see it, then try again.");
  return status;
}
