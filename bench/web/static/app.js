// bench web station: the runs table, run pages (live while the run is written), the start page and
// a unit's history. Numbers arrive from the server already written with their units (one formatter
// for every view: bench/quantity_format.py); a run that is not on real instruments carries its
// banner on every page; controls that end or change a run ask first and carry the acting person.
"use strict";

const TOKEN_KEY = "bench-token";
const NAME_KEY = "bench-operator";
const LIVE_PERIOD_MS = 1000;
const NEGATIVE = ["n", "no", "false"];  // answers that stop the run (bench/runner/operator.py NEGATIVE)
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
function bytes(n) { return n === null || n === undefined ? "" : n >= 1e6 ? `${(n / 1e6).toFixed(1)} MB` : `${(n / 1e3).toFixed(0)} kB`; }
function badge(text, extra) { return `<span class="badge ${esc(String(text || "").replace(/[ ()]/g, "-"))} ${extra || ""}">${esc(text)}</span>`; }
function modeBadge(word, evidence) { return `<span class="badge mode ${evidence ? "real" : "not-evidence"}">${esc(word)}</span>`; }
function banner(text) { return text ? `<div class="mode-banner" id="mode-banner">${esc(text)}</div>` : ""; }
function token() { return sessionStorage.getItem(TOKEN_KEY) || ""; }
function myName() { return sessionStorage.getItem(NAME_KEY) || ""; }

function showTokenState() {
  const el = document.getElementById("token-state");
  el.textContent = token() ? "token set: controls enabled" : "read-only (set the token to control runs)";
  el.className = token() ? "ok" : "";
  document.getElementById("name-input").value = myName();
}
document.getElementById("token-form").addEventListener("submit", (ev) => {
  ev.preventDefault();
  const v = document.getElementById("token-input").value.trim();
  if (v) { sessionStorage.setItem(TOKEN_KEY, v); } else if (!document.getElementById("name-input").value.trim()) { sessionStorage.removeItem(TOKEN_KEY); }
  const name = document.getElementById("name-input").value.trim();
  if (name) { sessionStorage.setItem(NAME_KEY, name); } else { sessionStorage.removeItem(NAME_KEY); }
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
    body: JSON.stringify(Object.assign({ operator: myName() }, body)) });
  const d = await r.json().catch(() => ({}));
  if (!r.ok) {
    const why = (d.errors || [r.statusText]).join("\n");
    throw new Error(r.status === 401 || r.status === 403 ? `${why} (set the token printed by 'bench serve')` : why);
  }
  return d;
}
// a question asked on the page itself (not the browser's dialog): `ok` runs once the person confirms
function confirmBox(host, id, text, okText, cancelText, ok) {
  host.innerHTML = `<div class="confirm" id="${id}"><div class="confirm-text">${esc(text)}</div>
    <button class="stop" id="${id}-ok">${esc(okText)}</button> <button id="${id}-cancel">${esc(cancelText)}</button></div>`;
  document.getElementById(`${id}-cancel`).addEventListener("click", () => { host.innerHTML = ""; });
  document.getElementById(`${id}-ok`).addEventListener("click", () => { host.innerHTML = ""; ok(); });
  document.getElementById(`${id}-cancel`).focus();
}

