// The fleet diagnostic job's report (?job=N): which engines changed state since the previous
// run (from -> to, with links to the engines) and which alerts (events) were raised.
import { api } from "./api.js";
import { $, badge, fmtNum, fmtTime, h, params, showError, sortableTable, startPage, tailLink } from "./ui.js";
import { layout, plot } from "./plots.js";

const STATES = ["no_data", "normal", "watch", "alert"];
const STATE_COLOURS = { no_data: "#8a97a6", normal: "#009E73", watch: "#E69F00", alert: "#D55E00" };
const stateBadge = (s) => (s ? badge(s) : h("span", { class: "muted" }, "none (first report)"));

// One bar per transition (from -> to), coloured by the state reached: how many engines moved.
async function drawTransitions(changes) {
  const counts = new Map();
  for (const c of changes) {
    const key = `${(c.from_state || "first report").replace("_", " ")} → ${c.to_state.replace("_", " ")}`;
    counts.set(key, { n: (counts.get(key)?.n || 0) + 1, to: c.to_state });
  }
  const rows = [...counts.entries()].sort((a, b) => STATES.indexOf(a[1].to) - STATES.indexOf(b[1].to));
  const height = Math.max(200, 80 + 30 * rows.length);
  $("#changes-plot").style.minHeight = `${height}px`;
  await plot($("#changes-plot"), [{
    type: "bar", orientation: "h", name: "engines", y: rows.map(([k]) => k), x: rows.map(([, v]) => v.n),
    marker: { color: rows.map(([, v]) => STATE_COLOURS[v.to]) }, hovertemplate: "%{x} engines<extra>%{y}</extra>",
  }], layout({
    height, showlegend: false, hovermode: "closest",
    xaxis: { title: { text: "Engines" }, dtick: 1, rangemode: "tozero" }, yaxis: { type: "category", automargin: true },
  }));
}

async function main() {
  await startPage(null);
  const id = Number(params().get("job"));
  if (!Number.isInteger(id) || id <= 0) {
    showError($("#message"), new Error("Give the diagnostic job as ?job=N (from the schedules page or the jobs list)."), "Report");
    document.body.dataset.ready = "true";
    return;
  }
  try {
    const job = await api(`/api/v1/jobs/${id}`);
    document.title = `Fleet diagnostic report of job ${id} · fleethealth`;
    $("#title").textContent = `Fleet diagnostic report · job #${id}`;
    const r = job.result;
    if (job.kind !== "fleet_diagnostics" || !r || !r.state_changes) {
      $("#message").replaceChildren(h("p", { class: "notice" }, job.kind !== "fleet_diagnostics"
        ? `Job #${id} is a ${job.kind.replaceAll("_", " ")} job, not a fleet diagnostic.`
        : `Job #${id} is ${job.status}${job.error ? `: ${job.error}` : ""}; it has no report${job.status === "succeeded" ? " (it ran before reports existed)" : " yet"}.`));
      document.body.dataset.ready = "true";
      return;
    }
    $("#period").replaceChildren(r.since
      ? h("span", {}, `Since the previous run (`, h("a", { href: `/diagnostic.html?job=${r.baseline_job_id}` }, `job #${r.baseline_job_id}`), `, ${fmtTime(r.since)}) up to ${fmtTime(r.as_of)}.`)
      : h("span", {}, `First report: every engine's state at ${fmtTime(r.as_of)}, and every alert stored so far.`));
    $("#summary").replaceChildren(
      h("div", { class: "card" }, h("div", { class: "muted" }, "Engines estimated"), h("div", { class: "big" }, r.n_engines)),
      h("div", { class: "card" }, h("div", { class: "muted" }, "Changed state"), h("div", { class: "big", id: "n-changes" }, r.state_changes.length)),
      h("div", { class: "card" }, h("div", { class: "muted" }, "Alerts raised"), h("div", { class: "big", id: "n-events" }, r.n_events_raised)),
      h("div", { class: "card" }, h("div", { class: "muted" }, "Active events now"), h("a", { class: "big", href: "/events.html?status=active" }, r.n_open_events)));
    $("#content").hidden = false;
    if (r.state_changes.length) await drawTransitions(r.state_changes);
    else $("#changes-plot").hidden = true;
    $("#changes").replaceChildren(r.state_changes.length ? sortableTable([
      { key: "esn", label: "ESN", cell: (c) => h("a", { href: `/engine.html?id=${c.engine_id}` }, c.esn) },
      { key: "tail", label: "Tail", value: (c) => c.tail || "", cell: (c) => (c.tail ? h("span", {}, tailLink(c.tail), ` #${c.position}`) : h("span", { class: "muted" }, "not installed")) },
      { key: "from_state", label: "From", value: (c) => STATES.indexOf(c.from_state), cell: (c) => stateBadge(c.from_state) },
      { key: "to_state", label: "To", value: (c) => STATES.indexOf(c.to_state), cell: (c) => stateBadge(c.to_state) },
      { key: "reason", label: "Why now", value: (c) => c.reason || "", cell: (c) => c.reason || h("span", { class: "muted" }, "within limits") },
    ], r.state_changes, { sortKey: "to_state", descending: true, rowClass: (c) => `change state-${c.to_state}` })
      : h("p", { class: "muted" }, "No engine changed state."));
    $("#events").replaceChildren(...(r.events_raised.length ? [sortableTable([
      { key: "event_id", label: "Event", numeric: true, cell: (e) => h("a", { href: `/events.html?id=${e.event_id}` }, `#${e.event_id}`) },
      { key: "esn", label: "ESN", cell: (e) => h("a", { href: `/engine.html?id=${e.engine_id}` }, e.esn) },
      { key: "kind", label: "What", value: (e) => e.fault || e.kind, cell: (e) => (e.kind === "wear" ? "wear" : (e.fault || e.kind.replace("_", " "))) },
      { key: "magnitude", label: "Magnitude", numeric: true, cell: (e) => fmtNum(e.magnitude) },
      { key: "detected_at", label: "Detected (record time)", cell: (e) => fmtTime(e.detected_at) },
      { key: "status", label: "Status at the report", cell: (e) => badge(e.status) },
    ], r.events_raised, { sortKey: "detected_at", descending: true, rowClass: () => "raised" }),
    r.n_events_raised > r.events_raised.length ? h("p", { class: "muted" }, `The newest ${r.events_raised.length} of ${r.n_events_raised}.`) : ""]
      : [h("p", { class: "muted" }, "No alert was raised.")]));
  } catch (err) {
    showError($("#message"), err, `Job ${id}`);
  }
  document.body.dataset.ready = "true";
}

main();
