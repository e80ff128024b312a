// Aircraft (tail): the engines of each position side by side on shared axes, the
// engine-to-engine difference of one parameter (the classic same-aircraft check: a shift seen on
// one engine only is the engine, seen on all is the aircraft, its instruments or the conditions),
// the installation history and the data coverage of every engine while it sat on the tail.
import { api } from "./api.js";
import { $, fmtNum, fmtTime, h, params, showError, sortableTable, startPage } from "./ui.js";
import { PALETTE, axisTitle, layout, lineWithBand, plot, rgba, syncZoom } from "./plots.js";
import { label as nameOf } from "./glossary.js";

const DAY_MS = 86400e3;
// A stretch without data longer than this (or 20 typical record spacings) is a gap.
const GAP_MIN_MS = 3 * DAY_MS;
let tail = null;
let installations = [];

const positionColour = (p) => PALETTE[(p - 1) % PALETTE.length];
const group = (segment, key) => segment.trend.groups.find((g) => g.key === key);
const seriesOf = (segment, name) => {
  for (const g of segment.trend.groups) {
    const s = g.series.find((x) => x.name === name);
    if (s) return s;
  }
  return null;
};
const positions = () => [...new Set(tail.segments.map((s) => s.position))].sort((a, b) => a - b);

// A null point inside every gap, so plotly breaks the line instead of joining its two sides.
function broken(time, series, spacings = 20) {
  const cut = new Set(gaps(time, spacings).map(([a]) => a));
  const x = [];
  const pick = (values) => values && [];
  const out = { ...series, value: [], sigma: pick(series.sigma), min: pick(series.min), max: pick(series.max) };
  time.forEach((t, i) => {
    x.push(t);
    for (const k of ["value", "sigma", "min", "max"]) if (out[k]) out[k].push(series[k][i]);
    if (cut.has(Date.parse(t)) && i + 1 < time.length) {
      x.push(new Date((Date.parse(t) + Date.parse(time[i + 1])) / 2).toISOString());
      for (const k of ["value", "sigma", "min", "max"]) if (out[k]) out[k].push(null);
    }
  });
  return [x, out];
}

function timeRange() {
  const times = tail.segments.flatMap((s) => s.trend.time.map((t) => Date.parse(t)));
  if (!times.length) return null;
  const a = Math.min(...times);
  const b = Math.max(...times);
  const pad = Math.max(3600e3, 0.01 * (b - a));
  return [new Date(a - pad).toISOString(), new Date(b + pad).toISOString()];
}

// One health scale for every position: the extent of value ± sigma over all engines.
function healthRange() {
  let lo = Infinity;
  let hi = -Infinity;
  for (const seg of tail.segments) {
    const g = group(seg, "health");
    if (!g) continue;
    for (const s of g.series) {
      s.value.forEach((v, i) => {
        if (v === null) return;
        const sd = s.sigma && s.sigma[i] !== null ? s.sigma[i] : 0;
        lo = Math.min(lo, v - sd);
        hi = Math.max(hi, v + sd);
      });
    }
  }
  if (!Number.isFinite(lo)) return null;
  const pad = Math.max(0.05 * (hi - lo), 0.01);
  return [lo - pad, hi + pad];
}

