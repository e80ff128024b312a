// Plot helpers on the plotly.js bundle served at /vendor/plotly.min.js (global Plotly).
// Colours: Okabe & Ito's colour-blind-safe palette (yellow left out: unreadable on white).

export const PALETTE = ["#0072B2", "#E69F00", "#009E73", "#D55E00", "#56B4E9", "#CC79A7", "#000000", "#999999"];
export const DASHES = ["solid", "dash", "dot", "dashdot"];
// Health parameters come in pairs per module: one colour per module, efficiency solid, flow dashed.
const MODULES = ["fan", "lpc", "hpc", "hpt", "lpt"];
export const MARKER_COLOURS = { installation: "#555555", maintenance: "#009E73", event: "#D55E00", wear: "#CC79A7" };

export function styleFor(name, index) {
  const module = MODULES.indexOf(String(name).split("_")[0].toLowerCase());
  if (module >= 0) {
    return { color: PALETTE[module], dash: String(name).endsWith("flow") ? "dash" : "solid" };
  }
  return { color: PALETTE[index % PALETTE.length], dash: DASHES[Math.floor(index / PALETTE.length) % DASHES.length] };
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
    margin: { l: 70, r: 20, t: 40, b: 55 },
    paper_bgcolor: "#ffffff",
    plot_bgcolor: "#ffffff",
    hovermode: "x unified",
    legend: { orientation: "h", x: 0, y: 1.02, yanchor: "bottom" },
    ...extra,
    xaxis: { gridcolor: "#e3e8ee", zerolinecolor: "#c5ced8", automargin: true, ...(extra.xaxis || {}) },
    yaxis: { gridcolor: "#e3e8ee", zerolinecolor: "#c5ced8", automargin: true, ...(extra.yaxis || {}) },
  };
}

// The plotted data as CSV: one row per point (x, y, trace), or per cell of a heatmap.
export function plotCsv(gd) {
  const quote = (v) => (v === null || v === undefined ? "" : /[",\n]/.test(String(v)) ? `"${String(v).replace(/"/g, '""')}"` : String(v));
  const rows = [];
  for (const t of gd.data) {
    if (t.meta && t.meta.role === "band") continue;
    if (t.type === "heatmap") {
      if (!rows.length) rows.push(["trace", "row", "column", "value"]);
      t.z.forEach((r, i) => r.forEach((v, j) => rows.push([t.name, t.y[i], t.x[j], v])));
    } else {
      if (!rows.length) rows.push(["trace", "x", "y", "error"]);
      (t.x || []).forEach((x, i) => rows.push([t.name, x, t.y[i], t.error_y && t.error_y.array ? t.error_y.array[i] : ""]));
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

// A line with its band: value ± 1 sigma where the series has a sigma, else (a decimated
// trend) the min-max envelope of each bucket, so a spike survives decimation. The band is a
// filled trace (legend-grouped, no hover) drawn under the line.
export function lineWithBand(x, series, index, { band = true } = {}) {
  const style = styleFor(series.name, index);
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
      name: `${series.name} ${sigma ? "±1σ" : "min–max"}`, meta: { role: "band" },
    });
  }
  traces.push({
    x, y: series.value, type: "scatter", mode: "lines", name: series.name, legendgroup: series.name,
    line: { color: style.color, dash: style.dash, width: 1.6 },
    hovertemplate: `%{y:.3f} ${series.unit}`, meta: { role: "line" },
  });
  return traces;
}

// Horizontal limit lines (amber, red) across the plot width, each labelled with its level.
const LIMIT_COLOURS = { amber: "#E69F00", red: "#C0392B" };
export function limitShapes(lines) {
  return lines.map((l) => ({
    type: "line", xref: "paper", yref: "y", x0: 0, x1: 1, y0: l.value, y1: l.value,
    line: { color: LIMIT_COLOURS[l.level], width: 1.5, dash: "dash" },
    label: { text: `${l.series} ${l.level} ${l.value}`, textposition: "end", font: { size: 10, color: LIMIT_COLOURS[l.level] } },
  }));
}

// Vertical marker lines (installation changes, maintenance, events) across the plot height.
export function markerShapes(markers) {
  return markers.map((m) => ({
    type: "line", xref: "x", yref: "paper", x0: m.x, x1: m.x, y0: 0, y1: 1,
    line: { color: MARKER_COLOURS[m.kind], width: m.kind === "event" || m.kind === "wear" ? 2 : 1.2, dash: m.kind === "maintenance" ? "dot" : m.kind === "installation" ? "dash" : "solid" },
  }));
}

// One label per marker time (an engine change and its shop visit share one), staggered over
// three rows so neighbours do not print over each other.
export function markerAnnotations(markers) {
  const byX = new Map();
  for (const m of markers) {
    const key = String(m.x);
    if (!byX.has(key)) byX.set(key, []);
    byX.get(key).push(m);
  }
  return [...byX.values()].map((group, i) => ({
    x: group[0].x, xref: "x", y: 1, yref: "paper", yanchor: "bottom",
    text: [...new Set(group.map((m) => m.short))].join(" · "),
    hovertext: group.map((m) => m.label).join("<br>"),
    showarrow: false, font: { size: 10, color: MARKER_COLOURS[group[0].kind] }, yshift: (i % 3) * 11,
  }));
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
