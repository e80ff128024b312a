// The REST API as the dashboard calls it: every request sends the API key kept for this
// browser (every tab and window of it, until signed out); a 401 sends the user back to sign-in;
// error bodies become ApiError.

export const KEY = "fleethealth.apiKey";
const ME = "fleethealth.me";

export function apiKey() { return localStorage.getItem(KEY); }

// Back to sign-in (with ``reason`` shown there), coming back to this page afterwards.
export function toSignIn(reason) {
  const next = encodeURIComponent(location.pathname + location.search);
  const why = reason ? `&reason=${encodeURIComponent(reason)}` : "";
  location.assign(`/signin.html?next=${next}${why}`);
}

// Forget the key in this browser: every other open tab sees the storage event and follows.
export function signOut(reason) {
  localStorage.removeItem(KEY);
  localStorage.removeItem(ME);
  toSignIn(reason);
}

export class ApiError extends Error {
  constructor(status, code, message, details) {
    super(message);
    this.status = status;
    this.code = code;
    this.details = details || [];
  }
}

// The {"error": {"code", "message", "details"}} body of a failed response as an ApiError.
export function errorFromBody(status, text) {
  let body = null;
  try { body = JSON.parse(text); } catch { /* not JSON: a proxy or the network */ }
  const err = body && body.error;
  if (err) return new ApiError(status, err.code, err.message, err.details);
  return new ApiError(status, "http_" + status, `HTTP ${status}: ${(text || "").slice(0, 200) || "no response body"}`);
}

export function url(path, query) {
  const u = new URL(path, location.origin);
  for (const [k, v] of Object.entries(query || {})) {
    if (v === undefined || v === null || v === "") continue;
    if (Array.isArray(v)) v.forEach((x) => u.searchParams.append(k, x));
    else u.searchParams.set(k, v);
  }
  return u.pathname + u.search;
}

async function request(path, { method = "GET", query, body, key, accept = "application/json" } = {}) {
  const headers = { "X-API-Key": key || apiKey() || "", Accept: accept };
  const init = { method, headers };
  if (body !== undefined) {
    headers["Content-Type"] = "application/json";
    init.body = JSON.stringify(body);
  }
  let response;
  try {
    response = await fetch(url(path, query), init);
  } catch (e) {
    throw new ApiError(0, "network", `The service did not answer (${e.message}).`);
  }
  if (response.status === 401 && !key) {
    signOut("Your API key was not accepted; sign in again.");
    throw new ApiError(401, "unauthorized", "signed out");
  }
  if (!response.ok) throw errorFromBody(response.status, await response.text());
  return response;
}

export async function api(path, options) {
  const response = await request(path, options);
  return response.status === 204 ? null : response.json();
}

// Every item of a paged list (``{items, total, limit, offset}``), a page of up to 1,000 at a time.
export async function apiAll(path, options = {}) {
  const items = [];
  for (;;) {
    const page = await api(path, { ...options, query: { ...(options.query || {}), limit: 1000, offset: items.length } });
    items.push(...page.items);
    if (!page.items.length || items.length >= page.total) return items;
  }
}

export async function apiText(path, options) {
  const response = await request(path, { ...options, accept: "text/csv" });
  return response.text();
}

// Check a key with GET /api/v1/me without the 401 redirect; the principal or an ApiError.
export async function checkKey(key) {
  return (await request("/api/v1/me", { key })).json();
}

export function rememberKey(key, me) {
  localStorage.setItem(ME, JSON.stringify(me));
  localStorage.setItem(KEY, key);
}

export async function me() {
  const cached = localStorage.getItem(ME);
  if (cached) return JSON.parse(cached);
  const principal = await api("/api/v1/me");
  localStorage.setItem(ME, JSON.stringify(principal));
  return principal;
}

// POST a file with upload progress (fetch reports none): onProgress(fraction).
export function uploadFile(path, file, { query, onProgress } = {}) {
  return new Promise((resolve, reject) => {
    const xhr = new XMLHttpRequest();
    xhr.open("POST", url(path, query));
    xhr.setRequestHeader("X-API-Key", apiKey() || "");
    xhr.setRequestHeader("Accept", "application/json");
    xhr.upload.onprogress = (e) => { if (e.lengthComputable && onProgress) onProgress(e.loaded / e.total); };
    xhr.onload = () => {
      if (xhr.status === 401) { signOut("Your API key was not accepted; sign in again."); return; }
      if (xhr.status >= 200 && xhr.status < 300) resolve(JSON.parse(xhr.responseText));
      else reject(errorFromBody(xhr.status, xhr.responseText));
    };
    xhr.onerror = () => reject(new ApiError(0, "network", "The upload did not reach the service."));
    const form = new FormData();
    form.append("file", file, file.name);
    xhr.send(form);
  });
}

// A file the API makes (a report) saved in the browser's downloads: requested with the key as
// every request is, named as the API's Content-Disposition names it (else ``filename``).
export async function apiDownload(path, { query, accept, filename } = {}) {
  const response = await request(path, { query, accept });
  const named = /filename="([^"]+)"/.exec(response.headers.get("Content-Disposition") || "");
  saveBlob(await response.blob(), named ? named[1] : filename);
}

// Save text as a file in the browser's downloads.
export function download(text, filename, type = "text/csv") {
  saveBlob(new Blob([text], { type }), filename);
}

export function saveBlob(blob, filename) {
  const link = document.createElement("a");
  link.href = URL.createObjectURL(blob);
  link.download = filename;
  document.body.append(link);
  link.click();
  setTimeout(() => { URL.revokeObjectURL(link.href); link.remove(); }, 0);
}
