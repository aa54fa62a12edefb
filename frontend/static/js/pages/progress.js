import { api } from "../api.js";
import { beforeAfterChart, lineChart } from "../chart.js";
import { element, pageFailed, pageReady, startPage, when } from "../shell.js";

const runs = new Map(); // id → latest RunPublic
const live = new Map(); // id → {metric: [[seconds, value], …]} collected from the stream
const cards = new Map();
const LIVE_METRIC = /loss|success|accuracy|reward|return/i;

const X_KEYS = ["epoch", "update", "env_steps", "step"];
const STAGE_NAMES = { var_finetune: "VAR", policy_improve: "policy", evaluate: "evaluation" };

function isNumberList(value) {
  return Array.isArray(value) && value.length > 1 && value.every((v) => Number.isFinite(v) || (Array.isArray(v) && v.length === 2));
}

/** The worker saves curves per stage as lists of records ({epoch, loss, accuracy, …} or {update, recent_success, …});
 * each plotted metric becomes a series "stage metric" of [x, y] points. Plain number lists are taken as they are. */
function savedCurves(metrics) {
  const curves = {};
  for (const [stage, points] of Object.entries(metrics.curves || {})) {
    if (isNumberList(points)) {
      curves[stage] = points;
      continue;
    }
    if (!Array.isArray(points)) continue;
    const records = points.filter((p) => p && typeof p === "object" && !Array.isArray(p));
    const xKey = X_KEYS.find((k) => records.some((p) => Number.isFinite(p[k])));
    for (const record of records) {
      for (const [key, value] of Object.entries(record)) {
        if (!LIVE_METRIC.test(key) || !Number.isFinite(value)) continue;
        const name = `${STAGE_NAMES[stage] || stage} ${key.replaceAll("_", " ")}`;
        const x = xKey && Number.isFinite(record[xKey]) ? record[xKey] : (curves[name] || []).length;
        (curves[name] = curves[name] || []).push([x, value]);
      }
    }
  }
  return Object.fromEntries(Object.entries(curves).filter(([, points]) => points.length > 1));
}

function promotionText(run) {
  const gate = (run.metrics || {}).gate;
  if (!gate || typeof gate !== "object") return "";
  const verdict = gate.promoted ? "Promoted: the new version is active." : "Not promoted: the active version stays.";
  return `${verdict} ${[].concat(gate.reasons || []).join("; ")}`.trim();
}

/** Before = the active version's scores, after = the candidate's (metrics.evaluation from the promotion gate). */
function beforeAfter(metrics) {
  const evaluation = metrics.evaluation || {};
  if (!evaluation.candidate || !evaluation.active) return null;
  const names = { triplet_accuracy: "triplet accuracy", sim_success: "sim success" };
  const before = {};
  const after = {};
  for (const [key, label] of Object.entries(names)) {
    if (Number.isFinite(evaluation.active[key]) && Number.isFinite(evaluation.candidate[key])) {
      before[label] = evaluation.active[key];
      after[label] = evaluation.candidate[key];
    }
  }
  return Object.keys(after).length ? { before, after } : null;
}

/** Latest figures of each stage, flattened to "stage metric" rows. */
function scalarRows(metrics) {
  const flat = {};
  for (const [group, values] of Object.entries(metrics.latest || {})) {
    for (const [key, value] of Object.entries(values || {})) flat[`${STAGE_NAMES[group] || group} ${key.replaceAll("_", " ")}`] = value;
  }
  for (const [key, value] of Object.entries(metrics)) flat[key.replaceAll("_", " ")] = value;
  return Object.entries(flat)
    .filter(([, v]) => (typeof v === "number" && Number.isFinite(v)) || typeof v === "string" || typeof v === "boolean")
    .map(([k, v]) => element("tr", {}, element("th", { scope: "row", text: k }), element("td", { text: typeof v === "number" ? String(Number(v.toPrecision(4))) : String(v) })));
}

