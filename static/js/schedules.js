// Job schedules (admin): list with the next run (UTC) and the last run's job with its progress,
// add (kind, cron expression or interval, design), enable or disable, delete, and "Run now".
// A fleet diagnostic's finished job links to its report (/diagnostic.html?job=N).
import { api } from "./api.js";
import { $, badge, errorBox, fmtAgo, fmtTime, h, progressBar, showError, sortableTable, startPage } from "./ui.js";

const API = "/api/v1/schedules";
const REFRESH_MS = 2000;
let kinds = [];
let designs = new Map();
let timer = null;

const kindOf = (name) => kinds.find((k) => k.name === name);
const needsDesign = (name) => Boolean(kindOf(name)?.parameters_schema?.properties?.design_id);

function timing(s) {
  if (s.cron) return h("span", {}, h("code", { class: "cron" }, s.cron), h("span", { class: "muted" }, " UTC"));
  const hours = s.interval_seconds / 3600;
  return `every ${hours >= 1 ? `${+hours.toFixed(2)} h` : `${Math.round(s.interval_seconds / 60)} min`}`;
}

function parametersText(s) {
  const { design_id: designId, ...rest } = s.parameters;
  const parts = [];
  if (designId !== undefined) parts.push(h("a", { href: "/designs.html" }, designs.get(designId)?.name || `design #${designId}`));
  if (Object.keys(rest).length) parts.push(h("code", {}, JSON.stringify(rest)));
  return parts.length ? h("span", {}, parts.flatMap((p, i) => (i ? [" ", p] : [p]))) : h("span", { class: "muted" }, "defaults");
}

function lastJob(s) {
  const j = s.last_job;
  if (!j) return h("span", { class: "muted" }, "not run yet");
  const report = s.kind === "fleet_diagnostics" && j.status === "succeeded"
    ? [" ", h("a", { href: `/diagnostic.html?job=${j.id}`, class: "report" }, "Read the report")] : null;
  return h("div", { class: "last-job", dataset: { job: j.id } },
    h("span", {}, `job #${j.id} `, badge(j.status), ` ${fmtTime(j.finished_at || j.created_at)}`, report),
    progressBar(j.progress, j.message, `job ${j.id} of schedule ${s.id}`));
}

async function act(s, what, request) {
  try {
    const out = await request();
    if (what === "run") $("#message").replaceChildren(h("div", { class: "notice", role: "status" }, `Schedule #${s.id}: job #${out.id} ${out.status}.`));
  } catch (err) {
    $("#message").replaceChildren(errorBox(err, `Schedule #${s.id}`));
  }
  await loadSchedules();
}

async function loadSchedules() {
  clearTimeout(timer);
  const box = $("#schedules");
  try {
    const rows = await api(API);
    const now = new Date().toISOString();
    box.replaceChildren(rows.length ? sortableTable([
      { key: "id", label: "#", numeric: true },
      { key: "kind", label: "Job", cell: (s) => s.kind.replaceAll("_", " ") },
      { key: "parameters", label: "Design and parameters", value: (s) => JSON.stringify(s.parameters), cell: parametersText },
      { key: "timing", label: "When", value: (s) => s.cron || s.interval_seconds, cell: timing },
      { key: "next_run_at", label: "Next run (UTC)", cell: (s) => (s.enabled
        ? h("span", { class: "next-run" }, fmtTime(s.next_run_at), h("span", { class: "muted" }, ` · ${fmtAgo(s.next_run_at, now)}`))
        : h("span", { class: "muted" }, "disabled")) },
      { key: "last_job", label: "Last run", value: (s) => s.last_job?.id ?? null, cell: lastJob },
      { key: "actions", label: "", value: () => 0, cell: (s) => h("span", { class: "actions" },
        h("button", { type: "button", class: "run", "aria-label": `Run schedule ${s.id} now`, onclick: () => act(s, "run", () => api(`${API}/${s.id}/run`, { method: "POST" })) }, "Run now"), " ",
        h("button", { type: "button", class: "secondary toggle", "aria-label": `${s.enabled ? "Disable" : "Enable"} schedule ${s.id}`,
          onclick: () => act(s, "toggle", () => api(`${API}/${s.id}`, { method: "PATCH", body: { enabled: !s.enabled } })) }, s.enabled ? "Disable" : "Enable"), " ",
        h("button", { type: "button", class: "secondary delete", "aria-label": `Delete schedule ${s.id}`,
          onclick: () => (confirm(`Delete schedule #${s.id}? The jobs it submitted stay.`) ? act(s, "delete", () => api(`${API}/${s.id}`, { method: "DELETE" })) : null) }, "Delete")) },
    ], rows, { sortKey: "id", rowClass: (s) => `schedule schedule-${s.id}${s.enabled ? "" : " disabled"}` })
      : h("p", { class: "muted" }, "No schedules yet."));
    $("#updated").textContent = `updated ${now.slice(11, 19)} UTC`;
    if (rows.some((s) => s.last_job && ["queued", "running"].includes(s.last_job.status))) timer = setTimeout(loadSchedules, REFRESH_MS);
  } catch (err) {
    showError(box, err, "Schedules");
  }
}

