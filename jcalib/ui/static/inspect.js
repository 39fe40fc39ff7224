// Calibrate & inspect page: calibrate in the app's process (warm after the first solve), every unknown with σ,
// warnings, goals, robot accuracy, views sortable by RMS with their residual vectors, exclude / include and
// re-solve, the comparison with the previous result, the full report.
import { api, content, el, fmt, message, on, runJob, table } from "./common.js";

const root = content();
const msg = el("div");
const summary = el("div", { id: "summary" });
const warnings = el("div", { id: "warnings" });
const goalsBox = el("div", { id: "goals" });
const unknowns = el("div", { id: "unknowns" });
const views = el("div", { id: "views" });
const viewer = el("div", { id: "viewer" });
const compareBox = el("div", { id: "compare" });
let selected = null;
let scale = 50;

root.append(
  el("div", { class: "panel" },
    el("div", { class: "row" },
      el("button", { class: "primary", id: "calibrate-button", onclick: calibrate }, "Calibrate"),
      el("a", { href: "/report", target: "_blank", id: "report-link" }, "Full HTML report")),
    msg, summary),
  el("div", { class: "row" },
    el("div", { class: "col panel" }, el("h2", {}, "Warnings"), warnings, el("h2", {}, "Goals"), goalsBox),
    el("div", { class: "col panel" }, el("h2", {}, "Compared with the previous result"), compareBox)),
  el("div", { class: "panel" }, el("h2", {}, "Unknowns"), unknowns),
  el("div", { class: "row" },
    el("div", { class: "col panel" }, el("h2", {}, "Views (click a row; sort by a column)"), views),
    el("div", { class: "col panel" }, el("h2", {}, "Residuals of the selected view"),
      el("label", {}, "arrow scale ", el("input", { type: "range", min: 5, max: 400, value: scale, id: "scale",
        oninput: (e) => { scale = Number(e.target.value); if (selected) showView(selected); } })), viewer)));

async function calibrate() {
  message(msg, "");
  try {
    const job = await runJob("/api/calibrate", {});
    if (job.status !== "done") { message(msg, job.error); return; }
    message(msg, job.result.summary, "ok");
    await load();
  } catch (e) { message(msg, e.message); }
}

async function setExcluded(station, camera, excluded) {
  try {
    const job = await runJob("/api/exclusions", { station, camera, excluded });
    if (job.status !== "done") { message(msg, job.error); return; }
    message(msg, job.result.summary, "ok");
    await load();
  } catch (e) { message(msg, e.message); }
}

function kv(pairs) { return el("div", { class: "kv" }, pairs.flatMap(([k, v]) => [el("span", { class: "muted" }, k), el("span", {}, v)])); }

async function load() {
  const r = await api("GET", "/api/result");
  if (!r.available) { summary.replaceChildren(el("p", { class: "muted" }, r.message)); return; }
  const s = r.stats;
  summary.replaceChildren(kv([
    ["reprojection RMS", `${fmt(s.rms_px, 4)} px per point (RMS of per-point error norms, as OpenCV prints)`],
    ["a-posteriori σ", `${fmt(s.sigma_px, 4)} px per coordinate`],
    ["solver", `${s.status}, ${s.iterations} iterations, ${s.num_residuals} residuals, ${s.outliers} outliers rejected`],
    ["views used", `${r.views.filter((v) => !v.excluded).length} of ${r.views.length}` + (r.excluded.length ? ` (excluded: ${r.excluded.join(", ")})` : "")],
    ["solve time", `${fmt(r.solve_s, 3)} s (in this process; warm after the first solve)`],
    ["robot accuracy", r.robot || "–"],
    ["result", r.path],
  ]));
  warnings.replaceChildren(r.warnings.length ? el("ol", {}, r.warnings.map((w) => el("li", {}, w))) : el("p", { class: "ok" }, "none"));
  goalsBox.replaceChildren(r.goals.length ? table([{ key: "goal", label: "goal" }, { key: "achieved", label: "achieved σ", num: true, fmt: (v) => fmt(v, 3) },
    { key: "limit", label: "limit", num: true }, { key: "met", label: "", render: (g) => el("span", { class: `badge ${g.met ? "ok" : "bad"}` }, g.met ? "met" : "not met") }],
  r.goals) : el("p", { class: "muted" }, "The cell names no goals."));
  unknowns.replaceChildren(
    ...r.cameras.map((c) => el("div", {}, el("h3", {}, `${c.name}: ${c.model}, ${c.image_size[0]}x${c.image_size[1]} px`),
      table([{ key: "name", label: "parameter" }, { key: "value", label: "value", num: true, fmt: (v) => fmt(v, 7) },
        { key: "std", label: "σ", num: true, fmt: (v, p) => (p.fixed ? "fixed" : fmt(v, 3)) }, { key: "unit", label: "unit" }], c.params))),
    r.transforms.length ? el("div", {}, el("h3", {}, "Transforms (T_a_b: frame b in frame a; σ over the right-perturbation tangent, in frame b)"),
      table([{ key: "name", label: "transform" }, { key: "t", label: "translation mm", render: (t) => t.t_mm.map((v) => fmt(v, 6)).join(", ") },
        { key: "st", label: "σ t mm", render: (t) => (t.std_t_mm || []).map((v) => fmt(v, 3)).join(", ") },
        { key: "r", label: "rotation vector deg", render: (t) => t.r_deg.map((v) => fmt(v, 6)).join(", ") },
        { key: "sr", label: "σ r deg", render: (t) => (t.std_r_deg || []).map((v) => fmt(v, 3)).join(", ") },
        { key: "note", label: "" }], r.transforms)) : "");
  const cols = [{ key: "camera", label: "camera" }, { key: "station", label: "station" },
    { key: "rms_px", label: "RMS px", num: true, fmt: (v) => fmt(v, 3) }, { key: "points", label: "points", num: true },
    { key: "outliers", label: "outliers", num: true },
    { key: "act", label: "", sortable: false, render: (v) => el("span", {},
      el("button", { class: "exclude-view", onclick: (e) => { e.stopPropagation(); setExcluded(v.station, v.camera, !v.excluded); } },
        v.excluded ? "include view" : "exclude view"), " ",
      el("button", { class: "exclude-station", onclick: (e) => { e.stopPropagation(); setExcluded(v.station, null, !v.station_excluded); } },
        v.station_excluded ? "include station" : "exclude station")) }];
  const t = table(cols, r.views, {
    sort: "rms_px", desc: true,
    onRow: (v, tr) => {
      tr.dataset.view = `${v.station}/${v.camera}`;
      if (v.excluded) tr.classList.add("excluded");
      if (selected && selected.station === v.station && selected.camera === v.camera) tr.classList.add("selected");
      tr.addEventListener("click", () => {
        selected = v; t.rerender();
        if (v.excluded) viewer.replaceChildren(el("p", { class: "muted" }, "This view is excluded: include it to see its residuals."));
        else showView(v);
      });
    },
  });
  t.id = "views-table";
  views.replaceChildren(el("div", { class: "scroll" }, t));
  compareBox.replaceChildren(r.compare ? compareTable(r.compare) : el("p", { class: "muted" }, "No previous result yet."));
  if (selected) {
    selected = r.views.find((v) => v.station === selected.station && v.camera === selected.camera) || null;
    if (selected && !selected.excluded) showView(selected);
    else viewer.replaceChildren(el("p", { class: "muted" }, "The selected view is excluded: include it to see its residuals."));
  }
}

