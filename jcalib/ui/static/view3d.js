// A small wireframe view of the cell (robot base frame, metres): frames as RGB axes, camera frustums,
// targets, planned and captured stations. Drag to orbit, wheel to zoom. Drawn on a 2-D canvas.
export class CellView {
  constructor(canvas) {
    this.canvas = canvas;
    this.scene = null;
    this.yaw = -0.9; this.pitch = 0.45; this.zoom = 1.0;
    let drag = null;
    canvas.addEventListener("mousedown", (e) => { drag = [e.clientX, e.clientY]; canvas.style.cursor = "grabbing"; });
    window.addEventListener("mouseup", () => { drag = null; canvas.style.cursor = "grab"; });
    window.addEventListener("mousemove", (e) => {
      if (!drag) return;
      this.yaw += (e.clientX - drag[0]) * 0.01;
      this.pitch = Math.max(-1.5, Math.min(1.5, this.pitch + (e.clientY - drag[1]) * 0.01));
      drag = [e.clientX, e.clientY];
      this.draw();
    });
    canvas.addEventListener("wheel", (e) => { e.preventDefault(); this.zoom *= e.deltaY > 0 ? 0.9 : 1.1; this.draw(); },
      { passive: false });
    window.addEventListener("resize", () => this.draw());
  }

  set(scene) {
    this.scene = scene;
    const pts = [];
    for (const f of scene.frames) pts.push(col(f.T, 3));
    for (const f of scene.frustums) pts.push(...f.points);
    for (const t of scene.targets) pts.push(...t.polygon);
    for (const T of [...scene.stations.planned, ...scene.stations.captured]) pts.push(col(T, 3));
    const n = pts.length || 1;
    this.center = [0, 1, 2].map((k) => pts.reduce((s, p) => s + p[k], 0) / n);
    this.radius = Math.max(0.3, ...pts.map((p) => Math.hypot(p[0] - this.center[0], p[1] - this.center[1], p[2] - this.center[2])));
    this.draw();
  }

  project(p) {
    const [cx, cy, cz] = this.center;
    let x = p[0] - cx, y = p[1] - cy, z = p[2] - cz;
    const cyw = Math.cos(this.yaw), syw = Math.sin(this.yaw);
    [x, y] = [cyw * x - syw * y, syw * x + cyw * y];
    const cp = Math.cos(this.pitch), sp = Math.sin(this.pitch);
    const depth = y * cp + z * sp;  // away from the viewer
    const up = -y * sp + z * cp;
    const d = 3.2 * this.radius;
    const s = (this.canvas.height * 0.45 * this.zoom * d) / (this.radius * (d + depth));
    return [this.canvas.width / 2 + s * x, this.canvas.height / 2 - s * up];
  }

  line(ctx, a, b) {
    const p = this.project(a), q = this.project(b);
    ctx.beginPath(); ctx.moveTo(p[0], p[1]); ctx.lineTo(q[0], q[1]); ctx.stroke();
  }

  axes(ctx, T, size, label, alpha = 1) {
    const o = col(T, 3);
    const colors = ["#d32f2f", "#2e7d32", "#1565c0"];
    for (let k = 0; k < 3; k++) {
      ctx.strokeStyle = colors[k]; ctx.globalAlpha = alpha; ctx.lineWidth = 2;
      this.line(ctx, o, o.map((v, i) => v + size * T[i][k]));
    }
    ctx.globalAlpha = 1;
    if (label) {
      const p = this.project(o);
      ctx.fillStyle = "#233"; ctx.font = "12px system-ui"; ctx.fillText(label, p[0] + 4, p[1] - 4);
    }
  }

  draw() {
    const c = this.canvas;
    c.width = c.clientWidth * devicePixelRatio; c.height = c.clientHeight * devicePixelRatio;
    const ctx = c.getContext("2d");
    ctx.clearRect(0, 0, c.width, c.height);
    if (!this.scene) return;
    ctx.lineWidth = 1;
    for (const t of this.scene.targets) {
      const pts = t.polygon.map((p) => this.project(p));
      ctx.fillStyle = t.source === "calibrated" ? "rgba(30,120,60,.25)" : "rgba(120,120,120,.2)";
      ctx.strokeStyle = "#445";
      ctx.beginPath(); pts.forEach((p, i) => (i ? ctx.lineTo(...p) : ctx.moveTo(...p))); ctx.closePath(); ctx.fill(); ctx.stroke();
    }
    for (const f of this.scene.frustums) {
      const [o, ...corners] = f.points;
      ctx.strokeStyle = f.source === "calibrated" ? "#1f5f99" : "#8a97a5";
      ctx.setLineDash(f.source === "calibrated" ? [] : [4, 3]);
      for (let k = 0; k < 4; k++) { this.line(ctx, o, corners[k]); this.line(ctx, corners[k], corners[(k + 1) % 4]); }
      ctx.setLineDash([]);
    }
    for (const T of this.scene.stations.planned) this.axes(ctx, T, 0.03, null, 0.35);
    for (const T of this.scene.stations.captured) {
      const p = this.project(col(T, 3));
      ctx.fillStyle = "#2e7d32"; ctx.beginPath(); ctx.arc(p[0], p[1], 3, 0, 7); ctx.fill();
    }
    for (const f of this.scene.frames) this.axes(ctx, f.T, f.size, f.name);
  }
}

function col(T, k) { return [T[0][k], T[1][k], T[2][k]]; }
