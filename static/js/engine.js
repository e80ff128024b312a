// Engine trend: tuners, health parameters and thrust/margins with 1-sigma bands, residuals and
// WSSR, against date or cycles, with installation, maintenance and event markers.
import { api, apiAll, apiText, download } from "./api.js";
import { $, fmtTime, h, params, showError, startPage, tailLink } from "./ui.js";
import { MARKER_COLOURS, axisTitle, layout, limitShapes, lineWithBand, markerAnnotations, markerScale, markerShapes, plot, syncZoom, trendMarkers, unitOf } from "./plots.js";
import { faultLabel, label } from "./glossary.js";
import { maintenancePanel } from "./maintenance.js";
import { reportButtons } from "./reports.js";

const ORDER = ["health", "aux", "tuners", "residuals", "wssr"];
// The auxiliary outputs are the design model's own (thrust and stall margins on the built-in
// engine, whatever the type's model declares on another): titled by their names.
const TITLES = {
  health: "Health parameters",
  aux: (group) => `Estimated auxiliary outputs: ${group.series.map((s) => label(s.name)).join(", ")}`,
  tuners: "Tuners",
  residuals: "Sensor residuals",
  wssr: "WSSR per fault hypothesis",
};
// Short y-axis titles, so the unit stays visible on a narrow plot.
const YLABELS = { health: "Health change", aux: "Output change", tuners: "Tuner", residuals: "Residual", wssr: "WSSR" };
let trend = null;
let designs = [];
let principal = null;

// The performance group (engineering units) drawn as one panel per quantity, each with the
// engine type's limit lines on its series.
const PERFORMANCE_PANELS = [
  { key: "perf-egt", title: "EGT margin (take-off, ISA+15 K)", ylabel: "EGT margin", series: ["egt_margin"] },
  { key: "perf-degt", title: "ΔEGT against the baseline (corrected, smoothed)", ylabel: "ΔEGT", series: ["dEGT"] },
  { key: "perf-deltas", title: "ΔWf, ΔN2, ΔN1 against the baseline (smoothed)", ylabel: "Delta", series: ["dWf", "dN2", "dN1"] },
  // Thrust itself differs fourfold between take-off and cruise: one line per phase.
  { key: "perf-thrust", title: "Net thrust, per flight phase", ylabel: "Thrust", series: ["Fn"], byPhase: true },
  { key: "perf-rated", title: "Net thrust in % of rated (take-off, sea level, ISA), per flight phase", ylabel: "Thrust", series: ["Fn_rated"], byPhase: true },
  { key: "perf-deficit", title: "Thrust deficit against the nominal engine at the same condition", ylabel: "Thrust deficit", series: ["thrust_deficit"] },
  { key: "perf-margins", title: "Stall margins", ylabel: "Stall margin", series: ["SM_fan", "SM_LPC", "SM_HPC"] },
  { key: "perf-margin-change", title: "Stall-margin change from the baseline", ylabel: "Change", series: ["SM_fan_change", "SM_LPC_change", "SM_HPC_change"] },
  { key: "perf-t40", title: "Turbine inlet temperature (T40, estimated) against the nominal engine at the same condition", ylabel: "ΔT40", series: ["T40_change"] },
  { key: "perf-bpr", title: "Bypass ratio (estimated), per flight phase", ylabel: "Bypass ratio", series: ["BPR"], byPhase: true },
];
const UNIT_LABELS = { degC: "°C", pts: "margin points" };
// What a tuners, aux or performance band is (the API's group ``uncertainty``).
const BAND_NOTES = {
  calibrated: "Band: the 1-sigma calibrated against the built-in engine's simulator (filter, model error and, away from nominal, its growth).",
  uncalibrated: "Band: the filter's own 1-sigma (the design has no calibrated model error); measured figures have none.",
  recalibrate: "Band: the filter's own 1-sigma (measured figures: none): the design was calibrated before these figures were; calibrate it again for their honest bands.",
};

// A series split by flight phase: the records of each phase (a bucket mixing phases has none),
// with their indices into the trend's points (``idx``).
function byPhase(s) {
  const phases = [...new Set(trend.phase.filter(Boolean))];
  const pick = (arr, idx) => (arr ? idx.map((i) => arr[i]) : arr);
  return phases.map((phase) => {
    const idx = trend.phase.map((p, i) => (p === phase ? i : -1)).filter((i) => i >= 0);
    return { ...s, name: `${s.name} (${phase})`, idx, value: pick(s.value, idx), sigma: pick(s.sigma, idx),
      min: pick(s.min, idx), max: pick(s.max, idx) };
  }).filter((p) => p.idx.length);
}

