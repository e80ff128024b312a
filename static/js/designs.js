// Estimator designs: analytic squared bias and variance (stacked bars) next to Monte Carlo,
// confusion matrices (linear Monte Carlo and the built-in nonlinear engine) and misclassification
// probabilities, two designs side by side; create a design and watch its evaluation job.
import { api } from "./api.js";
import { $, badge, fmtNum, fmtTime, h, params, progressBar, showError, sortableTable, startPage } from "./ui.js";
import { CIVIDIS, PALETTE, axisTitle, colourAt, layout, plot, textOn } from "./plots.js";
import { label } from "./glossary.js";

// The API's names on the data, the engineers' names on the axis and in the hover.
const named = (names) => ({ tickmode: "array", tickvals: names, ticktext: names.map(label) });

const VARIANTS = { wssr_q: "WSSR on tuner estimates", wssr_y: "WSSR on sensor estimates", max_h: "largest health change", wssr_q_diagnostic: "WSSR, diagnostics-aware design" };
// The job kind's defaults are the seed 002 settings (200 cases of 30 s, 300 s per fault).
const EVALUATION = { seed: 0 };
let designs = [];
let models = [];
const cache = new Map();

function squared(unit) {
  if (!unit || unit === "-" || unit === "1") return "1";
  return `${unit}²`;
}

function unitsOf(result, group) {
  const signals = (result.model && result.model.signals && result.model.signals[group]) || [];
  const byName = Object.fromEntries(signals.map((s) => [s.name, s.unit]));
  return (name) => byName[name] || "%";
}

async function details(id) {
  if (!cache.has(id)) {
    cache.set(id, Promise.all([api(`/api/v1/designs/${id}`), api(`/api/v1/designs/${id}/evaluation`)]));
  }
  return cache.get(id);
}

function errorBars(div, theory, unitOf, mc) {
  const names = theory.names;
  const traces = [
    { x: names, y: theory.bias2, type: "bar", name: "squared bias (theory)", offsetgroup: "theory", marker: { color: PALETTE[0] },
      customdata: names.map(label), hovertemplate: "%{customdata}: bias² %{y:.4f}<extra></extra>" },
    { x: names, y: theory.variance, base: theory.bias2, type: "bar", name: "variance (theory)", offsetgroup: "theory", marker: { color: PALETTE[4] },
      customdata: names.map(label), hovertemplate: "%{customdata}: variance %{y:.4f}<extra></extra>" },
  ];
  if (mc) {
    traces.push({ x: mc.names, y: mc.squared_error, type: "bar", name: "Monte Carlo squared error", offsetgroup: "mc", marker: { color: PALETTE[1] },
      error_y: { type: "data", array: mc.standard_error, visible: true, color: "#000000", thickness: 1 },
      customdata: mc.names.map((n, i) => [label(n), mc.standard_error[i]]),
      hovertemplate: "%{customdata[0]}: %{y:.4f} ± %{customdata[1]:.4f} (standard error)<extra>Monte Carlo</extra>" });
  }
  const units = [...new Set(names.map((n) => squared(unitOf(n))))].join(", ");
  return plot(div, traces, layout({
    barmode: "group", hovermode: "closest",
    xaxis: { title: { text: "Estimated parameter" }, ...named(names) },
    yaxis: { title: { text: axisTitle("Squared error", units) } },
    margin: { l: 70, r: 20, t: 20, b: 40 },
  }));
}

// A matrix as a heatmap with its values written in the cells.
function matrixPlot(div, z, rows, cols, { title, unit, digits = 1, xTitle, yTitle }) {
  const max = Math.max(...z.flat());
  return plot(div, [{
    z, x: cols, y: rows, type: "heatmap", colorscale: CIVIDIS, zmin: 0, zmax: max || 1,
    colorbar: { title: { text: unit, side: "right" }, thickness: 12 },
    hovertemplate: `true %{y}, isolated %{x}: %{z:.${digits}f} ${unit}<extra></extra>`, name: title,
  }], layout({
    hovermode: "closest",
    xaxis: { title: { text: xTitle }, side: "bottom", gridcolor: "rgba(0,0,0,0)" },
    yaxis: { title: { text: yTitle }, autorange: "reversed", gridcolor: "rgba(0,0,0,0)" },
    annotations: z.flatMap((row, i) => row.map((v, j) => ({
      x: cols[j], y: rows[i], text: v >= 10 ** -digits / 2 ? v.toFixed(digits) : "", showarrow: false,
      // Black or white by the cell's own colour: 4.5:1 or better in every cell.
      font: { size: 10, color: textOn(colourAt(CIVIDIS, v / (max || 1))) },
    }))),
    margin: { l: 70, r: 20, t: 20, b: 60 },
  }));
}

