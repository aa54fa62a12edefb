import { api, uploadWithProgress } from "../api.js";
import { Recorder, onHold } from "../recorder.js";
import { listening, tryItNow } from "../try_now.js";
import { describeCounts, groupCommands, targetsSentence } from "../commands.js";
import { element, pageFailed, pageReady, savedRobot, say, startPage, when } from "../shell.js";

const MIN_SECONDS = 0.3;
const MAX_SECONDS = 10;
const SILENCE_PEAK = 0.02;

const $ = (id) => document.getElementById(id);
const talk = $("talk");
const message = $("take-message");
const meterBar = $("level");
const meter = meterBar.parentElement;
let me;
let take = null; // {wav, seconds, peak, rms}
let takeUrl = null;
let holding = false;
let robot = null; // the household's chosen robot: "try it now" asks it

const recorder = new Recorder((level) => {
  meterBar.style.width = `${Math.round(level * 100)}%`;
  meter.setAttribute("aria-valuenow", String(Math.round(level * 100)));
});

async function begin() {
  if (holding) return;
  holding = true;
  showReview(false);
  try {
    await recorder.start();
  } catch (error) {
    holding = false;
    say(message, error.message, "error");
    $("retry-mic").hidden = false;
    return;
  }
  if (!holding) return finish(); // released while the microphone was still starting
  $("retry-mic").hidden = true;
  talk.setAttribute("aria-pressed", "true");
  talk.textContent = "Recording… let go to stop";
  say(message, "Recording…");
  if (tryingNow()) listening($("try-message"));
}

const tryingNow = () => $("try-now").checked;

function finish() {
  if (!recorder.recording) {
    holding = false;
    return;
  }
  holding = false;
  talk.setAttribute("aria-pressed", "false");
  talk.textContent = "Hold to talk";
  const result = recorder.stop();
  if (result.seconds < MIN_SECONDS) {
    say(message, `That was only ${result.seconds.toFixed(1)} s. Hold the button down for the whole command, then let go.`, "warn");
    return;
  }
  if (result.peak < SILENCE_PEAK) {
    say(message, "We heard only silence. Check that the right microphone is selected and not muted, move closer, and speak up — then record again.", "warn");
    return;
  }
  if (result.seconds > MAX_SECONDS) {
    say(message, `That was ${result.seconds.toFixed(1)} s; commands can be at most ${MAX_SECONDS} s. Record a shorter one.`, "warn");
    return;
  }
  if (tryingNow()) {
    say(message, "");
    tryItNow(result.wav, robot && robot.id, $("try-message"));
    return;
  }
  take = result;
  if (takeUrl) URL.revokeObjectURL(takeUrl);
  takeUrl = URL.createObjectURL(result.wav);
  $("take-audio").src = takeUrl;
  showReview(true);
  say(message, `Recorded ${result.seconds.toFixed(1)} s. Listen to it, then keep it or record again.`, "ok");
}

function showReview(visible) {
  $("review").hidden = !visible;
  if (!visible) take = null;
}

/** The name the recording is kept under: the chosen command's, or the new command's as typed. */
function commandName() {
  return $("command").value || $("clip-name").value.trim();
}

async function keep(blob, filename) {
  const form = new FormData();
  form.append("file", blob, filename);
  const name = commandName();
  if (name) form.append("name", name);
  $("upload").hidden = false;
  $("upload-progress").value = 0;
  $("keep").disabled = true;
  let clip;
  try {
    clip = await uploadWithProgress("/clips", form, (fraction) => ($("upload-progress").value = fraction));
  } catch (error) {
    say(message, `The server did not accept this recording: ${error.message}`, "error");
    return;
  } finally {
    $("upload").hidden = true;
    $("keep").disabled = false;
  }
  const kept = clip.name ? `Kept: recording ${clip.id} of “${clip.name}” (${clip.duration_s.toFixed(1)} s).` : `Kept: recording ${clip.id} (${clip.duration_s.toFixed(1)} s). It has no command name, so it counts as a command of its own.`;
  showReview(false);
  try {
    // "Kept" is said once the lists show the new recording, so what the page says is what it shows
    await Promise.all([listClips(), listCommands(clip.name)]);
  } catch (error) {
    say(message, `${kept} The list of recordings could not be refreshed (${error.message}): reload the page to see it.`, "warn");
    return;
  }
  say(message, kept, clip.name ? "ok" : "warn");
}