function performancePanels() {
  const group = trend.groups.find((g) => g.key === "performance");
  if (!group) return [];
  return PERFORMANCE_PANELS.map((panel) => ({
    key: panel.key, label: panel.ylabel, title: panel.title,
    series: group.series.filter((s) => panel.series.includes(s.name)).map((s) => ({ ...s, unit: UNIT_LABELS[s.unit] || s.unit }))
      .flatMap((s) => (panel.byPhase ? byPhase(s) : [s])),
    limits: (group.limits || []).filter((l) => panel.series.includes(l.series)),
    uncertainty: group.uncertainty,
    // Estimated from aux outputs the calibration corrects (the measured figures are not).
    corrected: panel.series.some((name) => (group.calibrated_series || []).includes(name)),
  })).filter((panel) => panel.series.length);
}

function query() {
  const q = { max_points: $("#max_points").value, design_id: $("#design").value || undefined,
    health: $("#health").value };
  if ($("#start").value) q.start = `${$("#start").value}T00:00:00Z`;
  if ($("#end").value) q.end = `${$("#end").value}T23:59:59Z`;
  return q;
}

// Time (ms) -> record number on the cycles axis, by the nearest record at or after it.
function seqAt(ms) {
  const times = trend.time.map((t) => Date.parse(t));
  const i = times.findIndex((t) => t >= ms);
  return i < 0 ? null : trend.seq[i];
}

function markers(axis) {
  return trendMarkers(trend, (iso, seq) => (axis === "date" ? iso : seq ?? seqAt(Date.parse(iso))), fmtTime);
}

// Where the engine had no data for long (off wing, in the shop), break the lines instead of
// joining the two sides: a null point between them (plotly leaves gaps at nulls).
const GAP_MIN_MS = 3 * 86400e3;

function gapBreaks() {
  const t = trend.time.map((x) => Date.parse(x));
  const steps = t.slice(1).map((v, i) => v - t[i]).sort((a, b) => a - b);
  const typical = steps.length ? steps[Math.floor(steps.length / 2)] : 0;
  const limit = Math.max(GAP_MIN_MS, 20 * typical);
  return t.slice(1).map((v, i) => (v - t[i] > limit ? i : -1)).filter((i) => i >= 0);
}

function withBreaks(values, breaks, mid) {
  if (!breaks.length) return values;
  const out = [];
  let b = 0;
  values.forEach((v, i) => {
    out.push(v);
    if (b < breaks.length && breaks[b] === i) { out.push(mid ? mid(i) : null); b += 1; }
  });
  return out;
}

function xRange(axis) {
  if (axis !== "date") {
    const pad = Math.max(1, 0.01 * (trend.seq[trend.seq.length - 1] - trend.seq[0]));
    return [trend.seq[0] - pad, trend.seq[trend.seq.length - 1] + pad];
  }
  const a = Date.parse(trend.time[0]);
  const b = Date.parse(trend.time[trend.time.length - 1]);
  const pad = Math.max(3600e3, 0.01 * (b - a));
  return [new Date(a - pad).toISOString(), new Date(b + pad).toISOString()];
}

