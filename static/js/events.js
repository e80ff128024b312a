// Event review (an abrupt shift, or wear: the change accumulated since a baseline): the detected
// shift, the WSSR of every fault hypothesis, the isolated fault and its magnitude, the confidence
// (posterior over the hypotheses, ambiguity group, the design's confusion row); the alert's
// handling: assign to a person, acknowledge or close with a reason, comment, and the history of
// who did what. Without ?id= the list of events.
import { api } from "./api.js";
import { $, badge, fmtNum, fmtTime, h, params, showError, sortableTable, startPage, tailLink } from "./ui.js";
import { MARKER_COLOURS, PALETTE, axisTitle, layout, lineWithBand, markerAnnotations, markerScale, markerShapes, plot, trendMarkers, unitOf } from "./plots.js";
import { label } from "./glossary.js";

const WINDOW_DAYS = 20;
const BASELINE_RECORDS = 20;

async function showList() {
  const content = $("#content");
  const status = params().get("status") ?? "active";
  const labels = { active: "active (open or acknowledged)", open: "open", acknowledged: "acknowledged", closed: "closed", "": "all" };
  const filter = h("select", { id: "status" }, Object.keys(labels).map((s) =>
    h("option", { value: s, selected: s === status }, labels[s])));
  const kind = params().get("kind") ?? "";
  const kinds = { "": "all", shift: "shift (not isolated)", isolated_fault: "isolated fault (abrupt)", wear: "wear (gradual)" };
  const kindFilter = h("select", { id: "kind" }, Object.keys(kinds).map((k) =>
    h("option", { value: k, selected: k === kind }, kinds[k])));
  const reload = () => location.assign(`/events.html?status=${filter.value}${kindFilter.value ? `&kind=${kindFilter.value}` : ""}`);
  filter.addEventListener("change", reload);
  kindFilter.addEventListener("change", reload);
  const page = await api("/api/v1/events", { query: { status: status || undefined, kind: kind || undefined, limit: 500 } });
  const columns = [
    { key: "id", label: "Event", numeric: true, cell: (e) => h("a", { href: `/events.html?id=${e.id}` }, `#${e.id}`) },
    { key: "detected_at", label: "Detected", cell: (e) => fmtTime(e.detected_at) },
    { key: "esn", label: "ESN", cell: (e) => h("a", { href: `/engine.html?id=${e.engine_id}` }, e.esn) },
    { key: "tail", label: "Tail", cell: (e) => (e.tail ? h("span", {}, tailLink(e.tail), ` #${e.position}`) : "–") },
    { key: "kind", label: "Kind", cell: (e) => e.kind.replace("_", " ") },
    { key: "fault", label: "Isolated fault", cell: (e) => e.fault || h("span", { class: "muted" }, "not isolated") },
    { key: "magnitude", label: "Magnitude", numeric: true, cell: (e) => fmtNum(e.magnitude) },
    { key: "confidence", label: "Confidence", value: (e) => (e.confidence ? e.confidence.probability : -1),
      cell: (e) => (e.confidence ? `${e.confidence.label} (${fmtNum(100 * e.confidence.probability, 0)} %)` : "–") },
    { key: "status", label: "Status", cell: (e) => badge(e.status) },
    { key: "assignee", label: "Assigned to", value: (e) => (e.assignee ? e.assignee.name : ""),
      cell: (e) => (e.assignee ? e.assignee.name : h("span", { class: "muted" }, "no one")) },
  ];
  content.replaceChildren(h("section", { class: "card" },
    h("div", { class: "toolbar" }, h("label", {}, "Status", filter), h("label", {}, "Kind", kindFilter), h("span", { class: "muted" }, `${page.total} event${page.total === 1 ? "" : "s"}`)),
    page.items.length ? h("div", { class: "table-wrap" }, sortableTable(columns, page.items, { sortKey: "detected_at", descending: true }))
      : h("p", { class: "muted" }, "No events with this status and kind.")));
}

