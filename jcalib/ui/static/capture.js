// Plan & capture page: plan stations, confirm, capture with pause / resume / abort (STOP in the header),
// station thumbnails with detections, goal progress of an adaptive capture, coverage per camera.
import { api, banner, content, el, fmt, message, on, runJob, table } from "./common.js";

const root = content();
const planMsg = el("div"), captureMsg = el("div");
const planBox = el("div", { id: "plan" });
const bar = el("div"), progressText = el("span", { class: "muted" });
const thumbs = el("div", { class: "thumbs", id: "thumbs" });
const chart = el("div", { id: "goal-chart" });
const coverageBox = el("div", { class: "row", id: "coverage" });
let cell = { cameras: [], targets: [], tools: [], goals: [] };

const kind = el("select", { id: "plan-kind" }, ["handeye", "viewsets", "tcp", "kinematics", "optimal"].map((k) => el("option", { value: k }, k)));
const stations = el("input", { type: "number", id: "plan-stations", min: 1, max: 500, value: 8, style: "width:80px" });
const seed = el("input", { type: "number", id: "plan-seed", value: 0, style: "width:70px" });
const goals = el("textarea", { id: "goals", rows: 3, style: "width:100%", placeholder: "T_flange_cam0:translation_mm<=0.5 (one goal per line)" });
const which = { camera: el("select", { id: "plan-camera" }), target: el("select", { id: "plan-target" }), tool: el("select", { id: "plan-tool" }) };

root.append(
  el("div", { class: "row" },
    el("div", { class: "col panel" },
      el("h2", {}, "1. Plan"),
      el("div", { class: "row" },
        el("label", {}, "kind ", kind), el("label", {}, "stations ", stations),
        el("label", {}, "camera ", which.camera), el("label", {}, "target ", which.target), el("label", {}, "tool ", which.tool),
        el("label", {}, "seed ", seed)),
      el("h3", {}, "Goals (optimal plans and capture toward goals)"), goals,
      el("div", { class: "row" }, el("button", { class: "primary", id: "plan-button", onclick: plan }, "Plan")),
      planMsg, planBox),
    el("div", { class: "col panel" },
      el("h2", {}, "2. Capture"),
      el("p", { class: "muted" }, "Motion starts only after you confirm the plan. Dry-run new plans at reduced speed first. ",
        "STOP (top right) halts the robot at once; the session can be resumed."),
      el("div", { class: "row" },
        el("button", { class: "primary", id: "capture-button", onclick: () => confirmCapture("plan") }, "Capture the plan…"),
        el("button", { id: "adaptive-button", onclick: () => confirmCapture("goals") }, "Capture toward the goals…"),
        el("button", { id: "pause-button", onclick: () => control("pause") }, "Pause"),
        el("button", { id: "resume-button", onclick: () => control("resume") }, "Resume"),
        el("button", { id: "abort-button", onclick: () => control("abort") }, "Abort")),
      el("div", { class: "progress", style: "margin:8px 0" }, bar), progressText, captureMsg,
      el("h3", {}, "Goals after each station (achieved σ, predicted σ, limit)"), chart)),
  el("div", { class: "panel" }, el("h2", {}, "Stations"), thumbs),
  el("div", { class: "panel" }, el("h2", {}, "Coverage"),
    el("p", { class: "muted" }, "Where corners have landed in each image (brighter: more), and the spread of board tilts and distances."),
    coverageBox));

function fillSelect(sel, names) { sel.replaceChildren(el("option", { value: "" }, "(default)"), ...names.map((n) => el("option", { value: n }, n))); }

async function loadCell() {
  const c = await api("GET", "/api/cell");
  cell = c.summary || cell;
  fillSelect(which.camera, cell.cameras || []); fillSelect(which.target, cell.targets || []); fillSelect(which.tool, cell.tools || []);
  if (!goals.value && c.goals && c.goals.length) goals.value = c.goals.join("\n");
}

function goalList() { return goals.value.split("\n").map((g) => g.trim()).filter(Boolean); }

async function plan() {
  message(planMsg, "");
  const body = { kind: kind.value, seed: Number(seed.value) };
  if (kind.value === "optimal") { body.goals = goalList(); body.max_stations = Number(stations.value); }
  else body.stations = Number(stations.value);
  for (const [k, sel] of Object.entries(which)) if (sel.value) body[k] = sel.value;
  try {
    const job = await runJob("/api/plan", body);
    if (job.status !== "done") { message(planMsg, job.error); return; }
    await loadPlan();
  } catch (e) { message(planMsg, e.message); }
}