// Baseline health on the nonlinear engine: RMS error per parameter (bars, %) and the fraction
// of engines inside the design's 95 % interval (markers, right axis; 95 % is honest).
function healthBars(div, health) {
  return plot(div, [
    { x: health.names, y: health.rms, type: "bar", name: "RMS error", marker: { color: PALETTE[0] },
      customdata: health.names.map(label), hovertemplate: "%{customdata}: RMS %{y:.2f} %<extra></extra>" },
    { x: health.names, y: health.coverage_95.map((c) => 100 * c), type: "scatter", mode: "markers", yaxis: "y2",
      name: "95 % interval coverage", marker: { color: PALETTE[1], size: 9, symbol: "diamond" },
      customdata: health.names.map(label), hovertemplate: "%{customdata}: coverage %{y:.0f} %<extra></extra>" },
    // What no design on these sensors can beat from the same records as the baseline: the
    // level's least 1-sigma (evaluations made before it have none).
    ...(health.floor ? [{ x: health.names, y: health.floor, type: "scatter", mode: "markers",
      name: `least 1σ these sensors allow from the same ${health.floor_records} take-off and cruise records`,
      marker: { color: "#000000", size: 14, symbol: "line-ew-open", line: { width: 2 } },
      customdata: health.names.map(label), hovertemplate: "%{customdata}: at best ±%{y:.2f} %<extra></extra>" }] : []),
  ], layout({
    hovermode: "closest",
    xaxis: { title: { text: "Health parameter" }, ...named(health.names) },
    yaxis: { title: { text: axisTitle("RMS error", "%") } },
    yaxis2: { title: { text: axisTitle("Coverage", "%") }, overlaying: "y", side: "right", range: [0, 105], showgrid: false, automargin: true },
    shapes: [{ type: "line", xref: "paper", x0: 0, x1: 1, yref: "y2", y0: 95, y1: 95, line: { dash: "dot", color: PALETTE[1], width: 1 } }],
    margin: { l: 70, r: 60, t: 20, b: 40 },
  }));
}

