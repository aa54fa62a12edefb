// The Label page's "did it do what I said?" mode: the robot's attempt at one of the household's commands
// (its final view large, a short replay cycling beside it), the command plays, and the member answers
// Y (yes, that's it) or N, then a number key for the command the view shows instead, or 0 for nothing.
// Each answer becomes ordinary is / is-not labels on the final view (POST /attempts/{id}/answer); undo
// deletes the labels it created.
import { api } from "../api.js";
import { element, say } from "../shell.js";

const $ = (id) => document.getElementById(id);
const REPLAY_MS = 350;
const POLL_MS = 1500;
const ASK_COUNT = 8;

export function attemptMode(currentRobot) {
  const message = $("attempt-message");
  let current = null; // the NextAttempt being judged
  let choosing = false; // after N: waiting for what the view shows instead
  const skipped = [];
  const history = []; // {kind: "answer" | "skip", attempt, labelIds}
  let replayTimer = null;
  let queue = Promise.resolve();

  const robotParam = () => (currentRobot() ? `robot_id=${currentRobot().id}` : "");
  const nextUrl = () => `/attempts/next?${[robotParam(), ...skipped.map((id) => `skip=${id}`)].filter(Boolean).join("&")}`;

  function setChoosing(on) {
    choosing = on && Boolean(current);
    $("attempt-instead").hidden = !choosing;
    $("attempt-answers").hidden = choosing;
    document.body.dataset.attemptStage = choosing ? "instead" : "ask";
  }

  function cycleReplay(frames) {
    clearInterval(replayTimer);
    const image = $("attempt-replay");
    $("attempt-replay-row").hidden = frames.length === 0;
    if (!frames.length) return;
    let index = 0;
    image.src = frames[0];
    replayTimer = setInterval(() => {
      index = (index + 1) % frames.length;
      image.src = frames[index];
    }, REPLAY_MS);
  }

  function play() {
    const audio = $("attempt-clip");
    if (!audio.src) return;
    audio.currentTime = 0;
    audio.play().catch(() => say(message, "Press Replay (R) to hear the command."));
  }

  function show(next, note) {
    current = next && next.snapshot ? next : null;
    document.body.dataset.attempt = current ? String(current.snapshot.id) : "";
    for (const id of ["attempt-yes", "attempt-no", "attempt-skip", "attempt-replay-sound"]) $(id).disabled = !current;
    $("attempt-undo").disabled = history.length === 0;
    $("attempt-final").hidden = !current;
    $("attempt-dry").hidden = Boolean(current);
    setChoosing(false);
    if (!current) {
      cycleReplay([]);
      $("attempt-clip").removeAttribute("src");
      $("attempt-command").textContent = "";
      $("attempt-dry-message").textContent = currentRobot()
        ? (next && next.message) || "No attempts left to judge."
        : "No robot yet: an admin of your household adds one on the Admin page.";
      $("attempt-ask").hidden = !currentRobot() || !currentRobot().kind.endsWith("-sim");
      if (note) say(message, note);
      return;
    }
    $("attempt-final").src = `/api/v1/snapshots/${current.snapshot.id}/image`;
    $("attempt-command").textContent = `The robot was asked: “${current.asked.name}”`;
    $("attempt-clip").src = `/api/v1/clips/${current.clip_id}/audio`;
    const choices = current.others.slice(0, 9).map((other, i) =>
      element("button", { type: "button", class: "secondary", "data-instead": other.key, "aria-keyshortcuts": String(i + 1) },
        `${other.name} `, element("kbd", { text: String(i + 1) })));
    choices.push(element("button", { type: "button", class: "secondary", "data-instead": "nothing", "aria-keyshortcuts": "0" },
      "nothing we said ", element("kbd", { text: "0" })));
    for (const button of choices) button.addEventListener("click", () => enqueue(() => answer(button.dataset.instead)));
    $("attempt-instead-choices").replaceChildren(...choices);
    cycleReplay(current.frames);
    play();
    if (note) say(message, note);
  }

  async function advance(note) {
    show(await api(nextUrl()), note);
  }

  async function answer(instead) {
    if (!current) return;
    const attempt = current;
    current = null;
    const json = instead === undefined ? { answer: "yes" } : { answer: "no", instead };
    try {
      const stored = await api(`/attempts/${attempt.snapshot.id}/answer`, { method: "POST", json });
      history.push({ kind: "answer", attempt, labelIds: stored.labels.map((label) => label.id) });
      await advance(stored.shows === "nothing" ? "Saved: it shows nothing we said." : `Saved: it shows “${stored.shows}”.`);
    } catch (error) {
      say(message, error.message, "error");
      if (error.status === 409) await advance();
      else show(attempt);
    }
  }

  async function skip() {
    if (!current) return;
    skipped.push(current.snapshot.id);
    history.push({ kind: "skip", attempt: current });
    await advance("Skipped.");
  }

  async function undo() {
    const last = history.pop();
    if (!last) return say(message, "Nothing to undo.");
    if (last.kind === "answer") {
      try {
        for (const id of last.labelIds) await api(`/labels/${id}`, { method: "DELETE" });
      } catch (error) {
        history.push(last);
        return say(message, `Could not undo: ${error.message}`, "error");
      }
    } else {
      skipped.splice(skipped.indexOf(last.attempt.snapshot.id), 1);
    }
    show(last.attempt, "Undone: answer this attempt again.");
  }

  async function askRobot() {
    const robot = currentRobot();
    if (!robot) return;
    $("attempt-ask").disabled = true;
    try {
      const queued = await api(`/robots/${robot.id}/attempts`, { method: "POST", json: { count: ASK_COUNT } });
      say(message, `Asked ${robot.name} to try ${queued.commands.join(", ")} (${queued.attempts} attempts)…`, "ok");
      for (;;) {
        await new Promise((resolve) => setTimeout(resolve, POLL_MS));
        const status = await api(`/robots/${robot.id}/attempts/${queued.task_id}`);
        if (status.state === "refused" || status.state === "failed") return say(message, status.message, "error");
        if (status.state === "done") return advance(status.message);
      }
    } catch (error) {
      say(message, error.message, "error");
    } finally {
      $("attempt-ask").disabled = false;
    }
  }

  function enqueue(action) {
    queue = queue.then(action).catch((error) => say(message, error.message, "error"));
  }

  /** A key pressed in this mode; true when it meant something here. */
  function key(name) {
    if (name === "r") return play() || true;
    if (choosing) {
      if (name === "escape") return setChoosing(false) || true;
      const digit = Number.parseInt(name, 10);
      if (Number.isNaN(digit) || !current) return false;
      if (digit === 0) enqueue(() => answer("nothing"));
      else if (digit <= Math.min(9, current.others.length)) enqueue(() => answer(current.others[digit - 1].key));
      else return false;
      return true;
    }
    const actions = { y: () => answer(), n: async () => setChoosing(true), s: skip, z: undo };
    if (!actions[name]) return false;
    enqueue(actions[name]);
    return true;
  }

  $("attempt-yes").addEventListener("click", () => enqueue(() => answer()));
  $("attempt-no").addEventListener("click", () => setChoosing(true));
  $("attempt-skip").addEventListener("click", () => enqueue(skip));
  $("attempt-undo").addEventListener("click", () => enqueue(undo));
  $("attempt-replay-sound").addEventListener("click", play);
  $("attempt-ask").addEventListener("click", askRobot);

  return {
    key,
    start: () => enqueue(() => advance()),
    stop: () => {
      clearInterval(replayTimer);
      $("attempt-clip").pause();
    },
  };
}
