// The Scene page's own controls beside the 3D view: which of the household's robots the scene shows, and
// "try it now" (hold the button or T, say a command, let go: the robot in the scene carries it out, nothing is kept).
import { api } from "../api.js";
import { Recorder, onHold } from "../recorder.js";
import { listening, tooShort, tryFailed, tryItNow } from "../try_now.js";
import { element, say } from "../shell.js";

const $ = (id) => document.getElementById(id);
const LATEST = ""; // the select's value for "the robot whose model was made active last"

async function offerRobots() {
  const [robots, shown] = await Promise.all([api("/robots"), api("/scene/robot")]);
  const choice = $("scene-robot");
  choice.replaceChildren(
    element("option", { value: LATEST, text: "the robot with the newest model" }),
    ...robots.map((robot) => element("option", { value: String(robot.id), text: `${robot.name} (${robot.kind})` })),
  );
  if (shown.robot_id !== null && robots.some((r) => r.id === shown.robot_id)) choice.value = String(shown.robot_id);
}

async function showRobot() {
  const value = $("scene-robot").value;
  if (value === LATEST) return;
  try {
    await api("/scene/robot", { method: "PUT", json: { robot_id: Number(value) } });
    say($("scene-try-message"), "Switching the scene to that robot…");
  } catch (error) {
    say($("scene-try-message"), `Could not show that robot: ${error.message}`, "error");
  }
}

function holdToTalk(button, message) {
  const recorder = new Recorder(() => {});
  let holding = false;
  const begin = async () => {
    if (holding) return;
    holding = true;
    listening(message, false);
    try {
      await recorder.start();
    } catch (error) {
      holding = false;
      tryFailed(message, error.message);
      return;
    }
    if (!holding) return send(); // let go while the microphone was still starting: too short
    button.setAttribute("aria-pressed", "true");
    listening(message);
  };
  const finish = () => {
    if (!holding) return;
    holding = false;
    if (recorder.recording) send();
  };
  const send = () => {
    button.setAttribute("aria-pressed", "false");
    const take = recorder.stop();
    if (tooShort(take, message)) return;
    const robot = $("scene-robot").value;
    tryItNow(take.wav, robot === LATEST ? null : Number(robot), message);
  };
  onHold(button, begin, finish);
  const isT = (event) => event.key.toLowerCase() === "t" && !["INPUT", "SELECT", "TEXTAREA"].includes(event.target.tagName);
  document.addEventListener("keydown", (event) => isT(event) && !event.repeat && begin());
  document.addEventListener("keyup", (event) => isT(event) && finish());
}

/** Attaches the controls' handlers (before the page says it is ready); the choices fill in afterwards. */
export function mountSceneControls() {
  holdToTalk($("scene-talk"), $("scene-try-message"));
  $("scene-robot").addEventListener("change", showRobot);
  $("scene-talk").disabled = false;
  return { refresh: () => offerRobots().catch((error) => say($("scene-try-message"), error.message, "error")) };
}
