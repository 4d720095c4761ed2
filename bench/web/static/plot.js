// bench web station: a small canvas plotter. Every plot of a run shares one time axis (zoom with
// the wheel, pan by dragging, double-click to see everything again); each plot asks the server for
// its column over the visible range at its pixel width (per-pixel min/max: never the whole stream).
"use strict";

const COLOURS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#8c564b", "#e377c2"];
const MARGIN = { left: 64, right: 12, top: 20, bottom: 26 };

function niceTicks(lo, hi, n) {
  if (!(hi > lo)) { return [lo]; }
  const raw = (hi - lo) / Math.max(1, n);
  const mag = Math.pow(10, Math.floor(Math.log10(raw)));
  const step = [1, 2, 5, 10].map((m) => m * mag).find((s) => s >= raw) || 10 * mag;
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) { out.push(Math.abs(v) < step * 1e-9 ? 0 : v); }
  return out;
}

function fmtTick(v) {
  const a = Math.abs(v);
  if (a !== 0 && (a >= 1e5 || a < 1e-3)) { return v.toExponential(1); }
  return String(Number(v.toPrecision(6)));
}

function setupCanvas(canvas, cssWidth, cssHeight) {
  const ratio = window.devicePixelRatio || 1;
  canvas.style.width = cssWidth + "px";
  canvas.style.height = cssHeight + "px";
  canvas.width = Math.round(cssWidth * ratio);
  canvas.height = Math.round(cssHeight * ratio);
  const ctx = canvas.getContext("2d");
  ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
  return ctx;
}

function drawAxes(ctx, w, h, xr, yr, xlabel, ylabel) {
  const pw = w - MARGIN.left - MARGIN.right, ph = h - MARGIN.top - MARGIN.bottom;
  ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, w, h);
  ctx.strokeStyle = "#ccc"; ctx.lineWidth = 1; ctx.font = "11px sans-serif"; ctx.fillStyle = "#333";
  const X = (v) => MARGIN.left + (v - xr[0]) / (xr[1] - xr[0] || 1) * pw;
  const Y = (v) => MARGIN.top + ph - (v - yr[0]) / (yr[1] - yr[0] || 1) * ph;
  ctx.textAlign = "center"; ctx.textBaseline = "top";
  for (const t of niceTicks(xr[0], xr[1], Math.max(2, Math.floor(pw / 90)))) {
    const x = X(t); ctx.beginPath(); ctx.moveTo(x, MARGIN.top); ctx.lineTo(x, MARGIN.top + ph); ctx.stroke();
    ctx.fillText(fmtTick(t), x, MARGIN.top + ph + 3);
  }
  ctx.textAlign = "right"; ctx.textBaseline = "middle";
  for (const v of niceTicks(yr[0], yr[1], Math.max(2, Math.floor(ph / 30)))) {
    const y = Y(v); ctx.beginPath(); ctx.moveTo(MARGIN.left, y); ctx.lineTo(MARGIN.left + pw, y); ctx.stroke();
    ctx.fillText(fmtTick(v), MARGIN.left - 4, y);
  }
  ctx.strokeStyle = "#666"; ctx.strokeRect(MARGIN.left, MARGIN.top, pw, ph);
  ctx.textAlign = "right"; ctx.textBaseline = "top"; ctx.fillText(xlabel, w - MARGIN.right, h - 12);
  ctx.textAlign = "left"; ctx.textBaseline = "top"; ctx.font = "bold 12px sans-serif"; ctx.fillText(ylabel, 4, 3);
  return { X, Y, pw, ph };
}

function range(arrays) {
  let lo = Infinity, hi = -Infinity;
  for (const a of arrays) { for (const v of a) { if (v !== null && v < lo) { lo = v; } if (v !== null && v > hi) { hi = v; } } }
  if (!isFinite(lo)) { return [0, 1]; }
  if (lo === hi) { const d = Math.abs(lo) * 0.05 || 1; return [lo - d, hi + d]; }
  const pad = (hi - lo) * 0.05; return [lo - pad, hi + pad];
}

