import { startCoaching } from "../coaching.js";
import { pageFailed, pageReady, say, startPage } from "../shell.js";
import { mountSceneControls } from "./scene_controls.js";

const SCENE_URL = "/scene/viser/";
const STARTING_POLL_MS = 1000; // the household's scene is started on demand: asked again until it is up
const STARTING_FOR_MS = 120_000;

async function sceneState() {
  const response = await fetch("/scene/status", { credentials: "same-origin" });
  if (response.status === 401) {
    location.assign("/login?next=/scene");
    return null;
  }
  return response.json();
}

async function main() {
  await startPage("scene");
  const controls = mountSceneControls(); // before the page says it is ready: its handlers are attached
  controls.refresh();
  pageReady(); // the coaching panel shows itself once its controls work
  startCoaching(document.getElementById("coaching")).catch(pageFailed);
  const message = document.getElementById("scene-message");
  const giveUpAt = Date.now() + STARTING_FOR_MS;
  let state = await sceneState();
  while (state && !state.available && state.starting && Date.now() < giveUpAt) {
    say(message, "Starting your household's 3D scene (a few seconds)…");
    await new Promise((resolve) => setTimeout(resolve, STARTING_POLL_MS));
    state = await sceneState();
  }
  if (!state) return;
  if (!state.available) {
    say(message, `The 3D scene is not available: ${state.detail}`, "warn");
    return;
  }
  say(message, "");
  controls.refresh(); // the scene is up: it says which robot it shows
  const frame = document.getElementById("scene");
  frame.src = SCENE_URL;
  frame.hidden = false;
}

main().catch(pageFailed);