async function column(id, side, calibrating) {
  const card = h("section", { class: "card", id: `design-${side}` });
  const [design, evaluation] = await details(id);
  const result = design.result || {};
  const theory = design.analytic_errors;
  const mc = evaluation && evaluation.result.monte_carlo;
  const conf = evaluation && evaluation.result.confusion;
  card.append(h("h2", {}, `${side.toUpperCase()}: ${design.name} `, design.active ? badge("active", "ready") : null),
    h("dl", { class: "kv" },
      h("dt", {}, "Method"), h("dd", {}, `${result.method ?? design.spec.method} with ${(result.tuners || []).length} tuners`),
      h("dt", {}, "Sensors"), h("dd", {}, (result.sensors || design.spec.sensors || []).join(", ")),
      h("dt", {}, "SSEE (theory)"), h("dd", {}, `health ${fmtNum(design.ssee_health, 3)} %² · aux ${fmtNum(design.ssee_aux, 3)}`),
      h("dt", {}, "Monte Carlo"), h("dd", {}, mc ? `${mc.n_cases} cases, SSEE ${fmtNum(mc.ssee_health, 3)} %² (theory ${fmtNum(mc.ssee_health_theory, 3)}), ${fmtTime(evaluation.finished_at)}`
        : h("span", {}, "not evaluated yet ", h("button", { type: "button", class: "secondary", onclick: () => evaluate(design.id) }, "Run evaluation"))),
      ...calibrationRow(design, result.uncertainty, result.stream_uncertainty, calibrating.get(design.id))));
  if (design.status !== "ready" || !theory) {
    card.append(h("p", { class: "notice" }, `Design is ${design.status}${design.failure ? `: ${design.failure}` : ""}.`));
    return card;
  }
  const health = h("div", { class: "plot", id: `health-${side}` });
  const aux = h("div", { class: "plot", id: `aux-${side}` });
  const confusion = h("div", { class: "plot tall", id: `confusion-${side}` });
  const pmc = h("div", { class: "plot tall", id: `pmc-${side}` });
  card.append(h("h3", {}, "Health parameters: squared bias + variance, theory next to Monte Carlo"), health,
    h("h3", {}, `Auxiliary outputs (${theory.aux.names.map(label).join(", ") || "none"}): squared bias + variance`), aux);
  const variant = $("#variant").value;
  if (conf && conf[variant]) {
    card.append(h("h3", {}, `Confusion matrix: ${VARIANTS[variant] || variant}, correct ${fmtNum(conf[variant].correct_rate, 1)} %`), confusion);
  } else {
    // A placeholder as tall as the plot keeps the two columns aligned.
    card.append(h("h3", {}, "Confusion matrix"), h("div", { class: "plot tall placeholder" },
      evaluation ? (evaluation.result.isolation_note || "No confusion matrix for this variant.")
        : h("div", {}, h("p", {}, "No Monte Carlo evaluation yet."),
          h("button", { type: "button", class: "run-evaluation", onclick: () => evaluate(design.id) }, "Run the Monte Carlo evaluation"))));
  }
  const engine = evaluation && evaluation.result.nonlinear_engine;
  const engineConf = h("div", { class: "plot tall", id: `engine-confusion-${side}` });
  const engineHealth = h("div", { class: "plot", id: `engine-health-${side}` });
  if (engine) {
    const vis = engine.visibility;
    card.append(h("h3", {}, `On the built-in nonlinear engine: correct ${fmtNum(engine.percent_correct, 1)} % of the ${engine.faults.length} faults`
      + (vis.percent_correct_visible != null ? `, ${fmtNum(vis.percent_correct_visible, 1)} % of the ${vis.visible.length} visible ones` : "")),
    h("p", { class: "muted engine-summary" },
      `${engine.n_engines} simulated engines (scatter, deterioration, actuator biases), ${engine.settings.records_before} snapshots before the fault, `
      + `${engine.settings.records_after} with it; ${engine.settings.signatures} fault signatures, fuel flow as ${engine.settings.wf}. `
      + `Baseline health RMS ${fmtNum(engine.health.rms_turbomachinery, 2)} %, 95 % interval coverage ${fmtNum(100 * engine.health.coverage_turbomachinery, 0)} % (ten turbomachinery parameters).`),
    vis.not_visible.length ? h("p", { class: "notice engine-invisible" },
      `No visible signature: ${vis.not_visible.map((f) => `${f} (${fmtNum(vis.event_sigmas[engine.faults.indexOf(f)], 1)} σ per event)`).join(", ")}. `
      + `Below ${fmtNum(vis.threshold_sigmas, 0)} noise sigmas over an event, no design can isolate these faults on this engine`
      + (vis.ceiling_percent_correct != null ? `; isolating the ones under 1 σ at chance, no design can expect more than ${fmtNum(vis.ceiling_percent_correct, 1)} % of all ${engine.faults.length}.` : ".")) : null,
    engine.ambiguity_groups.length ? h("p", { class: "engine-groups" },
      `Ambiguity groups: ${engine.ambiguity_groups.map((g) => g.join(" or ")).join("; ")} (naming the group is right for ${fmtNum(engine.group_percent_correct, 1)} % of the visible faults).`) : null,
    engine.posterior ? h("p", { class: "muted engine-tempering" },
      `Event confidence: tempered on ${engine.posterior.events} other faulted engines to be right as often as it says (WSSR scale ${fmtNum(engine.posterior.wssr_scale, 2)}, confusion weight ${fmtNum(engine.posterior.confusion_power, 2)}); `
      + `mean log probability of the true fault ${fmtNum(engine.posterior.log_score, 3)}, untempered ${fmtNum(engine.posterior.default_score, 3)} (0 is certain and right).`)
      : h("p", { class: "notice engine-tempering" }, "This evaluation predates the tempering of the events' confidence: its events show untempered probabilities, which claim more than they know. Run the evaluation again."),
    engineConf,
    h("h3", {}, "Nonlinear engine: baseline health RMS and 95 % interval coverage"), engineHealth);
  } else if (evaluation) {
    card.append(h("h3", {}, "On the built-in nonlinear engine"), h("p", { class: "notice engine-note" },
      evaluation.result.nonlinear_engine_note || "This evaluation predates the nonlinear-engine run: run the evaluation again."));
  }
  if (result.faults) card.append(h("h3", {}, `Misclassification probability (analytic), sum ${fmtNum(result.faults.pmc_sum, 3)}`), pmc);
  // Plot after the card is in the document, so the plots size to it.
  card.draw = () => Promise.all([
    errorBars(health, theory.health, unitsOf(result, "health"), mc && mc.health),
    errorBars(aux, theory.aux, unitsOf(result, "aux"), null),
    conf && conf[variant] ? matrixPlot(confusion, conf[variant].percent, conf[variant].faults, conf[variant].faults,
      { title: "confusion", unit: "%", xTitle: "Isolated fault", yTitle: "True fault" }) : null,
    engine ? matrixPlot(engineConf, engine.confusion_percent, engine.faults, engine.faults,
      { title: "confusion on the nonlinear engine", unit: "%", xTitle: "Isolated fault", yTitle: "True fault" }) : null,
    engine ? healthBars(engineHealth, engine.health) : null,
    result.faults ? matrixPlot(pmc, result.faults.pmc, result.faults.names, result.faults.names,
      { title: "misclassification probability", unit: "probability", digits: 3, xTitle: "Mistaken for", yTitle: "True fault" }) : null,
  ]);
  return card;
}