class TimePlot {
  constructor(set, channel, container) {
    this.set = set; this.channel = channel; this.data = null; this.updates = 0; this.pending = null;
    this.el = document.createElement("div"); this.el.className = "plot";
    this.canvas = document.createElement("canvas");
    this.canvas.dataset.key = channel.key; this.canvas.dataset.column = channel.column;
    this.canvas.dataset.points = "0"; this.canvas.dataset.updates = "0";
    this.el.appendChild(this.canvas); container.appendChild(this.el);
    this.legend = document.createElement("div"); this.legend.className = "legend"; this.el.appendChild(this.legend);
    set.attach(this);
  }
  get label() { return `${this.channel.key} ${this.channel.column}` + (this.channel.units ? ` [${this.channel.units}]` : ""); }
  width() { return Math.max(300, Math.floor(this.el.clientWidth || 800)); }
  async load(t0, t1) {
    const px = Math.max(50, this.width() - MARGIN.left - MARGIN.right);
    const q = new URLSearchParams({ id: this.set.runId, key: this.channel.key, column: this.channel.column, px: String(px) });
    if (t0 !== null) { q.set("t0", String(t0)); }
    if (t1 !== null) { q.set("t1", String(t1)); }
    const ticket = {}; this.pending = ticket;
    const r = await fetch("/api/stream?" + q.toString());
    if (!r.ok || this.pending !== ticket) { return; }
    this.data = await r.json(); this.draw();
  }
  draw() {
    const w = this.width(), h = 180, d = this.data;
    const ctx = setupCanvas(this.canvas, w, h);
    const xr = this.set.visible(d);
    const lows = d ? d.series.map((s) => s.min) : [], highs = d ? d.series.map((s) => s.max) : [];
    const yr = range(lows.concat(highs));
    const { X, Y } = drawAxes(ctx, w, h, xr, yr, "run time [s]", this.label);
    let points = 0;
    if (d) {
      ctx.save(); ctx.beginPath();
      ctx.rect(MARGIN.left, MARGIN.top, w - MARGIN.left - MARGIN.right, h - MARGIN.top - MARGIN.bottom); ctx.clip();
      d.series.forEach((s, j) => {
        ctx.strokeStyle = COLOURS[j % COLOURS.length]; ctx.lineWidth = 1.2; ctx.beginPath();
        let open = false;
        for (let i = 0; i < d.t.length; i++) {
          if (s.min[i] === null || s.max[i] === null) { open = false; continue; }
          const x = X(d.t[i]);
          if (!open) { ctx.moveTo(x, Y(s.min[i])); open = true; } else { ctx.lineTo(x, Y(s.min[i])); }
          if (s.max[i] !== s.min[i]) { ctx.lineTo(x, Y(s.max[i])); }
          points++;
        }
        ctx.stroke();
      });
      ctx.restore();
      this.legend.innerHTML = d.series.map((s, j) => s.label ? `<span class="c${j % COLOURS.length}">&#9632; ${s.label}</span>` : "").join(" ") +
        ` <span class="muted">${d.rows.toLocaleString()} rows; ${d.points.toLocaleString()} points sent${d.raw ? "" : " (min/max per pixel)"}</span>`;
    }
    this.updates++;
    this.canvas.dataset.points = String(points);
    this.canvas.dataset.rows = d ? String(d.rows) : "0";
    this.canvas.dataset.updates = String(this.updates);
    this.canvas.dataset.tLast = d && d.t_last_s !== null ? String(d.t_last_s) : "";
  }
}

class PlotSet {
  // plots sharing one time axis: `view` is null (everything, following a live run) or [t0, t1] (s)
  constructor(runId, container) {
    this.runId = runId; this.container = container; this.plots = []; this.view = null; this.drag = null;
  }
  attach(plot) {
    this.plots.push(plot);
    const c = plot.canvas;
    c.addEventListener("wheel", (ev) => { ev.preventDefault(); this.zoom(plot, ev); }, { passive: false });
    c.addEventListener("mousedown", (ev) => { this.drag = { x: ev.clientX, view: this.current(plot), plot }; });
    window.addEventListener("mouseup", () => { if (this.drag) { this.drag = null; this.reload(); } });
    c.addEventListener("mousemove", (ev) => {
      if (!this.drag || this.drag.plot !== plot) { return; }
      const [a, b] = this.drag.view, pw = plot.width() - MARGIN.left - MARGIN.right;
      const dt = (ev.clientX - this.drag.x) / pw * (b - a);
      this.view = [a - dt, b - dt]; this.plots.forEach((p) => p.draw());
    });
    c.addEventListener("dblclick", () => { this.view = null; this.reload(); });
  }
  current(plot) {
    if (this.view) { return this.view; }
    const d = plot.data; return d && d.t0_s !== null ? [d.t0_s, d.t1_s] : [0, 1];
  }
  visible(d) {
    if (this.view) { return this.view; }
    let lo = Infinity, hi = -Infinity;
    for (const p of this.plots) {
      if (p.data && p.data.t_first_s !== null) { lo = Math.min(lo, p.data.t_first_s); hi = Math.max(hi, p.data.t_last_s); }
    }
    if (!isFinite(lo)) { return d && d.t0_s !== null ? [d.t0_s, d.t1_s] : [0, 1]; }
    return hi > lo ? [lo, hi] : [lo - 0.5, lo + 0.5];
  }
  zoom(plot, ev) {
    const [a, b] = this.visible(plot.data);
    const rect = plot.canvas.getBoundingClientRect();
    const f = Math.min(1, Math.max(0, (ev.clientX - rect.left - MARGIN.left) / (rect.width - MARGIN.left - MARGIN.right)));
    const at = a + f * (b - a), k = ev.deltaY < 0 ? 0.7 : 1 / 0.7;
    this.view = [at - (at - a) * k, at + (b - at) * k];
    this.reload();
  }
  reload() {
    const [t0, t1] = this.view ? this.view : [null, null];
    return Promise.all(this.plots.map((p) => p.load(t0, t1).catch(() => {})));
  }
}

async function drawXY(canvas, runId, x, y) {
  const q = new URLSearchParams({ id: runId, xkey: x.key, xcol: x.column, xi: String(x.index), ykey: y.key, ycol: y.column,
    yi: String(y.index), points: "1000" });
  const r = await fetch("/api/xy?" + q.toString());
  const d = await r.json();
  const w = Math.max(300, canvas.parentElement.clientWidth || 600), h = 360;
  const ctx = setupCanvas(canvas, w, h);
  if (!r.ok) { ctx.fillText((d.errors || ["failed"]).join("; "), 10, 20); return; }
  const { X, Y } = drawAxes(ctx, w, h, range([d.x]), range([d.y]), `${x.label} [${d.x_units}]`, `${y.label} [${d.y_units}]`);
  ctx.fillStyle = COLOURS[0];
  for (let i = 0; i < d.x.length; i++) { ctx.fillRect(X(d.x[i]) - 1.5, Y(d.y[i]) - 1.5, 3, 3); }
  canvas.dataset.points = String(d.points);
}

window.BenchPlot = { PlotSet, TimePlot, drawXY };