function draw() {
  const axis = $("#axis").value;
  const breaks = gapBreaks();
  const x = axis === "date"
    ? withBreaks(trend.time, breaks, (i) => new Date((Date.parse(trend.time[i]) + Date.parse(trend.time[i + 1])) / 2).toISOString())
    : withBreaks(trend.seq, breaks, (i) => (trend.seq[i] + trend.seq[i + 1]) / 2);
  const broken = (s) => ({ ...s, value: withBreaks(s.value, breaks), sigma: s.sigma && withBreaks(s.sigma, breaks),
    min: s.min && withBreaks(s.min, breaks), max: s.max && withBreaks(s.max, breaks) });
  const marks = markers(axis);
  const container = $("#plots");
  container.className = "grid two";
  container.replaceChildren();
  const divs = [];
  const pending = [];
  const pendingClicks = [];
  // Health first (the change since the baseline, the view engineers read), then the
  // performance panels in engineering units, then the rest. Where the performance panels
  // show every auxiliary output in its unit (the built-in engine), the design's own view of
  // them in percent of the nominal engine's value is left to the CSV and the API.
  const performance = performancePanels();
  const inUnits = new Set((trend.groups.find((g) => g.key === "performance")?.series || []).map((s) => s.name));
  const auxInUnits = (g) => g.key === "aux" && g.series.every((s) => inUnits.has(s.name) || inUnits.has(`${s.name}_change`));
  const ordered = ORDER.map((k) => trend.groups.find((g) => g.key === k)).filter((g) => g && !auxInUnits(g));
  const groups = [...ordered.slice(0, 1), ...performance, ...ordered.slice(1)];
  for (const group of groups) {
    const id = `plot-${group.key}`;
    // Many traces: a taller plot, so the legend's rows below it leave the data its height.
    const div = h("div", { id, class: group.series.length > 6 ? "plot tall" : "plot" });
    // Health: the change since the engine's baseline (or the level) with the honest 1-sigma
    // band; a parameter the design cannot estimate comes back as nulls and is named, not drawn.
    const hidden = new Set(group.unobservable || []);
    const notes = [];
    if (group.key === "health") {
      if (hidden.size) notes.push(`Not observable with this design: ${[...hidden].map(label).join(", ")}.`);
      if (group.uncertainty === "uncalibrated") notes.push("Band: the filter's own 1-sigma (the design has no calibrated model error).");
      if (group.uncertainty === "calibrated") notes.push("Calibrated on the built-in engine's simulator: the estimate corrected for how this design reads the engine; band: the honest 1-sigma (bias, filter and model error).");
      if (group.view === "change") notes.push("Change since the engine's baseline (first settled records after installation or shop visit).");
    } else if (BAND_NOTES[group.uncertainty] && (!group.key.startsWith("perf-") || group.uncertainty !== "calibrated")) {
      // Tuners and aux outputs say what their band is; a performance panel only when it is
      // not the calibrated one.
      notes.push(BAND_NOTES[group.uncertainty]);
    }
    if (group.key === "tuners" && hidden.size) notes.push(`Not observable with this design: ${[...hidden].map(label).join(", ")}.`);
    if (group.key === "tuners" && (group.calibrated_series || []).length) {
      notes.push("Calibrated on the built-in engine's simulator: the tuners of the calibrated health above, seen along the design's tuner directions.");
    } else if (group.corrected || (group.key === "aux" && (group.calibrated_series || []).length)) {
      notes.push("Calibrated on the built-in engine's simulator: the estimate corrected for how this design reads the engine.");
    }
    const titled = typeof TITLES[group.key] === "function" ? TITLES[group.key](group) : TITLES[group.key];
    const title = group.key === "health" && group.view === "change" ? "Health parameters: change since baseline" : group.title || titled || group.label;
    container.append(h("section", { class: "card" }, h("h2", {}, title),
      ...notes.map((n) => h("p", { class: "muted" }, n)), div));
    const raw = axis === "date" ? trend.time : trend.seq;
    // WSSR series are fault hypotheses: named as faults, not as the sensor or actuator.
    const named = group.key === "wssr" ? group.series.map((s) => ({ ...s, label: faultLabel(s.name) })) : group.series;
    const traces = named.filter((s) => !hidden.has(s.name)).flatMap((s, i) => (s.idx
      ? lineWithBand(s.idx.map((k) => raw[k]), s, i) : lineWithBand(x, broken(s), i)));
    // Records summarised from stream recordings (one per steady window): open diamonds on the
    // health plot, each naming its recording; a click opens the recording page.
    if (group.key === "health") traces.push(...streamPoints(group, raw));
    // Event markers as points too: hovering one names the event.
    const events = marks.filter((m) => m.kind === "event" || m.kind === "wear");
    if (events.length) {
      traces.push({
        x: events.map((m) => m.x), y: events.map(() => 1), yaxis: "y2", type: "scatter", mode: "markers",
        name: label("events"), meta: { code: "events" }, marker: { symbol: "triangle-down", size: 12, color: events.map((m) => MARKER_COLOURS[m.kind]) },
        text: events.map((m) => m.label), hovertemplate: "%{text}<extra></extra>",
      });
    }
    const lay = layout({
      // The data's own extent: marker labels near the ends must not stretch the axis.
      xaxis: { title: { text: axis === "date" ? "Date (UTC)" : "Cycles (record number)" }, type: axis === "date" ? "date" : "linear",
        range: xRange(axis), autorange: false },
      yaxis: { title: { text: axisTitle(group.key === "health" && group.view === "level" ? "Health level" : YLABELS[group.key] || group.label, unitOf(group.series)) } },
      yaxis2: { overlaying: "y", range: [0, 1.05], visible: false, fixedrange: true },
      shapes: [...markerShapes(marks), ...limitShapes(group.limits || [])],
      margin: { l: 70, r: 20, t: 50, b: 40 },
    });
    divs.push(div);
    pending.push([div, traces, lay]);
    if (group.key === "health") pendingClicks.push(div);
  }
  // A type other than the built-in engine has no engineering-unit panels: said, not left out.
  if (trend.performance_note) {
    container.append(h("section", { class: "card", id: "performance-note" }, h("h2", {}, "Engineering units"),
      h("p", { class: "notice" }, trend.performance_note)));
  }
  // Plot once every card is in the grid, so each plot takes its card's final width (which the
  // marker labels are packed for).
  const labelled = marks.filter((m) => m.kind !== "event" && m.kind !== "wear");
  for (const [div, traces, lay] of pending) {
    const width = div.clientWidth - lay.margin.l - lay.margin.r;
    lay.annotations = markerAnnotations(labelled, markerScale(lay.xaxis.range, width));
    plot(div, traces, lay);
  }
  for (const div of pendingClicks) {
    div.on?.("plotly_click", (ev) => {
      const point = ev.points.find((p) => p.data.meta && p.data.meta.role === "stream");
      if (point) location.assign(`/recording.html?id=${point.customdata}`);
    });
  }
  syncZoom(divs);
}

