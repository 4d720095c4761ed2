// bench web station: the runs table, run pages (live while the run is written) and the start page.
"use strict";

const TOKEN_KEY = "bench-token";
const LIVE_PERIOD_MS = 1000;
const main = document.getElementById("main");

function esc(v) {
  return String(v === null || v === undefined ? "" : v).replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" }[c]));
}
function num(v, digits) { return v === null || v === undefined ? "" : Number(v).toFixed(digits === undefined ? 1 : digits); }
function hms(s) {
  if (s === null || s === undefined) { return ""; }
  s = Math.max(0, Math.round(s)); const h = Math.floor(s / 3600), m = Math.floor(s % 3600 / 60), x = s % 60;
  return `${h}:${String(m).padStart(2, "0")}:${String(x).padStart(2, "0")}`;
}
function badge(text) { return `<span class="badge ${esc(String(text || "").replace(/ /g, "-"))}">${esc(text)}</span>`; }
function token() { return sessionStorage.getItem(TOKEN_KEY) || ""; }

function showTokenState() {
  const el = document.getElementById("token-state");
  el.textContent = token() ? "token set: controls enabled" : "read-only (set the token to control runs)";
  el.className = token() ? "ok" : "";
}
document.getElementById("token-form").addEventListener("submit", (ev) => {
  ev.preventDefault();
  const v = document.getElementById("token-input").value.trim();
  if (v) { sessionStorage.setItem(TOKEN_KEY, v); } else { sessionStorage.removeItem(TOKEN_KEY); }
  document.getElementById("token-input").value = "";
  showTokenState();
});
showTokenState();

async function getJSON(url) {
  const r = await fetch(url);
  const d = await r.json();
  if (!r.ok) { throw new Error((d.errors || [r.statusText]).join("\n")); }
  return d;
}
async function post(url, body) {
  const r = await fetch(url, { method: "POST", headers: { "Content-Type": "application/json", Authorization: "Bearer " + token() },
    body: JSON.stringify(body) });
  const d = await r.json().catch(() => ({}));
  if (!r.ok) {
    const why = (d.errors || [r.statusText]).join("\n");
    throw new Error(r.status === 401 || r.status === 403 ? `${why} (set the token printed by 'bench serve')` : why);
  }
  return d;
}