function drawPositions() {
  const container = $("#positions");
  container.replaceChildren();
  const x = timeRange();
  const y = healthRange();
  const divs = [];
  const pending = [];
  // A parameter the design cannot estimate comes back as nulls: named once, not drawn.
  const hidden = unobservable();
  $("#unobservable")?.remove();
  if (hidden.size) {
    container.before(h("p", { class: "muted", id: "unobservable" },
      `Not observable with this design: ${[...hidden].map(nameOf).join(", ")}.`));
  }
  for (const p of positions()) {
    const segs = tail.segments.filter((s) => s.position === p && group(s, "health"));
    const div = h("div", { id: `plot-position-${p}`, class: "plot tall" });
    const esns = segs.map((s) => s.trend.esn);
    container.append(h("div", {}, h("h3", {}, `Position ${p}: ${esns.length ? [...new Set(esns)].join(", ") : "no data"}`), div));
    const traces = [];
    segs.forEach((seg, k) => {
      const g = group(seg, "health");
      g.series.forEach((s, i) => {
        if (hidden.has(s.name)) return;
        for (const t of lineWithBand(...broken(seg.trend.time, s), i)) {
          // One legend entry per parameter, however many engines the position had.
          // The hover names the engine, and the 1-sigma where the API gives one.
          const sigma = Array.isArray(t.meta.sigma) ? t.meta.sigma : null;
          traces.push({ ...t, showlegend: k === 0 && t.meta.role === "line", legendgroup: s.name,
            customdata: t.x.map((_, j) => [seg.trend.esn, sigma ? sigma[j] : null]),
            hovertemplate: t.meta.role === "line" ? `%{customdata[0]} ${nameOf(s.name)} %{y:.3f}${sigma ? " ± %{customdata[1]:.3f}" : ""} ${s.unit}${sigma ? " (1σ)" : ""}<extra></extra>` : undefined });
        }
      });
    });
    const unit = segs.length ? group(segs[0], "health").series[0].unit : "";
    pending.push([div, traces, layout({
      xaxis: { title: { text: "Date (UTC)" }, type: "date", range: x, autorange: !x },
      yaxis: { title: { text: axisTitle("Health level", unit) }, range: y, autorange: !y },
      margin: { l: 70, r: 20, t: 20, b: 40 },
    })]);
    divs.push(div);
  }
  for (const [div, traces, lay] of pending) plot(div, traces, lay);
  return divs;
}

// Daily means of one parameter per position: {day ms: {value, variance}}.
function dailyMeans(position, name) {
  const sums = new Map();
  for (const seg of tail.segments.filter((s) => s.position === position)) {
    const s = seriesOf(seg, name);
    if (!s) continue;
    seg.trend.time.forEach((t, i) => {
      const v = s.value[i];
      if (v === null) return;
      const day = Math.floor(Date.parse(t) / DAY_MS) * DAY_MS;
      const acc = sums.get(day) || { sum: 0, var: 0, n: 0 };
      acc.sum += v;
      acc.var += s.sigma && s.sigma[i] !== null ? s.sigma[i] ** 2 : 0;
      acc.n += 1;
      sums.set(day, acc);
    });
  }
  const out = new Map();
  for (const [day, a] of sums) out.set(day, { value: a.sum / a.n, variance: a.var / a.n });
  return out;
}

// Position 1 minus each other position, day by day where both have data. The band is the two
// estimates' 1-sigma combined (a day's mean keeps the typical sigma: the errors of one engine's
// records within a day are not independent).
function differences(name) {
  const [first, ...others] = positions();
  if (first === undefined || !others.length) return [];
  const ref = dailyMeans(first, name);
  return others.map((p) => {
    const other = dailyMeans(p, name);
    const days = [...ref.keys()].filter((d) => other.has(d)).sort((a, b) => a - b);
    return {
      label: `#${first} − #${p}`, position: p,
      time: days.map((d) => new Date(d + DAY_MS / 2).toISOString()),
      value: days.map((d) => ref.get(d).value - other.get(d).value),
      sigma: days.map((d) => Math.sqrt(ref.get(d).variance + other.get(d).variance)),
    };
  });
}

function drawComparison() {
  const name = $("#parameter").value;
  const x = timeRange();
  const overlay = [];
  let unit = "";
  for (const seg of tail.segments) {
    const s = seriesOf(seg, name);
    if (!s) continue;
    unit = s.unit;
    const colour = positionColour(seg.position);
    const [band, line] = lineWithBand(...broken(seg.trend.time, s), 0);
    const label = `#${seg.position} ${seg.trend.esn}`;
    overlay.push({ ...band, fillcolor: rgba(colour, 0.15), name: `${label} ±1σ`, legendgroup: label },
      { ...line, name: label, legendgroup: label, line: { color: colour, width: 1.6 } });
  }
  const title = axisTitle(nameOf(name), unit);
  plot($("#plot-overlay"), overlay, layout({
    title: { text: `${nameOf(name)} of every position`, font: { size: 13 } },
    xaxis: { title: { text: "Date (UTC)" }, type: "date", range: x, autorange: !x },
    yaxis: { title: { text: title } },
    margin: { l: 70, r: 20, t: 60, b: 50 },
  }));
  const delta = differences(name).flatMap((d) => lineWithBand(
    ...broken(d.time, { name: d.label, unit, value: d.value, sigma: d.sigma }, 1), d.position - 1).map((t) =>
    (t.meta.role === "line" ? { ...t, mode: "lines+markers", marker: { size: 4 } } : t)));
  plot($("#plot-delta"), delta, layout({
    title: { text: `Difference of ${nameOf(name)} between positions (daily means)`, font: { size: 13 } },
    xaxis: { title: { text: "Date (UTC)" }, type: "date", range: x, autorange: !x },
    yaxis: { title: { text: axisTitle(`${nameOf(name)} difference`, unit) }, zeroline: true, zerolinecolor: "#5b6b7c" },
    margin: { l: 70, r: 20, t: 60, b: 50 },
  }));
  $("#delta-title").textContent = `Engine-to-engine difference: ${nameOf(name)}`;
  $("#delta-note").textContent = positions().length < 2
    ? "Only one position has data: no difference to show."
    : "Left: the parameter of every position. Right: position 1 minus each other position, from the days both have data (daily means; band: the two estimates' ±1σ combined). A step in the difference that only one engine shows points at that engine; a step common to all points at the aircraft or its data.";
  return [$("#plot-overlay"), $("#plot-delta")];
}