function record(run) {
  const t = (Date.parse(run.updated_at) - Date.parse(run.created_at)) / 1000;
  const series = live.get(run.id) || {};
  for (const [group, values] of Object.entries((run.metrics || {}).latest || {})) {
    for (const [key, value] of Object.entries(values || {})) {
      if (!Number.isFinite(value) || !LIVE_METRIC.test(key)) continue;
      const name = `${STAGE_NAMES[group] || group} ${key.replaceAll("_", " ")}`;
      series[name] = series[name] || [];
      const last = series[name][series[name].length - 1];
      if (!last || last[0] !== t) series[name].push([t, value]);
    }
  }
  live.set(run.id, series);
}

function draw(run) {
  let card = cards.get(run.id);
  if (!card) {
    card = element("section", { class: "card run", "data-run-id": run.id, "aria-labelledby": `run-${run.id}-title` });
    cards.set(run.id, card);
    const list = document.getElementById("runs"); // newest first
    const older = [...list.children].find((other) => Number(other.dataset.runId) < run.id);
    list.insertBefore(card, older || null);
  }
  const percent = Math.round(run.progress * 100);
  const etaSeconds = (run.timings || {}).eta_s;
  const running = run.status === "running";
  const eta = running && Number.isFinite(etaSeconds) ? ` · about ${Math.max(1, Math.ceil(etaSeconds / 60))} min left` : "";
  card.innerHTML = "";
  card.append(
    element("div", { class: "row" },
      element("h2", { id: `run-${run.id}-title`, text: `Run ${run.id}: ${run.kind.replace("_", " ")} (${run.preset})` }),
      element("span", { class: `status-pill ${run.status}`, text: run.status })),
    element("p", { class: "muted", text: `Stage: ${run.stage} · ${percent}%${eta} · started ${when(run.started_at || run.created_at)}` }),
    element("progress", { class: "bar", max: 1, value: run.progress, "aria-label": `Run ${run.id} progress`, "aria-valuetext": `${percent}% — ${run.stage}` }),
  );
  if (run.error) card.append(element("p", { class: "message error", text: `Failed during ${run.stage}: ${run.error}` }));
  const promotion = promotionText(run);
  if (promotion) card.append(element("p", { class: `message ${/^Promoted/.test(promotion) ? "ok" : "warn"}`, text: promotion }));
  const metrics = run.metrics || {};
  const saved = savedCurves(metrics);
  const curves = Object.keys(saved).length ? saved : live.get(run.id) || {};
  const charts = element("div", { class: "grid two" });
  const groups = [
    ["Loss", /loss/i, "Loss"],
    ["Return", /return|reward/i, "Episode return (intrinsic reward)"],
    ["Success", /success|accuracy/i, "Success and accuracy"],
  ];
  for (const [title, pattern, caption] of groups) {
    const series = Object.fromEntries(Object.entries(curves).filter(([k]) => pattern.test(k)));
    if (Object.keys(series).length) charts.append(element("figure", {}, lineChart(series, { title }), element("figcaption", { class: "muted", text: caption })));
  }
  const comparison = beforeAfter(metrics);
  if (comparison) {
    charts.append(element("figure", { class: "before-after" }, beforeAfterChart(comparison.before, comparison.after), element("figcaption", { class: "muted", text: "Active version (before) and this run's candidate (after)" })));
  }
  if (charts.children.length) card.append(charts);
  const rows = scalarRows(metrics);
  if (rows.length) card.append(element("details", {}, element("summary", { text: "All figures" }), element("table", {}, element("tbody", {}, ...rows))));
}

function update(run) {
  runs.set(run.id, run);
  record(run);
  draw(run);
  document.getElementById("no-runs").hidden = runs.size > 0;
}

function connect() {
  const state = document.getElementById("stream-state");
  const source = new EventSource("/api/v1/runs/events?timeout=3600");
  source.addEventListener("open", () => (state.textContent = "Live: updates appear as they happen."));
  source.addEventListener("run", (event) => update(JSON.parse(event.data)));
  source.addEventListener("error", () => {
    state.textContent = "Live updates paused; reconnecting…";
  });
}

async function main() {
  await startPage("progress");
  const initial = await api("/runs?limit=20");
  document.getElementById("no-runs").hidden = initial.length > 0;
  for (const run of initial.reverse()) update(run);
  connect();
  pageReady();
}

main().catch(pageFailed);
