// Fleet status: every engine with its state, sortable and filterable; fleet-average deterioration.
import { api } from "./api.js";
import { $, badge, fmtAgo, fmtNum, fmtTime, h, showError, sortableTable, startPage, tailLink } from "./ui.js";
import { axisTitle, layout, plot, styleFor, unitOf } from "./plots.js";
import { reportButtons } from "./reports.js";
import { label as nameOf } from "./glossary.js";

let engines = [];
// engine id -> its data coverage (newest record, overdue), from /api/v1/fleet/data-coverage.
let coverage = new Map();
let coverageNow = null;
const DAY_MS = 86400e3;  // one day [ms]
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
    { key: "last_data", label: "Last data", value: (e) => coverage.get(e.engine_id)?.last_data ?? e.last_data, cell: lastDataCell },
    // Severity rank from the API: red, amber, normal, then by how far past the type's limits.
    { key: "rank", label: "State", value: (e) => -(e.rank ?? 1e9), cell: (e) => badge(e.state) },
    { key: "reason", label: "Reason", value: (e) => e.reason || "",
      cell: (e) => h("span", { title: checksText(e) }, e.reason || h("span", { class: "muted" }, "within limits")) },
    { key: "worst", label: "Largest health level from nominal [%]", value: (e) => (e.health ? Math.abs(e.health.worst_health_value ?? 0) : null),
      cell: (e) => (e.health && e.health.worst_health ? `${e.health.worst_health} ${fmtNum(e.health.worst_health_value)} ± ${fmtNum(e.health.worst_health_sigma)}` : "–") },
    { key: "thrust", label: "Thrust deficit [%]", numeric: true, value: (e) => e.health?.thrust_deficit ?? null, cell: (e) => withSigma(e.health?.thrust_deficit, check(e, "thrust_deficit")?.sigma) },
    { key: "n_records", label: "Records", numeric: true },
    { key: "open_events", label: "Active events", numeric: true,
      cell: (e) => (e.latest_event ? h("span", {}, `${e.open_events} `, h("a", { href: `/events.html?id=${e.latest_event.id}` },
        `${e.latest_event.fault || e.latest_event.kind} ${fmtTime(e.latest_event.detected_at).slice(0, 10)}`)) : String(e.open_events)) },
  ];
}

function check(e, limit) {
  return (e.checks || []).find((c) => c.limit === limit);
}

function withSigma(value, sigma) {
  if (value === null || value === undefined) return "–";
  return sigma !== null && sigma !== undefined ? `${fmtNum(value)} ± ${fmtNum(sigma)}` : fmtNum(value);
}

// Every limit check of the engine, its value with its 1-sigma where the design is calibrated:
// the reason cell's tooltip.
function checksText(e) {
  const unit = (u) => (u === "degC" ? "°C" : u);
  return (e.checks || []).map((c) => `${c.limit.replaceAll("_", " ")}: ${withSigma(c.value, c.sigma)} ${unit(c.unit)} (${c.level}; amber ${c.amber}, red ${c.red})`).join("\n");
}

function overdueBadge() {
  return h("span", { class: "badge alert overdue", title: `no data for longer than ${$("#overdue-days").value} days` }, "overdue");
}

// The newest record (from the coverage, which counts records not yet estimated too), how long
// ago, and the overdue flag.
function lastDataCell(e) {
  const c = coverage.get(e.engine_id);
  const last = c ? c.last_data : e.last_data;
  return h("span", { class: "last-data" }, fmtTime(last), c && last ? h("span", { class: "muted" }, ` · ${fmtAgo(last, coverageNow)}`) : null,
    c && c.overdue ? [" ", overdueBadge()] : null);
}