async function compare() {
  const a = $("#a").value;
  const b = $("#b").value;
  history.replaceState(null, "", `/designs.html?a=${a}&b=${b}`);
  const compareDiv = $("#compare");
  const cards = [];
  const calibrating = await activeCalibrations();
  for (const [id, side] of [[a, "a"], [b, "b"]]) {
    if (!id) continue;
    try {
      cards.push(await column(Number(id), side, calibrating));
    } catch (err) {
      const card = h("section", { class: "card" });
      showError(card, err, `Design ${id}`);
      cards.push(card);
    }
  }
  compareDiv.replaceChildren(...cards);
  await Promise.all(cards.map((c) => c.draw && c.draw()));
  const shown = [...calibrating.values()].find((job) => [Number(a), Number(b)].includes(job.parameters.design_id));
  if (shown && !following.has(shown.id)) follow(shown);
}

// Calibration jobs queued or running, by design id (the newest of each).
async function activeCalibrations() {
  const out = new Map();
  let jobs;
  try {
    jobs = await api("/api/v1/jobs", { query: { kind: "calibrate_design", status: ["queued", "running"] } });
  } catch {
    return out; // the page works without: the button stays
  }
  for (const job of jobs.items) if (!out.has(job.parameters.design_id)) out.set(job.parameters.design_id, job);
  return out;
}

// Watch a calibration job someone else started, then show what it stored.
const following = new Set();
async function follow(job) {
  following.add(job.id);
  const done = await watchJob(job, `Calibration of design ${job.parameters.design_id} on simulated fleets`);
  following.delete(job.id);
  cache.delete(job.parameters.design_id);
  if (done.status === "succeeded") await compare();
}

async function watchJob(job, label) {
  const box = $("#job");
  for (;;) {
    box.replaceChildren(h("p", {}, `${label}: job #${job.id} `, badge(job.status)), progressBar(job.progress, job.message));
    if (["succeeded", "failed", "cancelled"].includes(job.status)) return job;
    await new Promise((r) => setTimeout(r, 1000));
    job = await api(`/api/v1/jobs/${job.id}`);
  }
}

