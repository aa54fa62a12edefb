import { api } from "../api.js";
import { kindWords, stageWords, statusWords } from "../runs.js";
import { element, pageFailed, pageReady, robotPicker, say, startPage, when } from "../shell.js";

const $ = (id) => document.getElementById(id);
let picker;
let presetsDrawn = 0;

function formatMinutes(minutes) {
  const whole = Math.max(1, Math.round(minutes));
  return whole === 1 ? "1 minute" : `${whole} minutes`;
}

async function householdTriplets(robot) {
  if (!robot) return null;
  const stats = await api(`/triplets/stats?robot_id=${robot.id}`);
  return stats.triplets > 0 ? stats.triplets : null;
}

async function drawPresets() {
  // A robot picked while an earlier draw is still waiting must not have that draw's presets shown over its own.
  const draw = ++presetsDrawn;
  const triplets = await householdTriplets(picker.current());
  const presets = await api(triplets === null ? "/runs/presets" : `/runs/presets?triplets=${triplets}`);
  if (draw !== presetsDrawn) return;
  const box = $("presets");
  const chosen = new FormData($("start")).get("preset") || "quick";
  box.innerHTML = "";
  for (const [name, params] of Object.entries(presets)) {
    const id = `preset-${name}`;
    const count = `${params.budget_triplets.toLocaleString()} triplet${params.budget_triplets === 1 ? "" : "s"}`;
    const labels = triplets === null ? `about ${count}` : `this robot's ${count}`;
    const hint = `about ${formatMinutes(params.minutes_here)} on a 2-core computer with ${labels}: ${params.var_epochs} VAR epochs, ${params.policy_steps.toLocaleString()} policy steps, ${params.eval_episodes} test episodes`;
    box.append(element("div", { class: "row choice" },
      element("input", { type: "radio", name: "preset", id, value: name, checked: name === chosen, style: "width:auto;min-height:0" }),
      element("label", { for: id, style: "margin:0" }, `${name} `, element("span", { class: "muted", text: `(${hint})` }))));
  }
}

async function drawActiveRuns() {
  const unfinished = [...(await api("/runs?status=running")), ...(await api("/runs?status=queued"))];
  const list = $("active-runs");
  list.innerHTML = "";
  $("no-active").hidden = unfinished.length > 0;
  for (const run of unfinished) {
    const cancel = element("button", { type: "button", class: "danger", text: "Cancel", "aria-label": `Cancel run ${run.id}`,
      onclick: async () => {
        cancel.disabled = true;
        try {
          await api(`/runs/${run.id}:cancel`, { method: "POST" });
          say($("start-message"), `Run ${run.id} will stop at its next checkpoint.`, "ok");
        } catch (error) {
          say($("start-message"), error.message, "error");
        }
        drawActiveRuns();
      } });
    list.append(element("li", { class: "row" }, element("span", { text: `Run ${run.id} (${kindWords(run.kind)}) · ${statusWords(run.status)}, ${stageWords(run.status === "queued" ? "queued" : run.stage)} · ${Math.floor(Math.min(run.progress, 0.99) * 100)}%` }), cancel));
  }
}

async function drawHealth() {
  const body = $("health");
  body.innerHTML = "";
  const row = (name, value, ok) => body.append(element("tr", {}, element("th", { scope: "row", text: name }), element("td", { class: ok ? "" : "message error", text: value })));
  try {
    const health = await fetch("/api/v1/health").then((r) => r.json());
    row("Database", health.database, health.database === "ok");
    row("Broker (Redis)", health.broker, health.broker === "ok");
    const system = await api("/system/queues");
    for (const queue of system.queues) row(`Queue “${queue.name}”`, `${queue.waiting} waiting`, true);
    row("Workers", system.workers.length ? system.workers.map((w) => `${w.name} (${w.queues.join(", ")})`).join("; ") : system.workers_message, system.workers.length > 0);
  } catch (error) {
    row("Status", error.message, false);
  }
}

async function drawRobots() {
  const robots = await api("/robots");
  $("robots").innerHTML = "";
  if (!robots.length) $("robots").append(element("li", { class: "muted", text: "No robots yet: add the household's first one below." }));
  for (const robot of robots) $("robots").append(element("li", { text: `${robot.name} — ${robot.kind}${robot.active_model_id ? ` · active model ${robot.active_model_id}` : " · no active model"}` }));
}

