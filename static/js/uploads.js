// Uploads and jobs: upload a file with a progress bar, the upload history with row-level errors,
// and jobs with their progress (refreshed while any is queued or running).
import { api, uploadFile } from "./api.js";
import { $, badge, detailText, errorBox, fmtTime, h, params, progressBar, showError, sortableTable, startPage } from "./ui.js";

const REFRESH_MS = 2000;
let principal = null;
let timer = null;

function fileFormat(name) {
  return /\.(parquet|pq)$/i.test(name) ? "Parquet" : "CSV";
}

async function upload(e) {
  e.preventDefault();
  const file = $("#file").files[0];
  if (!file) return;
  const button = $("#upload-button");
  const bar = $("#upload-progress");
  const result = $("#upload-result");
  button.disabled = true;
  result.replaceChildren();
  bar.replaceChildren(progressBar(0, `sending ${file.name} (${fileFormat(file.name)}, ${(file.size / 1024).toFixed(1)} KiB)`, `upload of ${file.name}`));
  try {
    const out = await uploadFile("/api/v1/snapshots/file", file, {
      query: { source: "browser" },
      onProgress: (f) => bar.replaceChildren(progressBar(f, f < 1 ? `sending ${file.name}` : "sent; validating and storing…", `upload of ${file.name}`)),
    });
    bar.replaceChildren(progressBar(1, `${file.name} stored`, `upload of ${file.name}`));
    result.replaceChildren(h("div", { class: "notice", id: "upload-ok" },
      out.replayed ? h("strong", {}, `Already uploaded as upload #${out.id}: nothing new stored.`) : [
        h("strong", {}, `Upload #${out.id} stored. `),
        `${out.rows_received} rows received, ${out.rows_stored} stored, ${out.rows_duplicate} already stored. `,
        out.affected.length ? `Engines: ${out.affected.map((a) => `${a.esn} (${a.rows})`).join(", ")}; estimation queued.` : "",
        out.back_dated ? h("p", { class: "back-dated-warning" }, backDatedText(out)) : null,
        out.late ? h("p", { class: "late-warning" }, lateText(out)) : null]));
  } catch (err) {
    const refused = progressBar(1, `${file.name} refused`, `upload of ${file.name}`);
    refused.classList.add("refused");
    bar.replaceChildren(refused);
    result.replaceChildren(errorBox(err, "Upload refused, nothing stored"));
  } finally {
    button.disabled = false;
    await Promise.all([loadUploads(), loadJobs()]);
  }
}

const SOURCES = { browser: "uploads page", cli: "importer (CLI)", api: "API" };

function sourceText(u) {
  return `${SOURCES[u.source] || u.source}${u.api_key_name ? ` · key ${u.api_key_name}` : ""}`;
}

// Which engines' records reach before their last estimate: the estimation re-ran them from there.
// Late: records that arrived long after they were recorded (the service's upload lateness).
const LATE_TITLE = "records recorded longer before the upload than the upload lateness (7 days unless configured)";

function lateText(u) {
  return `Late: ${u.rows_late} of its ${u.rows_stored} new records were recorded longer before this upload arrived than the upload lateness (7 days unless configured).`;
}

function backDatedText(u) {
  const late = u.affected.filter((a) => a.estimated_until && new Date(a.earliest) < new Date(a.estimated_until));
  return `Back-dated: ${late.map((a) => `${a.esn} from ${fmtTime(a.earliest)} (estimated to ${fmtTime(a.estimated_until)})`).join("; ")}. `
    + "Its estimates and events from there are redone.";
}

async function showUpload(id) {
  const detail = $("#upload-detail");
  try {
    const u = await api(`/api/v1/uploads/${id}`);
    detail.replaceChildren(h("div", { class: "card", id: "upload-errors" }, h("h3", {}, `Upload #${u.id}: ${u.status}`),
      h("p", {}, h("strong", {}, "File: "), u.filename || "(no file name)", " · ", h("strong", {}, "Source: "), sourceText(u)),
      u.back_dated ? h("p", { class: "notice back-dated-warning" }, backDatedText(u)) : null,
      u.late ? h("p", { class: "notice late-warning" }, lateText(u)) : null,
      h("p", {}, u.message || ""),
      u.errors.length ? h("ul", {}, u.errors.map((e) => h("li", {}, detailText(e)))) : h("p", { class: "muted" }, "No errors."),
      u.affected.length ? h("p", {}, `Engines: ${u.affected.map((a) => `${a.esn}: ${a.rows} rows, ${fmtTime(a.earliest)} – ${fmtTime(a.latest)}`).join("; ")}`) : null,
      u.status === "stored" ? h("div", { id: "upload-events" }, h("h4", {}, "Events it caused"),
        u.events.length ? h("ul", {}, u.events.map((e) => h("li", {},
          h("a", { href: `/events.html?id=${e.id}` }, `#${e.id} ${e.kind === "wear" ? "wear" : (e.fault || e.kind.replace("_", " "))}`),
          ` · engine ${e.engine_id} · detected ${fmtTime(e.detected_at)} · ${e.status}`)))
          : h("p", { class: "muted" }, "None (yet: events appear once its estimation has run).")) : null));
    // The detail is drawn below a long history: bring it into view, its heading focused for
    // keyboard and screen-reader users.
    const heading = detail.querySelector("h3");
    heading.tabIndex = -1;
    heading.focus({ preventScroll: true });
    detail.scrollIntoView({ block: "start" });
  } catch (err) {
    showError(detail, err, `Upload ${id}`);
  }
}