// The design's calibration against the built-in engine's simulator (what makes the trends'
// bands honest): how it was made, or why the bands are the filter's own, with a button that
// runs it (built-in engine designs only: the others have no simulator).
function calibrationRow(design, cal, streams, running) {
  const model = models.find((m) => m.id === design.engine_model_id);
  if (!model || model.source !== "builtin" || design.status !== "ready") return [];
  // A calibration job of this design queued or running (the demo's first start queues one):
  // its progress shows in the job box, and no second one is offered.
  const button = (text) => running
    ? h("span", { class: "calibration-running muted" }, ` calibration job #${running.id} ${running.status} (${fmtNum(100 * (running.progress || 0), 0)} %): see its progress above`)
    : h("button", { type: "button", class: "secondary run-calibration", onclick: () => calibrate(design.id) }, text);
  let text;
  if (!cal) text = h("span", { class: "calibration-state" }, "not calibrated: the trends show the filter's own 1-sigma ");
  else {
    const src = cal.source || {};
    const made = `${(src.seeds || []).length || "?"} simulated fleets, ${src.engines ?? "?"} engines, ${src.records ?? "?"} records`;
    // Each later part of the calibration (the tuners' and deltas' bands, the calibrated aux
    // outputs, the rate of change's sigma) is missing from one made before it.
    const complete = (cal.tuner_names || []).length && (cal.delta_names || []).length && "aux_correction" in cal && "rate_std" in cal && "tuner_correction" in cal;
    text = complete
      ? h("span", { class: "calibration-state" }, `calibrated on ${made}: every band of the engine page `)
      : h("span", { class: "calibration-state" }, `calibrated on ${made} before every band of the engine page was (the tuners', deltas', the calibrated tuners, thrust and stall margins, the rate of change's): calibrate again for them `);
  }
  // The recording page's bands: calibrated by the same job on simulated recorded flights.
  const src = (streams && streams.source) || {};
  const shown = streams ? streams.names.filter((_, i) => streams.observable[i]) : [];
  // A stream calibration made before it filtered each engine's flights in sequence, as the
  // product filters an engine's recordings, under-covers the later recordings: again.
  const streamsMade = `stream estimates calibrated on ${src.flights ?? "?"} simulated flights (${src.windows ?? "?"} windows)`;
  const streamText = !streams
    ? "stream estimates not calibrated: the recording page shows the stream filter's own 1-sigma"
    : src.carried
      ? `${streamsMade}: shown ${shown.length ? shown.map(label).join(", ") : "none"}`
      : `${streamsMade} each from nominal, before the calibration followed an engine's recordings from one to the next: its bands are too narrow on an engine's later recordings; calibrate again`;
  return [h("dt", {}, "Calibration"), h("dd", {}, text, button(cal ? "Calibrate again" : "Calibrate against the simulator"),
    h("br"), h("span", { class: "stream-calibration-state muted" }, streamText))];
}

async function calibrate(designId) {
  const message = $("#create-message");
  message.replaceChildren();
  try {
    const job = await api("/api/v1/jobs", { method: "POST", body: { kind: "calibrate_design", parameters: { design_id: designId } } });
    const done = await watchJob(job, `Calibration of design ${designId} on simulated fleets`);
    if (done.status !== "succeeded") showError(message, new Error(done.error || `calibration ${done.status}`), "Calibration");
    cache.delete(designId);
    await compare();
  } catch (err) {
    showError(message, err, "Calibration");
  }
}

async function evaluate(designId) {
  const message = $("#create-message");
  message.replaceChildren();
  try {
    const job = await api("/api/v1/jobs", { method: "POST", body: { kind: "evaluate_design", parameters: { design_id: designId, ...EVALUATION } } });
    const done = await watchJob(job, `Monte Carlo evaluation of design ${designId}`);
    if (done.status !== "succeeded") showError(message, new Error(done.error || `evaluation ${done.status}`), "Evaluation");
    cache.delete(designId);
    await compare();
  } catch (err) {
    showError(message, err, "Evaluation");
  }
}

// The chosen model's sensors with their units, as its file declares them; a sensor that is also
// a measured input of the model (fuel flow on the built-in engine) starts unchecked: the
// estimator reads it as the input.
function sensorChecks() {
  const model = models.find((m) => String(m.id) === $("#model").value);
  const sensors = model ? model.signals.sensors : [];
  const inputs = new Set(model ? model.signals.inputs.map((s) => s.name) : []);
  $("#sensors").replaceChildren(...sensors.map((s) =>
    h("label", { "data-sensor": s.name }, h("input", { type: "checkbox", name: "sensor", value: s.name, checked: !inputs.has(s.name) }),
      ` ${s.name}`, s.unit ? h("span", { class: "muted" }, ` [${s.unit}]`) : "")));
}

