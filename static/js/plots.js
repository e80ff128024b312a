// Plot helpers on the plotly.js bundle served at /vendor/plotly.min.js (global Plotly).
// Traces are named by the glossary (engineers' names, glossary.js); the API's code of each is
// kept in the trace's meta.code (CSV export, tests).
import { label } from "./glossary.js";

// Thirteen colours, one for each trace of the largest plot (the 13 health parameters): Okabe
// and Ito's colour-blind-safe hues (yellow, orange and sky blue left out: under 3:1 on white)
// completed by Paul Tol's and Wong's darker ones. Each has a contrast of at least 3:1 against
// the white plot (WCAG 1.4.11, graphical objects) and any two differ by a CIE76 colour
// difference of at least 30.
export const PALETTE = ["#0072B2", "#D55E00", "#009E73", "#000000", "#E7298A", "#490092", "#999933",
  "#8C564B", "#B66DFF", "#CC79A7", "#00838F", "#920000", "#882255"];
export const DASHES = ["solid", "dash", "dot", "dashdot"];
// Health parameters keep one colour each wherever they are drawn (in this order), flow
// capacities dashed beside their module's solid efficiency.
const HEALTH = ["fan_eff", "fan_flow", "lpc_eff", "lpc_flow", "hpc_eff", "hpc_flow", "hpt_eff", "hpt_flow",
  "lpt_eff", "lpt_flow", "wf_bias", "vsv_bias", "vbv_bias"];
// Marker lines (graphical, 3:1 against white) and their labels (text, 4.5:1, WCAG 1.4.3).
export const MARKER_COLOURS = { installation: "#555555", maintenance: "#009E73", event: "#D55E00", wear: "#CC79A7" };
export const MARKER_TEXT = { installation: "#555555", maintenance: "#00704F", event: "#B84A00", wear: "#A3407E" };

export function styleFor(name, index) {
  const h = HEALTH.indexOf(String(name));
  if (h >= 0) return { color: PALETTE[h], dash: String(name).endsWith("flow") ? "dash" : "solid" };
  return { color: PALETTE[index % PALETTE.length], dash: DASHES[Math.floor(index / PALETTE.length) % DASHES.length] };
}

// plotly's Cividis scale (colour-blind safe, perceptually even), given explicitly so that the
// text written in a heatmap's cells can be chosen against each cell's colour.
export const CIVIDIS = [[0, "rgb(0,32,76)"], [0.058824, "rgb(0,42,102)"], [0.117647, "rgb(0,52,110)"],
  [0.176471, "rgb(39,63,108)"], [0.235294, "rgb(60,74,107)"], [0.294118, "rgb(76,85,107)"], [0.352941, "rgb(91,95,109)"],
  [0.411765, "rgb(104,106,112)"], [0.470588, "rgb(117,117,117)"], [0.529412, "rgb(131,129,120)"], [0.588235, "rgb(146,140,120)"],
  [0.647059, "rgb(161,152,118)"], [0.705882, "rgb(176,165,114)"], [0.764706, "rgb(192,177,109)"], [0.823529, "rgb(209,191,102)"],
  [0.882353, "rgb(225,204,92)"], [0.941176, "rgb(243,219,79)"], [1, "rgb(255,233,69)"]];

// The colour of a colour scale at ``f`` in [0, 1], as [r, g, b] (linear between stops).
export function colourAt(scale, f) {
  const rgb = (c) => c.match(/\d+/g).map(Number);
  const x = Math.max(0, Math.min(1, f));
  const k = Math.max(1, scale.findIndex(([stop]) => stop >= x));
  const [a, ca] = scale[k - 1];
  const [b, cb] = scale[k];
  const t = b > a ? (x - a) / (b - a) : 0;
  return rgb(ca).map((v, i) => v + t * (rgb(cb)[i] - v));
}

// Black or white, whichever reads better on ``rgb``: at least 4.58:1 on any background.
export function textOn(rgb) {
  const lin = rgb.map((v) => { const c = v / 255; return c <= 0.03928 ? c / 12.92 : ((c + 0.055) / 1.055) ** 2.4; });
  const luminance = 0.2126 * lin[0] + 0.7152 * lin[1] + 0.0722 * lin[2];
  return luminance >= 0.179 ? "#000000" : "#ffffff";
}

export function rgba(hex, alpha) {
  const n = parseInt(hex.slice(1), 16);
  return `rgba(${(n >> 16) & 255},${(n >> 8) & 255},${n & 255},${alpha})`;
}

// Axis title with its unit: "Health parameter change [%]".
export function axisTitle(label, unit) {
  const u = unit === "1" ? "dimensionless" : unit;
  return u ? `${label} [${u}]` : label;
}

export function unitOf(series) {
  const units = [...new Set(series.map((s) => s.unit))];
  return units.join(", ");
}