async function loadUploads() {
  try {
    const page = await api("/api/v1/uploads", { query: { limit: 200, status: $("#upload-filter").value || undefined } });
    $("#uploads").replaceChildren(page.items.length ? sortableTable([
      { key: "id", label: "#", numeric: true, cell: (u) => h("a", { href: "#", onclick: (ev) => { ev.preventDefault(); showUpload(u.id); } }, `#${u.id}`) },
      { key: "created_at", label: "When", cell: (u) => fmtTime(u.created_at) },
      { key: "filename", label: "File", value: (u) => u.filename || "", cell: (u) => u.filename || h("span", { class: "muted" }, "—") },
      { key: "source", label: "Source", value: (u) => sourceText(u), cell: (u) => sourceText(u) },
      { key: "kind", label: "Kind" },
      { key: "content_format", label: "Format" },
      { key: "status", label: "Status", value: (u) => u.status, cell: (u) => h("span", {}, badge(u.status),
        u.back_dated ? [" ", h("span", { class: "badge watch back-dated", title: "records older than an engine's last estimate" }, "back-dated")] : null,
        u.late ? [" ", h("span", { class: "badge watch late", title: `${u.rows_late} ${LATE_TITLE}` }, "late")] : null) },
      { key: "rows_received", label: "Rows", numeric: true },
      { key: "rows_stored", label: "Stored", numeric: true },
      { key: "rows_duplicate", label: "Duplicates", numeric: true },
      { key: "bytes_received", label: "Bytes", numeric: true },
      { key: "message", label: "Message", cell: (u) => u.message || "" },
    ], page.items, { sortKey: "id", descending: true, rowClass: (u) => `upload-${u.status}${u.back_dated ? " upload-back-dated" : ""}${u.late ? " upload-late" : ""}` }) : h("p", { class: "muted" }, "No uploads yet."));
  } catch (err) {
    showError($("#uploads"), err, "Upload history");
  }
}

async function cancel(id) {
  try { await api(`/api/v1/jobs/${id}/cancel`, { method: "POST" }); } catch (err) { showError($("#message"), err, `Job ${id}`); }
  await loadJobs();
}

async function loadJobs() {
  clearTimeout(timer);
  try {
    const active = $("#job-filter").value === "active";
    const list = await api("/api/v1/jobs", { query: { limit: 50, status: active ? ["queued", "running"] : undefined } });
    const canCancel = principal.role !== "viewer";
    $("#jobs").replaceChildren(list.items.length ? sortableTable([
      { key: "id", label: "#", numeric: true },
      { key: "kind", label: "Kind" },
      { key: "status", label: "Status", cell: (j) => badge(j.status) },
      { key: "progress", label: "Progress", cell: (j) => progressBar(j.progress, j.error || j.message, `job ${j.id} ${j.kind.replaceAll("_", " ")}`) },
      { key: "created_at", label: "Queued", cell: (j) => fmtTime(j.created_at) },
      { key: "finished_at", label: "Finished", cell: (j) => (j.kind === "fleet_diagnostics" && j.status === "succeeded"
        ? h("span", {}, fmtTime(j.finished_at), " · ", h("a", { href: `/diagnostic.html?job=${j.id}` }, "report")) : fmtTime(j.finished_at)) },
      { key: "cancel", label: "", value: () => 0, cell: (j) => (canCancel && ["queued", "running"].includes(j.status)
        ? h("button", { type: "button", class: "secondary", onclick: () => cancel(j.id) }, "Cancel") : "") },
    ], list.items, { sortKey: "id", descending: true, rowClass: (j) => `job-${j.kind}` })
      : h("p", { class: "muted" }, active ? "No job is queued or running." : "No jobs yet."));
    $("#jobs-updated").textContent = `updated ${new Date().toISOString().slice(11, 19)} UTC`;
    if (list.items.some((j) => j.status === "queued" || j.status === "running")) timer = setTimeout(loadJobs, REFRESH_MS);
  } catch (err) {
    showError($("#jobs"), err, "Jobs");
  }
}

async function main() {
  principal = await startPage("uploads");
  if (principal.role === "viewer") {
    $("#upload-button").disabled = true;
    $("#upload-result").append(h("p", { class: "notice" }, "Uploading needs an analyst key."));
  }
  $("#upload").addEventListener("submit", upload);
  $("#upload-filter").addEventListener("change", loadUploads);
  $("#job-filter").addEventListener("change", loadJobs);
  await Promise.all([loadUploads(), loadJobs(), loadRecordings()]);
  // ?upload=N (linked from an event's page): open that upload's detail.
  const linked = Number(params().get("upload"));
  if (Number.isInteger(linked) && linked > 0) await showUpload(linked);
  document.body.dataset.ready = "true";
}

// Stream recordings (whole flights and live), each linked to its recording page.
async function loadRecordings() {
  const section = h("section", { class: "card", id: "recordings" }, h("h2", {}, "Stream recordings"));
  $("main").append(section);
  try {
    const page = await api("/api/v1/streams", { query: { limit: 100 } });
    section.append(page.items.length ? sortableTable([
      { key: "id", label: "#", numeric: true, cell: (r) => h("a", { href: `/recording.html?id=${r.id}` }, `#${r.id}`) },
      { key: "started_at", label: "Started", cell: (r) => fmtTime(r.started_at) },
      { key: "engine_id", label: "Engine", numeric: true },
      { key: "n_samples", label: "Samples", numeric: true },
      { key: "status", label: "Status", cell: (r) => badge(r.status) },
    ], page.items, { sortKey: "id", descending: true }) : h("p", { class: "muted" }, "No stream recordings yet."));
  } catch (err) {
    showError(section, err, "Stream recordings");
  }
}

main();