function shiftPlot(div, event) {
  const names = Object.keys(event.health_shift);
  const x = names.map(label);
  const traces = [{
    x: names, y: names.map((n) => event.health_shift[n]), type: "bar", name: "detected health shift",
    customdata: x, marker: { color: PALETTE[0] }, hovertemplate: "%{customdata}: %{y:.3f} %<extra>detected</extra>",
  }];
  if (event.fault && Object.keys(event.fault_shift).length) {
    traces.push({
      x: names, y: names.map((n) => event.fault_shift[n] ?? 0), type: "bar", customdata: x,
      name: `${event.fault} signature × ${fmtNum(event.magnitude)}`, marker: { color: PALETTE[1] },
      hovertemplate: "%{customdata}: %{y:.3f} %<extra>isolated fault</extra>",
    });
  }
  return plot(div, traces, layout({
    barmode: "group", hovermode: "closest",
    // The API's names on the data, the engineers' names on the axis.
    xaxis: { title: { text: "Health parameter" }, tickmode: "array", tickvals: names, ticktext: x },
    yaxis: { title: { text: axisTitle("Shift against baseline", "%") } },
  }));
}

function wssrPlot(div, event) {
  const faults = Object.keys(event.wssr);
  const values = faults.map((f) => event.wssr[f]);
  // A log scale when the bars span decades, so small WSSRs and the threshold stay readable.
  const all = event.wssr_threshold === null ? values : values.concat([event.wssr_threshold]);
  const log = all.every((v) => v > 0) && Math.max(...all) / Math.min(...all) > 20;
  const shapes = event.wssr_threshold === null ? [] : [{
    type: "line", xref: "paper", x0: 0, x1: 1, yref: "y", y0: event.wssr_threshold, y1: event.wssr_threshold,
    line: { color: "#000000", dash: "dash", width: 1.5 },
  }];
  return plot(div, [{
    x: faults, y: values, type: "bar", name: "WSSR",
    marker: { color: faults.map((f) => (f === event.fault ? MARKER_COLOURS.event : PALETTE[0])) },
    text: values.map((v) => fmtNum(v, 1)), textposition: "outside", cliponaxis: false,
    hovertemplate: "%{x}: WSSR %{y:.2f}<extra></extra>",
  }], layout({
    hovermode: "closest", shapes, showlegend: false,
    annotations: event.wssr_threshold === null ? [] : [{ xref: "paper", x: 1, xanchor: "right", y: log ? Math.log10(event.wssr_threshold) : event.wssr_threshold, yref: "y", yanchor: "bottom",
      text: `accept below ${fmtNum(event.wssr_threshold, 1)}`, showarrow: false, font: { size: 11 } }],
    xaxis: { title: { text: "Fault hypothesis" } },
    yaxis: log
      ? { title: { text: `${axisTitle("WSSR", "1")}, log scale` }, type: "log", dtick: 1,
        range: [Math.log10(Math.min(...all) / 2), Math.log10(Math.max(...all) * 2)] }
      : { title: { text: axisTitle("WSSR", "1") }, type: "linear" },
  }));
}

const SOURCE_TEXT = {
  nonlinear_engine: "WSSR × the design's confusion on the built-in nonlinear engine",
  linear_monte_carlo: "WSSR × the design's linear Monte Carlo confusion",
  wssr_only: "WSSR alone (the design has no measured confusion yet)",
};

// Posterior probability of every fault hypothesis (bars, percent), the WSSR-only posterior
// beside it as markers, so what the design's confusion changes is visible.
function posteriorPlot(div, c) {
  return plot(div, [
    { x: c.faults, y: c.posterior.map((p) => 100 * p), type: "bar", name: "posterior",
      marker: { color: c.faults.map((f) => (c.ambiguity_group.includes(f) ? MARKER_COLOURS.event : PALETTE[0])) },
      text: c.posterior.map((p) => (p >= 0.005 ? `${(100 * p).toFixed(p >= 0.995 ? 1 : 0)} %` : "")), textposition: "outside", cliponaxis: false,
      hovertemplate: "%{x}: %{y:.1f} %<extra>posterior</extra>" },
    { x: c.faults, y: c.wssr_posterior.map((p) => 100 * p), type: "scatter", mode: "markers", name: "from WSSR alone",
      marker: { color: "#000000", symbol: "line-ew-open", size: 14, line: { width: 2 } },
      hovertemplate: "%{x}: %{y:.1f} %<extra>WSSR alone</extra>" },
  ], layout({
    hovermode: "closest",
    xaxis: { title: { text: "Fault hypothesis" } },
    yaxis: { title: { text: axisTitle("Probability", "%") }, range: [0, 110] },
  }));
}