// ---- runs table ------------------------------------------------------------------------------
const FILTERS = ["unit", "procedure", "status", "verdict", "since"];
async function runsPage() {
  const q = new URLSearchParams(location.search);
  const sel = (name, opts) => `<select name="${name}" id="f-${name}"><option value="">any</option>` +
    opts.map((o) => `<option${q.get(name) === o ? " selected" : ""}>${o}</option>`).join("") + "</select>";
  main.innerHTML = `<h1>Runs</h1>
    <form class="filters" id="filters">
      <label>unit<input name="unit" id="f-unit" value="${esc(q.get("unit") || "")}" placeholder="SN12 or SN*"></label>
      <label>procedure<input name="procedure" id="f-procedure" value="${esc(q.get("procedure") || "")}" placeholder="thermal_*"></label>
      <label>status${sel("status", ["running", "completed", "aborted", "failed", "crashed"])}</label>
      <label>verdict${sel("verdict", ["passed", "failed", "incomplete", "no verdict"])}</label>
      <label>since<input name="since" id="f-since" value="${esc(q.get("since") || "")}" placeholder="7d, 2026-11-23"></label>
      <button type="submit" id="f-apply">Filter</button> <a href="/">clear</a>
    </form><div id="runs-errors" class="errors"></div><div id="runs"></div>`;
  document.getElementById("filters").addEventListener("submit", (ev) => {
    ev.preventDefault();
    const f = new URLSearchParams();
    for (const k of FILTERS) { const v = document.getElementById("f-" + k).value.trim(); if (v) { f.set(k, v); } }
    history.pushState(null, "", "/" + (f.toString() ? "?" + f.toString() : ""));
    loadRuns(f);
  });
  const f = new URLSearchParams(); for (const k of FILTERS) { if (q.get(k)) { f.set(k, q.get(k)); } }
  loadRuns(f);
}
async function loadRuns(f) {
  const box = document.getElementById("runs"), err = document.getElementById("runs-errors");
  err.textContent = "";
  let d;
  try { d = await getJSON("/api/runs?" + f.toString()); } catch (e) { err.textContent = e.message; box.innerHTML = ""; return; }
  err.textContent = (d.warnings || []).join("\n");  // a catalogue that cannot be read: the rows below come from the files
  const rows = d.runs.map((r) => `<tr class="run-row" data-id="${esc(r.id)}" data-unit="${esc(r.unit_serial)}" data-status="${esc(r.status)}">
    <td>${esc((r.started_utc || "").replace("T", " ").replace("Z", ""))}</td><td>${esc(r.unit_serial)}</td>
    <td>${r.id ? `<a href="/run?id=${encodeURIComponent(r.id)}">${esc(r.procedure_name)}</a>` : esc(r.procedure_name)}</td>
    <td>${badge(r.status)}</td><td>${r.verdict ? badge(r.verdict) : ""}</td><td class="num">${hms(r.run_time_s)}</td>
    <td>${esc(r.station)}</td><td>${esc(r.operator)}</td><td>${esc(r.mode)}</td>
    <td class="num">${r.min_pressure_torr === null ? "" : Number(r.min_pressure_torr).toExponential(1)}</td>
    <td class="num">${r.temp_min_degc === null ? "" : `${num(r.temp_min_degc, 0)}..${num(r.temp_max_degc, 0)}`}</td>
    <td>${esc(r.first_failed_check || r.reason || "")}</td></tr>`).join("");
  box.innerHTML = `<p class="muted" id="runs-count">${d.runs.length} run(s), newest first</p>
    <table id="runs-table"><thead><tr><th>start UTC</th><th>unit</th><th>procedure</th><th>status</th><th>verdict</th><th>run time</th>
    <th>station</th><th>operator</th><th>mode</th><th>p min Torr</th><th>T degC</th><th>note</th></tr></thead><tbody>${rows}</tbody></table>`;
}

// ---- run page --------------------------------------------------------------------------------
async function runPage() {
  const id = new URLSearchParams(location.search).get("id") || "";
  let d;
  try { d = await getJSON("/api/run?id=" + encodeURIComponent(id)); } catch (e) { main.innerHTML = `<p class="errors">${esc(e.message)}</p>`; return; }
  const idn = d.identity || {};
  const q = encodeURIComponent(id);
  main.innerHTML = `<h1>${esc(d.procedure.name)} <span id="run-status">${badge(d.status)}</span></h1>
    <dl class="grid" id="identity"><dt>unit</dt><dd>${esc([idn.unit_serial, idn.unit_part, idn.unit_revision].filter((x) => x).join(" / ") || "—")}</dd>
      <dt>station</dt><dd>${esc(idn.station || "—")}</dd><dt>procedure</dt><dd>${esc(d.procedure.name)} <span class="muted">${esc(d.procedure.path)}</span></dd>
      <dt>operator</dt><dd>${esc(d.operator)}</dd><dt>mode</dt><dd>${esc(d.mode)}</dd>
      <dt>started / ended</dt><dd>${esc(d.started_utc)} / ${esc(d.ended_utc || "—")}</dd>
      <dt>file</dt><dd><a id="download" href="/api/file?id=${q}">${esc(d.file_name)}</a> (${(d.file_bytes / 1e6).toFixed(1)} MB) ·
        <a id="report" href="/api/report?id=${q}" target="_blank">HTML report</a></dd></dl>
    <div id="verdict"></div><div id="live"></div>
    <h2>Checks</h2><div id="checks"></div>
    <h2>Steps</h2><div id="steps"></div>
    <h2>Streams</h2><p class="muted">one time axis for all: wheel to zoom, drag to pan, double-click for everything</p><div id="plots"></div>
    <h2>X–Y</h2><div class="panel" id="xy-panel"><select id="xy-x"></select> horizontal, <select id="xy-y"></select> vertical
      <button id="xy-go">Plot X–Y</button><div><canvas id="xy-canvas"></canvas></div></div>
    <h2>Events</h2><div id="events"></div>`;
  renderSummary(d);
  const plots = new window.BenchPlot.PlotSet(id, document.getElementById("plots"));
  for (const ch of d.channels) { new window.BenchPlot.TimePlot(plots, ch, document.getElementById("plots")); }
  document.getElementById("plots").dataset.plots = String(d.channels.length);
  const comps = [];
  for (const ch of d.channels) { ch.components.forEach((c, i) => comps.push({ key: ch.key, column: ch.column, index: i, label: `${ch.key} ${ch.column}${c ? "." + c : ""}` })); }
  for (const s of ["xy-x", "xy-y"]) {
    document.getElementById(s).innerHTML = comps.map((c, i) => `<option value="${i}">${esc(c.label)}</option>`).join("");
  }
  if (comps.length > 1) { document.getElementById("xy-y").value = "1"; }
  document.getElementById("xy-go").addEventListener("click", () => {
    window.BenchPlot.drawXY(document.getElementById("xy-canvas"), id, comps[+document.getElementById("xy-x").value], comps[+document.getElementById("xy-y").value]);
  });
  await plots.reload();
  if (d.control || d.status === "running" || d.status === "waiting") { followLive(id, plots, d); }
}