// The trend's points that summarise a stream recording's steady window (``trend.recording``).
function streamIndices() {
  return (trend.recording || []).map((r, i) => (r === null || r === undefined ? -1 : i)).filter((i) => i >= 0);
}

// One marker trace per shown health series at the stream points, so that the steady windows
// stand apart from the snapshots on the line they share.
function streamPoints(group, raw) {
  const idx = streamIndices();
  if (!idx.length) return [];
  const hidden = new Set(group.unobservable || []);
  return group.series.filter((s) => !hidden.has(s.name)).map((s, i) => ({
    x: idx.map((k) => raw[k]), y: idx.map((k) => s.value[k]), customdata: idx.map((k) => trend.recording[k]),
    type: "scatter", mode: "markers", name: i === 0 ? "stream windows" : `${s.name} (stream)`,
    legendgroup: "stream", showlegend: i === 0, meta: { role: "stream" },
    marker: { symbol: "diamond-open", size: 9, color: "#444" },
    hovertemplate: `${s.name} %{y}<br>steady window of recording #%{customdata}<extra></extra>`,
  }));
}

function info() {
  const t = trend;
  $("#title").textContent = `Engine trend · ${t.esn}`;
  $("#info").replaceChildren(
    `${t.esn} · ${t.engine_type} · design ${t.design_name ?? "none"} · ${t.n_records} records`,
    t.decimated ? ` shown as ${t.n_points} buckets (mean; min/max in the CSV)` : "",
    t.n_records ? ` · ${fmtTime(t.time[0])} to ${fmtTime(t.time[t.time.length - 1])}` : "");
  const hist = $("#history");
  hist.hidden = false;
  hist.replaceChildren(h("h2", {}, "History"), h("div", { class: "grid" },
    h("div", {}, h("h3", {}, "Installations"), h("ul", {}, t.installations.map((i) =>
      h("li", {}, tailLink(i.tail), ` position ${i.position}: ${fmtTime(i.installed_at)} – ${i.removed_at ? fmtTime(i.removed_at) : "now"}`)))),
    h("div", {}, h("h3", {}, "Maintenance actions"), t.maintenance.length ? h("ul", {}, t.maintenance.map((m) =>
      h("li", {}, `${fmtTime(m.performed_at)}: ${m.kind.replace("_", " ")}${m.notes ? ` (${m.notes})` : ""}`))) : h("p", { class: "muted" }, "none")),
    h("div", {}, h("h3", {}, "Events"), t.events.length ? h("ul", {}, t.events.map((e) =>
      h("li", {}, h("a", { href: `/events.html?id=${e.id}` }, `${fmtTime(e.detected_at)}: ${e.kind === "wear" ? "wear " : ""}${e.fault || e.kind}`), ` · ${e.status}`))) : h("p", { class: "muted" }, "none"))));
}

async function load(engineId) {
  const message = $("#message");
  message.replaceChildren();
  try {
    trend = await api(`/api/v1/engines/${engineId}/trend`, { query: query() });
  } catch (err) {
    $("#plots").replaceChildren();
    $("#history").hidden = true;
    showError(message, err, `Engine ${engineId}`);
    return;
  }
  info();
  if (!trend.n_records) {
    $("#plots").replaceChildren(await noEstimates(engineId));
    return;
  }
  draw();
}

