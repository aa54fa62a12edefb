// What every page shares: the header with navigation, the signed-in member, messages, the chosen robot.
import { api } from "./api.js";

const LINKS = [
  ["", "Start"],
  ["record", "Record"],
  ["label", "Label"],
  ["progress", "Progress"],
  ["scene", "Scene"],
  ["household", "Household"],
  ["admin", "Admin"],
];

/** Signs the page in (or sends the visitor to the sign-in page) and draws the header. */
export async function startPage(active, { adminOnly = false } = {}) {
  const me = await api("/auth/me");
  const household = await api("/household");
  drawHeader(active, me, household);
  offerShortcutList();
  if (adminOnly && me.role !== "admin") {
    stopPage("Only a household admin can use this page. Ask an admin of your household to give you the admin role.", "warn");
    throw new PageStopped();
  }
  return { me, household };
}

/** Thrown once the page has replaced its controls with a note saying why it cannot go on. */
class PageStopped extends Error {}

function stopPage(text, kind) {
  const main = document.querySelector("main");
  const note = element("p", { role: "alert" });
  say(note, text, kind);
  main.replaceChildren(note);
  main.inert = false;
}

function drawHeader(active, me, household) {
  const header = document.createElement("header");
  header.className = "top";
  const links = LINKS.filter(([page]) => page !== "admin" || me.role === "admin")
    .map(([page, title]) => `<li><a href="/${page}"${page === active ? ' aria-current="page"' : ""}>${title}</a></li>`)
    .join("");
  header.innerHTML = `
    <a class="brand" href="/">varbot</a>
    <nav aria-label="Pages"><ul>${links}</ul></nav>
    <div class="who"><span></span><button type="button" class="signout">Sign out</button></div>`;
  header.querySelector(".who span").textContent = `${me.display_name} · ${household.name}${me.role === "admin" ? " (admin)" : ""}`;
  header.querySelector(".signout").addEventListener("click", async () => {
    try {
      await api("/auth/logout", { method: "POST" });
    } finally {
      location.assign("/login");
    }
  });
  const skip = document.createElement("a");
  skip.className = "skip-link";
  skip.href = "#main";
  skip.textContent = "Skip to content";
  document.body.prepend(skip, header);
}

/**
 * Every page's <main> starts inert: nothing in it can be clicked, typed into or submitted, since a press before
 * its handler exists would be lost and a form would be submitted natively. The page calls this once every
 * control's handler is attached.
 */
export function pageReady() {
  document.querySelector("main").inert = false;
  document.body.dataset.ready = "true";
}

/** A page's start-up failed: before it was ready, its controls give way to the reason; after, the error is only logged. */
export function pageFailed(error) {
  if (error instanceof PageStopped) return;
  console.warn(error);
  if (document.body.dataset.ready || error.status === 401) return; // 401: already on the way to the sign-in page
  stopPage(`This page could not start: ${error.message}. Reload the page to try again; if it fails again, ask your household's admin to check the server.`, "error");
}

/** Shows a message in an aria-live region: kind is "", "ok", "warn" or "error". */
export function say(element, text, kind = "") {
  element.className = `message ${kind}`.trim();
  element.textContent = text;
}

export function element(tag, attributes = {}, ...children) {
  const node = document.createElement(tag);
  for (const [key, value] of Object.entries(attributes)) {
    if (key === "class") node.className = value;
    else if (key === "text") node.textContent = value;
    else if (key === "style") node.style.cssText = value; // a style attribute would be refused by the CSP
    else if (key.startsWith("on")) node.addEventListener(key.slice(2), value);
    else if (value !== undefined && value !== null && value !== false) node.setAttribute(key, value === true ? "" : value);
  }
  node.append(...children);
  return node;
}

const ROBOT_KEY = "varbot.robot";

/** The robot chosen on an earlier page, or the household's first; null without robots. */
export function savedRobot(robots) {
  const saved = localStorage.getItem(ROBOT_KEY);
  return robots.find((r) => String(r.id) === saved) || robots[0] || null;
}

/** Fills a <select> with the household's robots; remembers the choice across pages. */
export async function robotPicker(select, onChange = () => {}) {
  const robots = await api("/robots");
  select.innerHTML = "";
  for (const robot of robots) {
    select.append(element("option", { value: robot.id, text: `${robot.name} (${robot.kind})` }));
  }
  const saved = savedRobot(robots);
  if (saved) select.value = saved.id;
  select.onchange = () => {  // a picker built again for the same select replaces the old one's handler
    localStorage.setItem(ROBOT_KEY, select.value);
    onChange(robotById(select.value));
  };
  const robotById = (id) => robots.find((r) => String(r.id) === String(id)) || null;
  return { robots, current: () => robotById(select.value) };
}

// --- the "?" shortcut list -----------------------------------------------------------------------------------

/** The page's shortcuts, from its controls' aria-keyshortcuts and their names: [[keys, what it does]]. */
function pageShortcuts() {
  return [...document.querySelectorAll("main [aria-keyshortcuts]")]
    .filter((control) => !control.closest("[hidden]"))
    .map((control) => [control.getAttribute("aria-keyshortcuts"), control.dataset.shortcut || shortcutName(control)]);
}

function shortcutName(control) {
  const copy = control.cloneNode(true);
  copy.querySelectorAll("kbd").forEach((kbd) => kbd.remove());
  return (control.getAttribute("aria-label") || copy.textContent).trim();
}

const hasShortcuts = () => document.querySelector("main [aria-keyshortcuts]") !== null;

/** On a page with keyboard shortcuts, "?" (or the header's button) opens their list; Escape closes it. */
function offerShortcutList() {
  if (!hasShortcuts()) return;
  const dialog = element("dialog", { class: "shortcuts", "aria-labelledby": "shortcuts-title" });
  document.body.append(dialog);
  const open = () => {
    const rows = pageShortcuts().flatMap(([keys, what]) => [element("dt", {}, element("kbd", { text: keys })), element("dd", { text: what })]);
    dialog.replaceChildren(
      element("h2", { id: "shortcuts-title", text: "Keyboard shortcuts" }),
      element("dl", {}, ...rows, element("dt", {}, element("kbd", { text: "?" })), element("dd", { text: "Show this list" })),
      element("button", { type: "button", text: "Close", onclick: () => dialog.close() }),
    );
    if (!dialog.open) dialog.showModal();
  };
  const button = element("button", { type: "button", class: "shortcuts-button", "aria-keyshortcuts": "?", "aria-label": "Keyboard shortcuts", text: "?", onclick: open });
  document.querySelector("header.top .who").prepend(button);
  document.addEventListener("keydown", (event) => {
    const tag = event.target.tagName;
    if (event.key !== "?" || event.ctrlKey || event.metaKey || tag === "INPUT" || tag === "TEXTAREA" || tag === "SELECT") return;
    event.preventDefault();
    open();
  });
}

export function when(iso) {
  return iso ? new Date(iso).toLocaleString() : "";
}
