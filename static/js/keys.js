// API keys (admin): the operator's keys with their roles, a new key shown once, revocation.
import { api, apiKey } from "./api.js";
import { $, badge, errorBox, fmtTime, h, showError, startPage } from "./ui.js";

const API = "/api/v1/keys";

// The key this browser signed in with is the one whose prefix it starts with.
function isOwn(k) {
  const own = apiKey() || "";
  return own.startsWith(k.prefix);
}

async function loadKeys() {
  const box = $("#keys");
  try {
    const page = await api(API, { query: { limit: 200, include_revoked: $("#show-revoked").checked } });
    if (!page.items.length) { box.replaceChildren(h("p", { class: "muted" }, "No keys.")); return; }
    box.replaceChildren(h("table", { class: "data", id: "key-table" },
      h("caption", { class: "sr-only" }, `${page.total} keys of this operator`),
      h("thead", {}, h("tr", {}, ["Name", "Role", "Starts with", "Made", "Status", "Actions"].map((t) => h("th", { scope: "col" }, t)))),
      h("tbody", {}, page.items.map((k) => h("tr", { dataset: { id: k.id }, class: k.revoked_at ? "revoked" : null },
        h("td", {}, k.name, isOwn(k) ? h("span", { class: "muted" }, " (this browser's)") : null),
        h("td", {}, k.role),
        h("td", {}, h("code", {}, `${k.prefix}…`)),
        h("td", {}, fmtTime(k.created_at)),
        h("td", {}, k.revoked_at ? badge("revoked", "failed") : badge("active", "normal"),
          k.revoked_at ? h("span", { class: "muted" }, ` ${fmtTime(k.revoked_at)}`) : null),
        h("td", {}, k.revoked_at ? null : h("button", {
          type: "button", class: "revoke", "aria-label": `Revoke ${k.name}`, onclick: () => revoke(k),
        }, "Revoke")))))));
  } catch (err) {
    showError(box, err, "Keys");
  }
}

async function revoke(k) {
  const warning = isOwn(k) ? " This is the key this browser signed in with: you will be signed out." : "";
  if (!confirm(`Revoke ${k.name} (${k.role})? Requests with it are refused from now on.${warning}`)) return;
  try {
    await api(`${API}/${k.id}`, { method: "DELETE" });
    $("#message").replaceChildren(h("div", { class: "notice", role: "status" }, `${k.name} revoked.`));
  } catch (err) {
    $("#message").replaceChildren(errorBox(err, `Revoking ${k.name}`));
  }
  await loadKeys();
}

async function create(event) {
  event.preventDefault();
  const form = event.target;
  const out = $("#key-result");
  const body = { name: form.name.value.trim(), role: form.role.value };
  try {
    const made = await api(API, { method: "POST", body });
    const copy = h("button", { type: "button", id: "key-copy", onclick: async () => {
      try { await navigator.clipboard.writeText(made.key); copy.textContent = "Copied"; } catch { copy.textContent = "Select and copy it"; }
    } }, "Copy");
    out.replaceChildren(h("div", { class: "notice", role: "status", id: "new-key" },
      h("p", {}, h("strong", {}, `Key for ${made.name} (${made.role}). `),
        "Copy it now: it is not shown again, and it cannot be recovered."),
      h("p", {}, h("code", { id: "new-key-value" }, made.key), " ", copy)));
    form.reset();
  } catch (err) {
    out.replaceChildren(errorBox(err, "Key not made, nothing stored"));
  }
  await loadKeys();
}

const principal = await startPage("keys");
if (principal.role !== "admin") {
  $("#message").replaceChildren(h("div", { class: "notice", role: "status" },
    `API keys are managed by administrators; your key is ${principal.role}.`));
  $("#key-form").querySelectorAll("input, select, button").forEach((el) => { el.disabled = true; });
} else {
  $("#key-form").addEventListener("submit", create);
  $("#show-revoked").addEventListener("change", loadKeys);
  await loadKeys();
}
document.body.dataset.ready = "true";