// No estimates: for a design that is not in service, say why (estimates are made by the active
// design, from its activation on) and offer to make it the active one, which re-estimates every
// engine of the type under it; else the range is empty.
async function noEstimates(engineId) {
  const chosen = $("#design").value;
  const option = $("#design").selectedOptions[0];
  const design = chosen ? designs.find((d) => String(d.id) === chosen) : null;
  if (!design || design.active) {
    return h("p", { class: "notice", id: "no-estimates" }, "No estimates for this engine in the chosen range.");
  }
  const message = h("div", { role: "status" });
  const button = h("button", { type: "button", id: "activate-design", disabled: principal.role === "viewer",
    onclick: async () => {
      button.disabled = true;
      try {
        await api(`/api/v1/designs/${design.id}/activate`, { method: "POST" });
        message.replaceChildren(h("p", {}, `Design ${design.name} is now the active design: the engines of this type are being estimated under it (see `,
          h("a", { href: "/uploads.html" }, "jobs"), "). Show the trend again when the job has finished."));
        option.textContent = `${design.name} (active)`;
      } catch (err) {
        button.disabled = false;
        showError(message, err, "Not activated");
      }
    } }, `Make ${design.name} the active design`);
  return h("section", { class: "notice", id: "no-estimates" },
    h("p", {}, `Design ${design.name} has no estimates for ${trend.esn}${$("#start").value || $("#end").value ? " in the chosen range" : ""}: `
      + "fleethealth estimates every engine with the active design of its type, from the time that design was made active. "
      + "To see this design's estimates, make it the active design: every engine of the type is then estimated again under it "
      + "(the previous design keeps the estimates it made)."),
    h("p", {}, button, " ", h("a", { href: `/designs.html?a=${design.id}` }, "compare the designs first")),
    principal.role === "viewer" ? h("p", { class: "muted" }, "Activating a design needs an analyst key.") : null,
    message);
}

// The shown data: the x range of the health plot (after zooming) as start/end of the CSV export.
function shownRange() {
  const div = $("#plot-health");
  if (!div || !div.layout || !trend?.n_records) return {};
  const [a, b] = div.layout.xaxis.range;
  const times = trend.time.map((t) => Date.parse(t));
  const xs = $("#axis").value === "date" ? times : trend.seq;
  const lo = $("#axis").value === "date" ? Date.parse(a) : a;
  const hi = $("#axis").value === "date" ? Date.parse(b) : b;
  const inside = times.filter((_, i) => xs[i] >= lo && xs[i] <= hi);
  if (!inside.length) return {};
  return { start: new Date(Math.min(...inside) - 1000).toISOString(), end: new Date(Math.max(...inside) + 1000).toISOString() };
}

async function exportCsv(engineId) {
  try {
    const q = { ...query(), ...shownRange(), format: "csv" };
    const text = await apiText(`/api/v1/engines/${engineId}/trend`, { query: q });
    download(text, `trend-${trend ? trend.esn : engineId}.csv`);
  } catch (err) {
    showError($("#message"), err, "CSV export");
  }
}

// The view in the URL (engine, design, health view, axis, date range, points), so a link or a
// reload shows the same thing: read once at start, written on every change.
const VIEW = ["design", "health", "axis", "start", "end", "max_points"];

function restoreView() {
  const p = params();
  for (const name of VIEW) {
    const value = p.get(name);
    const input = $(`#${name}`);
    if (value === null) continue;
    if (input.tagName === "SELECT" && ![...input.options].some((o) => o.value === value)) continue;
    input.value = value;
  }
}

function saveView() {
  const u = new URL(location.href);
  for (const name of VIEW) {
    const input = $(`#${name}`);
    const initial = input.tagName === "SELECT" ? ([...input.options].find((o) => o.defaultSelected) || input.options[0])?.value : "";
    if (input.value && input.value !== initial) u.searchParams.set(name, input.value);
    else u.searchParams.delete(name);
  }
  history.replaceState(null, "", u);
}

// Another engine, in the same view (the design belongs to an engine type: not carried over).
function engineUrl(id) {
  const u = new URL(location.href);
  u.searchParams.set("id", id);
  u.searchParams.delete("design");
  return u.pathname + u.search;
}

