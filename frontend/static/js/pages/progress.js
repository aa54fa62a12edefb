import { api } from "../api.js";
import { beforeAfterChart, lineChart } from "../chart.js";
import { kindWords, stageWords, statusWords } from "../runs.js";
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

/** The gate's verdict in sentences: its own summary (which uses the household's command words), or for runs
 * from before the summary existed, one built from the scores. */
function verdict(run) {
  const metrics = run.metrics || {};
  const gate = metrics.gate;
  if (!gate || typeof gate !== "object") return null;
  const kind = gate.verdict || (gate.promoted ? "better" : "no_change");
  const text = gate.summary || olderVerdict(gate, metrics.evaluation || {});
  return { kind, text, reasons: [].concat(gate.reasons || []) };
}

function olderVerdict(gate, evaluation) {
  const { candidate, active } = evaluation;
  const outcome = gate.promoted ? "the new version is active." : "kept the old version.";
  if (!candidate || !active) return `${gate.promoted ? "Promoted" : "Not promoted"}: ${outcome}`;
  const said = [];
  const n = candidate.held_out_triplets;
  if (n && Number.isFinite(candidate.triplet_accuracy) && Number.isFinite(active.triplet_accuracy)) {
    said.push(`it matches ${Math.round(candidate.triplet_accuracy * n)} of ${n} held-out answers, was ${Math.round(active.triplet_accuracy * n)} of ${n}`);
  }
  const tries = candidate.sim_episodes;
  if (tries && Number.isFinite(candidate.sim_success) && Number.isFinite(active.sim_success)) {
    said.push(`it reaches the target in ${Math.round(candidate.sim_success * tries)} of ${tries} simulated tries, was ${Math.round(active.sim_success * tries)} of ${tries}`);
  }
  const text = said.join("; ");
  return `${text ? text[0].toUpperCase() + text.slice(1) : gate.promoted ? "Promoted" : "Not promoted"}; ${outcome}`;
}

/** A verdict's text, with the *command words* the gate marks shown emphasised. */
function verdictParagraph(found) {
  const tone = { better: "ok", worse: "warn", no_change: "" }[found.kind] ?? "";
  const parts = found.text.split(/\*([^*]+)\*/).map((part, i) => (i % 2 ? element("strong", { text: part }) : part));
  return element("p", { class: `message verdict ${tone}`.trim(), "data-verdict": found.kind }, ...parts);
}

/** "about 3 min left", "less than a minute left", or "finishing up" once the bar is full: never a minute
 * left at 100 %. The ETA is as of the run's last update; time since then counts off. */
function timeLeft(run, shownFraction) {
  if (run.status !== "running") return "";
  if (shownFraction >= 0.99 || run.stage === "promoting") return " · finishing up";
  const eta = (run.timings || {}).eta_s;
  if (!Number.isFinite(eta)) return "";
  const left = eta - Math.max(0, (Date.now() - Date.parse(run.updated_at)) / 1000);
  if (left <= 5) return " · almost done";
  return left < 60 ? " · less than a minute left" : ` · about ${Math.round(left / 60)} min left`;
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
  // the bar is full when the run is, not while it is still testing or deciding
  const fraction = run.status === "succeeded" ? 1 : run.status === "running" || run.status === "queued" ? Math.min(run.progress, 0.99) : run.progress;
  const percent = Math.floor(fraction * 100);
  const stage = stageWords(run.status === "running" ? run.stage : run.status === "queued" ? "queued" : run.status);
  const kind = kindWords(run.kind);
  card.innerHTML = "";
  card.append(
    element("div", { class: "row" },
      element("h2", { id: `run-${run.id}-title`, text: `Run ${run.id}: ${kind} (${run.preset})` }),
      element("span", { class: `status-pill ${run.status}`, text: statusWords(run.status) })),
    element("p", { class: "muted", text: `Stage: ${stage} · ${percent}%${timeLeft(run, fraction)} · started ${when(run.started_at || run.created_at)}` }),
    element("progress", { class: "bar", max: 1, value: fraction, "aria-label": `Run ${run.id} progress`, "aria-valuetext": `${percent}% — ${stage}` }),
  );
  if (run.error) card.append(element("p", { class: "message error", text: `Stopped while ${stageWords(run.stage)}: ${run.error}` }));
  const found = verdict(run);
  if (found) {
    card.append(verdictParagraph(found));
    if (found.reasons.length) card.append(element("details", { class: "reasons" }, element("summary", { text: "How this was decided" }), element("ul", {}, ...found.reasons.map((reason) => element("li", { text: reason })))));
  }
  const metrics = run.metrics || {};
  const saved = savedCurves(metrics);
  const curves = Object.keys(saved).length ? saved : live.get(run.id) || {};
  const charts = element("div", { class: "grid two" });
  const groups = [
    ["Loss", /loss/i, "Loss"],
    ["Return", /return|reward/i, "Episode return (intrinsic reward)"],
    ["Success", /success|accuracy/i, "Success and accuracy (0 to 1)", [0, 1]],
  ];
  for (const [title, pattern, caption, range] of groups) {
    const series = Object.fromEntries(Object.entries(curves).filter(([k]) => pattern.test(k)));
    if (Object.keys(series).length) charts.append(element("figure", {}, lineChart(series, { title, range }), element("figcaption", { class: "muted", text: caption })));
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
