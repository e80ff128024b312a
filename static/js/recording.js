// One stream recording: its samples (decimated for the plot), the stream filter's tuners and
// health parameters with their ±1σ bands, the transient index and the bias correction when the
// estimates carry them, and the engine's events during the recording.
import { api, apiText } from "./api.js";
import { $, badge, fmtNum, fmtTime, h, params, showError, sortableTable, startPage } from "./ui.js";
import { MARKER_COLOURS, axisTitle, layout, lineWithBand, plot, styleFor, syncZoom } from "./plots.js";
import { label } from "./glossary.js";

const MAX_SAMPLE_POINTS = 4000;
const CONDITIONS = ["alt_ft", "mach", "dtamb_k", "power_pct"];

// CSV of numbers with a header row (the samples endpoint): column name -> values (null where empty).
function parseCsv(text) {
  const lines = text.trim().split(/\r?\n/);
  const names = lines[0].split(",").map((n) => n.replace(/^"|"$/g, ""));
  const columns = Object.fromEntries(names.map((n) => [n, []]));
  const stride = Math.max(1, Math.ceil((lines.length - 1) / MAX_SAMPLE_POINTS));
  for (let i = 1; i < lines.length; i += stride) {
    const cells = lines[i].split(",");
    names.forEach((n, k) => { const c = cells[k]; columns[n].push(c === "" || c === undefined ? null : Number(c)); });
  }
  return { columns, stride, n: lines.length - 1 };
}

function median(values) {
  const v = values.filter((x) => x !== null && Number.isFinite(x)).sort((a, b) => a - b);
  return v.length ? v[Math.floor(v.length / 2)] : null;
}

function eventShapes(events, recording) {
  const t0 = Date.parse(recording.started_at);
  return events.map((e) => ({
    type: "line", xref: "x", yref: "paper", y0: 0, y1: 1,
    x0: (Date.parse(e.detected_at) - t0) / 1000, x1: (Date.parse(e.detected_at) - t0) / 1000,
    line: { color: MARKER_COLOURS.event, width: 2 },
  }));
}

function drawSamples(recording, text, shapes) {
  const { columns, stride, n } = parseCsv(text);
  const t = columns.time_s || [];
  $("#samples-note").textContent = `${n} samples every ${fmtNum(recording.dt_s, 3)} s` +
    (stride > 1 ? `; every ${stride}th sample shown` : "") + ". Sensors in percent of their median over the recording.";
  const sensors = recording.signals.filter((s) => !CONDITIONS.includes(s) && s !== "time_s" && columns[s]);
  const traces = sensors.map((s, i) => {
    const m = median(columns[s]);
    const style = styleFor(s, i);
    return {
      x: t, y: columns[s].map((v) => (v === null || !m ? null : 100 * (v - m) / m)), type: "scatter", mode: "lines",
      name: label(s), line: { color: style.color, dash: style.dash, width: 1.2 }, meta: { role: "sample", code: s },
    };
  });
  plot($("#samples-plot"), traces, layout({
    title: { text: "Sensors" }, shapes,
    xaxis: { title: { text: axisTitle("Recording time", "s") } },
    yaxis: { title: { text: axisTitle("Change from the recording's median", "%") } },
  }));
  const cond = [];
  if (columns.alt_ft) cond.push({ x: t, y: columns.alt_ft, name: label("alt_ft"), type: "scatter", mode: "lines", line: { color: "#0072B2" }, meta: { role: "sample", code: "alt_ft" } });
  if (columns.power_pct) cond.push({ x: t, y: columns.power_pct, name: label("power_pct"), yaxis: "y2", type: "scatter", mode: "lines", line: { color: "#D55E00" }, meta: { role: "sample", code: "power_pct" } });
  plot($("#condition-plot"), cond, layout({
    title: { text: "Flight condition" }, shapes,
    xaxis: { title: { text: axisTitle("Recording time", "s") } },
    yaxis: { title: { text: axisTitle("Altitude", "ft") } },
    yaxis2: { title: { text: axisTitle("Power", "%") }, overlaying: "y", side: "right", automargin: true },
  }));
}

