// bench web station: a small canvas plotter. Every plot of a run shares one time axis (zoom with
// the wheel, pan by dragging, double-click to see everything again); each plot asks the server for
// its columns over the visible range at its pixel width (per-pixel min/max: never the whole stream).
// A plot holds the columns of one stream that share a unit (the four thermocouple channels in one
// plot); lines break where nothing was recorded; status words are bit fields drawn as steps with
// hexadecimal ticks; run times over ten minutes read h:mm:ss; plots follow the window's width.
"use strict";

const COLOURS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#8c564b", "#e377c2"];
const MARGIN = { left: 70, right: 12, top: 20, bottom: 26 };
const HMS_FROM_S = 600;          // a visible span longer than this (s) gets h:mm:ss ticks
const GAP_FACTOR = 5;            // a step in time this many times the typical one is a gap: the line breaks
const TIME_STEPS_S = [1, 2, 5, 10, 15, 30, 60, 120, 300, 600, 900, 1800, 3600, 7200, 10800, 21600, 43200, 86400];

function niceTicks(lo, hi, n) {
  if (!(hi > lo)) { return [lo]; }
  const raw = (hi - lo) / Math.max(1, n);
  const mag = Math.pow(10, Math.floor(Math.log10(raw)));
  const step = [1, 2, 5, 10].map((m) => m * mag).find((s) => s >= raw) || 10 * mag;
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) { out.push(Math.abs(v) < step * 1e-9 ? 0 : v); }
  return out;
}

function timeTicks(lo, hi, n) {
  const raw = (hi - lo) / Math.max(1, n);
  const step = TIME_STEPS_S.find((s) => s >= raw) || Math.ceil(raw / 86400) * 86400;
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-9; v += step) { out.push(v); }
  return out;
}

function fmtTick(v) {
  const a = Math.abs(v);
  if (a !== 0 && (a >= 1e5 || a < 1e-3)) { return v.toExponential(1); }
  return String(Number(v.toPrecision(6)));
}
function hmsTick(s) {
  const neg = s < 0; s = Math.round(Math.abs(s));
  const h = Math.floor(s / 3600), m = Math.floor(s % 3600 / 60), x = s % 60;
  return `${neg ? "-" : ""}${h}:${String(m).padStart(2, "0")}:${String(x).padStart(2, "0")}`;
}
function hexTick(v) { return Number.isInteger(v) && v >= 0 ? "0x" + v.toString(16).padStart(4, "0") : ""; }

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

// axes: `xtime` draws h:mm:ss ticks when the span is long; `yhex` hexadecimal value ticks (status words)
function drawAxes(ctx, w, h, xr, yr, xlabel, ylabel, opts) {
  opts = opts || {};
  const pw = w - MARGIN.left - MARGIN.right, ph = h - MARGIN.top - MARGIN.bottom;
  ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, w, h);
  ctx.strokeStyle = "#ccc"; ctx.lineWidth = 1; ctx.font = "11px sans-serif"; ctx.fillStyle = "#333";
  const X = (v) => MARGIN.left + (v - xr[0]) / (xr[1] - xr[0] || 1) * pw;
  const Y = (v) => MARGIN.top + ph - (v - yr[0]) / (yr[1] - yr[0] || 1) * ph;
  ctx.textAlign = "center"; ctx.textBaseline = "top";
  const hms = opts.xtime && xr[1] - xr[0] > HMS_FROM_S;
  // ticks: [value, label] pairs given by the caller (dates, unit names), else computed
  const xt = opts.xticks || (hms ? timeTicks(xr[0], xr[1], Math.max(2, Math.floor(pw / 90))).map((t) => [t, hmsTick(t)])
    : niceTicks(xr[0], xr[1], Math.max(2, Math.floor(pw / 90))).map((t) => [t, fmtTick(t)]));
  for (const [t, label] of xt) {
    const x = X(t); ctx.beginPath(); ctx.moveTo(x, MARGIN.top); ctx.lineTo(x, MARGIN.top + ph); ctx.stroke();
    ctx.fillText(label, x, MARGIN.top + ph + 3);
  }
  ctx.textAlign = "right"; ctx.textBaseline = "middle";
  const yt = opts.yticks || (opts.yhex ? niceTicks(yr[0], yr[1], Math.max(2, Math.floor(ph / 30))).filter((v) => Number.isInteger(v)).map((v) => [v, hexTick(v)])
    : niceTicks(yr[0], yr[1], Math.max(2, Math.floor(ph / 30))).map((v) => [v, fmtTick(v)]));
  for (const [v, label] of yt) {
    const y = Y(v); ctx.beginPath(); ctx.moveTo(MARGIN.left, y); ctx.lineTo(MARGIN.left + pw, y); ctx.stroke();
    ctx.fillText(label, MARGIN.left - 4, y);
  }
  ctx.strokeStyle = "#666"; ctx.strokeRect(MARGIN.left, MARGIN.top, pw, ph);
  const xl = typeof xlabel === "function" ? xlabel(hms) : xlabel;
  ctx.textAlign = "right"; ctx.textBaseline = "top"; ctx.fillText(xl, w - MARGIN.right, h - 12);
  ctx.textAlign = "left"; ctx.textBaseline = "top"; ctx.font = "bold 12px sans-serif"; ctx.fillText(ylabel, 4, 3);
  return { X, Y, pw, ph, hms };
}