// The design's confusion row of the isolated fault: where that fault ends up when it is true.
function confusionRowPlot(div, row) {
  return plot(div, [{
    x: row.faults, y: row.percent, type: "bar", name: `true ${row.true_fault}`,
    marker: { color: row.faults.map((f) => (f === row.true_fault ? MARKER_COLOURS.event : PALETTE[4])) },
    text: row.percent.map((v) => (v >= 0.5 ? `${v.toFixed(0)} %` : "")), textposition: "outside", cliponaxis: false,
    hovertemplate: `true ${row.true_fault}, isolated %{x}: %{y:.1f} %<extra></extra>`,
  }], layout({
    hovermode: "closest", showlegend: false,
    xaxis: { title: { text: "Isolated as" } },
    yaxis: { title: { text: axisTitle(`Share of true ${row.true_fault} faults`, "%") }, range: [0, 110] },
  }));
}

// A wear event ranks module deteriorations only (wear is no actuator bias): the faults left
// out are named, and a notice says when one of them fits the change clearly better than the
// isolated fault (the API's fits_better).
function leftOutNote(event, c) {
  if (!c.left_out || !c.left_out.length) return null;
  const wssr = event.wssr || {};
  const better = c.fits_better || [];
  return h("p", { class: better.length ? "notice" : "muted", id: "left-out" },
    `Wear is attributed among the module deteriorations fitted with a positive magnitude; not ranked: ${c.left_out.join(", ")}.`
    + (better.length ? ` ${better.join(" and ")} fit${better.length > 1 ? "" : "s"} this change better (WSSR ${better.map((f) => fmtNum(wssr[f], 1)).join(", ")} against ${fmtNum(wssr[c.isolated], 1)} for ${c.isolated}): `
      + "check the fuel metering and actuator rigging, and the sensors, before reading it as wear." : ""));
}