// ---- runs table ------------------------------------------------------------------------------
const FILTERS = ["unit", "procedure", "status", "verdict", "mode", "since"];
async function runsPage() {
  const q = new URLSearchParams(location.search);
  const sel = (name, opts) => `<select name="${name}" id="f-${name}"><option value="">any</option>` +
    opts.map((o) => `<option${q.get(name) === o ? " selected" : ""}>${o}</option>`).join("") + "</select>";
  main.innerHTML = `<h1>Runs</h1>
    <form class="filters" id="filters">
      <label>unit<input name="unit" id="f-unit" value="${esc(q.get("unit") || "")}" placeholder="SN12 or SN*" size="10"></label>
      <label>procedure<input name="procedure" id="f-procedure" value="${esc(q.get("procedure") || "")}" placeholder="thermal_*" size="14"></label>
      <label>status${sel("status", ["running", "completed", "aborted", "failed", "crashed"])}</label>
      <label>verdict${sel("verdict", ["passed", "failed", "incomplete", "no verdict"])}</label>
      <label>mode${sel("mode", ["real", "dry-run", "replay", "imported"])}</label>
      <label>since<input name="since" id="f-since" value="${esc(q.get("since") || "")}" placeholder="7d, 2026-11-23" size="10"></label>
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
  const rows = d.runs.map((r) => `<tr class="run-row${r.evidence ? "" : " not-evidence"}" data-id="${esc(r.id)}" data-unit="${esc(r.unit_serial)}"
      data-status="${esc(r.status)}" data-mode="${esc(r.mode)}">
    <td class="nowrap">${esc((r.started_utc || "").replace("T", " ").replace(/:\d\dZ$/, ""))}</td>
    <td class="wrap">${r.id ? `<a class="run-link" href="/run?id=${encodeURIComponent(r.id)}">${esc(r.procedure_name)}</a>` : esc(r.procedure_name)}</td>
    <td>${r.unit_serial ? `<a class="unit-link" href="/unit?serial=${encodeURIComponent(r.unit_serial)}">${esc(r.unit_serial)}</a>` : ""}</td>
    <td>${modeBadge(r.mode_word, r.evidence)}</td>
    <td>${badge(r.status)}${r.waiting_for ? `<div class="muted">${esc(r.waiting_for)}</div>` : ""}</td>
    <td>${r.verdict ? badge(r.verdict_text, r.evidence ? "" : "not-evidence") : ""}</td><td class="num">${esc(r.run_time_text)}</td>
    <td class="wrap">${esc(r.station)}<div class="muted">${esc(r.operator)}</div></td>
    <td class="num">${esc(r.pressure_text)}</td><td class="num nowrap">${esc(r.temperature_text)}</td>
    <td class="wrap note">${esc(r.first_failed_check || r.reason || "")}</td></tr>`).join("");
  const dry = d.runs.filter((r) => !r.evidence).length;
  box.innerHTML = `<p class="muted" id="runs-count">${d.runs.length} run(s), newest first${dry ? `; <b>${dry} DRY-RUN(s) or replays: not acceptance evidence</b>` : ""}</p>
    <div class="table-box"><table id="runs-table"><thead><tr><th>start UTC</th><th>procedure</th><th>unit</th><th>mode</th><th>status</th><th>verdict</th>
    <th>run time</th><th>station / operator</th><th>p min Torr</th><th>T degC</th><th>note</th></tr></thead><tbody>${rows}</tbody></table></div>`;
}

// ---- run page --------------------------------------------------------------------------------
function identityHTML(d, id) {
  const idn = d.identity || {}, q = encodeURIComponent(id);
  const unit = [idn.unit_serial, idn.unit_part, idn.unit_revision].filter((x) => x).join(" / ");
  return `<dt>unit</dt><dd>${idn.unit_serial ? `<a href="/unit?serial=${encodeURIComponent(idn.unit_serial)}">${esc(unit)}</a>` : "—"}</dd>
      <dt>station</dt><dd>${esc(idn.station || "—")}</dd><dt>procedure</dt><dd>${esc(d.procedure.name)} <span class="muted">${esc(d.procedure.path)}</span></dd>
      <dt>operator</dt><dd id="operator">${esc(d.operator_text || d.operator)}</dd><dt>mode</dt><dd>${modeBadge(d.mode_word, d.evidence)} <span class="muted">${esc(d.mode)}</span></dd>
      <dt>started / ended</dt><dd>${esc(d.started_utc)} / <span id="ended">${esc(d.ended_utc || "—")}</span></dd>
      <dt>file</dt><dd><a id="download" href="/api/file?id=${q}">${esc(d.file_name)}</a> (<span id="file-size">${bytes(d.file_bytes)}</span>) ·
        <a id="report" href="/api/report?id=${q}" target="_blank">HTML report</a></dd>`;
}

async function runPage() {
  const id = new URLSearchParams(location.search).get("id") || "";
  let d;
  try { d = await getJSON("/api/run?id=" + encodeURIComponent(id)); } catch (e) { main.innerHTML = `<p class="errors">${esc(e.message)}</p>`; return; }
  main.innerHTML = `${banner(d.banner)}<h1>${esc(d.procedure.name)} <span id="run-status">${badge(d.status)}</span></h1>
    <dl class="grid" id="identity">${identityHTML(d, id)}</dl>
    <div id="verdict"></div><div id="live"></div>
    <h2>Checks</h2><div id="checks"></div>
    <h2>Steps</h2><div id="steps"></div>
    <h2>Streams</h2><p class="muted">one time axis for all: wheel to zoom, drag to pan, double-click for everything; lines break where nothing was recorded</p><div id="plots"></div>
    <h2>X–Y</h2><div class="panel" id="xy-panel"><select id="xy-x"></select> horizontal, <select id="xy-y"></select> vertical
      <button id="xy-go">Plot X–Y</button><div><canvas id="xy-canvas"></canvas></div></div>
    <h2>Events</h2><div id="events"></div>`;
  renderSummary(d);
  const plots = new window.BenchPlot.PlotSet(id, document.getElementById("plots"));
  const groups = window.BenchPlot.groupChannels(d.channels);
  for (const g of groups) { new window.BenchPlot.TimePlot(plots, g, document.getElementById("plots")); }
  document.getElementById("plots").dataset.plots = String(groups.length);
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
  const cls = d.evidence || v.word !== "PASSED" ? v.word.replace(/ /g, "-") : "not-evidence";
  document.getElementById("verdict").innerHTML = `<div class="verdict ${esc(cls)}" id="verdict-box"><span id="verdict-word">${esc(v.word)}</span>` +
    (d.evidence ? "" : ` <span id="verdict-mode" class="badge mode not-evidence">${esc(d.mode_word)}: not acceptance evidence</span>`) + "</div>" +
    `<ul>${v.reasons.map((r) => `<li>${esc(r)}</li>`).join("")}</ul>` + (d.abort_reason ? `<p><b>Reason:</b> ${esc(d.abort_reason)}</p>` : "") +
    (d.status_detail ? `<p class="muted">${esc(d.status_detail)}</p>` : "");
  document.getElementById("checks").innerHTML = d.checks.length ? `<table id="checks-table"><tr><th>check</th><th>what</th><th>value</th><th>limits</th><th>outcome</th></tr>` +
    d.checks.map((c) => `<tr><td>${esc(c.name)}</td><td class="wrap">${esc(c.what)}</td>
      <td class="num">${esc(c.value_text)}</td><td class="nowrap">${esc(c.limits_text)}</td><td>${badge(c.outcome, d.evidence ? "" : "not-evidence")}</td></tr>`).join("") +
    "</table>" : `<p class="muted">no checks</p>`;
  renderSteps(d.steps);
  const ev = d.events;
  const traffic = Object.entries(ev.traffic || {}).map(([n, t]) => `<li>${esc(n)}: ${t.polls.toLocaleString()} polls, ${t.commands.toLocaleString()} commands, ${t.replies.toLocaleString()} replies</li>`).join("");
  document.getElementById("events").innerHTML = `<p class="muted">${ev.total.toLocaleString()} events; instrument traffic summarised:</p><ul id="traffic">${traffic}</ul>` +
    `<table id="events-table"><tr><th>run time</th><th>kind</th><th>source</th><th>step</th><th>message</th></tr>` +
    ev.recent.map((e) => `<tr><td class="num">${esc(e.t_text)}</td><td>${esc(e.kind)}</td><td>${esc(e.source)}</td><td>${esc(e.step || "")}</td><td class="wrap">${esc(e.text)}</td></tr>`).join("") + "</table>";
}

function renderSteps(steps) {
  document.getElementById("steps").innerHTML = `<table id="steps-table"><tr><th>#</th><th>step</th><th>type</th><th>outcome</th><th>took</th><th>detail</th></tr>` +
    steps.map((s) => `<tr><td>${s.step}</td><td>${esc(s.name)}</td><td>${esc(s.type)}</td><td>${badge(s.outcome)}</td>
      <td class="num">${esc(s.duration_text || (s.t_end_s !== null && s.t_start_s !== null ? num(s.t_end_s - s.t_start_s) + " s" : ""))}</td><td class="wrap">${esc(s.detail || "")}</td></tr>`).join("") + "</table>";
}