function range(arrays) {
  let lo = Infinity, hi = -Infinity;
  for (const a of arrays) { for (const v of a) { if (v !== null && v < lo) { lo = v; } if (v !== null && v > hi) { hi = v; } } }
  if (!isFinite(lo)) { return [0, 1]; }
  if (lo === hi) { const d = Math.abs(lo) * 0.05 || 1; return [lo - d, hi + d]; }
  const pad = (hi - lo) * 0.05; return [lo - pad, hi + pad];
}

// the time step beyond which two neighbouring points are not joined: GAP_FACTOR times the typical
// (median) step, and never less than two pixels' worth of time
function gapLimit(t, pxTime) {
  const steps = [];
  for (let i = 1; i < t.length; i++) { const d = t[i] - t[i - 1]; if (d > 0) { steps.push(d); } }
  if (!steps.length) { return Infinity; }
  steps.sort((a, b) => a - b);
  return Math.max(GAP_FACTOR * steps[Math.floor(steps.length / 2)], 2 * pxTime);
}

class TimePlot {
  // `group`: {key, columns: [{column, units, components}], units, status}
  constructor(set, group, container) {
    this.set = set; this.group = group; this.data = null; this.updates = 0; this.pending = null;
    this.el = document.createElement("div"); this.el.className = "plot";
    this.canvas = document.createElement("canvas");
    this.canvas.dataset.key = group.key; this.canvas.dataset.column = group.columns[0].column;
    this.canvas.dataset.columns = group.columns.map((c) => c.column).join(",");
    this.canvas.dataset.points = "0"; this.canvas.dataset.updates = "0"; this.canvas.dataset.gaps = "0";
    this.canvas.dataset.status = group.status ? "1" : "0";
    this.el.appendChild(this.canvas); container.appendChild(this.el);
    this.legend = document.createElement("div"); this.legend.className = "legend"; this.el.appendChild(this.legend);
    set.attach(this);
  }
  get label() {
    const g = this.group, names = g.columns.map((c) => c.column);
    const what = names.length > 2 ? `${names[0]}..${names[names.length - 1]}` : names.join(", ");
    return `${g.key} ${what}` + (g.status ? " [status word, hex]" : (g.units ? ` [${g.units}]` : ""));
  }
  width() { return Math.max(300, Math.floor(this.el.clientWidth || 800)); }
  async load(t0, t1) {
    const px = Math.max(50, this.width() - MARGIN.left - MARGIN.right);
    const ticket = {}; this.pending = ticket;
    const bodies = await Promise.all(this.group.columns.map(async (c) => {
      const q = new URLSearchParams({ id: this.set.runId, key: this.group.key, column: c.column, px: String(px) });
      if (t0 !== null) { q.set("t0", String(t0)); }
      if (t1 !== null) { q.set("t1", String(t1)); }
      const r = await fetch("/api/stream?" + q.toString());
      return r.ok ? r.json() : null;
    }));
    if (this.pending !== ticket || bodies.some((b) => b === null)) { return; }
    this.data = bodies; this.draw();
  }
  // the first body carries the time range of the stream (every column of a stream has the same rows)
  get head() { return this.data && this.data.length ? this.data[0] : null; }
  draw() {
    const w = this.width(), h = 180, bodies = this.data || [], d = this.head;
    const ctx = setupCanvas(this.canvas, w, h);
    const xr = this.set.visible(d);
    const lows = [], highs = [];
    for (const b of bodies) { for (const s of b.series) { lows.push(s.min); highs.push(s.max); } }
    const yr = range(lows.concat(highs));
    const { X, Y, pw, hms } = drawAxes(ctx, w, h, xr, yr, (long) => long ? "run time [h:mm:ss]" : "run time [s]", this.label,
      { xtime: true, yhex: this.group.status });
    let points = 0, gaps = 0, j = 0;
    const legend = [];
    if (d) {
      ctx.save(); ctx.beginPath();
      ctx.rect(MARGIN.left, MARGIN.top, w - MARGIN.left - MARGIN.right, h - MARGIN.top - MARGIN.bottom); ctx.clip();
      const pxTime = (xr[1] - xr[0]) / Math.max(1, pw);
      for (const b of bodies) {
        const limit = gapLimit(b.t, pxTime);
        b.series.forEach((s) => {
          const colour = COLOURS[j % COLOURS.length];
          ctx.strokeStyle = colour; ctx.lineWidth = 1.2; ctx.beginPath();
          let open = false, lastT = null, lastY = null, breaks = 0;
          for (let i = 0; i < b.t.length; i++) {
            if (s.min[i] === null || s.max[i] === null) { open = false; continue; }
            const x = X(b.t[i]);
            if (open && b.t[i] - lastT > limit) { open = false; breaks++; }
            if (!open) { ctx.moveTo(x, Y(s.min[i])); open = true; }
            else if (this.group.status) { ctx.lineTo(x, Y(lastY)); ctx.lineTo(x, Y(s.min[i])); }  // a word holds until it changes
            else { ctx.lineTo(x, Y(s.min[i])); }
            if (s.max[i] !== s.min[i]) { ctx.lineTo(x, Y(s.max[i])); }
            lastT = b.t[i]; lastY = s.max[i];
            points++;
          }
          ctx.stroke();
          gaps = Math.max(gaps, breaks);  // the gaps of the recording: the same in every series of the stream
          const name = b.series.length > 1 ? `${b.column}${s.label ? " " + s.label : ""}` : b.column;
          legend.push(`<span class="c${j % COLOURS.length}">&#9632; ${name}</span>`);
          j++;
        });
      }
      ctx.restore();
      this.legend.innerHTML = legend.join(" ") +
        ` <span class="muted">${d.rows.toLocaleString()} rows; ${bodies.reduce((n, b) => n + b.points, 0).toLocaleString()} points sent` +
        `${d.raw ? "" : " (min/max per pixel)"}${gaps ? `; ${gaps} gap(s) in the recording left open` : ""}</span>`;
    }
    this.updates++;
    this.canvas.dataset.points = String(points);
    this.canvas.dataset.gaps = String(gaps);
    this.canvas.dataset.timeAxis = hms ? "hms" : "s";
    this.canvas.dataset.rows = d ? String(d.rows) : "0";
    this.canvas.dataset.updates = String(this.updates);
    this.canvas.dataset.tLast = d && d.t_last_s !== null ? String(d.t_last_s) : "";
    this.canvas.dataset.width = String(w);
  }
}

