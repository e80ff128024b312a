// Page shell (sign-in check, nav bar), small DOM helpers, formatting and error display.
import { ApiError, KEY, apiKey, me, signOut, toSignIn } from "./api.js";

const PAGES = [
  ["fleet", "/", "Fleet status"],
  ["aircraft", "/aircraft.html", "Aircraft"],
  ["engine", "/engine.html", "Engine trend"],
  ["events", "/events.html", "Events"],
  ["designs", "/designs.html", "Estimator designs"],
  ["uploads", "/uploads.html", "Uploads and jobs"],
  ["schedules", "/schedules.html", "Schedules"],
  ["settings", "/settings.html", "Notifications"],
  ["keys", "/keys.html", "API keys"],
  ["glossary", "/glossary.html", "Glossary"],
];

export function h(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (v === undefined || v === null || v === false) continue;
    if (k.startsWith("on")) node.addEventListener(k.slice(2), v);
    else if (k === "class") node.className = v;
    else if (k === "dataset") Object.assign(node.dataset, v);
    else node.setAttribute(k, v === true ? "" : v);
  }
  for (const c of children.flat()) {
    if (c === undefined || c === null || c === false) continue;
    node.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return node;
}

export const $ = (sel, root = document) => root.querySelector(sel);

// Every page: without a key go to sign-in; else draw the nav bar and return the principal.
export async function startPage(active) {
  if (!apiKey()) { signOut(); return new Promise(() => {}); }
  followSignInElsewhere();
  const principal = await me();
  const nav = h("nav", { class: "topnav", "aria-label": "main" },
    h("a", { class: "brand", href: "/" }, "fleethealth"),
    h("ul", {}, PAGES.map(([id, href, label]) =>
      h("li", {}, h("a", { href, class: id === active ? "active" : null, "aria-current": id === active ? "page" : null }, label)))),
    h("span", { class: "who" }, `${principal.operator} · ${principal.role}`),
    h("button", { class: "link", type: "button", onclick: () => signOut() }, "Sign out"));
  document.body.prepend(nav);
  return principal;
}

// A tail number as a link to its aircraft page.
export function tailLink(tail, text) {
  return h("a", { href: `/aircraft.html?tail=${encodeURIComponent(tail)}`, class: "tail" }, text ?? tail);
}

// Another tab signed out (the key is gone): this one leaves too. Another tab signed in with
// another key (another operator or role): this page reloads with it.
function followSignInElsewhere() {
  window.addEventListener("storage", (e) => {
    if (e.key !== KEY && e.key !== null) return;
    if (!apiKey()) toSignIn("You signed out in another tab.");
    else if (e.key === KEY && e.newValue !== e.oldValue) location.reload();
  });
}

export function params() { return new URLSearchParams(location.search); }

// An error as people read it: the API's message and every row/column/reason detail.
export function errorBox(err, context) {
  const box = h("div", { class: "error", role: "alert" });
  const title = context ? `${context}: ` : "";
  if (err instanceof ApiError) {
    box.append(h("strong", {}, `${title}${err.message}`));
    if (err.status) box.append(h("span", { class: "code" }, ` (${err.status} ${err.code})`));
    if (err.details && err.details.length) {
      box.append(h("ul", {}, err.details.slice(0, 50).map((d) => h("li", {}, detailText(d)))));
      if (err.details.length > 50) box.append(h("p", {}, `… and ${err.details.length - 50} more`));
    }
  } else {
    box.append(h("strong", {}, `${title}${err && err.message ? err.message : err}`));
  }
  return box;
}

export function detailText(d) {
  if (typeof d !== "object" || d === null) return String(d);
  const where = [];
  if (d.row !== undefined && d.row !== null) where.push(`row ${d.row}`);
  if (d.column) where.push(`column ${d.column}`);
  if (d.location) where.push(Array.isArray(d.location) ? d.location.join(".") : d.location);
  return `${where.length ? where.join(", ") + ": " : ""}${d.reason || d.message || JSON.stringify(d)}`;
}

export function showError(container, err, context) {
  container.replaceChildren(errorBox(err, context));
}

export function fmtTime(iso) {
  if (!iso) return "–";
  const d = new Date(iso);
  return d.toISOString().slice(0, 16).replace("T", " ") + " UTC";
}

// How far ``iso`` is from ``now`` (ISO times; ``now`` from the service), in the largest unit
// that reads well: "40 min ago", "5 h ago", "12 d ago", or "in 3 h" for a time ahead.
export function fmtAgo(iso, now) {
  if (!iso) return "never";
  const ms = Date.parse(now || new Date().toISOString()) - Date.parse(iso);
  const span = Math.abs(ms);
  const text = span < 3600e3 ? `${Math.round(span / 60e3)} min` : span < 2 * 86400e3 ? `${Math.round(span / 3600e3)} h` : `${Math.round(span / 86400e3)} d`;
  return ms >= 0 ? `${text} ago` : `in ${text}`;
}

export function fmtNum(x, digits = 2) {
  if (x === null || x === undefined || Number.isNaN(x)) return "–";
  return Number(x).toFixed(digits);
}

export function badge(text, kind) { return h("span", { class: `badge ${kind || text}` }, text.replace("_", " ")); }

// ``name``: what is progressing ("job 12 evaluate_design"), the bar's accessible name.
export function progressBar(fraction, label, name) {
  const pct = Math.round(100 * Math.max(0, Math.min(1, fraction || 0)));
  return h("div", { class: "progress", role: "progressbar", "aria-valuemin": 0, "aria-valuemax": 100, "aria-valuenow": pct,
    "aria-label": name || label || "progress", "aria-valuetext": label ? `${pct} %, ${label}` : `${pct} %` },
    h("div", { class: "bar", style: `width:${pct}%` }),
    h("span", {}, label ? `${pct} % · ${label}` : `${pct} %`));
}

// A sortable table: columns [{key, label, value(row) -> sortable, cell(row) -> node|text}].
export function sortableTable(columns, rows, { sortKey, descending = false, rowClass } = {}) {
  let key = sortKey || columns[0].key;
  let desc = descending;
  const table = h("table", { class: "data sortable" });
  const thead = h("thead");
  const tbody = h("tbody");
  table.append(thead, tbody);
  const col = (k) => columns.find((c) => c.key === k);
  function draw() {
    thead.replaceChildren(h("tr", {}, columns.map((c) => h("th", {
      scope: "col", "aria-sort": c.key === key ? (desc ? "descending" : "ascending") : "none",
      dataset: { key: c.key }, tabindex: 0,
      onclick: () => { desc = c.key === key ? !desc : false; key = c.key; draw(); },
      onkeydown: (e) => { if (e.key === "Enter") e.target.click(); },
    }, c.label, c.key === key ? (desc ? " ▼" : " ▲") : ""))));
    const value = col(key).value || ((r) => r[key]);
    const sorted = [...rows].sort((a, b) => {
      const x = value(a), y = value(b);
      if (x === y) return 0;
      if (x === null || x === undefined) return 1;
      if (y === null || y === undefined) return -1;
      return (x < y ? -1 : 1) * (desc ? -1 : 1);
    });
    tbody.replaceChildren(...sorted.map((r) => h("tr", { class: rowClass ? rowClass(r) : null },
      columns.map((c) => h("td", { class: c.numeric ? "num" : null }, c.cell ? c.cell(r) : (c.value || ((x) => x[c.key]))(r) ?? "–")))));
  }
  draw();
  return table;
}