function followLive(id, plots, first) {
  const box = document.getElementById("live");
  document.getElementById("verdict").innerHTML = `<p class="muted">the verdict and the checks are shown when the run ends</p>`;
  box.innerHTML = `<div class="panel live" id="live-panel"><div id="live-state"></div><div id="prompt-box"></div>
    <div id="controls"><button id="pause-btn">Pause</button> <button id="stop-btn" class="stop">Stop the run…</button>
    <span id="control-msg" class="errors"></span><div id="confirm-host"></div></div><div id="interlocks"></div><div id="limits"></div><div id="messages" class="muted"></div></div>`;
  const msg = (t) => { document.getElementById("control-msg").textContent = t || ""; };
  const act = async (url, body) => { msg(""); try { await post(url, Object.assign({ id }, body)); return true; } catch (e) { msg(e.message); return false; } };
  let paused = false, shownPrompt = null, updates = 0, stopped = false;
  document.getElementById("pause-btn").addEventListener("click", () => act("/api/pause", { paused: !paused }));
  document.getElementById("stop-btn").addEventListener("click", () => confirmBox(document.getElementById("confirm-host"), "stop-confirm-box",
    "Stop this run? The instruments go to their safe state and the run ends aborted; it cannot be resumed.",
    "Stop the run", "Keep running", () => act("/api/stop", {})));
  const sendAnswer = async (answer, confirmed) => {
    const err = document.getElementById("prompt-error");
    err.textContent = "";
    const ok = await (async () => {
      try { await post("/api/answer", { id, answer, confirm_abort: !!confirmed }); return true; } catch (e) { err.textContent = e.message; return false; }
    })();
    const text = document.getElementById("answer-text");
    if (text) { text.value = ""; if (!ok) { text.focus(); } }
  };
  const answerNo = (answer) => confirmBox(document.getElementById("prompt-confirm"), "no-confirm-box",
    `Answering "${answer}" stops the run: the instruments go to their safe state and the run ends aborted.`,
    "Stop the run", "Back to the question", () => sendAnswer(answer, true));
  const tick = async () => {
    const began = performance.now();
    let d;
    try { d = await getJSON("/api/live?id=" + encodeURIComponent(id)); } catch (e) { msg(e.message); setTimeout(tick, LIVE_PERIOD_MS); return; }
    const f = d.file, c = d.control;
    updates++; box.dataset.updates = String(updates);
    const over = !!(f && f.final) || !!(c && !c.running);
    document.getElementById("controls").hidden = !(c && c.running) || over;
    const isPaused = !!(c && c.paused && !over);
    if (f) {
      const shown = isPaused ? "paused" : f.status;
      document.getElementById("run-status").innerHTML = badge(shown);
      const cur = f.current_step ? `step ${f.current_step.step} of ${f.steps_total}: ${esc(f.current_step.name)} (${esc(f.current_step.type)})` : "";
      const est = c && c.progress.estimated_total_s ? c.progress.estimated_total_s : null;
      const frac = est ? Math.min(1, f.run_time_s / est) : (f.steps_total ? f.steps_done / f.steps_total : 0);
      document.getElementById("live-state").innerHTML = `<b id="live-word" class="${isPaused ? "paused-word" : ""}">${esc(isPaused ? "PAUSED" : f.status)}</b> · run time
        <span id="live-run-time">${hms(f.run_time_s)}</span> · ${cur}
        <div class="progress${isPaused ? " paused" : ""}"><div id="progress-bar"></div></div> <span class="muted">${f.steps_done}/${f.steps_total} steps</span>
        <div class="muted">${esc(isPaused ? "paused: timed steps are on hold, instruments stay under watch; Resume to go on" : f.status_detail)}</div>`;
      document.getElementById("progress-bar").style.width = (100 * frac).toFixed(1) + "%";
      if (f.ended_utc) { document.getElementById("ended").textContent = f.ended_utc; }
      if (f.file_bytes !== null && f.file_bytes !== undefined) { document.getElementById("file-size").textContent = bytes(f.file_bytes); }
      renderSteps(f.steps.map((s) => Object.assign({ detail: "" }, s)));
    } else if (d.error) { msg(d.error); }
    const question = over ? null : (c ? (c.prompt ? c.prompt.text : null) : (f && f.waiting_for ? f.waiting_for.prompt : null));
    if (question !== shownPrompt) {
      shownPrompt = question;
      const pb = document.getElementById("prompt-box");
      pb.innerHTML = question ? `<div class="prompt" id="prompt"><div class="question">${esc(question)}</div>` +
        (c ? `<button id="answer-yes">Yes</button> <button id="answer-no" class="stop">No — stop the run…</button>
          <span class="answer-other"><input id="answer-text" size="12" placeholder="or type yes / no"> <button id="answer-send">Send</button></span>
          <div id="prompt-error" class="prompt-error"></div><div id="prompt-confirm"></div>` :
          `<span class="muted">answer it where the run was started (this run is not controlled by this station)</span>`) + "</div>" : "";
      if (question && c) {
        document.getElementById("answer-yes").addEventListener("click", () => sendAnswer("yes", false));
        document.getElementById("answer-no").addEventListener("click", () => answerNo("no"));
        const typed = () => {
          const t = document.getElementById("answer-text").value.trim();
          if (NEGATIVE.includes(t.toLowerCase())) { answerNo(t); } else { sendAnswer(t, false); }
        };
        document.getElementById("answer-send").addEventListener("click", typed);
        document.getElementById("answer-text").addEventListener("keydown", (ev) => { if (ev.key === "Enter") { typed(); } });
      }
    }
    if (c) {
      paused = c.paused;
      document.getElementById("pause-btn").textContent = paused ? "Resume" : "Pause";
      document.getElementById("interlocks").innerHTML = c.interlocks.length ? `<table id="interlocks-table"><tr><th>interlock</th><th>signal</th><th>limits</th><th>value</th><th>state</th></tr>` +
        c.interlocks.map((i) => `<tr><td>${esc(i.name)}</td><td>${esc(i.signal)}</td><td>${esc(i.limits_text)}</td>
          <td class="num">${esc(i.value_text)}</td><td class="${i.state === "beyond" ? "bad-state" : "ok-state"}">${esc(i.state)}</td></tr>`).join("") + "</table>" : "";
      const lims = c.limits || [];
      document.getElementById("limits").innerHTML = lims.length ? `<table id="limits-table"><tr><th>limit</th><th>range</th><th>from</th><th>watched</th><th>value</th><th>state</th></tr>` +
        lims.map((l) => `<tr><td>${esc(l.instrument)} ${esc(l.quantity)}</td><td>${esc(l.limits_text)}</td>
          <td>${esc(l.source)}</td><td>${esc(l.watch || "every step, before the run")}</td><td class="num">${esc(l.value_text)}</td>
          <td class="${l.state === "beyond" ? "bad-state" : "ok-state"}">${esc(l.state)}</td></tr>`).join("") + "</table>" : "";
      document.getElementById("messages").innerHTML = c.messages.map((m) => esc(m.replace(/\[\/?[a-z ]*\]/g, "").replace(/\\\[/g, "["))).join("<br>") +
        (c.progress.readings ? `<div id="readings">${esc(c.progress.readings)}</div>` : "") + (c.error ? `<div class="errors">${esc(c.error)}</div>` : "");
    }
    if (!plots.view || plots.follow) { await plots.reload(); }
    if (over && !stopped) {
      stopped = true;
      document.getElementById("controls").hidden = true;
      document.getElementById("prompt-box").innerHTML = "";
      const full = await getJSON("/api/run?id=" + encodeURIComponent(id));
      document.getElementById("run-status").innerHTML = badge(full.status);
      document.getElementById("identity").innerHTML = identityHTML(full, id);  // ended, file size: as they are now
      renderSummary(full);
      document.getElementById("live-panel").classList.add("ended");
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
  const ops = session.operators || [];
  const opField = ops.length ? `<select id="s-operator"><option value="">choose…</option>${ops.map((o) => `<option${o === myName() ? " selected" : ""}>${esc(o)}</option>`).join("")}</select>`
    : `<input id="s-operator" placeholder="your name" value="${esc(myName())}">`;
  const lab = session.lab || {};
  main.innerHTML = `<h1>Start a run</h1>
    <div class="panel lab-line ${lab.sim_only ? "sim-lab" : "real-lab"}" id="s-lab">${esc(lab.text || "")}</div>
    <div class="panel"><div class="form-row"><label>procedure</label><select id="s-procedure">${procs.map((p) =>
      `<option value="${esc(p.name)}">${esc(p.name)}${p.title ? " — " + esc(p.title) : ""}</option>`).join("")}</select></div>
    <div id="s-info" class="muted"></div>
    <h3>Parameters <span class="muted">(leave empty for the procedure's value; write units: 30 min, -20 degC)</span></h3><div id="s-params"></div>
    <div class="form-row"><label for="s-operator">operator (required)</label>${opField}</div>
    <div class="form-row"><label for="s-unit">unit serial</label><input id="s-unit" placeholder="e.g. SN0042"></div>
    <div class="form-row"><label>lab</label><label><input type="checkbox" id="s-dry" checked ${lab.real ? "" : "disabled"}> dry-run on the simulators (not acceptance evidence)</label>
      <label><input type="checkbox" id="s-realtime" checked> at wall-clock pace (watchable)</label></div>
    <div class="form-row"><label></label><label><input type="checkbox" id="s-overdue"> run on instruments past their calibration date</label></div>
    <button id="s-plan">Show plan</button> <button id="s-start">Start run</button></div>
    <div id="s-errors" class="errors"></div><div id="s-started"></div><pre class="plan" id="s-plan-text" hidden></pre>`;
  const sel = document.getElementById("s-procedure");
  const showProc = () => {
    const p = procs.find((x) => x.name === sel.value);
    if (!p) { return; }
    document.getElementById("s-info").textContent = p.error ? p.error :
      `${p.procedure}: ${p.steps} steps on ${p.instruments.join(", ")}; ${p.prompts} operator prompt${p.prompts === 1 ? "" : "s"}` +
      (p.description ? ` — ${p.description}` : "");
    const notes = p.parameter_notes || {};
    document.getElementById("s-params").innerHTML = Object.entries(p.parameters || {}).map(([k, v]) =>
      `<div class="form-row param-row"><label for="p-${esc(k)}">${esc(k)}</label><input class="s-param" id="p-${esc(k)}" data-name="${esc(k)}" placeholder="default">
        <span class="default">default <b>${esc(v)}</b></span>${notes[k] ? `<div class="param-note">${esc(notes[k])}</div>` : ""}</div>`).join("") ||
      `<p class="muted">no parameters</p>`;
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
    const operator = document.getElementById("s-operator").value.trim();
    if (operator) { sessionStorage.setItem(NAME_KEY, operator); showTokenState(); }
    try {
      const d = await post("/api/start", { procedure: sel.value, params: params(), unit: document.getElementById("s-unit").value, operator,
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
        <td>${f ? badge(c && c.paused && c.running ? "paused" : f.status) : ""}</td><td>${f && f.current_step ? esc(f.current_step.name) : ""}</td><td class="num">${f ? hms(f.run_time_s) : ""}</td>
        <td>${c && c.prompt ? esc(c.prompt.text) : ""}</td></tr>`;
    }).join("") + "</table>";
  clearTimeout(renderStarted.timer);
  renderStarted.timer = setTimeout(renderStarted, LIVE_PERIOD_MS);
}

// ---- a unit's history ------------------------------------------------------------------------
async function unitPage() {
  const q = new URLSearchParams(location.search);
  const serial = q.get("serial") || "";
  let d;
  try { d = await getJSON("/api/unit?" + new URLSearchParams({ serial, part: q.get("part") || "" }).toString()); }
  catch (e) { main.innerHTML = `<h1>Unit ${esc(serial)}</h1><p class="errors">${esc(e.message)}</p>`; return; }
  const runs = d.runs.map((r, i) => `<tr class="unit-run${r.evidence ? "" : " not-evidence"}" data-mode="${esc(r.mode)}"><td>${i + 1}</td>
    <td class="nowrap">${esc((r.started_utc || "").replace("T", " ").replace(/:\d\dZ$/, ""))}</td>
    <td>${r.id ? `<a href="/run?id=${encodeURIComponent(r.id)}">${esc(r.procedure)}</a>` : esc(r.procedure)}</td><td>${esc(r.station)}</td>
    <td>${modeBadge(r.mode_word, r.evidence)}</td><td>${r.verdict ? badge(r.verdict_text, r.evidence ? "" : "not-evidence") : badge(r.status)}</td>
    <td>${esc(r.first_failed_check || "")}</td><td>${esc(r.operator)}</td></tr>`).join("");
  main.innerHTML = (d.dry_runs ? banner(`${d.dry_runs} of ${d.runs.length} runs of ${d.serial} are DRY-RUNs or replays: shown hollow and marked, never acceptance evidence`) : "") +
    `<h1>Unit ${esc(d.serial)} <span class="muted">part ${esc(d.part || "not recorded")}</span></h1>
    <p>${d.lot_units.length ? `Its lot: ${d.lot_units.length} other unit(s) of ${esc(d.part)}: ${d.lot_units.map((u) => `<a href="/unit?serial=${encodeURIComponent(u)}">${esc(u)}</a>`).join(", ")}` : "No other unit of its part number is catalogued."}
      · <a id="unit-package" href="/api/unit_package?serial=${encodeURIComponent(d.serial)}">acceptance data package (one HTML file)</a></p>
    ${d.notes.map((n) => `<p class="muted">note: ${esc(n)}</p>`).join("")}
    <h2>Runs</h2><div class="table-box"><table id="unit-runs"><tr><th>#</th><th>start UTC</th><th>procedure</th><th>station</th><th>mode</th><th>verdict</th><th>first failed check</th><th>operator</th></tr>${runs}</table></div>
    <h2>Key figures</h2><p class="muted">each figure by date (● real run, ○ dry-run) and against the other units of ${esc(d.part || "its part number")} (their latest real value; band: the lot's median ± 3.5 robust spreads)</p>
    <div id="figures">${d.figures.length ? "" : `<p class="muted">none of its runs recorded a check of bias, scale-factor error or noise on a sensor axis</p>`}</div>`;
  const box = document.getElementById("figures");
  for (const f of d.figures) {
    const el = document.createElement("div"); el.className = "figure" + (f.outlier ? " outlier" : "");
    el.dataset.name = f.name; el.dataset.outlier = f.outlier ? "1" : "0";
    el.innerHTML = `<h3>${esc(f.name)} <span class="muted">[${esc(f.units)}]</span> <span class="figure-verdict ${f.outlier ? "bad-state" : ""}">${esc(f.verdict)}${f.z !== null ? ` (z ${f.z >= 0 ? "+" : ""}${f.z.toFixed(1)})` : ""}</span></h3>
      <div class="figure-row"><canvas class="by-date"></canvas><canvas class="by-lot"></canvas></div>
      <div class="muted">latest ${esc(f.latest ? f.latest.text : "-")}${f.latest && !f.latest.evidence ? " (dry-run)" : ""}; lot median ${esc(f.lot_median_text || "-")} (${f.lot.length} units)</div>`;
    box.appendChild(el);
    drawUnitFigure(el, d, f);
  }
  let timer = null, width = box.clientWidth;
  new ResizeObserver(() => {
    if (box.clientWidth === width) { return; }
    width = box.clientWidth; clearTimeout(timer);
    timer = setTimeout(() => { box.querySelectorAll(".figure").forEach((el, i) => drawUnitFigure(el, d, d.figures[i])); }, 100);
  }).observe(box);
}

function drawUnitFigure(el, d, f) {
  const P = window.BenchPlot, M = P.MARGIN;
  const row = el.querySelector(".figure-row");
  const full = Math.max(600, (row && row.clientWidth) || 900);
  const w1 = Math.floor(full * 0.58), w2 = full - w1 - 16, h = 220;
  const times = f.points.map((p) => Date.parse(p.utc) / 1000), values = f.points.map((p) => p.value);
  const lotValues = f.lot.map((v) => v.value);
  const yr = P.range([values, lotValues, f.lot_median === null ? [] : [f.lot_median]]);
  const c1 = el.querySelector(".by-date"), c2 = el.querySelector(".by-lot");
  let ctx = P.setupCanvas(c1, w1, h);
  const t0 = Math.min(...times), t1 = Math.max(...times), pad = Math.max(86400, (t1 - t0) * 0.05);
  const fmtDate = (s) => new Date(s * 1000).toISOString().slice(0, 10);
  const days = Math.max(1, Math.ceil((t1 - t0 + 2 * pad) / 86400 / Math.max(2, Math.floor((w1 - M.left) / 90))));
  const xticks = [];
  for (let s = Math.ceil((t0 - pad) / 86400) * 86400; s <= t1 + pad; s += days * 86400) { xticks.push([s, fmtDate(s)]); }
  const a1 = P.drawAxes(ctx, w1, h, [t0 - pad, t1 + pad], yr, "run start (UTC date)", `${f.name} [${f.units}]`, { xticks });
  if (f.lot_median !== null) { ctx.strokeStyle = "#888"; ctx.setLineDash([5, 4]); ctx.beginPath(); ctx.moveTo(M.left, a1.Y(f.lot_median)); ctx.lineTo(w1 - M.right, a1.Y(f.lot_median)); ctx.stroke(); ctx.setLineDash([]); }
  let real = 0, dry = 0;
  f.points.forEach((p, i) => {
    ctx.beginPath(); ctx.arc(a1.X(times[i]), a1.Y(p.value), 5, 0, 2 * Math.PI);
    ctx.strokeStyle = "#1f5fa8"; ctx.lineWidth = 2;
    if (p.evidence) { ctx.fillStyle = "#1f5fa8"; ctx.fill(); real++; } else { ctx.stroke(); dry++; }
  });
  c1.dataset.real = String(real); c1.dataset.dry = String(dry);
  // against the lot: each other unit's latest value, this unit's latest in red
  ctx = P.setupCanvas(c2, w2, h);
  const serials = f.lot.map((v) => v.serial).concat([d.serial]);
  const a2 = P.drawAxes(ctx, w2, h, yr, [-0.5, serials.length - 0.5], `${f.name} [${f.units}]`, `${d.serial} among ${d.part || "its lot"}`,
    { yticks: serials.map((s, i) => [i, s]) });
  if (f.lot_median !== null && f.lot_spread) {
    ctx.fillStyle = "rgba(120,120,120,0.15)";
    const xa = a2.X(f.lot_median - 3.5 * f.lot_spread), xb = a2.X(f.lot_median + 3.5 * f.lot_spread);
    ctx.fillRect(Math.max(M.left, xa), M.top, Math.min(w2 - M.right, xb) - Math.max(M.left, xa), h - M.top - M.bottom);
  }
  f.lot.forEach((v, i) => { ctx.beginPath(); ctx.arc(a2.X(v.value), a2.Y(i), 4.5, 0, 2 * Math.PI); ctx.strokeStyle = ctx.fillStyle = "#777"; if (v.evidence) { ctx.fill(); } else { ctx.stroke(); } });
  if (f.latest) {
    const x = a2.X(f.latest.value), y = a2.Y(serials.length - 1);
    ctx.beginPath(); ctx.moveTo(x, y - 7); ctx.lineTo(x + 7, y); ctx.lineTo(x, y + 7); ctx.lineTo(x - 7, y); ctx.closePath();
    ctx.fillStyle = ctx.strokeStyle = "#c62828"; if (f.latest.evidence) { ctx.fill(); } else { ctx.stroke(); }
  }
  c2.dataset.units = String(serials.length);
}

// ---- routing ---------------------------------------------------------------------------------
const route = { "/": runsPage, "/run": runPage, "/start": startPage, "/unit": unitPage }[location.pathname] || runsPage;
window.addEventListener("popstate", () => route());
route().catch((e) => { main.innerHTML = `<p class="errors">${esc(e.message)}</p>`; });