function drawTiming() {
  const cron = $("#timing-cron").checked;
  $("#cron").disabled = !cron;
  $("#cron").required = cron;
  $("#interval-hours").disabled = cron;
}

function drawKind() {
  const kind = kindOf($("#kind").value);
  $("#kind-description").textContent = kind ? kind.description : "";
  $("#design-field").hidden = !needsDesign($("#kind").value);
  $("#design").required = needsDesign($("#kind").value);
}

async function create(ev) {
  ev.preventDefault();
  const result = $("#create-result");
  let parameters;
  try {
    parameters = JSON.parse($("#parameters").value || "{}");
    if (typeof parameters !== "object" || parameters === null || Array.isArray(parameters)) throw new Error("not an object");
  } catch (err) {
    result.replaceChildren(h("div", { class: "error", role: "alert" }, `Parameters: give a JSON object (${err.message}).`));
    return;
  }
  const kind = $("#kind").value;
  if (needsDesign(kind)) parameters.design_id = Number($("#design").value);
  const body = { kind, parameters, enabled: $("#enabled").checked };
  if ($("#timing-cron").checked) body.cron = $("#cron").value;
  else body.interval_seconds = Math.round(Number($("#interval-hours").value) * 3600);
  try {
    const out = await api(API, { method: "POST", body });
    result.replaceChildren(h("div", { class: "notice", role: "status", id: "created" },
      `Schedule #${out.id} added: ${kind.replaceAll("_", " ")}, next run ${fmtTime(out.next_run_at)}.`));
  } catch (err) {
    result.replaceChildren(errorBox(err, "Schedule not added, nothing stored"));
  }
  await loadSchedules();
}

async function main() {
  const principal = await startPage("schedules");
  if (principal.role !== "admin") {
    $("main").replaceChildren(h("h1", {}, "Schedules"),
      h("p", { class: "error", role: "alert" }, "Only administrators see and change job schedules."));
    document.body.dataset.ready = "true";
    return;
  }
  try {
    const [allKinds, page] = await Promise.all([api("/api/v1/jobs/kinds"), api("/api/v1/designs", { query: { limit: 200 } })]);
    kinds = allKinds.filter((k) => k.submittable);
    designs = new Map(page.items.map((d) => [d.id, d]));
    $("#kind").replaceChildren(...kinds.map((k) => h("option", { value: k.name, selected: k.name === "fleet_diagnostics" }, k.name.replaceAll("_", " "))));
    $("#design").replaceChildren(...page.items.filter((d) => d.status === "ready").map((d) => h("option", { value: d.id }, `${d.name} (#${d.id}${d.active ? ", active" : ""})`)));
  } catch (err) {
    showError($("#message"), err, "Job kinds and designs");
  }
  drawKind();
  drawTiming();
  $("#kind").addEventListener("change", drawKind);
  for (const id of ["timing-cron", "timing-interval"]) $(`#${id}`).addEventListener("change", drawTiming);
  $("#schedule-form").addEventListener("submit", create);
  await loadSchedules();
  document.body.dataset.ready = "true";
}

main();
