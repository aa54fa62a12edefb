// Coaching the robot by voice (backend/services/coaching.py): the robot works on a command in the scene, slowly;
// hold Space (or the button) and say the command when it is where it should be. Each clip goes to the API with
// when it was said, on this browser's clock, and when it was sent, so the API can place it on its own clock.
import { api } from "./api.js";
import { groupCommands } from "./commands.js";
import { Recorder } from "./recorder.js";
import { element, robotPicker, say } from "./shell.js";

const POLL_MS = 500;
const ENDED = new Set(["done", "cancelled", "refused", "failed"]);
const MIN_TALK_MS = 300; // shorter than the API's shortest clip
const MAX_TALK_S = 9.5; // the API takes clips of at most 10 s: a longer hold is sent at this length

export async function startCoaching(section) {
  const parts = {
    robot: section.querySelector("#coach-robot"),
    command: section.querySelector("#coach-command"),
    seconds: section.querySelector("#coach-seconds"),
    start: section.querySelector("#coach-start"),
    talk: section.querySelector("#coach-talk"),
    stop: section.querySelector("#coach-stop"),
    message: section.querySelector("#coach-message"),
    heard: section.querySelector("#coach-heard"),
  };
  const robots = await robotPicker(parts.robot);
  const commands = groupCommands(await api("/clips?limit=1000")).filter((command) => command.named);
  parts.command.replaceChildren(...commands.map((command) => element("option", { value: command.name, text: command.name })));
  if (!robots.robots.length || !commands.length) {
    parts.start.disabled = true;
    say(parts.message, robots.robots.length ? "Record a command on the Record page first; then you can coach the robot on it." : "Add a robot on the Admin page first.", "warn");
  } else {
    const coach = new CoachingSession(parts, robots);
    parts.start.addEventListener("click", () => coach.begin());
    parts.stop.addEventListener("click", () => coach.cancel());
    holdToTalk(parts.talk, coach);
  }
  section.hidden = false;
}

function holdToTalk(button, coach) {
  button.addEventListener("pointerdown", (event) => {
    event.preventDefault();
    coach.talk();
  });
  for (const end of ["pointerup", "pointerleave", "pointercancel"]) button.addEventListener(end, () => coach.done());
  document.addEventListener("keydown", (event) => {
    if (event.code !== "Space" || event.repeat || !coach.running || isTyping(event.target)) return;
    event.preventDefault();
    coach.talk();
  });
  document.addEventListener("keyup", (event) => {
    if (event.code !== "Space" || !coach.running) return;
    event.preventDefault();
    coach.done();
  });
}

const isTyping = (target) => ["INPUT", "TEXTAREA", "SELECT"].includes(target.tagName);

class CoachingSession {
  constructor(parts, robots) {
    this.parts = parts;
    this.robots = robots;
    this.recorder = new Recorder(() => this.listening());
    this.session = null;
    this.saidFrom = null;
    this.answers = 0;
  }

  get running() {
    return this.session !== null && this.session.state === "running";
  }

  async begin() {
    const { parts } = this;
    parts.start.disabled = true;
    say(parts.message, "Starting… the robot will move in the scene above once it is ready.");
    try {
      await this.recorder.open();
      const robot = this.robots.current();
      this.robotId = robot.id;
      this.session = await api(`/robots/${robot.id}/coaching`, {
        method: "POST",
        json: { command: parts.command.value, seconds: Number(parts.seconds.value) },
      });
    } catch (error) {
      parts.start.disabled = false;
      say(parts.message, `Coaching could not start: ${error.message}`, "error");
      return;
    }
    this.answers = 0;
    parts.heard.textContent = "";
    parts.stop.hidden = false;
    this.show(this.session);
    this.poll();
  }

  async poll() {
    while (this.session && !ENDED.has(this.session.state)) {
      await new Promise((resolve) => setTimeout(resolve, POLL_MS));
      try {
        this.show(await api(`/robots/${this.robotId}/coaching/${this.session.session_id}`));
      } catch (error) {
        say(this.parts.message, `Lost touch with the coaching session: ${error.message}. It goes on; this page tries again.`, "warn");
      }
    }
  }

  show(status) {
    this.session = status;
    const { parts } = this;
    document.body.dataset.coaching = status.state;
    document.body.dataset.coachingStep = String(status.step);
    parts.talk.disabled = status.state !== "running";
    const ended = ENDED.has(status.state);
    parts.stop.hidden = ended;
    parts.start.disabled = !ended;
    const kind = { done: "ok", refused: "warn", failed: "error" }[status.state] || "";
    say(parts.message, status.message, kind);
  }

  /** While Space is held: how much of the voice has been heard so far (from the microphone's samples). */
  listening() {
    if (this.saidFrom === null || !this.recorder.recording) return;
    const samples = this.recorder.chunks.reduce((n, chunk) => n + chunk.length, 0);
    const seconds = samples / this.recorder.context.sampleRate;
    document.body.dataset.coachingListenedS = seconds.toFixed(2);
    say(this.parts.heard, `Listening… ${seconds.toFixed(1)} s: let go when you have said “${this.session.command_name}”.`);
    if (seconds >= MAX_TALK_S) this.done(); // what was said so far is sent; let go and hold again for more
  }

  talk() {
    if (!this.running || this.saidFrom !== null) return;
    this.saidFrom = Date.now();
    this.parts.talk.classList.add("talking");
    this.parts.talk.setAttribute("aria-pressed", "true");
    this.recorder.start();
  }

  async done() {
    if (this.saidFrom === null) return;
    const saidFrom = this.saidFrom;
    const saidTo = Date.now();
    this.saidFrom = null;
    this.parts.talk.classList.remove("talking");
    this.parts.talk.setAttribute("aria-pressed", "false");
    const clip = this.recorder.stop();
    if (saidTo - saidFrom < MIN_TALK_MS || clip.seconds < MIN_TALK_MS / 1000) {
      say(this.parts.heard, "That was too short to hear: hold Space while you say the whole command.", "warn");
      return;
    }
    say(this.parts.heard, "Sending what you said…");
    const form = new FormData();
    form.append("file", new Blob([clip.wav], { type: "audio/wav" }), "coaching.wav");
    form.append("said_from_ms", String(saidFrom));
    form.append("said_to_ms", String(saidTo));
    form.append("sent_at_ms", String(Date.now()));
    try {
      const answer = await api(`/robots/${this.robotId}/coaching/${this.session.session_id}/clips`, { method: "POST", form });
      this.answers += 1;
      document.body.dataset.coachingAnswers = String(this.answers);
      say(this.parts.heard, `${answer.message} (${this.answers} so far)`, "ok");
    } catch (error) {
      say(this.parts.heard, `Not saved: ${error.message}`, "warn");
    }
  }

  async cancel() {
    if (!this.session) return;
    try {
      this.show(await api(`/robots/${this.robotId}/coaching/${this.session.session_id}/cancel`, { method: "POST" }));
    } catch (error) {
      say(this.parts.message, `Could not stop: ${error.message}`, "error");
    }
  }
}