export function layout(extra = {}) {
  const big = window.matchMedia("(min-width: 1900px)").matches;
  return {
    font: { family: "system-ui, -apple-system, Segoe UI, Roboto, sans-serif", size: big ? 16 : 12, color: "#1d2733" },
    margin: { l: 70, r: 20, t: 40, b: 40 },
    paper_bgcolor: "#ffffff",
    plot_bgcolor: "#ffffff",
    hovermode: "x unified",
    // Below the plot, left-aligned, wrapping over as many rows as it needs: no entry is hidden
    // behind a scroll bar, and the plot's width is the data's.
    legend: { orientation: "h", x: 0, xanchor: "left", y: 0, yref: "container", yanchor: "bottom", font: { size: big ? 14 : 11 } },
    ...extra,
    xaxis: { gridcolor: "#e3e8ee", zerolinecolor: "#c5ced8", automargin: true, ...(extra.xaxis || {}) },
    yaxis: { gridcolor: "#e3e8ee", zerolinecolor: "#c5ced8", automargin: true, ...(extra.yaxis || {}) },
  };
}

// The API's name of a trace's series (its code), else the trace's name.
const codeOf = (t) => (t.meta && t.meta.code) || t.name;

// The plotted data as CSV: one row per point (x, y, trace), or per cell of a heatmap.
export function plotCsv(gd) {
  const quote = (v) => (v === null || v === undefined ? "" : /[",\n]/.test(String(v)) ? `"${String(v).replace(/"/g, '""')}"` : String(v));
  const rows = [];
  for (const t of gd.data) {
    if (t.meta && t.meta.role === "band") continue;
    if (t.type === "heatmap") {
      if (!rows.length) rows.push(["trace", "row", "column", "value"]);
      t.z.forEach((r, i) => r.forEach((v, j) => rows.push([codeOf(t), t.y[i], t.x[j], v])));
    } else {
      if (!rows.length) rows.push(["trace", "x", "y", "error"]);
      const err = t.error_y && t.error_y.array ? t.error_y.array : t.meta && Array.isArray(t.meta.sigma) ? t.meta.sigma : null;
      (t.x || []).forEach((x, i) => rows.push([codeOf(t), x, t.y[i], err ? err[i] : ""]));
    }
  }
  return rows.map((r) => r.map(quote).join(",")).join("\n") + "\n";
}

const CSV_ICON = { width: 24, height: 24, path: "M4 2h11l5 5v15H4z M14 3v5h5 M7 12h10v2H7z M7 16h10v2H7z" };

export const CONFIG = {
  responsive: true, displaylogo: false, modeBarButtonsToRemove: ["lasso2d", "select2d"],
  modeBarButtonsToAdd: [{
    name: "Download data as CSV", icon: CSV_ICON,
    click: (gd) => {
      const link = document.createElement("a");
      link.href = URL.createObjectURL(new Blob([plotCsv(gd)], { type: "text/csv" }));
      link.download = `${gd.id || "plot"}.csv`;
      document.body.append(link);
      link.click();
      setTimeout(() => { URL.revokeObjectURL(link.href); link.remove(); }, 0);
    },
  }],
};

export function plot(div, traces, lay) {
  if (typeof Plotly === "undefined") {
    div.replaceChildren(Object.assign(document.createElement("p"), {
      className: "error", textContent: "The plotting library did not load from /vendor/plotly.min.js (is the plotly package installed on the server?).",
    }));
    return Promise.resolve(div);
  }
  describe(div, traces, lay);
  return Plotly.react(div, traces, lay, CONFIG);
}

const textOf = (t) => (typeof t === "string" ? t : t && t.text) || "";
const num = (v) => (Math.abs(v) >= 1000 || Math.abs(v) < 0.01 ? v.toPrecision(3) : v.toFixed(2));
let described = 0;

// The text alternative of a plot for screen readers: the plot is a figure named by its title,
// described by a hidden summary of every trace (points, range of values, last value).
export function plotSummary(traces, lay) {
  const x = textOf(lay.xaxis && lay.xaxis.title);
  const y = textOf(lay.yaxis && lay.yaxis.title);
  const shown = traces.filter((t) => !(t.meta && t.meta.role === "band"));
  const parts = shown.map((t) => {
    if (t.type === "heatmap") return `${t.name || "matrix"}: ${(t.y || []).length} rows by ${(t.x || []).length} columns`;
    const values = (t.y || []).filter((v) => typeof v === "number" && Number.isFinite(v));
    if (!values.length) return `${t.name || "series"}: no data`;
    const last = values[values.length - 1];
    const kind = t.type === "bar" ? "bars" : "points";
    return `${t.name || "series"}: ${values.length} ${kind} from ${num(Math.min(...values))} to ${num(Math.max(...values))}, last ${num(last)}`;
  });
  const axes = y && x ? `${y} against ${x}. ` : "";
  return `${axes}${shown.length} series. ${parts.join("; ")}.`;
}

function describe(div, traces, lay) {
  if (!div.id) { described += 1; div.id = `plot-${described}`; }
  const id = `${div.id}-summary`;
  let summary = document.getElementById(id);
  if (!summary) {
    summary = Object.assign(document.createElement("p"), { id, className: "sr-only" });
    div.after(summary);
  }
  summary.textContent = plotSummary(traces, lay);
  div.setAttribute("role", "figure");
  div.setAttribute("aria-label", textOf(lay.title) || textOf(lay.yaxis && lay.yaxis.title) || "plot");
  div.setAttribute("aria-describedby", id);
}

// A line with its band (named ``series.label``, else the glossary's name of ``series.name``): value ± 1 sigma where the series has a sigma, else (a decimated
// trend) the min-max envelope of each bucket, so a spike survives decimation. The band is a
// filled trace (legend-grouped, no hover) drawn under the line.
export function lineWithBand(x, series, index, { band = true } = {}) {
  const style = styleFor(series.name, index);
  const name = series.label || label(series.name);
  const unit = series.unit === "1" ? "" : series.unit;
  const traces = [];
  const sigma = series.sigma;
  const upper = sigma ? series.value.map((v, i) => (v === null || sigma[i] === null ? null : v + sigma[i])) : series.max;
  const lower = sigma ? series.value.map((v, i) => (v === null || sigma[i] === null ? null : v - sigma[i])) : series.min;
  if (band && upper && lower) {
    // One closed polygon (upper edge forward, lower edge back) per run of known values,
    // separated by nulls: plotly's "toself" fills each null-separated segment on its own.
    const bx = [];
    const by = [];
    let run = [];
    const flush = () => {
      if (run.length) {
        if (bx.length) { bx.push(null); by.push(null); }
        for (const i of run) { bx.push(x[i]); by.push(upper[i]); }
        for (const i of [...run].reverse()) { bx.push(x[i]); by.push(lower[i]); }
      }
      run = [];
    };
    upper.forEach((u, i) => {
      if (u === null || lower[i] === null || x[i] === null) flush();
      else run.push(i);
    });
    flush();
    traces.push({
      x: bx, y: by,
      type: "scatter", mode: "lines", fill: "toself", fillcolor: rgba(style.color, sigma ? 0.15 : 0.1),
      line: { width: 0 }, hoverinfo: "skip", showlegend: false, legendgroup: series.name,
      name: `${name} ${sigma ? "±1σ" : "min–max"}`, meta: { role: "band", code: series.name },
    });
  }
  // The hover carries the estimate's 1-sigma where the API gives one, the bucket's min–max
  // where a decimated series has no sigma.
  const line = {
    x, y: series.value, type: "scatter", mode: "lines", name, legendgroup: series.name,
    line: { color: style.color, dash: style.dash, width: 1.6 },
    hovertemplate: `%{y:.3f} ${unit}`, meta: { role: "line", code: series.name },
  };
  if (sigma) {
    Object.assign(line, { customdata: sigma, hovertemplate: `%{y:.3f} ± %{customdata:.3f} ${unit} (1σ)` });
    line.meta.sigma = sigma;  // the CSV export's error column
  } else if (series.min && series.max) {
    Object.assign(line, { customdata: series.min.map((v, i) => [v, series.max[i]]),
      hovertemplate: `%{y:.3f} ${unit} (bucket %{customdata[0]:.3f} to %{customdata[1]:.3f})` });
  }
  traces.push(line);
  return traces;
}

// Horizontal limit lines (amber, red) across the plot width, each labelled with its level.
const LIMIT_COLOURS = { amber: "#E69F00", red: "#C0392B" };
const LIMIT_TEXT = { amber: "#8A5F00", red: "#B03A2E" };
export function limitShapes(lines) {
  return lines.map((l) => ({
    type: "line", xref: "paper", yref: "y", x0: 0, x1: 1, y0: l.value, y1: l.value,
    line: { color: LIMIT_COLOURS[l.level], width: 1.5, dash: "dash" },
    label: { text: `${label(l.series)} ${l.level} ${l.value}`, textposition: "end", font: { size: 10, color: LIMIT_TEXT[l.level] } },
  }));
}

// Vertical marker lines (installation changes, maintenance, events) across the plot height.
export function markerShapes(markers) {
  return markers.map((m) => ({
    type: "line", xref: "x", yref: "paper", x0: m.x, x1: m.x, y0: 0, y1: 1,
    line: { color: MARKER_COLOURS[m.kind], width: m.kind === "event" || m.kind === "wear" ? 2 : 1.2, dash: m.kind === "maintenance" ? "dot" : m.kind === "installation" ? "dash" : "solid" },
  }));
}

// One label per marker time (an engine change and its shop visit share one), packed over three
// rows above the plot so that no two labels overlap: each goes on the lowest row where it clears
// its left neighbour (widths estimated from the text at 10 px); a label that fits on no row
// becomes a small "+" whose hover names it. ``toPixel`` maps an x value to pixels across the
// plot (markerScale gives it for an axis range and width).
const ROWS = 3;
const ROW_HEIGHT = 15;
const CHAR_PX = 6.2;
export function markerAnnotations(markers, toPixel) {
  const byX = new Map();
  for (const m of markers) {
    const key = String(m.x);
    if (!byX.has(key)) byX.set(key, []);
    byX.get(key).push(m);
  }
  const groups = [...byX.values()].map((group) => ({ group, px: toPixel ? toPixel(group[0].x) : 0 }))
    .sort((a, b) => a.px - b.px);
  const rowEnds = Array(ROWS).fill(-Infinity);
  const place = (width, px) => {
    const row = rowEnds.findIndex((endPx) => px - width / 2 >= endPx + 4);
    if (row >= 0) rowEnds[row] = px + width / 2;
    return row;
  };
  const out = [];
  for (const { group, px } of groups) {
    const text = [...new Set(group.map((m) => m.short))].join(" · ");
    let row = place(text.length * CHAR_PX + 4, px);
    let shown = text;
    if (row < 0) { shown = "+"; row = place(10, px); }
    if (row < 0) continue;  // no room even for the "+": the history lists it
    out.push({
      x: group[0].x, xref: "x", y: 1, yref: "paper", yanchor: "bottom", xanchor: "center",
      text: shown, hovertext: group.map((m) => m.label).join("<br>"),
      showarrow: false, font: { size: 10, color: MARKER_TEXT[group[0].kind] }, yshift: row * ROW_HEIGHT,
    });
  }
  return out;
}

// x value -> pixels across a plot ``width`` pixels wide showing ``range`` (dates as ISO strings).
export function markerScale(range, width) {
  const num = (v) => (typeof v === "string" ? Date.parse(v) : v);
  const [a, b] = range.map(num);
  return (x) => ((num(x) - a) / (b - a || 1)) * width;
}

// The markers of an engine trend (``GET /engines/{id}/trend``) inside its time span: installation
// changes, maintenance actions and events, each with a short label and a full one; ``at`` maps a
// time (and the record number where known) to the plot's x.
export function trendMarkers(trend, at, fmtTime) {
  const first = Date.parse(trend.time[0]);
  const last = Date.parse(trend.time[trend.time.length - 1]);
  const inside = (iso) => { const t = Date.parse(iso); return t >= first && t <= last; };
  const out = [];
  for (const inst of trend.installations) {
    if (inside(inst.installed_at)) out.push({ kind: "installation", x: at(inst.installed_at), short: `on ${inst.tail}`, label: `installed on ${inst.tail} position ${inst.position}, ${fmtTime(inst.installed_at)}` });
    if (inst.removed_at && inside(inst.removed_at)) out.push({ kind: "installation", x: at(inst.removed_at), short: `off ${inst.tail}`, label: `removed from ${inst.tail} position ${inst.position}, ${fmtTime(inst.removed_at)}` });
  }
  for (const m of trend.maintenance) {
    if (inside(m.performed_at)) out.push({ kind: "maintenance", x: at(m.performed_at), short: m.kind.replace("_", " "), label: `${m.kind.replace("_", " ")}, ${fmtTime(m.performed_at)}${m.notes ? `: ${m.notes}` : ""}` });
  }
  for (const e of trend.events) {
    const wear = e.kind === "wear";
    out.push({ kind: wear ? "wear" : "event", event: e.id, x: at(e.detected_at, e.seq), short: wear ? `wear ${e.fault || ""}`.trim() : e.fault || e.kind, label: `event ${e.id}: ${wear ? "wear, " : ""}${e.fault || e.kind} (${e.status})` });
  }
  return out.filter((m) => m.x !== null && m.x !== undefined);
}

// Zooming one plot zooms the others on the same x axis.
export function syncZoom(divs) {
  let busy = false;
  for (const div of divs) {
    div.on("plotly_relayout", (ev) => {
      if (busy) return;
      const range = ev["xaxis.range[0]"] !== undefined ? [ev["xaxis.range[0]"], ev["xaxis.range[1]"]]
        : ev["xaxis.range"] ? ev["xaxis.range"] : null;
      const auto = ev["xaxis.autorange"];
      if (!range && !auto) return;
      busy = true;
      const update = range ? { "xaxis.range": range } : { "xaxis.autorange": true };
      Promise.all(divs.filter((d) => d !== div).map((d) => Plotly.relayout(d, update))).finally(() => { busy = false; });
    });
  }
}