async function loadPlan() {
  const p = await api("GET", "/api/plan");
  planBox.replaceChildren();
  if (!p.stations) { planBox.append(el("p", { class: "muted" }, p.message || "No plan yet.")); return p; }
  const mm = (v) => v.toFixed(1);
  const cols = [{ key: "id", label: "station" }, { key: "x", label: "x mm", num: true, fmt: mm },
    { key: "y", label: "y mm", num: true, fmt: mm }, { key: "z", label: "z mm", num: true, fmt: mm },
    { key: "status", label: "status" }];
  for (const g of p.goals || []) cols.push({ key: g, label: `predicted ${g}`, num: true, fmt: (v) => fmt(v, 3) });
  planBox.append(el("p", {}, `${p.kind} plan: ${p.stations.length} stations`, p.dropped ? ` (${p.dropped} candidates dropped: unreachable or not in view)` : "",
      p.verdict ? ` · ${p.verdict}` : ""),
    el("div", { class: "scroll" }, table(cols, p.stations)));
  return p;
}

function confirmCapture(mode) {
  api("GET", "/api/plan").then((p) => {
    const n = mode === "plan" ? (p.stations ? p.stations.length : 0) : null;
    if (mode === "plan" && !n) { message(captureMsg, "Plan stations first (1. Plan)."); return; }
    const mm = (v) => v.toFixed(1);
    const list = mode === "plan" ? el("div", { class: "scroll", style: "max-height:240px" }, table(
      [{ key: "id", label: "station" }, { key: "x", label: "x mm", num: true, fmt: mm },
        { key: "y", label: "y mm", num: true, fmt: mm }, { key: "z", label: "z mm", num: true, fmt: mm }],
      p.stations)) : el("p", {}, "Goals: ", goalList().join(", ") || "(the cell's goals)");
    const box = el("div", { class: "modal", id: "confirm" }, el("div", { class: "box" },
      el("h2", {}, mode === "plan" ? `Move the robot through ${n} stations?` : "Move the robot toward the goals?"),
      el("p", {}, "The robot will move on its own. Make sure the cell is clear and nobody is inside."),
      el("p", { class: "warn" }, "Dry-run a new plan at reduced speed first (override 10 % or less on the pendant)."),
      list,
      el("div", { class: "row", style: "margin-top:10px" },
        el("button", { class: "primary", id: "confirm-button", onclick: async () => { box.remove(); await capture(mode); } }, "Confirm: start the robot"),
        el("button", { onclick: () => box.remove() }, "Cancel"))));
    document.body.append(box);
  }).catch((e) => message(captureMsg, e.message));
}

async function capture(mode) {
  message(captureMsg, "");
  banner("");
  const body = { confirm: true, mode };
  if (mode === "goals") { body.goals = goalList(); body.max_stations = Number(stations.value) || 20; }
  try {
    const job = await runJob("/api/capture/start", body);
    if (job.status === "done") message(captureMsg, job.result && job.result.summary, "ok");
    else message(captureMsg, job.error);
    await Promise.all([loadSession(), loadPlan()]);
  } catch (e) { message(captureMsg, e.message); }
}

async function control(what) {
  try { const r = await api("POST", `/api/capture/${what}`); message(captureMsg, r.message, "ok"); } catch (e) { message(captureMsg, e.message); }
}

function showProgress(done, total, text) {
  bar.style.width = total ? `${(100 * done) / total}%` : "0";
  progressText.textContent = text;
}

async function loadSession() {
  const s = await api("GET", "/api/session");
  thumbs.replaceChildren();
  for (const st of s.stations) {
    const views = Object.entries(st.views || {});
    const items = views.length ? views.map(([cam, v]) => el("div", { class: "thumb" },
      el("img", { src: `/api/session/thumb/${encodeURIComponent(st.id)}/${encodeURIComponent(cam)}?v=${v.version}`, alt: `${st.id} ${cam}` }),
      `${cam}: ${v.summary}`)) : [el("div", { class: "thumb muted" }, st.status)];
    thumbs.append(el("div", { class: "panel", style: "padding:6px" }, el("b", {}, st.id), " ", el("span", { class: "muted" }, st.status), el("div", { class: "thumbs" }, items)));
  }
  showProgress(s.done, s.planned || s.done, s.capture ? `${s.capture.state}: ${s.done} of ${s.planned || "?"} stations` : `${s.done} stations in the session`);
  coverageBox.replaceChildren();
  for (const c of s.coverage || []) {
    coverageBox.append(el("div", { class: "panel" },
      el("h3", {}, `${c.camera}: ${fmt(c.covered_pct, 3)} % of the image covered, ${c.views} views`),
      el("img", { src: `/api/coverage/${encodeURIComponent(c.camera)}.png?v=${s.version}`, alt: `coverage ${c.camera}`, width: 320 }),
      histogram("tilt (deg)", c.tilts_deg, 0, 60), histogram("distance (mm)", c.distances_m.map((d) => 1000 * d))));
  }
}

