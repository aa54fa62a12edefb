import { api } from "../api.js";
import { beforeAfterChart, lineChart } from "../chart.js";
import { element, startPage, when } from "../shell.js";

const runs = new Map(); // id → latest RunPublic
const live = new Map(); // id → {metric: [[seconds, value], …]} collected from the stream
const cards = new Map();
const LIVE_METRIC = /loss|success|accuracy|reward|return/i;

function isNumberList(value) {
  return Array.isArray(value) && value.length > 1 && value.every((v) => Number.isFinite(v) || (Array.isArray(v) && v.length === 2));
}

/** Curves saved with the run: metrics.curves {name: [...]} or any metric that is a list of numbers. */
function savedCurves(metrics) {
  const curves = {};
  for (const [key, value] of Object.entries(metrics.curves || {})) if (isNumberList(value)) curves[key] = value;
  for (const [key, value] of Object.entries(metrics)) if (isNumberList(value)) curves[key] = value;
  return curves;
}

function promotionText(run) {
  const m = run.metrics || {};
  const p = m.promotion;
  if (p && typeof p === "object") {
    const reasons = [].concat(p.reasons || p.reason || []).join(" ");
    return `${p.promoted ? "Promoted: the new version is active." : "Not promoted: the active version stays."} ${reasons}`.trim();
  }
  const reasons = m.promotion_reasons || m.promotion_reason;
  if (reasons) return `${m.promoted ? "Promoted." : "Not promoted."} ${[].concat(reasons).join(" ")}`;
  if (typeof m.promoted === "boolean") return m.promoted ? "Promoted: the new version is active." : "Not promoted: the active version stays.";
  return "";
}

function scalarRows(metrics) {
  return Object.entries(metrics)
    .filter(([, v]) => typeof v === "number" || typeof v === "string" || typeof v === "boolean")
    .map(([k, v]) => element("tr", {}, element("th", { scope: "row", text: k }), element("td", { text: typeof v === "number" ? v.toPrecision(4) : String(v) })));
}

function record(run) {
  const t = (Date.parse(run.updated_at) - Date.parse(run.created_at)) / 1000;
  const series = live.get(run.id) || {};
  for (const [key, value] of Object.entries(run.metrics || {})) {
    if (typeof value === "number" && Number.isFinite(value) && LIVE_METRIC.test(key)) {
      series[key] = series[key] || [];
      const last = series[key][series[key].length - 1];
      if (!last || last[0] !== t) series[key].push([t, value]);
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
  const eta = run.metrics && Number.isFinite(run.metrics.eta_s) ? ` · about ${Math.ceil(run.metrics.eta_s / 60)} min left` : "";
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
  const curves = { ...(live.get(run.id) || {}), ...savedCurves(metrics) };
  const charts = element("div", { class: "grid two" });
  const losses = Object.fromEntries(Object.entries(curves).filter(([k]) => /loss/i.test(k)));
  const successes = Object.fromEntries(Object.entries(curves).filter(([k]) => !/loss/i.test(k)));
  if (Object.keys(losses).length) charts.append(element("figure", {}, lineChart(losses, { title: "Loss" }), element("figcaption", { class: "muted", text: "Loss" })));
  if (Object.keys(successes).length) charts.append(element("figure", {}, lineChart(successes, { title: "Success" }), element("figcaption", { class: "muted", text: "Success and accuracy" })));
  if (metrics.before && metrics.after) {
    charts.append(element("figure", {}, beforeAfterChart(metrics.before, metrics.after), element("figcaption", { class: "muted", text: "Before and after this fine-tune" })));
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
}

main().catch((error) => console.warn(error));
