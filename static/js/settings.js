// Notification settings (admin): webhook and e-mail channels, a test message, the delivery
// log with every attempt (time, HTTP status or error, duration).
import { api } from "./api.js";
import { $, badge, errorBox, fmtTime, h, showError, startPage } from "./ui.js";

const API = "/api/v1/notifications";
const REFRESH_MS = 2000;
let timer = null;

function channelTarget(c) {
  if (c.kind === "webhook") return c.url;
  const login = c.username ? ` as ${c.username}` : "";
  return `${c.smtp_host}:${c.smtp_port}${c.starttls ? " (STARTTLS)" : ""}${login} · ${c.mail_from} → ${(c.mail_to || []).join(", ")}`;
}

async function loadChannels() {
  const box = $("#channels");
  try {
    const rows = await api(`${API}/channels`);
    if (!rows.length) { box.replaceChildren(h("p", { class: "muted" }, "No channels yet.")); return; }
    box.replaceChildren(h("table", { class: "data", id: "channel-table" },
      h("thead", {}, h("tr", {}, ["Name", "Kind", "Target", "Enabled", "Actions"].map((t) => h("th", { scope: "col" }, t)))),
      h("tbody", {}, rows.map((c) => h("tr", { dataset: { id: c.id } },
        h("td", {}, c.name), h("td", {}, c.kind), h("td", {}, channelTarget(c)),
        h("td", {}, c.enabled ? "yes" : "no"),
        h("td", {},
          h("button", { type: "button", class: "test", "aria-label": `Send a test message to ${c.name}`, onclick: () => sendTest(c) }, "Send test"), " ",
          h("button", { type: "button", class: "toggle", onclick: () => toggle(c) }, c.enabled ? "Disable" : "Enable"), " ",
          h("button", { type: "button", class: "delete", "aria-label": `Delete ${c.name}`, onclick: () => remove(c) }, "Delete")))))));
  } catch (err) {
    showError(box, err, "Channels");
  }
}

async function sendTest(c) {
  try {
    const out = await api(`${API}/channels/${c.id}/test`, { method: "POST" });
    $("#message").replaceChildren(h("div", { class: "notice", role: "status" }, `Test message #${out.delivery_id} to ${c.name} queued.`));
    await loadDeliveries();
  } catch (err) {
    $("#message").replaceChildren(errorBox(err, `Test of ${c.name}`));
  }
}

async function toggle(c) {
  try {
    await api(`${API}/channels/${c.id}`, { method: "PATCH", body: { enabled: !c.enabled } });
  } catch (err) {
    $("#message").replaceChildren(errorBox(err, c.name));
  }
  await loadChannels();
}

async function remove(c) {
  if (!confirm(`Delete ${c.name} and its delivery log?`)) return;
  try {
    await api(`${API}/channels/${c.id}`, { method: "DELETE" });
  } catch (err) {
    $("#message").replaceChildren(errorBox(err, c.name));
  }
  await Promise.all([loadChannels(), loadDeliveries()]);
}

// One attempt: its time (to the second), the answer's status (HTTP for a webhook, SMTP for
// e-mail) or the error, and how long it took.
function attemptText(a, kind) {
  const when = new Date(a.attempted_at).toISOString().slice(0, 19).replace("T", " ") + " UTC";
  const code = a.status_code !== null ? `${kind === "email" ? "SMTP" : "HTTP"} ${a.status_code}` : null;
  const what = a.ok ? code : (a.error || code || "failed");
  return `${when} · ${a.ok ? "ok" : "failed"} · ${what} · ${a.duration_ms.toFixed(0)} ms`;
}

async function loadDeliveries() {
  const box = $("#deliveries");
  clearTimeout(timer);
  try {
    const [page, channels] = await Promise.all([api(`${API}/deliveries`, { query: { limit: 50 } }), api(`${API}/channels`)]);
    const byId = Object.fromEntries(channels.map((c) => [c.id, c]));
    if (!page.items.length) { box.replaceChildren(h("p", { class: "muted" }, "Nothing sent yet.")); return; }
    box.replaceChildren(h("table", { class: "data", id: "delivery-table" },
      h("thead", {}, h("tr", {}, ["#", "Subject", "Channel", "Status", "Attempts"].map((t) => h("th", { scope: "col" }, t)))),
      h("tbody", {}, page.items.map((d) => h("tr", { class: `delivery-${d.status}`, dataset: { id: d.id } },
        h("td", {}, d.id), h("td", {}, d.subject), h("td", {}, byId[d.channel_id]?.name ?? `#${d.channel_id}`),
        h("td", {}, badge(d.status, d.status === "sent" ? "succeeded" : d.status),
          d.status === "pending" && d.attempts ? ` next try ${fmtTime(d.next_attempt_at)}` : ""),
        h("td", {}, d.log.length ? h("ol", { class: "attempts" }, d.log.map((a) => h("li", {}, attemptText(a, byId[d.channel_id]?.kind)))) : "–"))))));
    if (page.items.some((d) => d.status === "pending")) timer = setTimeout(loadDeliveries, REFRESH_MS);
  } catch (err) {
    showError(box, err, "Delivery log");
  }
}

async function addWebhook(e) {
  e.preventDefault();
  const result = $("#webhook-result");
  try {
    const out = await api(`${API}/channels`, { method: "POST", body: { kind: "webhook", name: $("#webhook-name").value, url: $("#webhook-url").value } });
    result.replaceChildren(h("div", { class: "notice", id: "webhook-secret" },
      h("strong", {}, `Webhook ${out.name} added. `), "Its signing secret, shown only now: ",
      h("code", {}, out.secret),
      h("p", {}, "Each POST carries X-Fleethealth-Timestamp and X-Fleethealth-Signature: sha256= the HMAC-SHA256 of \"timestamp.body\" under this secret; refuse old timestamps.")));
    e.target.reset();
  } catch (err) {
    result.replaceChildren(errorBox(err, "Webhook refused, nothing stored"));
  }
  await loadChannels();
}

async function addEmail(e) {
  e.preventDefault();
  const result = $("#email-result");
  const optional = (id) => $(id).value.trim() || null;
  const body = {
    kind: "email", name: $("#email-name").value, smtp_host: $("#email-host").value,
    smtp_port: Number($("#email-port").value), starttls: $("#email-starttls").checked,
    username: optional("#email-username"), password: optional("#email-password"),
    mail_from: $("#email-from").value, mail_to: $("#email-to").value.split(",").map((s) => s.trim()).filter(Boolean),
  };
  try {
    const out = await api(`${API}/channels`, { method: "POST", body });
    result.replaceChildren(h("div", { class: "notice", id: "email-ok" }, `E-mail channel ${out.name} added.`));
    e.target.reset();
  } catch (err) {
    result.replaceChildren(errorBox(err, "E-mail channel refused, nothing stored"));
  }
  await loadChannels();
}

const principal = await startPage("settings");
if (principal.role !== "admin") {
  $("main").replaceChildren(h("h1", {}, "Notifications"),
    h("p", { class: "error", role: "alert" }, "Only administrators see and change the notification settings."));
} else {
  $("#webhook-form").addEventListener("submit", addWebhook);
  $("#email-form").addEventListener("submit", addEmail);
  $("#log-refresh").addEventListener("click", loadDeliveries);
  await Promise.all([loadChannels(), loadDeliveries()]);
}
document.body.dataset.ready = "true";
