// Export page: every `jcalib export` format, with the same refusals, as a download.
import { TOKEN, CLIENT, api, content, el, message } from "./common.js";

const root = content();
const msg = el("div");
const fmtSel = el("select", { id: "export-format" });
const options = el("div", { class: "row", id: "export-options" });
let formats = {};

root.append(el("div", { class: "panel" },
  el("p", { class: "muted" }, "Exports of the latest result, exactly as `jcalib export` writes them."),
  el("div", { class: "row" }, el("label", {}, "format ", fmtSel), options,
    el("button", { class: "primary", id: "export-button", onclick: download }, "Download")),
  msg));

function showOptions() {
  const f = formats[fmtSel.value];
  options.replaceChildren(...(f ? f.options : []).map((o) => el("label", {}, `${o.name} `,
    o.choices ? el("select", { id: `opt-${o.name}` }, el("option", { value: "" }, "(default)"), o.choices.map((c) => el("option", { value: c }, c)))
      : el("input", { id: `opt-${o.name}`, placeholder: o.placeholder || "" }))));
}

async function download() {
  message(msg, "");
  const body = { format: fmtSel.value, options: {} };
  for (const o of formats[fmtSel.value].options) {
    const v = document.getElementById(`opt-${o.name}`).value.trim();
    if (v) body.options[o.name] = o.list ? v.split(/\s*;\s*/) : v;
  }
  const r = await fetch("/api/export", { method: "POST", headers: { "X-Jcalib-Token": TOKEN, "X-Jcalib-Client": CLIENT, "Content-Type": "application/json" }, body: JSON.stringify(body) });
  if (!r.ok) { const e = await r.json().catch(() => ({ error: r.statusText })); message(msg, e.error); return; }
  const name = (r.headers.get("content-disposition") || "").match(/filename="([^"]+)"/)?.[1] || "export.txt";
  const blob = await r.blob();
  const a = el("a", { href: URL.createObjectURL(blob), download: name });
  document.body.append(a); a.click(); a.remove();
  message(msg, `downloaded ${name}`, "ok");
}

async function load() {
  const r = await api("GET", "/api/export/formats");
  formats = Object.fromEntries(r.formats.map((f) => [f.name, f]));
  fmtSel.replaceChildren(...r.formats.map((f) => el("option", { value: f.name }, `${f.name} – ${f.description}`)));
  fmtSel.addEventListener("change", showOptions);
  showOptions();
  if (!r.result) message(msg, "No result yet: calibrate first (Calibrate & inspect).");
}
load().catch((e) => message(msg, e.message));
