// Shared by every page: the API client (token in a header), the event stream, the header (job, control, STOP).
export const TOKEN = document.querySelector('meta[name="jcalib-token"]').content;
export const CLIENT = (() => {
  let id = sessionStorage.getItem("jcalib-client");
  if (!id) {
    id = Array.from(crypto.getRandomValues(new Uint8Array(12)), (b) => b.toString(16).padStart(2, "0")).join("");
    sessionStorage.setItem("jcalib-client", id);
  }
  return id;
})();

// el("div", {class: "x", onclick: f}, child, "text", ...)
export function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (v === undefined || v === null || v === false) continue;
    if (k.startsWith("on")) node.addEventListener(k.slice(2), v);
    else if (k === "html") node.innerHTML = v;
    else node.setAttribute(k, v === true ? "" : v);
  }
  for (const c of children.flat()) {
    if (c === null || c === undefined || c === false) continue;
    node.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return node;
}

export const content = () => document.getElementById("content");

export class ApiError extends Error {
  constructor(status, message) { super(message); this.status = status; }
}

// JSON API call; state-changing calls carry the token and this browser's id in headers.
export async function api(method, path, body) {
  const headers = { "X-Jcalib-Token": TOKEN, "X-Jcalib-Client": CLIENT };
  const opts = { method, headers };
  if (body !== undefined) { headers["Content-Type"] = "application/json"; opts.body = JSON.stringify(body); }
  const r = await fetch(path, opts);
  const type = r.headers.get("content-type") || "";
  const data = type.includes("application/json") ? await r.json() : await r.text();
  if (!r.ok) throw new ApiError(r.status, (data && data.error) || (typeof data === "string" ? data : r.statusText));
  return data;
}

export function fmt(x, digits = 4) {
  if (x === null || x === undefined || Number.isNaN(x)) return "–";
  if (typeof x !== "number") return String(x);
  const a = Math.abs(x);
  if (a !== 0 && (a >= 1e5 || a < 1e-3)) return x.toExponential(2);
  return x.toPrecision(digits).replace(/\.?0+$/, (m) => (m.startsWith(".") ? "" : m));
}

export function message(node, text, kind = "error") {
  node.replaceChildren(text ? el("div", { class: `message ${kind}` }, text) : "");
}

export function banner(text, kind = "") {
  const b = document.getElementById("banner");
  b.hidden = !text;
  b.className = `banner ${kind}`;
  b.textContent = text || "";
}

// --- event stream: one websocket per page, reconnecting ------------------------------------------------
const listeners = {};
export function on(type, fn) { (listeners[type] ||= []).push(fn); }
function dispatch(ev) { for (const fn of listeners[ev.type] || []) fn(ev); for (const fn of listeners["*"] || []) fn(ev); }

let socket = null;
export function wsUrl(path, params = {}) {
  const q = new URLSearchParams({ token: TOKEN, client: CLIENT, ...params });
  return `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}${path}?${q}`;
}
function connect() {
  socket = new WebSocket(wsUrl("/ws/events"));
  socket.onmessage = (m) => dispatch(JSON.parse(m.data));
  socket.onclose = () => setTimeout(connect, 1000);
  socket.onerror = () => {};
}

// --- header: job, control, STOP ------------------------------------------------------------------------
export const state = { control: { you: false, holder: null }, job: null };

function showJob(job) {
  const node = document.getElementById("job");
  if (!job) { node.textContent = ""; return; }
  const pct = job.progress === null || job.progress === undefined ? "" : ` ${Math.round(100 * job.progress)} %`;
  const msg = job.status === "running" ? `${job.title}:${pct} ${job.message || ""}`
    : `${job.title}: ${job.status}${job.error ? " – " + job.error.split("\n")[0] : ""} (${job.elapsed_s.toFixed(1)} s)`;
  node.textContent = msg;
  node.title = job.error || msg;
}

function showControl(c) {
  state.control = c;
  const node = document.getElementById("control");
  node.replaceChildren();
  if (c.you) node.append("you control the cell", el("button", { onclick: releaseControl }, "release"));
  else if (c.holder) node.append("read-only: another browser controls the cell");
  else node.append("nobody controls the cell", el("button", { onclick: takeControl }, "take control"));
  document.body.classList.toggle("readonly", !c.you && !!c.holder);
  for (const fn of listeners["control"] || []) fn(c);
}

export async function takeControl() {
  try { showControl(await api("POST", "/api/control/claim")); } catch (e) { banner(e.message, "error"); }
}
async function releaseControl() {
  try { showControl(await api("POST", "/api/control/release")); } catch (e) { banner(e.message, "error"); }
}

export async function refreshState() {
  const s = await api("GET", "/api/state");
  showControl(s.control);
  state.job = s.jobs.current;
  showJob(s.jobs.current);
  return s;
}

document.getElementById("stop").addEventListener("click", async () => {
  try {
    const r = await api("POST", "/api/stop");
    banner(r.message, "error");
  } catch (e) { banner(`STOP: ${e.message}`, "error"); }
});

on("job", (ev) => { state.job = ev.job; showJob(ev.job); });
on("control", (ev) => api("GET", "/api/control").then(showControl).catch(() => {}));
on("stopped", (ev) => banner(ev.message, "error"));
connect();
refreshState().catch((e) => banner(e.message, "error"));

// Resolves when the given job id ends (done, failed or stopped).
export function waitJob(id) {
  return new Promise((resolve) => {
    const check = (ev) => { if (ev.job.id === id && ev.job.status !== "running") resolve(ev.job); };
    on("job", check);
  });
}

// Start a job through `path` and wait for it; errors of the request itself are thrown.
export async function runJob(path, body) {
  const r = await api("POST", path, body);
  if (!r.job) return r;
  if (state.job && state.job.id === r.job.id && state.job.status !== "running") return state.job;
  return waitJob(r.job.id);
}

export function table(columns, rows, opts = {}) {
  // columns: [{key, label, num, fmt}], rows: [{...}]; opts.onRow(row, tr), opts.sort (key)
  let sortKey = opts.sort || null, desc = !!opts.desc;
  const t = el("table");
  const body = el("tbody");
  const head = el("tr");
  const render = () => {
    const sorted = sortKey ? [...rows].sort((a, b) => {
      const x = a[sortKey], y = b[sortKey];
      const c = typeof x === "number" && typeof y === "number" ? x - y : String(x).localeCompare(String(y));
      return desc ? -c : c;
    }) : rows;
    body.replaceChildren(...sorted.map((r) => {
      const tr = el("tr", {}, columns.map((c) => el("td", { class: c.num ? "num" : "" },
        c.render ? c.render(r) : c.fmt ? c.fmt(r[c.key], r) : (r[c.key] ?? ""))));
      if (opts.onRow) opts.onRow(r, tr);
      return tr;
    }));
  };
  for (const c of columns) {
    const th = el("th", { class: (c.num ? "num " : "") + (c.sortable === false ? "" : "sortable") }, c.label);
    if (c.sortable !== false) th.addEventListener("click", () => { desc = sortKey === c.key ? !desc : !!c.num; sortKey = c.key; render(); });
    head.append(th);
  }
  t.append(el("thead", {}, head), body);
  render();
  t.rerender = render;
  return t;
}