function renderSummary(d) {
  const v = d.verdict;
  document.getElementById("verdict").innerHTML = `<div class="verdict ${esc(v.word.replace(/ /g, "-"))}" id="verdict-word">${esc(v.word)}</div>
    <ul>${v.reasons.map((r) => `<li>${esc(r)}</li>`).join("")}</ul>` + (d.abort_reason ? `<p><b>Reason:</b> ${esc(d.abort_reason)}</p>` : "") +
    (d.status_detail ? `<p class="muted">${esc(d.status_detail)}</p>` : "");
  document.getElementById("checks").innerHTML = d.checks.length ? `<table><tr><th>check</th><th>signal</th><th>statistic</th><th>window</th><th>value</th><th>limits</th><th>outcome</th></tr>` +
    d.checks.map((c) => `<tr><td>${esc(c.name)}</td><td>${esc(c.signal)}</td><td>${esc(c.statistic)}</td><td>${esc(c.window)}</td>
      <td class="num">${c.value === null ? "–" : esc(Number(c.value).toPrecision(6))} ${esc(c.units || "")}</td><td>${esc(c.limits || "")}</td><td>${badge(c.outcome)}</td></tr>`).join("") +
    "</table>" : `<p class="muted">no checks</p>`;
  renderSteps(d.steps);
  const ev = d.events;
  const traffic = Object.entries(ev.traffic || {}).map(([n, t]) => `<li>${esc(n)}: ${t.polls.toLocaleString()} polls, ${t.commands.toLocaleString()} commands, ${t.replies.toLocaleString()} replies</li>`).join("");
  document.getElementById("events").innerHTML = `<p class="muted">${ev.total.toLocaleString()} events; instrument traffic summarised:</p><ul id="traffic">${traffic}</ul>` +
    `<table id="events-table"><tr><th>run time s</th><th>kind</th><th>source</th><th>step</th><th>message</th></tr>` +
    ev.recent.map((e) => `<tr><td class="num">${num(e.t_s)}</td><td>${esc(e.kind)}</td><td>${esc(e.source)}</td><td>${esc(e.step || "")}</td><td>${esc(e.message)}</td></tr>`).join("") + "</table>";
}