function compareTable(c) {
  const rows = [];
  for (const [cam, v] of Object.entries(c.cameras || {})) rows.push({ what: `${cam} projection difference`, value: `RMS ${fmt(v.rms_px, 3)} px, max ${fmt(v.max_px, 3)} px`, verdict: v.verdict });
  for (const t of c.transforms || []) rows.push({ what: t.name, value: `${fmt(t.translation_mm, 3)} mm, ${fmt(t.rotation_deg, 3)} deg`, verdict: t.verdict });
  return el("div", {}, el("p", { class: "muted" }, c.note), table([{ key: "what", label: "" }, { key: "value", label: "change (B − A)" }, { key: "verdict", label: "" }], rows));
}

async function showView(v) {
  try {
    const d = await api("GET", `/api/result/view/${encodeURIComponent(v.station)}/${encodeURIComponent(v.camera)}`);
    const [w, h] = d.image_size;
    const img = el("img", { src: `/api/session/image/${encodeURIComponent(v.station)}/${encodeURIComponent(v.camera)}`, alt: `${v.station} ${v.camera}` });
    const maxr = Math.max(1e-9, ...d.points.map((p) => Math.hypot(p.r[0], p.r[1])));
    const color = (r) => { const x = Math.min(1, r / Math.max(3 * (d.sigma_px || maxr), 1e-9)); return `rgb(${Math.round(255 * x)},${Math.round(200 * (1 - x))},60)`; };
    const parts = d.points.map((p) => {
      const [u, v2] = p.px; const [ru, rv] = p.r;
      if (!p.inlier) return `<g stroke="#ff1744" stroke-width="2"><line x1="${u - 6}" y1="${v2 - 6}" x2="${u + 6}" y2="${v2 + 6}"/><line x1="${u - 6}" y1="${v2 + 6}" x2="${u + 6}" y2="${v2 - 6}"/></g>`;
      return `<line x1="${u}" y1="${v2}" x2="${u + scale * ru}" y2="${v2 + scale * rv}" stroke="${color(Math.hypot(ru, rv))}" stroke-width="1.6"/><circle cx="${u}" cy="${v2}" r="1.5" fill="#fff"/>`;
    });
    const svg = `<svg viewBox="-0.5 -0.5 ${w} ${h}" preserveAspectRatio="none">${parts.join("")}</svg>`;
    viewer.replaceChildren(el("p", {}, `${v.station} / ${v.camera}: RMS ${fmt(d.rms_px, 3)} px, ${d.points.length} points, ${d.points.filter((p) => !p.inlier).length} outliers (red X); arrows: observed − predicted × ${scale}`),
      el("div", { class: "viewer", id: "residual-view" }, img, el("div", { html: svg })));
  } catch (e) { viewer.replaceChildren(el("div", { class: "message error" }, e.message)); }
}

on("job", (ev) => { if (ev.job.kind === "calibrate" && ev.job.status === "done") load(); });
on("report", () => load());
load().catch((e) => message(msg, e.message));
