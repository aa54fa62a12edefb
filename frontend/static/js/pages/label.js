import { api } from "../api.js";
import { element, pageFailed, pageReady, robotPicker, say, startPage } from "../shell.js";
import { attemptMode } from "./label_attempts.js";

const $ = (id) => document.getElementById(id);
const message = $("label-message");
const POLL_MS = 2000;
const SKIP_RETRIES = 6;

let picker;
let current = null; // {snapshot, clip}
const skipped = new Set(); // "snapshot:clip" keys skipped during this visit
const history = []; // {kind: "label" | "skip", pair, labelId}
let sessionCount = 0;
let queue = Promise.resolve(); // answers are applied one after another, however fast the keys come
let waitingForViews = null;
let attempts = null; // the "did it do what I said?" mode (label_attempts.js)
let judgingAttempts = false;

const pairKey = (pair) => `${pair.snapshot.id}:${pair.clip.id}`;

function robotQuery() {
  const robot = picker && picker.current();
  return robot ? `?robot_id=${robot.id}` : "";
}

async function fetchNext() {
  let next = await api(`/labels/next${robotQuery()}`);
  for (let i = 0; next.snapshot && skipped.has(pairKey(next)) && i < SKIP_RETRIES; i++) {
    next = await api(`/labels/next${robotQuery()}`);
  }
  return next;
}

function show(pair, note) {
  current = pair && pair.snapshot ? pair : null;
  document.body.dataset.pair = current ? pairKey(current) : "";
  const enabled = Boolean(current);
  for (const id of ["yes", "no", "skip", "replay"]) $(id).disabled = !enabled;
  $("undo").disabled = history.length === 0;
  $("camera").hidden = !enabled;
  $("dry").hidden = enabled;
  if (!enabled) {
    $("clip").removeAttribute("src");
    $("clip-title").textContent = "";
    dryQueue(note || (pair && pair.message) || "");
    return;
  }
  $("camera").src = `/api/v1/snapshots/${current.snapshot.id}/image`;
  $("camera").alt = `Robot camera view ${current.snapshot.id}`;
  $("clip-title").textContent = `Command: ${current.clip.name || `recording ${current.clip.id}`}`;
  const audio = $("clip");
  audio.src = `/api/v1/clips/${current.clip.id}/audio`;
  play();
  if (note) say(message, note);
}

function play() {
  const audio = $("clip");
  audio.currentTime = 0;
  audio.play().catch(() => say(message, "Press Replay (R) to hear the command."));
}

/** Why there is nothing to ask, and what to do next. */
async function dryQueue(serverMessage) {
  const robot = picker.current();
  const [clips, views] = await Promise.all([api("/clips?limit=1"), robot ? api(`/snapshots?robot_id=${robot.id}&limit=1`) : []]);
  const noClips = clips.length === 0;
  $("go-admin").hidden = Boolean(robot);
  $("go-record").hidden = !robot || !noClips;
  $("capture").hidden = !robot || noClips || !robot.kind.endsWith("-sim");
  $("dry-message").textContent = !robot
    ? "No robot yet: an admin of your household adds one on the Admin page."
    : noClips
      ? "Nothing to ask yet: record a command first, on the Record page."
      : waitingForViews
        ? "Rendering new camera views… they appear here in a moment."
        : views.length === 0
          ? `No camera views of ${robot.name} yet: capture some with the button below${robot.kind.endsWith("-sim") ? "" : " (a real robot sends its own frames)"}.`
          : "Every pair is answered. Capture more camera views to keep going.";
}

async function advance(note) {
  show(await fetchNext(), note);
  refreshCounters();
}

async function refreshCounters() {
  const stats = await api(`/triplets/stats${robotQuery()}`);
  $("answered").textContent = stats.labels;
  $("triplets").textContent = stats.triplets;
  $("session-count").textContent = sessionCount;
  const line = (count) => element("li", {}, element("strong", { text: String(count.triplets) }), ` ${count.name}`);
  $("per-command").replaceChildren(...stats.per_command.map(line));
  $("per-member").replaceChildren(...stats.per_member.map(line));
  $("per-counts").hidden = stats.triplets === 0;
}

async function answer(verdict) {
  if (!current) return;
  const pair = current;
  current = null;
  try {
    const label = await api("/labels", { method: "POST", json: { snapshot_id: pair.snapshot.id, clip_id: pair.clip.id, verdict } });
    history.push({ kind: "label", pair, labelId: label.id });
    sessionCount += 1;
    await advance(verdict === "is" ? "Saved: it is." : "Saved: it is not.");
  } catch (error) {
    say(message, error.message, "error");
    if (error.status === 409) await advance();
    else show(pair);
  }
}

