import { api } from "../api.js";
import { element, pageFailed, pageReady, say, startPage } from "../shell.js";

const $ = (id) => document.getElementById(id);
let me;

async function listMembers() {
  const members = await api("/members");
  const body = $("members");
  body.innerHTML = "";
  const admin = me.role === "admin";
  for (const member of members) {
    const label = `Role of ${member.display_name}`;
    const role = admin && member.id !== me.id
      ? element("select", { "aria-label": label, onchange: (e) => update(member, { role: e.target.value }) },
          ...["member", "admin"].map((r) => element("option", { value: r, text: r, selected: r === member.role })))
      : element("span", { text: member.role });
    const active = admin && member.id !== me.id
      ? element("input", { type: "checkbox", checked: member.is_active, "aria-label": `${member.display_name} may sign in`, style: "width:auto;min-height:0",
          onchange: (e) => update(member, { is_active: e.target.checked }) })
      : element("span", { text: member.is_active ? "yes" : "no" });
    body.append(element("tr", {}, element("td", { text: member.display_name }), element("td", { text: member.username }), element("td", {}, role), element("td", {}, active)));
  }
}

async function update(member, change) {
  try {
    await api(`/members/${member.id}`, { method: "PATCH", json: change });
    say($("members-message"), `Saved ${member.display_name}.`, "ok");
  } catch (error) {
    say($("members-message"), error.message, "error");
  }
  await listMembers();
}

async function main() {
  ({ me } = await startPage("household"));
  $("invite-card").hidden = me.role !== "admin";
  $("invite").addEventListener("submit", async (event) => {
    event.preventDefault();
    const form = event.target;
    const body = Object.fromEntries(new FormData(form));
    try {
      const user = await api("/members", { method: "POST", json: body });
      say($("invite-message"), `Added ${user.display_name}: they can sign in as “${user.username}”.`, "ok");
      form.reset();
      await listMembers();
    } catch (error) {
      say($("invite-message"), error.message, "error");
    }
  });
  pageReady();
  await listMembers();
}

main().catch(pageFailed);