async function listClips() {
  const clips = await api(`/clips?speaker_id=${me.id}`);
  const list = $("clips");
  list.innerHTML = "";
  $("clips-empty").hidden = clips.length > 0;
  for (const clip of clips) {
    const title = clip.name || `Recording ${clip.id}`;
    const audio = element("audio", { controls: true, preload: "none", src: `/api/v1/clips/${clip.id}/audio`, "aria-label": `Play ${title}` });
    const remove = element("button", {
      type: "button",
      class: "danger",
      "aria-label": `Delete ${title}`,
      text: "Delete",
      onclick: async () => {
        remove.disabled = true;
        try {
          await api(`/clips/${clip.id}`, { method: "DELETE" });
          await listClips();
        } catch (error) {
          remove.disabled = false;
          say(message, `Could not delete: ${error.message}`, "error");
        }
      },
    });
    list.append(
      element(
        "li",
        { "data-clip-id": clip.id },
        element("div", { class: "row" }, element("strong", { text: title }), element("span", { class: "muted", text: `${clip.duration_s.toFixed(1)} s · ${when(clip.created_at)}` })),
        element("div", { class: "row" }, audio, remove),
      ),
    );
  }
}

/** The household's commands, each with its recordings per member; they are also the choices of "Which command is this?". */
async function listCommands(choose = undefined) {
  const [clips, members] = await Promise.all([api("/clips?limit=1000"), api("/members")]);
  const names = new Map(members.map((m) => [m.id, m.display_name]));
  const commands = groupCommands(clips).filter((c) => c.named);
  const select = $("command");
  const chosen = choose === undefined ? select.value : choose || "";
  select.replaceChildren(element("option", { value: "", text: "a new command" }), ...commands.map((c) => element("option", { value: c.name, text: `${c.name} (${c.clips.length} recorded)` })));
  const same = commands.find((c) => c.name.toLocaleLowerCase() === chosen.toLocaleLowerCase());
  select.value = same ? same.name : "";
  showNameField();
  $("commands-empty").hidden = commands.length > 0;
  $("commands").replaceChildren(...commands.map((command) => element("li", { "data-command": command.name },
    element("strong", { text: command.name }), " ",
    element("span", { class: "muted", text: describeCounts(command.clips.length, "recording", command.bySpeaker, names) + (command.clips.length < 2 ? " · record it once more" : "") }))));
}

function showNameField() {
  const isNew = $("command").value === "";
  $("new-command").hidden = !isNew;
  if (!isNew) $("clip-name").value = "";
}

async function showTargets() {
  robot = savedRobot(await api("/robots"));
  $("targets").hidden = !robot;
  if (robot) $("targets").textContent = targetsSentence(robot);
}

function isTyping(event) {
  const tag = event.target && event.target.tagName;
  return tag === "INPUT" || tag === "TEXTAREA" || tag === "SELECT";
}

async function main() {
  ({ me } = await startPage("record"));
  onHold(talk, begin, finish);
  document.addEventListener("keydown", (event) => {
    if (event.code !== "Space" || isTyping(event) || (event.target.tagName === "BUTTON" && event.target !== talk)) return;
    event.preventDefault();
    if (!event.repeat) begin();
  });
  document.addEventListener("keyup", (event) => {
    if (event.code !== "Space" || isTyping(event) || (event.target.tagName === "BUTTON" && event.target !== talk)) return;
    event.preventDefault();
    finish();
  });
  $("keep").addEventListener("click", () => take && keep(take.wav, "recording.wav"));
  $("rerecord").addEventListener("click", () => {
    showReview(false);
    say(message, "Hold the button (or the space bar) and speak.");
    talk.focus();
  });
  $("retry-mic").addEventListener("click", async () => {
    recorder.close();
    try {
      await recorder.open();
      $("retry-mic").hidden = true;
      say(message, "The microphone works now. Hold the button and speak.", "ok");
    } catch (error) {
      say(message, error.message, "error");
    }
  });
  $("file").addEventListener("change", async (event) => {
    const file = event.target.files[0];
    if (file) await keep(file, file.name);
    event.target.value = "";
  });
  $("command").addEventListener("change", showNameField);
  $("try-now").addEventListener("change", () => ($("try-now-help").hidden = !tryingNow()));
  talk.disabled = $("file").disabled = false; // disabled in the HTML until their handlers exist
  pageReady();
  await Promise.all([listClips(), listCommands(), showTargets()]);
}

main().catch(pageFailed);