function renderSteps(steps) {
  document.getElementById("steps").innerHTML = `<table id="steps-table"><tr><th>#</th><th>step</th><th>type</th><th>outcome</th><th>duration</th><th>detail</th></tr>` +
    steps.map((s) => `<tr><td>${s.step}</td><td>${esc(s.name)}</td><td>${esc(s.type)}</td><td>${badge(s.outcome)}</td>
      <td class="num">${s.t_end_s !== null && s.t_start_s !== null ? num(s.t_end_s - s.t_start_s) + " s" : ""}</td><td>${esc(s.detail || "")}</td></tr>`).join("") + "</table>";
}

function followLive(id, plots, first) {
  const box = document.getElementById("live");
  document.getElementById("verdict").innerHTML = `<p class="muted">the verdict and the checks are shown when the run ends</p>`;
  box.innerHTML = `<div class="panel live" id="live-panel"><div id="live-state"></div><div id="prompt-box"></div>
    <div id="controls"><button id="pause-btn">Pause</button> <button id="stop-btn" class="stop">Stop (instruments to safe state)</button>
    <span id="control-msg" class="errors"></span></div><div id="interlocks"></div><div id="limits"></div><div id="messages" class="muted"></div></div>`;
  const msg = (t) => { document.getElementById("control-msg").textContent = t || ""; };
  const act = async (url, body) => { msg(""); try { await post(url, Object.assign({ id }, body)); } catch (e) { msg(e.message); } };
  let paused = false, shownPrompt = null, updates = 0, stopped = false;
  document.getElementById("pause-btn").addEventListener("click", () => act("/api/pause", { paused: !paused }));
  document.getElementById("stop-btn").addEventListener("click", () => act("/api/stop", {}));
  const tick = async () => {
    const began = performance.now();
    let d;
    try { d = await getJSON("/api/live?id=" + encodeURIComponent(id)); } catch (e) { msg(e.message); return; }
    const f = d.file, c = d.control;
    updates++; box.dataset.updates = String(updates);
    if (f) {
      document.getElementById("run-status").innerHTML = badge(f.status);
      const cur = f.current_step ? `step ${f.current_step.step} of ${f.steps_total}: ${esc(f.current_step.name)} (${esc(f.current_step.type)})` : "";
      const est = c && c.progress.estimated_total_s ? c.progress.estimated_total_s : null;
      const frac = est ? Math.min(1, f.run_time_s / est) : (f.steps_total ? f.steps_done / f.steps_total : 0);
      document.getElementById("live-state").innerHTML = `<b>${esc(f.status)}</b> · run time ${hms(f.run_time_s)} · ${cur}
        <div class="progress"><div id="progress-bar"></div></div> <span class="muted">${f.steps_done}/${f.steps_total} steps</span>
        <div class="muted">${esc(f.status_detail)}</div>`;
      document.getElementById("progress-bar").style.width = (100 * frac).toFixed(1) + "%";
      renderSteps(f.steps.map((s) => Object.assign({ detail: "" }, s)));
    } else if (d.error) { msg(d.error); }
    const question = c ? (c.prompt ? c.prompt.text : null) : (f && f.waiting_for ? f.waiting_for.prompt : null);
    if (question !== shownPrompt) {
      shownPrompt = question;
      const pb = document.getElementById("prompt-box");
      pb.innerHTML = question ? `<div class="prompt" id="prompt"><div class="question">${esc(question)}</div>` +
        (c ? `<button id="answer-yes">Yes</button> <button id="answer-no">No</button>
          <input id="answer-text" size="12" placeholder="other answer"> <button id="answer-send">Send</button>` :
          `<span class="muted">answer it where the run was started (this run is not controlled by this station)</span>`) + "</div>" : "";
      if (question && c) {
        document.getElementById("answer-yes").addEventListener("click", () => act("/api/answer", { answer: "yes" }));
        document.getElementById("answer-no").addEventListener("click", () => act("/api/answer", { answer: "no" }));
        document.getElementById("answer-send").addEventListener("click", () => act("/api/answer", { answer: document.getElementById("answer-text").value }));
      }
    }
    document.getElementById("controls").hidden = !(c && c.running);
    if (c) {
      paused = c.paused;
      document.getElementById("pause-btn").textContent = paused ? "Resume" : "Pause";
      document.getElementById("interlocks").innerHTML = c.interlocks.length ? `<table id="interlocks-table"><tr><th>interlock</th><th>signal</th><th>limits</th><th>value</th><th>state</th></tr>` +
        c.interlocks.map((i) => `<tr><td>${esc(i.name)}</td><td>${esc(i.signal)}</td><td>${i.min === null ? "" : esc(i.min)} .. ${i.max === null ? "" : esc(i.max)}${i.max_gap_s ? "max gap " + esc(i.max_gap_s) + " s" : ""}</td>
          <td class="num">${i.value === null ? "" : num(i.value, 2)}</td><td class="${i.state === "beyond" ? "bad-state" : "ok-state"}">${esc(i.state)}</td></tr>`).join("") + "</table>" : "";
      const lims = c.limits || [];
      document.getElementById("limits").innerHTML = lims.length ? `<table id="limits-table"><tr><th>limit</th><th>range</th><th>from</th><th>watched</th><th>value</th><th>state</th></tr>` +
        lims.map((l) => `<tr><td>${esc(l.instrument)} ${esc(l.quantity)}</td><td>${l.min === null ? "" : esc(l.min)} .. ${l.max === null ? "" : esc(l.max)} ${esc(l.units)}</td>
          <td>${esc(l.source)}</td><td>${esc(l.watch || "every step, before the run")}</td><td class="num">${l.value === null ? "" : num(l.value, 2)}</td>
          <td class="${l.state === "beyond" ? "bad-state" : "ok-state"}">${esc(l.state)}</td></tr>`).join("") + "</table>" : "";
      document.getElementById("messages").innerHTML = c.messages.map((m) => esc(m.replace(/\[\/?[a-z ]*\]/g, "").replace(/\\\[/g, "["))).join("<br>") +
        (c.progress.readings ? `<div>${esc(c.progress.readings)}</div>` : "") + (c.error ? `<div class="errors">${esc(c.error)}</div>` : "");
    }
    if (!plots.view || plots.follow) { await plots.reload(); }
    const over = f && f.final && !(c && c.running);
    if (over && !stopped) {
      stopped = true;
      const full = await getJSON("/api/run?id=" + encodeURIComponent(id));
      document.getElementById("run-status").innerHTML = badge(full.status);
      renderSummary(full);
      document.getElementById("controls").hidden = true;
      await plots.reload();
      return;
    }
    setTimeout(tick, Math.max(100, LIVE_PERIOD_MS - (performance.now() - began)));  // one update per second
  };
  tick();
}

// ---- start a run -----------------------------------------------------------------------------
async function startPage() {
  const [session, lib] = await Promise.all([getJSON("/api/session"), getJSON("/api/procedures")]);
  const procs = lib.procedures;
  main.innerHTML = `<h1>Start a run</h1>
    <div class="panel"><div class="form-row"><label>procedure</label><select id="s-procedure">${procs.map((p) =>
      `<option value="${esc(p.name)}">${esc(p.name)}${p.title ? " — " + esc(p.title) : ""}</option>`).join("")}</select></div>
    <div id="s-info" class="muted"></div><div id="s-params"></div>
    <div class="form-row"><label>unit serial</label><input id="s-unit" placeholder="SN0042"></div>
    <div class="form-row"><label>lab</label><label><input type="checkbox" id="s-dry" checked ${session.real_lab ? "" : "disabled"}> dry-run on the simulators</label>
      <label><input type="checkbox" id="s-realtime" checked> at wall-clock pace (watchable)</label></div>
    <div class="form-row"><label></label><label><input type="checkbox" id="s-overdue"> run on instruments past their calibration date</label></div>
    <p class="muted">dry-runs: ${esc(session.dry_run_config || "no simulated lab config")}; real lab: ${esc(session.config || "none (start bench serve with --config)")}</p>
    <button id="s-plan">Show plan</button> <button id="s-start">Start run</button></div>
    <div id="s-errors" class="errors"></div><div id="s-started"></div><pre class="plan" id="s-plan-text" hidden></pre>`;
  const sel = document.getElementById("s-procedure");
  const showProc = () => {
    const p = procs.find((x) => x.name === sel.value);
    if (!p) { return; }
    document.getElementById("s-info").textContent = p.error ? p.error : `${p.procedure}: ${p.steps} steps, instruments ${p.instruments.join(", ")}, ${p.prompts} prompt(s)`;
    document.getElementById("s-params").innerHTML = Object.entries(p.parameters || {}).map(([k, v]) =>
      `<div class="form-row"><label>${esc(k)}</label><input class="s-param" data-name="${esc(k)}" placeholder="${esc(v)}"></div>`).join("");
    document.getElementById("s-plan-text").hidden = true;
  };
  sel.addEventListener("change", showProc);
  const qp = new URLSearchParams(location.search).get("procedure");
  if (qp && procs.some((p) => p.name === qp)) { sel.value = qp; }
  showProc();
  const params = () => { const o = {}; for (const i of document.querySelectorAll(".s-param")) { if (i.value.trim()) { o[i.dataset.name] = i.value.trim(); } } return o; };
  const errs = (t) => { document.getElementById("s-errors").textContent = t || ""; };
  document.getElementById("s-plan").addEventListener("click", async () => {
    errs("");
    try {
      const d = await getJSON("/api/plan?" + new URLSearchParams({ procedure: sel.value, params: JSON.stringify(params()) }).toString());
      const pre = document.getElementById("s-plan-text"); pre.hidden = false; pre.textContent = d.text || "";
      if (!d.ok) { errs(d.errors.join("\n")); }
    } catch (e) { errs(e.message); }
  });
  document.getElementById("s-start").addEventListener("click", async () => {
    errs("");
    try {
      const d = await post("/api/start", { procedure: sel.value, params: params(), unit: document.getElementById("s-unit").value,
        dry_run: document.getElementById("s-dry").checked, realtime: document.getElementById("s-realtime").checked,
        accept_overdue: document.getElementById("s-overdue").checked });
      startedRuns.push(d.id); renderStarted();
    } catch (e) { errs(e.message); }
  });
  renderStarted();
}
const startedRuns = [];
async function renderStarted() {
  const box = document.getElementById("s-started");
  if (!box || !startedRuns.length) { return; }
  const rows = await Promise.all(startedRuns.map((id) => getJSON("/api/live?id=" + encodeURIComponent(id)).catch(() => null)));
  box.innerHTML = `<h2>Runs started here</h2><table id="started-table"><tr><th>run</th><th>status</th><th>step</th><th>run time</th><th>waiting for</th></tr>` +
    rows.map((d, i) => {
      const f = d && d.file, c = d && d.control;
      return `<tr><td><a class="started-run" href="/run?id=${encodeURIComponent(startedRuns[i])}">${esc(startedRuns[i])}</a></td>
        <td>${f ? badge(f.status) : ""}</td><td>${f && f.current_step ? esc(f.current_step.name) : ""}</td><td class="num">${f ? hms(f.run_time_s) : ""}</td>
        <td>${c && c.prompt ? esc(c.prompt.text) : ""}</td></tr>`;
    }).join("") + "</table>";
  clearTimeout(renderStarted.timer);
  renderStarted.timer = setTimeout(renderStarted, LIVE_PERIOD_MS);
}

// ---- routing ---------------------------------------------------------------------------------
const route = { "/": runsPage, "/run": runPage, "/start": startPage }[location.pathname] || runsPage;
window.addEventListener("popstate", () => route());
route().catch((e) => { main.innerHTML = `<p class="errors">${esc(e.message)}</p>`; });
