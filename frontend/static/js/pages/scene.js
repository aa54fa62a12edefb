import { pageFailed, pageReady, say, startPage } from "../shell.js";

const SCENE_URL = "/scene/viser/";

async function main() {
  await startPage("scene");
  pageReady(); // the scene page has no controls of its own
  const message = document.getElementById("scene-message");
  const response = await fetch("/scene/status", { credentials: "same-origin" });
  if (response.status === 401) return location.assign("/login?next=/scene");
  const state = await response.json();
  if (!state.available) {
    say(message, `The 3D scene is not available: ${state.detail}`, "warn");
    return;
  }
  const frame = document.getElementById("scene");
  frame.src = SCENE_URL;
  frame.hidden = false;
}

main().catch(pageFailed);