async function skip() {
  if (!current) return;
  skipped.add(pairKey(current));
  history.push({ kind: "skip", pair: current });
  await advance("Skipped.");
}

async function undo() {
  const last = history.pop();
  if (!last) return say(message, "Nothing to undo.");
  if (last.kind === "label") {
    try {
      await api(`/labels/${last.labelId}`, { method: "DELETE" });
      sessionCount -= 1;
    } catch (error) {
      history.push(last);
      return say(message, `Could not undo: ${error.message}`, "error");
    }
  } else {
    skipped.delete(pairKey(last.pair));
  }
  show(last.pair, "Undone: answer this pair again.");
  refreshCounters();
}

async function captureMore() {
  const robot = picker.current();
  if (!robot) return;
  $("capture").disabled = true;
  try {
    await api(`/robots/${robot.id}/snapshots:capture`, { method: "POST", json: { count: 20 } });
    waitingForViews = Date.now();
    say(message, "Asked the robot for 20 new camera views.", "ok");
    dryQueue("");
    pollForViews();
  } catch (error) {
    say(message, error.message, "error");
  } finally {
    $("capture").disabled = false;
  }
}

async function pollForViews() {
  while (waitingForViews && Date.now() - waitingForViews < 120_000) {
    await new Promise((resolve) => setTimeout(resolve, POLL_MS));
    const next = await fetchNext();
    if (next.snapshot) {
      waitingForViews = null;
      show(next, "New views are here.");
      return;
    }
  }
  if (waitingForViews) {
    waitingForViews = null;
    say(message, "No new views arrived. Is the robot worker running? An admin can check on the Admin page.", "warn");
    dryQueue("");
  }
}

function enqueue(action) {
  queue = queue.then(action).catch((error) => say(message, error.message, "error"));
}

const KEYS = { y: () => answer("is"), n: () => answer("is_not"), s: skip, z: undo, r: async () => play() };

/** Switch between "is it this command?" (pairs) and "did it do what I said?" (attempts). */
function setMode(toAttempts) {
  judgingAttempts = toAttempts;
  document.body.dataset.mode = toAttempts ? "attempts" : "pairs";
  $("mode-pairs").setAttribute("aria-pressed", String(!toAttempts));
  $("mode-attempts").setAttribute("aria-pressed", String(toAttempts));
  $("pair-view").hidden = toAttempts;
  $("attempt-view").hidden = !toAttempts;
  if (toAttempts) {
    $("clip").pause();
    attempts.start();
  } else {
    attempts.stop();
    enqueue(() => advance());
  }
}

async function main() {
  await startPage("label");
  picker = await robotPicker($("robot"), () => (judgingAttempts ? attempts.start() : enqueue(() => advance())));
  attempts = attemptMode(() => picker.current());
  $("mode-pairs").addEventListener("click", () => setMode(false));
  $("mode-attempts").addEventListener("click", () => setMode(true));
  $("yes").addEventListener("click", () => enqueue(() => answer("is")));
  $("no").addEventListener("click", () => enqueue(() => answer("is_not")));
  $("skip").addEventListener("click", () => enqueue(skip));
  $("undo").addEventListener("click", () => enqueue(undo));
  $("replay").addEventListener("click", play);
  $("capture").addEventListener("click", captureMore);
  document.addEventListener("keydown", (event) => {
    if (event.ctrlKey || event.metaKey || event.altKey || event.repeat) return;
    const tag = event.target.tagName;
    if (tag === "INPUT" || tag === "SELECT" || tag === "TEXTAREA") return;
    const name = event.key.toLowerCase();
    if (name === "m") {
      event.preventDefault();
      return setMode(!judgingAttempts);
    }
    if (judgingAttempts) {
      if (attempts.key(name)) event.preventDefault();
      return;
    }
    const action = KEYS[name];
    if (!action) return;
    event.preventDefault();
    if (event.key.toLowerCase() === "r") play();
    else enqueue(action);
  });
  document.body.dataset.mode = "pairs";
  pageReady();
  if (location.hash === "#attempts") return setMode(true); // /label#attempts opens "did it do what I said?"
  await advance();
}

main().catch(pageFailed);