class PlotSet {
  // plots sharing one time axis: `view` is null (everything, following a live run) or [t0, t1] (s)
  constructor(runId, container) {
    this.runId = runId; this.container = container; this.plots = []; this.view = null; this.drag = null;
    this.width = container.clientWidth;
    // the plots follow the window: a new width redraws them at once and asks for data at that width
    let timer = null;
    const resized = () => {
      if (container.clientWidth === this.width) { return; }
      this.width = container.clientWidth;
      this.plots.forEach((p) => { if (p.data) { p.draw(); } });
      clearTimeout(timer); timer = setTimeout(() => this.reload(), 250);
    };
    if (window.ResizeObserver) { new ResizeObserver(resized).observe(container); } else { window.addEventListener("resize", resized); }
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
    const d = plot.head; return d && d.t0_s !== null ? [d.t0_s, d.t1_s] : [0, 1];
  }
  visible(d) {
    if (this.view) { return this.view; }
    let lo = Infinity, hi = -Infinity;
    for (const p of this.plots) {
      const h = p.head;
      if (h && h.t_first_s !== null) { lo = Math.min(lo, h.t_first_s); hi = Math.max(hi, h.t_last_s); }
    }
    if (!isFinite(lo)) { return d && d.t0_s !== null ? [d.t0_s, d.t1_s] : [0, 1]; }
    return hi > lo ? [lo, hi] : [lo - 0.5, lo + 0.5];
  }
  zoom(plot, ev) {
    const [a, b] = this.visible(plot.head);
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

// the plots of a run's channels: a vector column alone (its x, y, z), a status word alone, and the
// other scalar columns of one stream together when they share a unit
function groupChannels(channels) {
  const groups = [], byKey = new Map();
  for (const ch of channels) {
    const status = /status/i.test(ch.column);
    if (ch.components.length > 1 || status) {
      groups.push({ key: ch.key, columns: [ch], units: ch.units, status });
      continue;
    }
    const id = ch.key + "\u0000" + ch.units;
    if (!byKey.has(id)) { const g = { key: ch.key, columns: [], units: ch.units, status: false }; byKey.set(id, g); groups.push(g); }
    byKey.get(id).columns.push(ch);
  }
  return groups;
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

window.BenchPlot = { PlotSet, TimePlot, drawXY, groupChannels, drawAxes, setupCanvas, range, COLOURS, MARGIN };