async function create(e) {
  e.preventDefault();
  const message = $("#create-message");
  const button = $("#create-button");
  message.replaceChildren();
  const sensors = [...document.querySelectorAll("input[name=sensor]:checked")].map((x) => x.value);
  const model = models.find((m) => String(m.id) === $("#model").value);
  const healthNames = model.health_names.filter((n) => !n.endsWith("_bias"));
  const spec = {
    format: "fleethealth.design-spec/1", method: $("#method").value, tuners: Number($("#tuners").value),
    sensors, health: healthNames, noise: { Q: 1e-4, Qh: 1e-4, Ph: 4.0 },
  };
  button.disabled = true;
  $("#create-status").textContent = "checking the spec…";
  try {
    // In the background: the spec is checked now (422 names what is wrong), the design step
    // runs as a create_design job whose progress shows below, then the evaluation job.
    const design = await api("/api/v1/designs", { method: "POST", query: { background: true },
      body: { engine_model_id: model.id, name: $("#name").value.trim(), spec } });
    $("#create-status").textContent = `design ${design.id} ${design.status}`;
    if (design.job_id) {
      const done = await watchJob(await api(`/api/v1/jobs/${design.job_id}`), `Design step of design ${design.id}`);
      if (done.status !== "succeeded") {
        showError(message, new Error(done.error || `design job ${done.status}`), "Design not made");
        await loadList();
        return;
      }
    }
    $("#create-status").textContent = `design ${design.id} ready`;
    await loadList(design.id);
    await evaluate(design.id);
  } catch (err) {
    $("#create-status").textContent = "";
    showError(message, err, "Design not created");
  } finally {
    button.disabled = false;
  }
}

async function loadList(selectB) {
  const page = await api("/api/v1/designs", { query: { limit: 200 } });
  designs = page.items;
  const p = params();
  const a = $("#a").value || p.get("a") || String((designs.find((d) => d.active) || designs[0] || {}).id || "");
  const b = selectB ? String(selectB) : $("#b").value || p.get("b") || String((designs.find((d) => String(d.id) !== a) || {}).id || "");
  for (const [sel, value] of [["#a", a], ["#b", b]]) {
    $(sel).replaceChildren(h("option", { value: "" }, "none"), ...designs.map((d) =>
      h("option", { value: d.id, selected: String(d.id) === value }, `#${d.id} ${d.name}`)));
  }
  $("#list").replaceChildren(designs.length ? sortableTable([
    { key: "id", label: "#", numeric: true },
    { key: "name", label: "Name" },
    { key: "method", label: "Method", value: (d) => d.spec.method },
    { key: "tuners", label: "Tuners", numeric: true, value: (d) => d.spec.tuners },
    { key: "status", label: "Status", cell: (d) => badge(d.status) },
    { key: "active", label: "In service", cell: (d) => (d.active ? badge("active", "ready") : "") },
    { key: "ssee_health", label: "SSEE health [%²]", numeric: true, cell: (d) => fmtNum(d.ssee_health, 3) },
    { key: "ssee_aux", label: "SSEE aux", numeric: true, cell: (d) => fmtNum(d.ssee_aux, 3) },
    { key: "created_at", label: "Created", cell: (d) => fmtTime(d.created_at) },
  ], designs, { sortKey: "id", descending: true }) : h("p", { class: "muted" }, "No designs yet: create one below."));
}

async function main() {
  const principal = await startPage("designs");
  $("#variant").replaceChildren(...Object.entries(VARIANTS).map(([k, v]) => h("option", { value: k }, v)));
  try {
    await loadList();
    models = (await api("/api/v1/engine-models", { query: { limit: 200 } })).items;
    const types = Object.fromEntries((await api("/api/v1/engine-types", { query: { limit: 200 } })).items.map((t) => [t.id, t.name]));
    $("#model").replaceChildren(...models.map((m) => h("option", { value: m.id }, `${types[m.engine_type_id] ?? `type ${m.engine_type_id}`}: ${m.name} v${m.version}`)));
    sensorChecks();
  } catch (err) {
    showError($("#message"), err, "Designs");
  }
  if (principal.role === "viewer") {
    $("#create-button").disabled = true;
    $("#create-message").append(h("p", { class: "notice" }, "Creating designs needs an analyst key."));
  }
  $("#model").addEventListener("change", sensorChecks);
  $("#create").addEventListener("submit", create);
  for (const id of ["a", "b", "variant"]) $(`#${id}`).addEventListener("change", compare);
  await compare();
  document.body.dataset.ready = "true";
}

main();