async function main() {
  principal = await startPage("engine");
  const id = params().get("id");
  // Every engine of the operator by ESN, with the tail and position it is on now.
  let engines;
  try {
    engines = await apiAll("/api/v1/engines");
  } catch (err) {
    showError($("#message"), err, "Engines");
    return;
  }
  const select = $("#engine");
  select.replaceChildren(h("option", { value: "" }, "choose an engine…"), ...engines.map((e) =>
    h("option", { value: e.id, selected: String(e.id) === id }, `${e.esn}${e.tail ? ` (${e.tail} #${e.position})` : ""}`)));
  $("#controls").hidden = false;
  select.addEventListener("change", () => { if (select.value) location.assign(engineUrl(select.value)); });
  if (!id) {
    $("#message").append(h("p", { class: "notice" }, "Choose an engine to see its trend."));
    document.body.dataset.ready = "true";
    return;
  }
  let engineType = null;
  try {
    const engine = await api(`/api/v1/engines/${id}`);
    engineType = engine.engine_type_id;
    designs = (await api("/api/v1/designs", { query: { engine_type_id: engine.engine_type_id, limit: 100 } })).items;
    $("#design").replaceChildren(h("option", { value: "" }, "active design"), ...designs.filter((d) => d.status === "ready")
      .map((d) => h("option", { value: d.id }, `${d.name}${d.active ? " (active)" : ""}`)));
  } catch (err) {
    showError($("#message"), err, `Engine ${id}`);
    document.body.dataset.ready = "true";
    return;
  }
  restoreView();
  $("#form").addEventListener("submit", (e) => { e.preventDefault(); saveView(); load(id); });
  $("#axis").addEventListener("change", () => { saveView(); if (trend?.n_records) draw(); });
  $("#export").addEventListener("click", () => exportCsv(id));
  // The engine's report (active design, every record), as PDF or Excel with the plots as images.
  $("#export").after(...reportButtons(`/api/v1/engines/${id}/report`, $("#message"), `engine-report-${id}`));
  await load(id);
  await parameterSet(engineType);
  await listRecordings(id);
  await maintenancePanel(id, () => load(id));
  document.body.dataset.ready = "true";
}

// The signals of the engine's type with their units, as its models declare them (the columns its
// snapshots carry), and the operating-condition columns every record needs.
async function parameterSet(typeId) {
  const section = h("section", { class: "card", id: "parameters" }, h("h2", {}, "Signals of this engine type"));
  $("main").append(section);
  try {
    const p = await api(`/api/v1/engine-types/${typeId}/parameters`);
    section.querySelector("h2").textContent = `Signals of ${p.engine_type}`;
    section.append(
      p.from_models ? "" : h("p", { class: "muted" }, "No model of this type declares its signals yet: the built-in engine's stand in."),
      h("ul", { class: "signals" }, p.signals.map((s) => h("li", { "data-signal": s.name }, `${s.name} [${s.unit || "–"}]`))),
      h("p", { class: "muted" }, p.scheduled_on.length
        ? `Every record needs ${p.scheduled_on.join(", ")}${p.phase_required ? " and phase" : ""}.`
        : "Records need no operating condition (the type's model is at one operating point)."));
  } catch (err) {
    showError(section, err, "Signals");
  }
}

// The engine's stream recordings, each linked to its recording page.
async function listRecordings(id) {
  const section = h("section", { class: "card", id: "recordings" }, h("h2", {}, "Stream recordings"));
  $("main").append(section);
  try {
    const page = await api("/api/v1/streams", { query: { engine_id: id, limit: 50 } });
    // How many of the trend's points each recording's steady windows gave.
    const windows = {};
    for (const r of trend?.recording || []) if (r !== null && r !== undefined) windows[r] = (windows[r] || 0) + 1;
    section.append(page.items.length ? h("ul", {}, page.items.map((r) => h("li", { "data-recording": r.id },
      h("a", { href: `/recording.html?id=${r.id}` }, `#${r.id}`), ` started ${fmtTime(r.started_at)}, ${r.n_samples} samples`,
      r.samples_removed_at ? h("span", { class: "muted", "data-samples-removed": "" }, ` (samples removed ${fmtTime(r.samples_removed_at)}, estimates kept)`) : "",
      windows[r.id] ? h("span", { class: "stream-windows" }, ` · ${windows[r.id]} steady windows in the trend (open diamonds)`) : "")))
      : h("p", { class: "muted" }, "No stream recordings of this engine."));
  } catch (err) {
    showError(section, err, "Stream recordings");
  }
}

main();