async function drawModels() {
  const robot = picker.current();
  const body = $("models");
  body.innerHTML = "";
  if (!robot) return;
  const versions = await api(`/robots/${robot.id}/models`);
  for (const version of versions) {
    const figures = Object.entries(version.metrics || {}).filter(([, v]) => typeof v === "number").slice(0, 4).map(([k, v]) => `${k} ${v.toPrecision(3)}`).join(", ");
    const action = version.status === "active" ? element("span", { class: "muted", text: "in use" })
      : element("button", { type: "button", class: "secondary", text: "Activate", "aria-label": `Activate version ${version.id}`,
          onclick: () => modelAction(`/models/${version.id}:activate`, `Version ${version.id} is active now.`) });
    const cell = (label, ...content) => element("td", { "data-label": label }, ...content);
    body.append(element("tr", {}, cell("Version", String(version.id)), cell("Status", element("span", { class: `status-pill ${version.status === "active" ? "succeeded" : ""}`, text: version.status })),
      cell("From run", origin(version)), cell("Figures", figures || "—"), cell("Created", when(version.created_at)), element("td", {}, action)));
  }
  if (!versions.length) body.append(element("tr", {}, element("td", { colspan: 6, class: "muted", text: `No model versions for ${robot.name} yet: once a training run finishes, its version appears here.` })));
}

function origin(version) {
  const adapted = version.metrics?.room_adaptation;
  if (adapted && adapted.share === 0) return `version ${adapted.from_version} with its base model's view back`;
  if (adapted) return `version ${adapted.from_version} adapted to its room (${adapted.views} views)`;
  return version.run_id ? `run ${version.run_id}` : "base";
}

async function adaptToRoom(robot) {
  const button = $("adapt");
  button.disabled = true;
  try {
    const queued = await api(`/robots/${robot.id}/models:adapt-to-room`, { method: "POST", json: {} });
    say($("models-message"), `Adapting ${robot.name} to its room from ${queued.views} views of it…`, "ok");
    let status = queued;
    while (!["done", "refused", "failed"].includes(status.state)) {
      await new Promise((resolve) => setTimeout(resolve, 1000));
      status = await api(`/robots/${robot.id}/adaptations/${queued.task_id}`);
    }
    say($("models-message"), status.state === "done" ? `${robot.name}: ${status.message}.` : `Not adapted: ${status.message}`, status.state === "done" ? "ok" : "error");
  } catch (error) {
    say($("models-message"), error.message, "error");
  } finally {
    button.disabled = false;
  }
  await Promise.all([drawModels(), drawRobots()]);
}

async function modelAction(path, done) {
  try {
    await api(path, { method: "POST" });
    say($("models-message"), done, "ok");
  } catch (error) {
    say($("models-message"), error.message, "error");
  }
  await Promise.all([drawModels(), drawRobots()]);
}

async function main() {
  await startPage("admin", { adminOnly: true });
  picker = await robotPicker($("robot"), () => Promise.all([drawModels(), drawPresets()]));
  $("start").addEventListener("submit", async (event) => {
    event.preventDefault();
    const robot = picker.current();
    if (!robot) return say($("start-message"), "Add a robot first: name it and choose its kind under “Robots”.", "error");
    const preset = new FormData(event.target).get("preset") || "quick";
    $("start-run").disabled = true;
    try {
      const run = await api("/runs", { method: "POST", json: { robot_id: robot.id, kind: $("kind").value, preset } });
      say($("start-message"), `Run ${run.id} is queued. Follow it on the Progress page.`, "ok");
    } catch (error) {
      say($("start-message"), error.message, "error");
    } finally {
      $("start-run").disabled = false;
    }
    drawActiveRuns();
  });
  $("new-robot").addEventListener("submit", async (event) => {
    event.preventDefault();
    try {
      const robot = await api("/robots", { method: "POST", json: Object.fromEntries(new FormData(event.target)) });
      say($("robot-message"), `Added ${robot.name}.`, "ok");
      event.target.reset();
      picker = await robotPicker($("robot"), () => Promise.all([drawModels(), drawPresets()]));
      await Promise.all([drawRobots(), drawPresets()]);
    } catch (error) {
      say($("robot-message"), error.message, "error");
    }
  });
  $("adapt").addEventListener("click", () => {
    const robot = picker.current();
    if (robot) adaptToRoom(robot);
  });
  $("rollback").addEventListener("click", () => {
    const robot = picker.current();
    if (robot) modelAction(`/robots/${robot.id}/models:rollback`, `Rolled back: ${robot.name} uses its previous version again.`);
  });
  $("refresh-health").addEventListener("click", drawHealth);
  pageReady();
  await Promise.all([drawPresets(), drawActiveRuns(), drawHealth(), drawRobots(), drawModels()]);
  setInterval(drawActiveRuns, 5000);
}

main().catch(pageFailed);