function histogram(label, values, lo, hi) {
  if (!values.length) return el("div", { class: "muted" }, `${label}: –`);
  lo = lo ?? Math.min(...values); hi = hi ?? Math.max(...values);
  if (hi <= lo) hi = lo + 1;
  const bins = new Array(10).fill(0);
  for (const v of values) bins[Math.min(9, Math.max(0, Math.floor(((v - lo) / (hi - lo)) * 10)))]++;
  const m = Math.max(...bins);
  const svg = `<svg width="200" height="40">${bins.map((b, i) => `<rect x="${i * 20}" y="${40 - (36 * b) / m}" width="18" height="${(36 * b) / m}" fill="#1f5f99"/>`).join("")}</svg>`;
  return el("div", {}, el("div", { class: "muted" }, `${label}: ${fmt(lo, 3)} … ${fmt(hi, 3)}`), el("div", { html: svg }));
}

function drawChart(history) {
  if (!history || !history.steps.length) { chart.replaceChildren(el("span", { class: "muted" }, "(an adaptive capture shows its goals here)")); return; }
  const W = 460, H = 200, pad = 36;
  const n = history.steps.map((s) => s.num_stations);
  const xs = (v) => pad + ((v - Math.min(...n)) / Math.max(1, Math.max(...n) - Math.min(...n))) * (W - 2 * pad);
  const parts = [];
  const colors = ["#1f5f99", "#c2185b", "#2e7d32", "#ef6c00", "#6a1b9a"];
  history.goals.forEach((g, k) => {
    const ratio = (s, key) => s[key][g.text] / g.limit;
    const vals = history.steps.flatMap((s) => [ratio(s, "achieved"), ratio(s, "predicted")]).concat([1]);
    const top = Math.max(...vals) * 1.1;
    const ys = (v) => H - pad + 10 - (v / top) * (H - 2 * pad);
    const path = (key) => history.steps.map((s, i) => `${i ? "L" : "M"}${xs(s.num_stations)},${ys(ratio(s, key))}`).join(" ");
    parts.push(`<path d="${path("achieved")}" stroke="${colors[k % 5]}" fill="none" stroke-width="2"/>`);
    parts.push(`<path d="${path("predicted")}" stroke="${colors[k % 5]}" fill="none" stroke-dasharray="4 3"/>`);
    if (k === 0) parts.push(`<line x1="${pad}" x2="${W - pad}" y1="${ys(1)}" y2="${ys(1)}" stroke="#b3261e" stroke-dasharray="6 3"/>`,
      `<text x="${W - pad}" y="${ys(1) - 3}" font-size="11" text-anchor="end" fill="#b3261e">limit</text>`);
  });
  const legend = history.goals.map((g, k) => `<tspan fill="${colors[k % 5]}">${g.text}  </tspan>`).join("");
  chart.innerHTML = `<svg width="${W}" height="${H + 30}">${parts.join("")}<text x="${pad}" y="${H + 20}" font-size="11">${legend}</text>` +
    `<text x="4" y="12" font-size="11">σ / limit (solid: achieved, dashed: predicted), by stations captured</text></svg>`;
}

on("capture", (ev) => { showProgress(ev.done, ev.total, `${ev.state}: ${ev.done} of ${ev.total} · ${ev.station || ""} ${ev.event}`); });
let sessionTimer = null;
on("session", () => {  // at most one refresh per second while stations arrive
  if (sessionTimer) return;
  sessionTimer = setTimeout(() => { sessionTimer = null; loadSession().then(loadPlan).catch(() => {}); }, 1000);
});
on("adaptive", (ev) => drawChart(ev.history));
on("job", (ev) => { if (ev.job.kind === "plan" && ev.job.status === "done") loadPlan(); });

async function init() {
  await loadCell();
  await loadPlan();
  await loadSession();
  const a = await api("GET", "/api/capture");
  drawChart(a.history);
}
init().catch((e) => message(captureMsg, e.message));
