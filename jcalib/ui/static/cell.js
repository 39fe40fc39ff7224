// Cell page: the cell spec (edit, validate with the CLI's messages, save, upload) and the 3-D view.
import { api, content, el, message, on } from "./common.js";
import { CellView } from "./view3d.js";

const root = content();
const status = el("div");
const editor = el("textarea", { class: "code", spellcheck: "false", id: "cell-text" });
const summary = el("div", { class: "muted" });
const upload = el("input", { type: "file", accept: ".yaml,.yml,.json", hidden: true });
const canvas = el("canvas", { class: "scene", id: "scene" });
const view = new CellView(canvas);
const legend = el("div", { class: "legend" },
  el("span", {}, "frames: x red, y green, z blue"), el("span", {}, "solid blue frustum: calibrated; dashed: nominal"),
  el("span", {}, "faint axes: planned stations; green dots: captured"));

root.append(el("div", { class: "row" },
  el("div", { class: "col panel" },
    el("h2", {}, "Cell spec ", el("span", { class: "muted", id: "cell-path" })),
    summary, editor,
    el("div", { class: "row" },
      el("button", { onclick: validate, id: "validate" }, "Validate"),
      el("button", { class: "primary", onclick: save, id: "save" }, "Save"),
      el("button", { onclick: () => upload.click() }, "Upload a file…"), upload),
    status),
  el("div", { class: "col panel" }, el("h2", {}, "The cell in 3-D ", el("span", { class: "muted", id: "scene-source" })),
    canvas, legend)));

upload.addEventListener("change", async () => {
  const f = upload.files[0];
  if (!f) return;
  editor.value = await f.text();
  validate();
});

function describe(s) {
  if (!s) return "";
  const parts = [];
  for (const [k, v] of Object.entries(s)) if (v.length) parts.push(`${k}: ${v.join(", ")}`);
  return parts.join(" · ");
}

async function load() {
  const c = await api("GET", "/api/cell");
  editor.value = c.text;
  document.getElementById("cell-path").textContent = c.path;
  summary.textContent = describe(c.summary);
  if (c.error) message(status, c.error);
  await loadScene();
}

async function loadScene() {
  try {
    const s = await api("GET", "/api/cell/scene");
    document.getElementById("scene-source").textContent = s.source;
    view.set(s);
  } catch (e) { document.getElementById("scene-source").textContent = `(${e.message})`; }
}

async function validate() {
  try {
    const r = await api("POST", "/api/cell/validate", { text: editor.value });
    summary.textContent = describe(r.summary);
    message(status, "valid: " + describe(r.summary), "ok");
  } catch (e) { message(status, e.message); }
}

async function save() {
  try {
    const r = await api("PUT", "/api/cell", { text: editor.value });
    summary.textContent = describe(r.summary);
    message(status, `saved ${r.path}`, "ok");
    await loadScene();
  } catch (e) { message(status, e.message); }
}

on("job", (ev) => { if (ev.job.status === "done" && ["plan", "capture", "calibrate"].includes(ev.job.kind)) loadScene(); });
load().catch((e) => message(status, e.message));