function gaps(times, spacings = 20) {
  const t = times.map((x) => Date.parse(x));
  const steps = t.slice(1).map((v, i) => v - t[i]).sort((a, b) => a - b);
  const typical = steps.length ? steps[Math.floor(steps.length / 2)] : 0;
  const limit = Math.max(GAP_MIN_MS, spacings * typical);
  const out = [];
  for (let i = 1; i < t.length; i += 1) if (t[i] - t[i - 1] > limit) out.push([t[i - 1], t[i]]);
  return out;
}

function drawCoverage() {
  const newest = Math.max(...tail.segments.flatMap((s) => s.trend.time.map((t) => Date.parse(t))), -Infinity);
  const rows = tail.segments.map((seg) => {
    const t = seg.trend.time;
    return {
      position: seg.position, esn: seg.trend.esn, engine_id: seg.trend.engine_id,
      period: [seg.installed_at, seg.removed_at], n_records: seg.trend.n_records,
      first: t.length ? t[0] : null, last: t.length ? t[t.length - 1] : null,
      behind: t.length && Number.isFinite(newest) ? (newest - Date.parse(t[t.length - 1])) / DAY_MS : null,
      gaps: gaps(t),
    };
  });
  $("#coverage").replaceChildren(rows.length ? h("div", { class: "table-wrap" }, sortableTable([
    { key: "position", label: "Pos.", numeric: true },
    { key: "esn", label: "ESN", cell: (r) => h("a", { href: `/engine.html?id=${r.engine_id}` }, r.esn) },
    { key: "n_records", label: "Records", numeric: true },
    { key: "last", label: "Last data", cell: (r) => (r.last ? fmtTime(r.last) : h("span", { class: "muted" }, "none")) },
    { key: "behind", label: "Behind the tail's newest [days]", numeric: true, cell: (r) => (r.behind === null ? "–" : fmtNum(r.behind, 1)) },
    { key: "gaps", label: "Gaps (> 3 days without data)", value: (r) => r.gaps.length, cell: (r) => (r.gaps.length
      ? h("ul", { class: "plain" }, r.gaps.map(([a, b]) => h("li", {}, `${fmtTime(new Date(a).toISOString()).slice(0, 10)} – ${fmtTime(new Date(b).toISOString()).slice(0, 10)} (${fmtNum((b - a) / DAY_MS, 1)} days)`)))
      : h("span", { class: "muted" }, "none")) },
  ], rows, { sortKey: "position", rowClass: (r) => `coverage-${r.position}` })) : h("p", { class: "muted" }, "No engine has been installed on this tail."));
  $("#coverage").append(h("p", { class: "legend-note" }, "Over each engine's time on this tail; the first data may lag the installation until the engine's first upload."));
}

