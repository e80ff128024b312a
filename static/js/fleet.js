// Fleet status: every engine with its state, sortable and filterable; fleet-average deterioration.
import { api } from "./api.js";
import { $, badge, fmtNum, fmtTime, h, showError, sortableTable, startPage, tailLink } from "./ui.js";
import { axisTitle, layout, plot, styleFor, unitOf } from "./plots.js";
import { label as nameOf } from "./glossary.js";

let engines = [];
// Engines per page: the API ranks the whole fleet, worst first, and sends a page of it.
const PAGE = 200;
let offset = 0;
let total = 0;

function columns() {
  return [
    { key: "esn", label: "ESN", cell: (e) => h("a", { href: `/engine.html?id=${e.engine_id}` }, e.esn) },
    { key: "tail", label: "Tail", value: (e) => e.tail, cell: (e) => (e.tail ? tailLink(e.tail) : null) || h("span", { class: "muted" }, "not installed") },
    { key: "position", label: "Pos.", numeric: true },
    { key: "engine_type", label: "Engine type" },
    { key: "last_data", label: "Last data", cell: (e) => fmtTime(e.last_data) },
    // Severity rank from the API: red, amber, normal, then by how far past the type's limits.
    { key: "rank", label: "State", value: (e) => -(e.rank ?? 1e9), cell: (e) => badge(e.state) },
    { key: "reason", label: "Reason", value: (e) => e.reason || "", cell: (e) => e.reason || h("span", { class: "muted" }, "within limits") },
    { key: "worst", label: "Largest health change [%]", value: (e) => (e.health ? Math.abs(e.health.worst_health_value ?? 0) : null),
      cell: (e) => (e.health && e.health.worst_health ? `${e.health.worst_health} ${fmtNum(e.health.worst_health_value)} ± ${fmtNum(e.health.worst_health_sigma)}` : "–") },
    { key: "thrust", label: "Thrust deficit [%]", numeric: true, value: (e) => e.health?.thrust_deficit ?? null, cell: (e) => fmtNum(e.health?.thrust_deficit) },
    { key: "n_records", label: "Records", numeric: true },
    { key: "open_events", label: "Active events", numeric: true,
      cell: (e) => (e.latest_event ? h("span", {}, `${e.open_events} `, h("a", { href: `/events.html?id=${e.latest_event.id}` },
        `${e.latest_event.fault || e.latest_event.kind} ${fmtTime(e.latest_event.detected_at).slice(0, 10)}`)) : String(e.open_events)) },
  ];
}

function pager() {
  if (total <= PAGE) return h("span");
  const go = (to) => h("button", { type: "button", onclick: () => { offset = to; loadStatus().catch((err) => showError($("#message"), err, "Fleet status")); } });
  const prev = go(Math.max(0, offset - PAGE));
  prev.textContent = "◀ more severe";
  prev.disabled = offset === 0;
  const next = go(offset + PAGE);
  next.textContent = "less severe ▶";
  next.disabled = offset + PAGE >= total;
  return h("div", { class: "toolbar", id: "pager" }, prev,
    h("span", { class: "muted" }, `engines ${offset + 1}–${Math.min(offset + PAGE, total)} of ${total}, worst first`), next);
}

function drawTable() {
  const text = $("#filter").value.trim().toLowerCase();
  const open = $("#open").value;
  const rows = engines.filter((e) => (!open || e.open_events > 0) &&
    (!text || [e.esn, e.tail, e.engine_type, e.health?.worst_health, e.state].some((v) => v && String(v).toLowerCase().includes(text))));
  $("#count").textContent = total > engines.length ? `${rows.length} of ${engines.length} engines on this page (${total} in all)` : `${rows.length} of ${total} engines`;
  $("#table").replaceChildren(rows.length ? sortableTable(columns(), rows, { sortKey: "rank", descending: true, rowClass: (e) => `state-${e.state}` })
    : h("p", { class: "muted" }, total ? "No engine matches the filter." : "No engines yet: add engines and upload snapshots."), pager());
}

async function loadStatus() {
  const state = $("#state").value;
  const status = await api("/api/v1/fleet/status", { query: { limit: PAGE, offset, ...(state ? { state } : {}) } });
  engines = status.engines;
  total = status.total;
  const by = (s) => status.states[s];
  $("#summary").replaceChildren(
    h("div", { class: "card" }, h("div", { class: "muted" }, "Engines"), h("div", { class: "big" }, status.n_engines)),
    h("div", { class: "card" }, h("div", { class: "muted" }, "Active events"), h("a", { class: "big", href: "/events.html?status=active" }, status.n_open_events)),
    h("div", { class: "card" }, h("div", { class: "muted" }, "Red (alert) / amber (watch) / normal"), h("div", { class: "big" }, `${by("alert")} / ${by("watch")} / ${by("normal")}`)),
    h("div", { class: "card" }, h("div", { class: "muted" }, "Operator"), h("div", { class: "big" }, status.operator)));
  drawTable();
}

async function loadDeterioration() {
  const div = $("#deterioration");
  const message = $("#deterioration-message");
  message.replaceChildren();
  try {
    const data = await api("/api/v1/fleet/deterioration", { query: { bucket: $("#bucket").value } });
    const which = $("#which").value;
    const traces = [];
    const multi = data.groups.length > 1;
    let units = [];
    data.groups.forEach((g, gi) => {
      const series = g[which];
      units = units.concat(series.map((s) => s.unit));
      series.forEach((s, i) => {
        const style = styleFor(s.name, i);
        traces.push({
          x: g.time, y: s.mean, type: "scatter", mode: "lines+markers",
          name: multi ? `${nameOf(s.name)} (${g.engine_type})` : nameOf(s.name), meta: { role: "line", code: s.name },
          line: { color: style.color, dash: gi ? "dot" : style.dash, width: 1.8 },
          error_y: { type: "data", array: s.sigma, visible: true, thickness: 1, width: 3, color: style.color },
          customdata: g.n_engines.map((n, k) => [n, s.sigma[k]]),
          hovertemplate: `%{y:.3f} ± %{customdata[1]:.3f} ${s.unit} (1σ over %{customdata[0]} engines)`,
        });
      });
    });
    if (!traces.length) message.append(h("p", { class: "muted" }, "No estimates yet."));
    const label = which === "health" ? "Fleet-average health parameter change" : "Fleet-average thrust and margin change";
    await plot(div, traces, layout({
      xaxis: { title: { text: "Date (UTC)" }, type: "date" },
      yaxis: { title: { text: axisTitle(label, unitOf(units.map((unit) => ({ unit })))) } },
    }));
  } catch (err) {
    showError(message, err, "Fleet-average deterioration");
  }
}

async function main() {
  await startPage("fleet");
  for (const id of ["filter", "open"]) $(`#${id}`).addEventListener("input", drawTable);
  $("#state").addEventListener("change", () => { offset = 0; loadStatus().catch((err) => showError($("#message"), err, "Fleet status")); });
  for (const id of ["bucket", "which"]) $(`#${id}`).addEventListener("change", loadDeterioration);
  try { await loadStatus(); } catch (err) { showError($("#message"), err, "Fleet status"); }
  await loadDeterioration();
  document.body.dataset.ready = "true";
}

main();