// What the stream estimates' bands are (the API's ``uncertainty``).
const STREAM_BANDS = {
  calibrated: "Calibrated on the built-in engine's simulated flights: the estimates corrected for how this design reads the engine, bands the honest 1σ (filter and model error).",
  uncalibrated: "Bands: the stream filter's own 1σ (sensor noise alone), much narrower than the real error; calibrate the design for honest bands.",
  sensors: "Bands: the stream filter's own 1σ: this recording lacks a sensor the design's stream calibration used, so it does not apply.",
};

// The series of ``values`` ({name: [T]}) but those named in ``hidden``.
function shownOnly(values, hidden) {
  return Object.fromEntries(Object.entries(values).filter(([name]) => !hidden.includes(name)));
}

function bandPlot(div, t, values, sigmas, title, shapes) {
  const traces = Object.keys(values).flatMap((name, i) =>
    lineWithBand(t, { name, value: values[name], sigma: sigmas[name], unit: "%" }, i));
  plot(div, traces, layout({
    title: { text: title }, shapes,
    xaxis: { title: { text: axisTitle("Recording time", "s") } },
    yaxis: { title: { text: axisTitle(title, "%") } },
  }));
}

// Seed 004's bias compensation adds these to the estimates when the design has it: a transient
// index per window (`transient_index`, [T]) and the bias correction applied to each sensor
// (`bias_correction`, {sensor: [T]}, in the sensor's percent). Absent: said so, nothing drawn.
function drawOptional(est, shapes) {
  const ti = est.transient_index;
  if (Array.isArray(ti) && ti.length) {
    $("#transient-body").replaceChildren(h("div", { id: "transient-plot" }));
    plot($("#transient-plot"), [{ x: est.t_s, y: ti, type: "scatter", mode: "lines", name: "transient index", line: { color: "#882255" }, meta: { role: "line" } }],
      layout({ shapes, xaxis: { title: { text: axisTitle("Recording time", "s") } }, yaxis: { title: { text: "Transient index" } } }));
  } else {
    $("#transient-body").replaceChildren(h("p", { class: "muted", id: "transient-absent" },
      "These estimates carry no transient index (it comes with the design's bias compensation)."));
  }
  const bias = est.bias_correction;
  if (bias && typeof bias === "object" && Object.keys(bias).length) {
    $("#bias-body").replaceChildren(h("div", { id: "bias-plot" }));
    const traces = Object.entries(bias).map(([name, y], i) => {
      const style = styleFor(name, i);
      return { x: est.t_s, y, name: label(name), type: "scatter", mode: "lines", line: { color: style.color, dash: style.dash }, meta: { role: "line", code: name } };
    });
    plot($("#bias-plot"), traces, layout({ shapes, xaxis: { title: { text: axisTitle("Recording time", "s") } },
      yaxis: { title: { text: axisTitle("Bias correction", "%") } } }));
  } else {
    $("#bias-body").replaceChildren(h("p", { class: "muted", id: "bias-absent" },
      "No bias correction was applied to these estimates."));
  }
}

function drawEvents(events) {
  $("#events").replaceChildren(events.length ? sortableTable([
    { key: "id", label: "#", numeric: true, cell: (e) => h("a", { href: `/events.html?id=${e.id}` }, `#${e.id}`) },
    { key: "detected_at", label: "Detected", cell: (e) => fmtTime(e.detected_at) },
    { key: "kind", label: "Kind", cell: (e) => badge(e.kind) },
    { key: "fault", label: "Fault", cell: (e) => e.fault || "" },
    { key: "magnitude", label: "Magnitude", numeric: true, cell: (e) => (e.magnitude === null ? "" : fmtNum(e.magnitude)) },
    { key: "status", label: "Status", cell: (e) => badge(e.status) },
  ], events, { sortKey: "detected_at", rowClass: () => "event" }) : h("p", { class: "muted" }, "No events during this recording."));
}