async function loadCoverage() {
  const message = $("#coverage-message");
  message.replaceChildren();
  try {
    const days = $("#overdue-days").value;
    const data = await api("/api/v1/fleet/data-coverage", { query: { overdue_days: days || undefined } });
    if (!days) $("#overdue-days").value = data.overdue_days;
    coverage = new Map(data.engines.map((e) => [e.engine_id, e]));
    coverageNow = data.now;
    $("#overdue-count").textContent = `${data.n_overdue} of ${data.engines.filter((e) => e.tail).length} installed engines overdue`;
    const withData = data.engines.filter((e) => e.last_data).reverse();  // oldest at the top
    const age = (e) => (Date.parse(data.now) - Date.parse(e.last_data)) / DAY_MS;
    const label = (e) => `${e.esn}${e.tail ? ` (${e.tail} #${e.position})` : ""}`;
    const colour = (e) => (e.overdue ? "#D55E00" : e.tail ? "#009E73" : "#999999");
    const height = Math.max(260, 90 + 22 * withData.length);
    $("#coverage-plot").style.minHeight = `${height}px`;
    await plot($("#coverage-plot"), [{
      type: "bar", orientation: "h", name: "days since last data",
      y: withData.map(label), x: withData.map(age), marker: { color: withData.map(colour) },
      customdata: withData.map((e) => fmtTime(e.last_data)), hovertemplate: "%{x:.1f} d (last record %{customdata})<extra></extra>",
    }], layout({
      height, hovermode: "closest", showlegend: false,
      xaxis: { title: { text: "Days since the newest record [d]" }, rangemode: "tozero" },
      yaxis: { type: "category", automargin: true },
      shapes: [{ type: "line", xref: "x", yref: "paper", x0: data.overdue_days, x1: data.overdue_days, y0: 0, y1: 1, line: { color: "#D55E00", dash: "dash", width: 1.5 } }],
      annotations: [{ xref: "x", yref: "paper", x: data.overdue_days, y: 1, yanchor: "bottom", text: `overdue after ${fmtNum(data.overdue_days, 1)} d`, showarrow: false, font: { color: "#B84A00" } }],
    }));
    const onTail = (t) => data.engines.filter((e) => e.aircraft_id === t.aircraft_id).sort((a, b) => a.position - b.position);
    $("#coverage-tails").replaceChildren(data.tails.length ? sortableTable([
      { key: "tail", label: "Tail", cell: (t) => tailLink(t.tail) },
      { key: "last_data", label: "Last data (any position)", cell: (t) => h("span", {}, fmtTime(t.last_data), t.last_data ? h("span", { class: "muted" }, ` · ${fmtAgo(t.last_data, data.now)}`) : null) },
      { key: "engines", label: "Engines installed: last data", value: (t) => t.engines_installed, cell: (t) => h("ul", { class: "plain" }, onTail(t).map((e) =>
        h("li", { class: `coverage-engine${e.overdue ? " overdue" : ""}`, dataset: { engine: e.engine_id } }, `#${e.position} `, h("a", { href: `/engine.html?id=${e.engine_id}` }, e.esn),
          ` ${e.last_data ? fmtAgo(e.last_data, data.now) : "no data yet"}`, e.overdue ? [" ", overdueBadge()] : null))) },
      { key: "engines_overdue", label: "Overdue", numeric: true },
    ], data.tails, { sortKey: "engines_overdue", descending: true, rowClass: (t) => `coverage-tail${t.engines_overdue ? " overdue" : ""}` })
      : h("p", { class: "muted" }, "No aircraft yet."));
  } catch (err) {
    showError(message, err, "Last data");
  }
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
  await drawEgtMargins();
}

// The EGT margin of each engine of the page that has one (the status's egt_margin check),
// worst at the top, coloured by its level, ±1σ where the design is calibrated, with the amber
// and red limits as lines where every engine's type has the same.
async function drawEgtMargins() {
  const LEVEL_COLOUR = { red: "#D55E00", amber: "#E69F00", normal: "#009E73" };
  const rows = engines.map((e) => ({ e, c: (e.checks || []).find((c) => c.limit === "egt_margin") }))
    .filter((r) => r.c && r.c.value !== null && r.c.value !== undefined)
    .sort((a, b) => b.c.value - a.c.value);  // plotly draws the first category at the bottom
  const message = $("#egt-message");
  message.replaceChildren();
  if (!rows.length) {
    $("#egt-plot").replaceChildren();
    message.append(h("p", { class: "muted" }, "No EGT margin yet: it needs a design of the built-in engine and records with EGT (T48)."));
    return;
  }
  const same = (key) => rows.every((r) => r.c[key] === rows[0].c[key]);
  const lines = same("amber") && same("red") ? [["amber", rows[0].c.amber], ["red", rows[0].c.red]] : [];
  const height = Math.max(260, 90 + 22 * rows.length);
  $("#egt-plot").style.minHeight = `${height}px`;
  await plot($("#egt-plot"), [{
    type: "bar", orientation: "h", name: "EGT margin",
    y: rows.map((r) => `${r.e.esn}${r.e.tail ? ` (${r.e.tail} #${r.e.position})` : ""}`),
    x: rows.map((r) => r.c.value), marker: { color: rows.map((r) => LEVEL_COLOUR[r.c.level] || "#999999") },
    // ±1σ where the design's calibration gives one (the figure scored against the simulator).
    error_x: { type: "data", array: rows.map((r) => r.c.sigma ?? 0), visible: rows.some((r) => r.c.sigma != null), color: "#333333", thickness: 1.2, width: 3 },
    customdata: rows.map((r) => (r.c.sigma != null ? `${r.c.reason} (±${fmtNum(r.c.sigma, 1)} °C, 1σ)` : r.c.reason)),
    hovertemplate: "%{customdata}<extra></extra>",
    meta: { role: "egt-margin" },
  }], layout({
    height, hovermode: "closest", showlegend: false,
    xaxis: { title: { text: "EGT margin [°C]" }, zeroline: true },
    yaxis: { type: "category", automargin: true },
    shapes: lines.map(([level, x]) => ({ type: "line", xref: "x", yref: "paper", x0: x, x1: x, y0: 0, y1: 1, line: { color: LEVEL_COLOUR[level], dash: "dash", width: 1.5 } })),
    annotations: lines.map(([level, x]) => ({ xref: "x", yref: "paper", x, y: 1, yanchor: "bottom", text: `${level} ${fmtNum(x, 0)} °C`, showarrow: false, font: { color: LEVEL_COLOUR[level] } })),
  }));
}

// Fleet-average deterioration slope per health parameter: a number ± 1σ (both in the group's
// unit, %/year), "unobservable" where the design cannot observe it (listed by the API), or no
// trend yet (no engine trend long enough). A design calibrated before the 1σ held the gain's
// standard error shows its slope with "1σ: recalibrate" instead of a sigma.
function slopeText(g, p) {
  if (p.sigma !== null) return `${fmtNum(p.slope)} ± ${fmtNum(p.sigma)} ${g.unit}`;
  if (g.uncertainty === "recalibrate") return `${fmtNum(p.slope)} ${g.unit} (1σ: recalibrate the design)`;
  return `${fmtNum(p.slope)} ${g.unit}`;
}

function drawSlopes(groups) {
  const rows = [];
  for (const g of groups) {
    const s = g;
    for (const p of s.health) {
      rows.push(h("tr", { "data-code": p.name },
        h("td", {}, nameOf(p.name)),
        groups.length > 1 ? h("td", {}, g.engine_type) : null,
        p.slope === null
          ? h("td", { class: "muted" }, s.unobservable.includes(p.name) ? "unobservable" : "no trend yet (an engine needs about 3 months between baseline resets)")
          : h("td", { class: "num" }, slopeText(s, p))));
    }
  }
  const state = { calibrated: "calibrated: ±1σ", uncalibrated: "uncalibrated: no σ", recalibrate: "calibrated before the 1σ held the gain's own error: recalibrate the design for a σ" };
  const note = groups.map((g) => `${g.engine_type}: ${g.pieces} engine trends over ${g.engines} engines (${state[g.uncertainty] ?? g.uncertainty})`).join("; ");
  $("#slopes").replaceChildren(
    h("table", { class: "compact" },
      h("thead", {}, h("tr", {}, h("th", {}, "Health parameter"), groups.length > 1 ? h("th", {}, "Engine type") : null, h("th", {}, "Slope ± 1σ [%/year]"))),
      h("tbody", {}, ...rows)),
    h("p", { class: "legend-note" }, note));
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
      // A health parameter the design cannot observe: named, not drawn.
      const hidden = new Set(which === "health" ? g.unobservable || [] : []);
      if (hidden.size) {
        message.append(h("p", { class: "muted", id: `unobservable-${g.design_id}` },
          `${multi ? `${g.engine_type}: n` : "N"}ot observable with its design: ${[...hidden].map(nameOf).join(", ")}.`));
      }
      const series = g[which].filter((s) => !hidden.has(s.name));
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
    drawSlopes((await api("/api/v1/fleet/deterioration/slopes")).groups);
    // The auxiliary outputs as the estimates keep them: each record's change from the nominal
    // engine at its own condition, in percent of that engine's value (a stall margin at -50 %
    // is half the nominal margin); the engine page has them in their units.
    const label = which === "health" ? "Fleet-average health level" : "Fleet-average change from the nominal engine";
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
  $("#reports").append(...reportButtons("/api/v1/fleet/report", $("#message"), "fleet-report"));
  for (const id of ["filter", "open"]) $(`#${id}`).addEventListener("input", drawTable);
  $("#state").addEventListener("change", () => { offset = 0; loadStatus().catch((err) => showError($("#message"), err, "Fleet status")); });
  for (const id of ["bucket", "which"]) $(`#${id}`).addEventListener("change", loadDeterioration);
  $("#overdue-days").addEventListener("change", async () => { await loadCoverage(); drawTable(); });
  await loadCoverage();
  try { await loadStatus(); } catch (err) { showError($("#message"), err, "Fleet status"); }
  await loadDeterioration();
  document.body.dataset.ready = "true";
}

main();