function confidenceCard(event) {
  const c = event.confidence;
  if (!c) return [h("section", { class: "card", id: "confidence" }, h("h2", {}, "Confidence"), h("p", { class: "muted" }, "No WSSR stored for this event."))];
  const post = h("div", { id: "posterior", class: "plot" });
  const row = h("div", { id: "confusion-row", class: "plot" });
  const group = c.ambiguity_group.length > 1
    ? h("p", { class: "notice", id: "ambiguity" }, `This design cannot reliably tell ${c.ambiguity_group.join(" or ")} apart `
      + `(${c.source === "nonlinear_engine" ? "on the built-in nonlinear engine" : "in its Monte Carlo evaluation"}): treat the finding as "${c.ambiguity_group.join(" or ")}".`)
    : null;
  const fit = c.fit_probability < c.fit_level
    ? h("p", { class: "notice" }, `No library fault explains the event well (chi-squared tail probability ${fmtNum(c.fit_probability, 3)}): the probabilities rank the library's faults only.`)
    : null;
  const card = h("section", { class: "card", id: "confidence" },
    h("h2", {}, c.fit_probability < c.fit_level ? `Confidence: closest library fault ${c.label}, but none fits the event`
      : `Confidence: ${c.label} (${fmtNum(100 * c.probability, 0)} % ${c.isolated})`),
    h("p", { class: "muted", id: "confidence-source" }, `${SOURCE_TEXT[c.source] || c.source}${c.evaluation_job_id ? ` (evaluation job #${c.evaluation_job_id})` : ""}; the label names the fewest faults holding ${fmtNum(100 * c.credible_mass, 0)} % of the probability.${c.tempering ? ` Probabilities tempered to be right as often as they say on ${c.tempering.events} faulted engines of that evaluation (WSSR scale ${fmtNum(c.tempering.wssr_scale, 2)}, confusion weight ${fmtNum(c.tempering.confusion_power, 2)}).` : ""}`),
    group, fit,
    c.not_visible.length ? h("p", { class: "muted" }, `Faults with no visible signature on the built-in engine, which no design isolates: ${c.not_visible.join(", ")}.`) : null,
    c.explained !== null && c.explained !== undefined
      ? h("p", { class: "muted", id: "explained" }, `${c.isolated} explains ${fmtNum(100 * c.explained, 0)} % of the change accumulated since the wear baseline (weighed as the health change).`)
      : null,
    leftOutNote(event, c),
    h("div", { class: "grid" },
      h("div", {}, h("h3", {}, "Probability of each fault hypothesis"), post),
      h("div", {}, h("h3", {}, c.confusion_row ? `How the design isolates a true ${c.confusion_row.true_fault} fault` : "Confusion row"),
        c.confusion_row ? row : h("p", { class: "muted" }, "No measured confusion: run the design's evaluation on the designs page."))));
  card.draw = () => Promise.all([posteriorPlot(post, c), c.confusion_row ? confusionRowPlot(row, c.confusion_row) : null]);
  return [card];
}

async function windowPlot(div, event) {
  const t = Date.parse(event.detected_at);
  const day = 86400e3;
  const trend = await api(`/api/v1/engines/${event.engine_id}/trend`, { query: {
    design_id: event.design_id, start: new Date(t - WINDOW_DAYS * day).toISOString(),
    end: new Date(t + WINDOW_DAYS * day).toISOString(), max_points: 1000 } });
  const group = trend.groups.find((g) => g.key === "health");
  if (!group || !trend.n_records) { div.replaceWith(h("p", { class: "muted" }, "No estimates around the event.")); return; }
  // Each parameter against its mean over the last records before the detection, so the
  // shift shows as a step whatever the engine's accumulated deterioration.
  const before = trend.time.map((x, i) => [Date.parse(x), i]).filter(([x]) => x < t).slice(-BASELINE_RECORDS).map(([, i]) => i);
  const series = group.series.map((s) => {
    const known = before.map((i) => s.value[i]).filter((v) => v !== null);
    const base = known.length ? known.reduce((a, b) => a + b, 0) / known.length : 0;
    return { ...s, value: s.value.map((v) => (v === null ? null : v - base)) };
  });
  const traces = series.flatMap((s, i) => lineWithBand(trend.time, s, i));
  // The engine's installation changes, maintenance actions and other events in the window,
  // marked and labelled as on the engine page; this event's line is the thick one.
  const marks = trendMarkers(trend, (iso) => iso, fmtTime).filter((m) => m.event !== event.id);
  const range = [new Date(t - WINDOW_DAYS * day).toISOString(), new Date(t + WINDOW_DAYS * day).toISOString()];
  const lay = layout({
    xaxis: { title: { text: "Date (UTC)" }, type: "date", range },
    yaxis: { title: { text: axisTitle("Change since before detection", unitOf(group.series)) } },
    shapes: [...markerShapes(marks), { ...markerShapes([{ kind: "event", x: event.detected_at }])[0], line: { color: MARKER_COLOURS.event, width: 3 } }],
    margin: { l: 70, r: 20, t: 50, b: 40 },
  });
  const labelled = [...marks.filter((m) => m.kind !== "event" && m.kind !== "wear"),
    { kind: "event", x: event.detected_at, short: `event #${event.id}`, label: `this event, detected ${fmtTime(event.detected_at)}` }];
  lay.annotations = markerAnnotations(labelled, markerScale(range, div.clientWidth - lay.margin.l - lay.margin.r));
  return plot(div, traces, lay);
}

const ACTION_TEXT = {
  assigned: (s) => `assigned it to ${s.assignee}`,
  unassigned: () => "took the assignment away",
  acknowledged: () => "acknowledged",
  commented: () => "commented",
  closed: () => "closed",
};

function timeline(event) {
  if (!event.history.length) return h("p", { class: "muted", id: "history" }, "Nothing done yet.");
  return h("ol", { class: "timeline", id: "history", "aria-label": "Alert history, oldest first" }, event.history.map((s) =>
    h("li", { class: `step ${s.action}` },
      h("time", { datetime: s.created_at }, fmtTime(s.created_at)), " ",
      h("strong", {}, s.actor), ` ${ACTION_TEXT[s.action](s)}`,
      s.reason ? h("div", { class: "reason" }, s.action === "commented" ? s.reason : `Reason: ${s.reason}`) : null)));
}

function actions(event, principal, refresh, people) {
  const canWrite = principal.role !== "viewer";
  const open = event.status !== "closed";
  const reason = h("textarea", { id: "reason", rows: 2, style: "width:100%", placeholder: "what was found, what was done" });
  const text = h("textarea", { id: "comment", rows: 2, style: "width:100%" });
  const assignee = h("select", { id: "assignee", disabled: !canWrite || !open },
    h("option", { value: "" }, "no one"),
    people.map((p) => h("option", { value: String(p.key_id), selected: event.assignee && event.assignee.key_id === p.key_id }, `${p.name} (${p.role})`)));
  const message = h("div", { role: "status" });
  const run = async (path, body) => {
    message.replaceChildren();
    try {
      const updated = await api(`/api/v1/events/${event.id}/${path}`, { method: "POST", body });
      refresh(updated);
    } catch (err) {
      showError(message, err, "Not saved");
    }
  };
  const withReason = (path) => {
    if (!reason.value.trim()) { showError(message, new Error("Give a reason first.")); reason.focus(); return; }
    run(path, { reason: reason.value.trim() });
  };
  return h("section", { class: "card", id: "review" }, h("h2", {}, "Alert handling"),
    canWrite ? null : h("p", { class: "notice" }, "Your key is a viewer key: assigning, acknowledging and commenting need an analyst key."),
    h("p", { id: "assigned-to" }, "Assigned to: ", h("strong", {}, event.assignee ? event.assignee.name : "no one")),
    h("div", { class: "toolbar" },
      h("label", { for: "assignee" }, "Assign to", assignee),
      h("button", { id: "assign", type: "button", class: "secondary", disabled: !canWrite || !open, onclick: () =>
        run("assign", { assignee_key_id: assignee.value ? Number(assignee.value) : null }) }, "Assign")),
    h("label", { for: "reason", style: "display:block;margin-top:.6rem" }, "Reason (required to acknowledge or close)", reason),
    h("div", { class: "toolbar", style: "margin-top:.5rem" },
      h("button", { id: "ack", type: "button", disabled: !canWrite || event.status !== "open", onclick: () => withReason("ack") }, "Acknowledge"),
      h("button", { id: "close", type: "button", class: "secondary", disabled: !canWrite || !open, onclick: () => withReason("close") }, "Close event")),
    h("label", { for: "comment", style: "display:block;margin-top:.6rem" }, "Comment", text),
    h("div", { class: "toolbar", style: "margin-top:.5rem" },
      h("button", { id: "add-comment", type: "button", class: "secondary", disabled: !canWrite, onclick: () => {
        if (!text.value.trim()) { showError(message, new Error("Write a comment first.")); return; }
        run("comments", { body: text.value.trim() });
      } }, "Add comment")),
    message,
    h("h3", {}, "History"),
    timeline(event),
    h("h3", {}, `Comments (${event.comments.length})`),
    event.comments.length ? h("ul", { class: "comments", id: "comments" }, event.comments.map((c) =>
      h("li", {}, h("div", { class: "muted" }, `${c.author} · ${fmtTime(c.created_at)}`), c.body))) : h("p", { class: "muted" }, "No comments yet."));
}

// The uploads that caused the event: its record's upload, and back-dated uploads whose re-run
// reached it; each opens in the upload history.
function causedBy(event) {
  const dd = h("dd", { id: "caused-by" }, h("span", { class: "muted" }, "…"));
  api(`/api/v1/events/${event.id}/uploads`).then((uploads) => dd.replaceChildren(...(uploads.length
    ? uploads.flatMap((u, i) => [i ? "; " : "", h("a", { href: `/uploads.html?upload=${u.id}` }, `upload #${u.id}`),
      ` ${u.filename ? `(${u.filename})` : ""}${u.back_dated ? " back-dated" : ""}`])
    : [h("span", { class: "muted" }, "none found")])))
    .catch((err) => showError(dd, err, "Uploads"));
  return dd;
}

function statusLine(event) {
  return [badge(event.status), event.acknowledged_at ? ` acknowledged ${fmtTime(event.acknowledged_at)}` : "",
    event.closed_at ? ` · closed ${fmtTime(event.closed_at)}` : ""];
}

function showEvent(event, principal, people) {
  $("#title").textContent = `Event #${event.id} · ${event.esn}`;
  // After assign/acknowledge/comment/close only the status and the handling card change.
  const refresh = (updated) => {
    $("#status").replaceChildren(...statusLine(updated));
    $("#review").replaceWith(actions(updated, principal, refresh, people));
  };
  const wear = event.kind === "wear";
  const isolated = event.fault
    ? `${event.fault}, magnitude ${fmtNum(event.magnitude)} × the library's nominal shift${wear ? " accumulated since the baseline" : ""}`
    : wear ? "no module deterioration fits the accumulated change" : "no fault hypothesis accepted (WSSR above the threshold for all)";
  const shift = h("div", { id: "shift", class: "plot" });
  const wssr = h("div", { id: "wssr", class: "plot" });
  const around = h("div", { id: "around", class: "plot tall" });
  const [confidence] = confidenceCard(event);
  $("#content").replaceChildren(
    h("section", { class: "card" }, h("dl", { class: "kv" },
      h("dt", {}, "Engine"), h("dd", {}, h("a", { href: `/engine.html?id=${event.engine_id}` }, event.esn), event.tail ? h("span", {}, " on ", tailLink(event.tail), ` position ${event.position}`) : ""),
      h("dt", {}, "Detected"), h("dd", {}, `${fmtTime(event.detected_at)} (record ${event.seq})`),
      h("dt", {}, "Kind"), h("dd", {}, event.kind.replace("_", " ")),
      h("dt", {}, "Isolated fault"), h("dd", { id: "isolated" }, isolated),
      h("dt", {}, "Detector statistic"), h("dd", {}, fmtNum(event.statistic, 2)),
      h("dt", {}, "Status"), h("dd", { id: "status" }, ...statusLine(event)),
      h("dt", {}, "Caused by"), causedBy(event))),
    h("div", { class: "grid" },
      h("section", { class: "card" }, h("h2", {}, wear ? "Change accumulated since the wear baseline" : "Detected shift"), shift),
      h("section", { class: "card" }, h("h2", {}, "WSSR of every fault hypothesis"), wssr)),
    confidence,
    h("section", { class: "card" }, h("h2", {}, `Health parameters ±${WINDOW_DAYS} days around the detection, against their mean over the ${BASELINE_RECORDS} records before it`), around),
    actions(event, principal, refresh, people));
  return Promise.all([shiftPlot(shift, event), wssrPlot(wssr, event), windowPlot(around, event),
    confidence.draw ? confidence.draw() : null]);
}

async function main() {
  const principal = await startPage("events");
  const id = params().get("id");
  try {
    if (id) {
      const [event, people] = await Promise.all([api(`/api/v1/events/${id}`), api("/api/v1/events/assignees")]);
      await showEvent(event, principal, people);
    }
    else await showList();
  } catch (err) {
    showError($("#message"), err, id ? `Event ${id}` : "Events");
  }
  document.body.dataset.ready = "true";
}

main();