function drawInstallations() {
  $("#installations").replaceChildren(installations.length ? sortableTable([
    { key: "position", label: "Pos.", numeric: true },
    { key: "esn", label: "ESN", cell: (i) => h("a", { href: `/engine.html?id=${i.engine_id}` }, i.esn) },
    { key: "installed_at", label: "Installed", cell: (i) => fmtTime(i.installed_at) },
    { key: "removed_at", label: "Removed", value: (i) => i.removed_at || "9999", cell: (i) => (i.removed_at ? fmtTime(i.removed_at) : h("strong", {}, "installed")) },
    { key: "days", label: "Days on the tail", numeric: true,
      value: (i) => ((i.removed_at ? Date.parse(i.removed_at) : Date.now()) - Date.parse(i.installed_at)) / DAY_MS,
      cell: (i) => fmtNum(((i.removed_at ? Date.parse(i.removed_at) : Date.now()) - Date.parse(i.installed_at)) / DAY_MS, 0) },
  ], installations, { sortKey: "installed_at", descending: true, rowClass: () => "installation" })
    : h("p", { class: "muted" }, "No installations recorded."));
}

// Health parameters no segment's design estimates (each segment's ``unobservable``).
function unobservable() {
  const groups = tail.segments.map((seg) => group(seg, "health")).filter(Boolean);
  if (!groups.length) return new Set();
  const seen = groups.map((g) => new Set(g.unobservable || []));
  return new Set([...seen[0]].filter((n) => seen.every((set) => set.has(n))));
}

function drawParameterChoices() {
  const names = [];
  const hidden = unobservable();
  for (const seg of tail.segments) {
    for (const g of seg.trend.groups.filter((x) => x.key === "health" || x.key === "aux")) {
      for (const s of g.series) if (!names.includes(s.name) && !hidden.has(s.name)) names.push(s.name);
    }
  }
  const wanted = params().get("parameter");
  $("#parameter").replaceChildren(...names.map((n) => h("option", { value: n, selected: n === wanted }, nameOf(n))));
}

async function resolveId() {
  const p = params();
  if (p.get("id")) return p.get("id");
  if (p.get("tail")) {
    const found = await api("/api/v1/aircraft", { query: { tail: p.get("tail") } });
    if (!found.items.length) throw new Error(`No aircraft with tail ${p.get("tail")}.`);
    return String(found.items[0].id);
  }
  return null;
}

async function main() {
  await startPage("aircraft");
  let id;
  try {
    id = await resolveId();
    const all = await api("/api/v1/aircraft", { query: { limit: 1000 } });
    $("#aircraft").replaceChildren(h("option", { value: "" }, "choose an aircraft…"),
      ...all.items.map((a) => h("option", { value: a.id, selected: String(a.id) === id }, a.tail)));
  } catch (err) {
    showError($("#message"), err, "Aircraft");
    document.body.dataset.ready = "true";
    return;
  }
  $("#controls").hidden = false;
  $("#aircraft").addEventListener("change", (e) => { if (e.target.value) location.assign(`/aircraft.html?id=${e.target.value}`); });
  if (!id) {
    $("#message").append(h("p", { class: "notice" }, "Choose an aircraft to see its engines."));
    document.body.dataset.ready = "true";
    return;
  }
  try {
    const [aircraft, trend, history, now] = await Promise.all([
      api(`/api/v1/aircraft/${id}`),
      api(`/api/v1/aircraft/${id}/trend`, { query: { max_points: 1000 } }),
      api(`/api/v1/aircraft/${id}/installations`, { query: { limit: 1000 } }),
      api(`/api/v1/aircraft/${id}/engines`),
    ]);
    tail = trend;
    installations = history.items;
    document.title = `${aircraft.tail} · Aircraft · fleethealth`;
    $("#title").textContent = `Aircraft ${aircraft.tail}`;
    $("#info").textContent = `${aircraft.aircraft_type || "type not recorded"} · ${aircraft.engine_positions} engine positions`;
    $("#now").replaceChildren(h("p", {}, "Installed now: ", ...now.flatMap((slot, i) => [i ? " · " : "", `#${slot.position} `,
      slot.engine ? h("a", { href: `/engine.html?id=${slot.engine.id}` }, slot.engine.esn) : h("span", { class: "muted" }, "empty")])));
  } catch (err) {
    showError($("#message"), err, `Aircraft ${id}`);
    document.body.dataset.ready = "true";
    return;
  }
  $("#content").hidden = false;
  drawParameterChoices();
  drawInstallations();
  drawCoverage();
  const zoomable = [...drawPositions(), ...drawComparison()];
  syncZoom(zoomable);
  $("#parameter").addEventListener("change", () => {
    const u = new URL(location.href);
    u.searchParams.set("parameter", $("#parameter").value);
    history.replaceState(null, "", u);
    drawComparison();
  });
  document.body.dataset.ready = "true";
}

main();
