// Live page: each camera's stream with the detection overlay, image quality, GenICam settings, board pose.
import { api, content, el, fmt, message, wsUrl } from "./common.js";

const root = content();
window.jcalibLive = {}; // counters the tests and benchmarks read: frames and overlays drawn, rates

const SETTINGS = ["ExposureTime", "Gain", "Focus", "Zoom"];

function cameraPanel(cam) {
  const canvas = el("canvas", { id: `live-${cam.name}`, width: cam.width || 640, height: cam.height || 480 });
  const stats = el("div", { class: "stats" });
  const board = el("div", { class: "board" });
  const reason = el("div", { class: "muted" });
  const msg = el("div");
  const form = el("div", { class: "row settings" });
  for (const f of SETTINGS) {
    const feat = cam.features[f];
    if (!feat) { form.append(el("span", { class: "muted" }, `${f}: not supported`)); continue; }
    const input = el("input", { type: "number", step: "any", value: feat.value, id: `set-${cam.name}-${f}`, style: "width:110px" });
    form.append(el("label", {}, `${f} `, input, feat.unit ? ` ${feat.unit} ` : " "));
  }
  const apply = el("button", {
    onclick: async () => {
      const values = {};
      for (const f of SETTINGS) {
        const i = document.getElementById(`set-${cam.name}-${f}`);
        if (i && i.value !== "" && String(cam.features[f].value) !== i.value) values[f] = Number(i.value);
      }
      try {
        const r = await api("POST", `/api/cameras/${encodeURIComponent(cam.name)}/settings`, { settings: values });
        for (const [k, v] of Object.entries(r.features)) cam.features[k] = v;
        message(msg, Object.keys(values).length ? `set ${Object.keys(values).join(", ")}` : "nothing changed", "ok");
      } catch (e) { message(msg, e.message); }
    },
  }, "Apply");
  form.append(apply);
  const panel = el("div", { class: "panel camera" },
    el("h2", {}, `${cam.name} `, el("span", { class: "muted" }, `${cam.address} · ${cam.driver}`)),
    canvas, stats, reason, board, el("h3", {}, "Camera settings (GenICam)"), form, msg);
  start(cam, canvas, stats, reason, board);
  return panel;
}

function start(cam, canvas, stats, reason, board) {
  const ctx = canvas.getContext("2d");
  const counters = (window.jcalibLive[cam.name] = { frames: 0, overlays: 0, fps: 0, overlayRate: 0, last: null });
  let meta = null, overlay = null, bitmap = null, lastOverlaySeq = -1;
  const times = [], otimes = [];
  const rate = (arr) => (arr.length < 2 ? 0 : (arr.length - 1) / ((arr[arr.length - 1] - arr[0]) / 1000));

  function draw() {
    if (!bitmap) return;
    if (canvas.width !== bitmap.width || canvas.height !== bitmap.height) { canvas.width = bitmap.width; canvas.height = bitmap.height; }
    ctx.drawImage(bitmap, 0, 0);
    if (!overlay || !meta) return;
    const s = meta.scale || 1;
    const P = (u, v) => [(u + 0.5) * s - 0.5, (v + 0.5) * s - 0.5];
    for (const t of overlay.targets || []) {
      if (!t.found) continue;
      ctx.strokeStyle = "#00e676"; ctx.lineWidth = 2;
      ctx.beginPath();
      t.outline.forEach(([u, v], i) => { const [x, y] = P(u, v); i ? ctx.lineTo(x, y) : ctx.moveTo(x, y); });
      ctx.closePath(); ctx.stroke();
      ctx.fillStyle = "#ffeb3b"; ctx.font = `${Math.max(10, 11 * s)}px system-ui`;
      for (const [u, v, id] of t.corners) {
        const [x, y] = P(u, v);
        ctx.beginPath(); ctx.arc(x, y, 3, 0, 7); ctx.fill();
        if (t.corners.length <= 120) ctx.fillText(String(id), x + 4, y - 3);
      }
    }
  }

  function showOverlay(o) {
    const q = o.quality || {};
    stats.replaceChildren(
      el("span", {}, `frames/s ${fmt(counters.fps, 3)}`), el("span", {}, `overlays/s ${fmt(counters.overlayRate, 3)}`),
      el("span", { title: "edge width: about 1-3 px in focus" }, `sharpness (edge) ${fmt(q.edge_width_px, 3)} px`),
      el("span", {}, `contrast ${fmt(q.contrast, 2)}`),
      el("span", {}, `mean grey ${fmt(100 * (q.mean || 0), 3)} %`),
      el("span", { class: q.saturated_pct > 1 ? "warn" : "" }, `saturated ${fmt(q.saturated_pct, 2)} %`),
      el("span", { class: q.dark_pct > 20 ? "warn" : "" }, `black ${fmt(q.dark_pct, 2)} %`),
      el("span", {}, o.error ? `overlay error: ${o.error}` : ""));
    const lines = [];
    for (const t of o.targets || []) {
      if (!t.found) { lines.push(`${t.target}: not found (${t.reason}) – ${t.message}`); continue; }
      let line = `${t.target}: ${t.num_points}/${t.num_board_points} points` + (t.warnings.length ? ` (${t.warnings.join(", ")})` : "");
      if (t.pose) line += ` · distance ${fmt(1000 * t.pose.distance_m, 4)} mm · tilt ${fmt(t.pose.tilt_deg, 3)}°`;
      lines.push(line);
    }
    reason.replaceChildren(...lines.map((l) => el("div", {}, l)));
    board.textContent = (o.targets || []).some((t) => t.pose) ? "" : "board pose: needs the camera's intrinsics (cell or result) and a detected board";
  }

  function connect() {
    const ws = new WebSocket(wsUrl("/ws/live", { camera: cam.name }));
    ws.binaryType = "blob";
    ws.onmessage = async (m) => {
      if (typeof m.data === "string") {
        const msg = JSON.parse(m.data);
        if (msg.type === "frame") meta = msg;
        else if (msg.type === "overlay") {
          overlay = msg;
          if (msg.seq !== lastOverlaySeq) {
            lastOverlaySeq = msg.seq; counters.overlays++;
            otimes.push(performance.now()); if (otimes.length > 20) otimes.shift();
            counters.overlayRate = rate(otimes);
          }
          showOverlay(msg); draw();
        } else if (msg.type === "error") reason.textContent = msg.message;
        return;
      }
      bitmap = await createImageBitmap(m.data);
      counters.frames++;
      times.push(performance.now()); if (times.length > 30) times.shift();
      counters.fps = rate(times);
      counters.last = meta;
      draw();
      ws.send("ack");
    };
    ws.onclose = () => setTimeout(connect, 1000);
  }
  connect();
}

async function load() {
  const cams = await api("GET", "/api/cameras");
  if (!cams.cameras.length) {
    root.append(el("div", { class: "panel" }, cams.error || "No camera is connected: start the app with --camera NAME=gige://ADDRESS or --simulate."));
    return;
  }
  root.append(el("div", { class: "row" }, cams.cameras.map(cameraPanel)));
}
load().catch((e) => root.append(el("div", { class: "message error" }, e.message)));
