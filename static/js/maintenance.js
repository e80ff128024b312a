// The engine's maintenance: a form to record a water wash, module change, shop visit or
// borescope finding with notes, the list of the engine's actions, and for each wash the
// recovery measured across it (GET /maintenance-actions/{id}/recovery: the change of the EGT
// margin and the health levels between the records before and the settled records after).
import { api, me } from "./api.js";
import { fmtNum, fmtTime, h, showError } from "./ui.js";

export const KINDS = {
  water_wash: "water wash",
  module_change: "module change",
  shop_visit: "shop visit",
  borescope_finding: "borescope finding",
};

const signed = (x, digits) => `${x >= 0 ? "+" : "−"}${fmtNum(Math.abs(x), digits)}`;

function recoveryView(r) {
  if (r.note) return h("span", { class: "muted" }, r.note);
  // EGT margin first, then the health parameters by the size of their change.
  const rows = [...r.series].sort((a, b) => (a.group === b.group ? Math.abs(b.change) - Math.abs(a.change) : a.group === "performance" ? -1 : 1));
  return h("div", {},
    h("ul", { class: "recovery" }, rows.map((s) => h("li", { dataset: { series: s.name } },
      `${s.name === "egt_margin" ? "EGT margin" : s.name} ${signed(s.change, 2)} ${s.unit}`,
      s.standard_error === null ? "" : h("span", { class: "muted" }, ` ±${fmtNum(s.standard_error, 2)}`)))),
    h("div", { class: "muted" }, `${r.n_before} records before, ${r.n_after} settled records after`));
}

async function actionRows(engineId) {
  const page = await api("/api/v1/maintenance-actions", { query: { engine_id: engineId, limit: 200 } });
  const washes = page.items.filter((m) => m.kind === "water_wash");
  const recoveries = await Promise.all(washes.map((m) =>
    api(`/api/v1/maintenance-actions/${m.id}/recovery`).catch((err) => ({ error: err }))));
  const byId = new Map(washes.map((m, i) => [m.id, recoveries[i]]));
  return page.items.map((m) => {
    const r = byId.get(m.id);
    const recovery = !r ? h("span", { class: "muted" }, "–")
      : r.error ? h("span", { class: "muted" }, `not measured: ${r.error.message}`) : recoveryView(r);
    return h("tr", { dataset: { id: m.id, kind: m.kind } },
      h("td", {}, fmtTime(m.performed_at)), h("td", {}, KINDS[m.kind] || m.kind),
      h("td", {}, m.notes || h("span", { class: "muted" }, "–")), h("td", { class: "recovery-cell" }, recovery));
  });
}

function form(engineId, principal, onRecorded) {
  const kind = h("select", { id: "mx-kind", name: "kind" }, Object.entries(KINDS).map(([v, label]) => h("option", { value: v }, label)));
  const at = h("input", { id: "mx-at", name: "performed_at", type: "datetime-local", required: true });
  const notes = h("textarea", { id: "mx-notes", name: "notes", rows: 2, style: "width:100%", placeholder: "what was done or found" });
  const message = h("div", { role: "status" });
  const canWrite = principal.role !== "viewer";
  const submit = async (e) => {
    e.preventDefault();
    message.replaceChildren();
    if (!at.value) { showError(message, new Error("Give the date and time the action was performed.")); return; }
    const performed = new Date(`${at.value}:00Z`);
    try {
      await api("/api/v1/maintenance-actions", { method: "POST", body: {
        engine_id: Number(engineId), kind: kind.value, performed_at: performed.toISOString(), notes: notes.value.trim() } });
      notes.value = "";
      message.replaceChildren(h("p", { class: "notice" }, `Recorded: ${KINDS[kind.value]} at ${fmtTime(performed.toISOString())}. The engine's estimates from then on are redone in the background.`));
      await onRecorded();
    } catch (err) {
      showError(message, err, "Not recorded");
    }
  };
  return h("form", { id: "mx-form", onsubmit: submit },
    canWrite ? null : h("p", { class: "notice" }, "Your key is a viewer key: recording maintenance needs an analyst key."),
    h("div", { class: "toolbar" },
      h("label", { for: "mx-kind" }, "Action", kind),
      h("label", { for: "mx-at" }, "Performed at (UTC)", at)),
    h("label", { for: "mx-notes", style: "display:block;margin-top:.5rem" }, "Notes", notes),
    h("div", { class: "toolbar", style: "margin-top:.5rem" },
      h("button", { type: "submit", id: "mx-record", disabled: !canWrite }, "Record action")),
    message);
}

// The maintenance section of the engine page; ``onChange`` runs after an action is recorded
// (the page redraws its trend, so the new marker shows).
export async function maintenancePanel(engineId, onChange) {
  const section = h("section", { class: "card", id: "maintenance", "aria-labelledby": "maintenance-title" },
    h("h2", { id: "maintenance-title" }, "Maintenance"));
  document.querySelector("main").append(section);
  const principal = await me();
  const body = h("tbody", { id: "mx-rows" });
  const table = h("table", { class: "data", id: "mx-list" },
    h("caption", { class: "muted", style: "text-align:left" }, "The engine's maintenance actions, newest first; for a water wash the recovery measured across it (after minus before)."),
    h("thead", {}, h("tr", {}, ["When", "Action", "Notes", "Recovery"].map((c) => h("th", { scope: "col" }, c)))), body);
  const refresh = async () => {
    const rows = await actionRows(engineId);
    body.replaceChildren(...(rows.length ? rows : [h("tr", {}, h("td", { colspan: 4, class: "muted" }, "No maintenance recorded."))]));
  };
  section.append(form(engineId, principal, async () => { await refresh(); if (onChange) await onChange(); }),
    h("h3", {}, "Actions"), h("div", { class: "table-wrap" }, table));
  try {
    await refresh();
  } catch (err) {
    showError(section, err, "Maintenance actions");
  }
}