async function main() {
  await startPage("uploads");
  const id = params().get("id");
  if (!id) {
    $("#message").append(h("p", { class: "notice" }, "No recording chosen: open one from an engine page or the uploads page."));
    document.body.dataset.ready = "true";
    return;
  }
  let recording;
  try {
    recording = await api(`/api/v1/streams/${id}`);
  } catch (err) {
    showError($("#message"), err, `Recording ${id}`);
    document.body.dataset.ready = "true";
    return;
  }
  const engine = await api(`/api/v1/engines/${recording.engine_id}`).catch(() => null);
  const end = new Date(Date.parse(recording.started_at) + 1000 * recording.n_samples * recording.dt_s);
  $("#title").textContent = `Recording #${recording.id}${engine ? ` · ${engine.esn}` : ""}`;
  $("#summary").hidden = false;
  $("#summary").replaceChildren(h("p", {},
    `Started ${fmtTime(recording.started_at)}, ${recording.n_samples} samples at ${fmtNum(1 / recording.dt_s, 1)} Hz `,
    `(${fmtNum(recording.n_samples * recording.dt_s / 60, 1)} min), ${recording.n_chunks} chunk(s), `, badge(recording.status), " ",
    engine ? h("a", { href: `/engine.html?id=${recording.engine_id}`, id: "engine-link" }, `engine ${engine.esn} trend`) : ""));
  // The stream sample retention may have removed the raw samples: said so, nothing fetched.
  const removed = recording.samples_removed_at;
  if (removed) {
    $("#samples-note").replaceChildren(h("span", { class: "notice", id: "samples-removed" },
      `The raw samples were removed on ${fmtTime(removed)} by the stream sample retention; ` +
      "the estimates below and the steady-window records on the engine trend are kept."));
  }
  const [samples, est, events] = await Promise.all([
    removed ? Promise.resolve(null)
      : apiText(`/api/v1/streams/${id}/samples`, { query: { format: "csv" } }).catch((err) => { showError($("#samples-plot"), err, "Samples"); return null; }),
    api(`/api/v1/streams/${id}/estimates`).catch((err) => { showError($("#tuners-plot"), err, "Estimates"); return null; }),
    api("/api/v1/events", { query: { engine_id: recording.engine_id, since: recording.started_at, until: end.toISOString(), limit: 200 } })
      .catch((err) => { showError($("#events"), err, "Events"); return null; }),
  ]);
  const evs = events ? events.items : [];
  const shapes = eventShapes(evs, recording);
  if (samples) drawSamples(recording, samples, shapes);
  if (est) {
    if (!est.t_s.length) {
      $("#estimates-note").textContent = "Not estimated yet (the estimation job runs after each upload).";
    } else {
      const hidden = [...(est.unobservable || []), ...(est.tuners_unobservable || [])];
      $("#estimates-note").textContent = `${est.n_samples_estimated} of ${est.n_samples} samples estimated under design #${est.design_id}; ` +
        `means over ${fmtNum(est.window_s, 1)} s windows, bands ±1σ. ${STREAM_BANDS[est.uncertainty] || ""}` +
        (hidden.length ? ` Not observable with this design: ${hidden.map(label).join(", ")}.` : "");
      $("#estimates-note").dataset.uncertainty = est.uncertainty || "uncalibrated";
      bandPlot($("#tuners-plot"), est.t_s, shownOnly(est.q_hat, hidden), est.q_sigma, "Tuners", shapes);
      bandPlot($("#health-plot"), est.t_s, shownOnly(est.h_hat, hidden), est.h_sigma, "Health parameter change", shapes);
    }
    drawOptional(est, shapes);
  }
  if (events) drawEvents(evs);
  const divs = ["#samples-plot", "#condition-plot", "#tuners-plot", "#health-plot", "#transient-plot", "#bias-plot"]
    .map((s) => $(s)).filter((d) => d && d.on);
  syncZoom(divs);
  document.body.dataset.ready = "true";
}

main();
