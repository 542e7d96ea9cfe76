// cabinplan operator page: plan list, submit form, 3D scene, clearance and drive curves; assembly cycles (legs
// and events on the time axis, the unit on its dock, held, then in its bay) and campaigns (the units with
// their status, the cabin filling up as the scrub runs through the units).
// Every pose drawn here comes from the service (GET /api/v1/plans/{id}/scene, computed by the planner's own
// robot model); this file does no kinematics. A read-only hook, window.cabinplanViewer.state(), reports
// what is drawn (for the browser tests and for support).
import yaml from 'js-yaml';
import { Scene3D, webglAvailable } from './scene3d.js';
import { ClearanceChart, DriveCharts } from './charts.js';

const API = '/api/v1';
const KEY_STORE = 'cabinplan.apiKey';
const $ = (sel) => document.querySelector(sel);

const state = {
  view: null,
  mode: null,          // 'plan' | 'refusal' | 'pprs6' | 'cycle' | 'campaign'
  planId: null,
  jobPath: null,       // '/plans/{id}', '/cycles/{id}', '/campaigns/{id}'
  job: null,           // the job document (cycles and campaigns)
  scene: null,         // the scene document
  result: null,        // the plan's result document (profile or refusal)
  frame: 0,
  t: 0,
  playing: false,
  speed: 1,
  ready: false,
  error: null,
  webgl: null,
  lastAuthMessage: null,
};
let viewer3d = null;
let clearanceChart = null;
let driveCharts = null;
let listTimer = null;
let planTimer = null;

// ------------------------------------------------------------------------------------------------- API
function apiKey() { return sessionStorage.getItem(KEY_STORE) || ''; }

class ApiError extends Error {
  constructor(status, problem) {
    super(problem && problem.detail ? problem.detail : `HTTP ${status}`);
    this.status = status;
    this.problem = problem || {};
  }
}

async function api(path, options = {}) {
  const headers = Object.assign({}, options.headers || {});
  const key = apiKey();
  if (key) headers['X-API-Key'] = key;
  const resp = await fetch(API + path, Object.assign({}, options, { headers }));
  if (!resp.ok) {
    let problem = null;
    try { problem = await resp.json(); } catch (e) { problem = null; }
    const err = new ApiError(resp.status, problem);
    if (resp.status === 401) showAuthProblem(err);
    throw err;
  }
  hideAuthProblem();
  const type = resp.headers.get('content-type') || '';
  return type.includes('json') ? resp.json() : resp;
}

function showAuthProblem(err) {
  const box = $('#auth-message');
  const msg = apiKey()
    ? `The API key was refused: ${err.message}. Enter a valid key above (ask your administrator, or use the ` +
      'key that "make serve" prints).'
    : 'No API key: enter your API key above (the local key is printed by "make serve").';
  box.textContent = msg;
  box.hidden = false;
  state.lastAuthMessage = msg;
}
function hideAuthProblem() { $('#auth-message').hidden = true; state.lastAuthMessage = null; }

function status(text, isError = false) {
  const el = $('#status-line');
  el.textContent = text;
  el.classList.toggle('error', isError);
  el.hidden = !text;
  if (isError) state.error = text;
}

function describeError(err) {
  if (err instanceof ApiError) {
    const p = err.problem;
    const fields = (p.errors || []).map((e) => `${e.field}: ${e.reason}`).join('; ');
    return `${err.status} ${p.title || ''}: ${err.message}${fields ? ` (${fields})` : ''}`;
  }
  return String(err && err.message ? err.message : err);
}

// ------------------------------------------------------------------------------------------- formatting
const fmt = (v, digits = 3) => (v === null || v === undefined || Number.isNaN(v) ? '–' : Number(v).toFixed(digits));
function mm(v) {
  if (v === null || v === undefined) return '–';
  if (v <= 0) return 'in contact';
  return `${(1000 * v).toFixed(1)} mm`;
}
function esc(text) {
  return String(text).replace(/[&<>"']/g, (c) => ({ '&': '&amp;', '<': '&lt;', '>': '&gt;', '"': '&quot;', "'": '&#39;' }[c]));
}
function when(seconds) { return seconds ? new Date(seconds * 1000).toLocaleString() : '–'; }

// ---------------------------------------------------------------------------------------------- routing
function route() {
  const hash = location.hash || '#/plans';
  stopTimers();
  for (const el of document.querySelectorAll('.view')) el.hidden = true;
  status('');
  const m = hash.match(/^#\/plan\/([0-9a-f]+)$/);
  if (m) { state.view = 'plan'; $('#view-plan').hidden = false; openPlan(m[1]); return; }
  const t = hash.match(/^#\/(cycle|campaign)\/([0-9a-f]+)$/);
  if (t) { state.view = t[1]; $('#view-plan').hidden = false; openTask(t[1], t[2]); return; }
  if (hash === '#/pprs6') {
    state.view = 'pprs6';
    $('#view-pprs6').hidden = false;
    resetPlanView('pprs6: submit a pose path (empty: the paper\'s E-F-G-H-E)');
    return;
  }
  state.view = 'plans';
  $('#view-plans').hidden = false;
  loadPlans();
}

function stopTimers() {
  if (listTimer) clearTimeout(listTimer);
  if (planTimer) clearTimeout(planTimer);
  listTimer = planTimer = null;
  state.playing = false;
}

// ------------------------------------------------------------------------------------------ plan list
async function loadPlans() {
  if (!apiKey()) { showAuthProblem(new ApiError(401, null)); return; }
  let page;
  try { page = await api('/plans?limit=50'); } catch (err) { if (err.status !== 401) status(describeError(err), true); return; }
  const body = $('#plan-table tbody');
  body.innerHTML = '';
  for (const job of page.items) {
    const tr = document.createElement('tr');
    tr.dataset.plan = job.id;
    const progress = job.status === 'running' || job.status === 'queued'
      ? `<progress max="1" value="${job.progress || 0}"></progress> ${Math.round(100 * (job.progress || 0))}% ${esc(job.stage || '')}`
      : (job.status === 'succeeded' ? '100%' : '');
    const reason = job.reason ? `<b>${esc(job.reason.replaceAll('_', ' '))}</b>: ${esc(job.message || '')}` : '';
    tr.innerHTML = `<td>${esc(job.scenario.name || job.id.slice(0, 8))}</td>` +
      `<td class="status-${job.status}">${job.status}</td><td>${progress}</td><td>${reason}</td><td>${when(job.created_at)}</td>`;
    tr.addEventListener('click', () => { location.hash = `#/plan/${job.id}`; });
    body.appendChild(tr);
  }
  $('#plan-empty').hidden = page.items.length > 0;
  const active = await loadTasks();
  if (active || page.items.some((j) => j.status === 'queued' || j.status === 'running')) {
    listTimer = setTimeout(loadPlans, 1500);
  }
}

// The tenant's cycles and campaigns, newest first; whether any is still active.
async function loadTasks() {
  let cycles;
  let campaigns;
  try {
    [cycles, campaigns] = await Promise.all([api('/cycles?limit=25'), api('/campaigns?limit=25')]);
  } catch (err) { if (err.status !== 401) status(describeError(err), true); return false; }
  const jobs = [...cycles.items.map((j) => ['cycle', j]), ...campaigns.items.map((j) => ['campaign', j])]
    .sort((a, b) => b[1].created_at - a[1].created_at);
  const body = $('#task-table tbody');
  body.innerHTML = '';
  for (const [kind, job] of jobs) {
    const tr = document.createElement('tr');
    tr.dataset.kind = kind;
    tr.dataset.job = job.id;
    const units = job.units ? ` (${job.units.filter((u) => u.status === 'planned').length}/${job.units.length} units planned)` : '';
    const progress = job.status === 'running' || job.status === 'queued'
      ? `<progress max="1" value="${job.progress || 0}"></progress> ${Math.round(100 * (job.progress || 0))}% ${esc(job.stage || '')}${esc(units)}`
      : (job.status === 'succeeded' ? `100%${esc(units)}` : esc(units));
    const reason = job.reason ? `<b>${esc(job.reason.replaceAll('_', ' '))}</b>: ${esc(job.message || '')}` : '';
    const name = (job[kind] && job[kind].name) || job.id.slice(0, 8);
    tr.innerHTML = `<td>${kind}</td><td>${esc(name)}</td><td class="status-${job.status}">${job.status}</td>` +
      `<td>${progress}</td><td>${reason}</td><td>${when(job.created_at)}</td>`;
    tr.addEventListener('click', () => { location.hash = `#/${kind}/${job.id}`; });
    body.appendChild(tr);
  }
  $('#task-empty').hidden = jobs.length > 0;
  return jobs.some(([, j]) => j.status === 'queued' || j.status === 'running');
}

async function loadExamples() {
  try {
    const resp = await fetch('./examples/index.json');
    const index = await resp.json();
    const sel = $('#submit-example');
    for (const item of index.examples) {
      const opt = document.createElement('option');
      opt.value = item.file;
      opt.textContent = `${item.name} – ${item.summary}`;
      sel.appendChild(opt);
    }
  } catch (err) { /* the form still takes files */ }
}

async function readScenario() {
  const file = $('#submit-file').files[0];
  const example = $('#submit-example').value;
  let text;
  if (file) text = await file.text();
  else if (example) text = await (await fetch(`./examples/${example}`)).text();
  else throw new Error('choose a reference scenario or a scenario file');
  const data = yaml.load(text);
  if (!data || typeof data !== 'object') throw new Error('the scenario file is not a YAML/JSON mapping');
  return data;
}

async function submitPlan(ev) {
  ev.preventDefault();
  const out = $('#submit-result');
  out.textContent = 'submitting…';
  try {
    const scenario = await readScenario();
    const mesh = $('#submit-mesh').files[0];
    if (mesh) {
      const form = new FormData();
      form.append('file', mesh, mesh.name);
      form.append('units', $('#submit-units').value);
      form.append('name', mesh.name);
      const cabin = await api('/cabins', { method: 'POST', body: form });
      scenario.cabin = { mesh: cabin.id, units: cabin.units };
    }
    const job = await api('/plans', {
      method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(scenario),
    });
    out.textContent = `queued as ${job.id}`;
    location.hash = `#/plan/${job.id}`;
  } catch (err) {
    out.textContent = describeError(err);
  }
}

// ------------------------------------------------------------------------------------------- one plan
function resetPlanView(title) {
  state.ready = false;
  state.mode = null;
  state.scene = null;
  state.result = null;
  state.job = null;
  state.jobPath = null;
  state.error = null;
  $('#plan-title').textContent = title;
  $('#timeline').hidden = true;
  $('#leg-readout').hidden = true;
  $('#units-panel').hidden = true;
  $('#refusal').hidden = true;
  $('#plan-progress').hidden = true;
  $('#figures').innerHTML = '';
  $('#provenance').innerHTML = '';
  $('#closest-readout').textContent = '';
  $('#clearance-value').textContent = '';
  $('#clearance-panel').hidden = true;
  $('#drive-panel').hidden = true;
  $('#legend').innerHTML = '';
  $('#player').hidden = false;
  if (viewer3d) viewer3d.clear();
  if (clearanceChart) { clearanceChart.destroy(); clearanceChart = null; }
  if (driveCharts) { driveCharts.destroy(); driveCharts = null; }
  $('#view-plan').hidden = false;
}

async function openPlan(id) {
  resetPlanView(`plan ${id.slice(0, 12)}`);
  state.planId = id;
  state.jobPath = `/plans/${id}`;
  if (!apiKey()) { showAuthProblem(new ApiError(401, null)); return; }
  let job;
  try { job = await api(`/plans/${id}`); } catch (err) {
    if (err.status !== 401) status(describeError(err), true);
    return;
  }
  $('#plan-title').textContent = `${job.scenario.name || 'plan'} – ${job.status}`;
  if (job.status === 'queued' || job.status === 'running') {
    const box = $('#plan-progress');
    box.hidden = false;
    box.querySelector('progress').value = job.progress || 0;
    box.querySelector('span').textContent = `${job.status} ${job.stage || ''} ${Math.round(100 * (job.progress || 0))}%`;
    planTimer = setTimeout(() => openPlan(id), 1000);
    return;
  }
  state.result = job.result;
  let scene;
  try { scene = await api(`/plans/${id}/scene`); } catch (err) { status(describeError(err), true); return; }
  state.scene = scene;
  if (scene.kind === 'refusal') showRefusal(job, scene); else showPlan(job, scene);
}

function ensure3d() {
  if (viewer3d) return viewer3d;
  state.webgl = webglAvailable();
  if (!state.webgl) {
    const box = $('#webgl-message');
    box.textContent = 'This browser cannot show the 3D scene: WebGL is not available (turned off, or no graphics ' +
      'support). The figures, the clearance and the drive curves below are still shown.';
    box.hidden = false;
    return null;
  }
  try {
    viewer3d = new Scene3D($('#scene-canvas'));
  } catch (err) {
    state.webgl = false;
    const box = $('#webgl-message');
    box.textContent = `This browser cannot show the 3D scene: creating a WebGL context failed (${err.message}).`;
    box.hidden = false;
    return null;
  }
  return viewer3d;
}

async function buildScene(scene, withCabin) {
  const v = ensure3d();
  if (!v) return;
  v.setBodies(scene.bodies);
  if (scene.frames) v.showFrame(scene.frames, 0, null); // posed before the camera frames them
  if (withCabin) {
    try { await v.loadCabin(`${API}${state.jobPath}/cabin.glb`, apiKey()); } catch (err) {
      status(`the cabin mesh could not be loaded: ${err.message}`, true);
    }
  }
  v.setMarkers(scene);
  v.frameCamera();
  renderLegend(scene);
}

function renderLegend(scene) {
  const items = [['#8fa3bf', 'robot bodies'], ['#f59e0b', 'payload'], ['#ef4444', 'closest pair / contact'],
    ['#22d3ee', 'approach line'], ['#9ca3af', 'cabin']];
  if (scene.kind === 'pprs6') items.splice(0, 5, ['#8fa3bf', 'chains'], ['#f59e0b', 'platform'], ['#22d3ee', 'workspace boundary']);
  $('#legend').innerHTML = items.map(([c, t]) => `<div><span style="background:${c}"></span>${t}</div>`).join('');
}

async function showPlan(job, scene) {
  state.mode = 'plan';
  await buildScene(scene, scene.has_cabin);
  figures(job, scene);
  const frames = scene.frames;
  const duration = frames.t_s[frames.t_s.length - 1];
  setupPlayer(duration, job.result.sample_period_s);
  $('#clearance-panel').hidden = false;
  clearanceChart = new ClearanceChart($('#clearance-chart'), scene.clearance, scene.clearance_m, (t) => setTime(t));
  $('#drive-panel').hidden = false;
  driveCharts = new DriveCharts($('#drive-charts'), $('#drive-select'), job.result, scene, (t) => setTime(t));
  setTime(0);
  state.ready = true;
}

function showRefusal(job, scene) {
  state.mode = 'refusal';
  const box = $('#refusal');
  box.hidden = false;
  $('#refusal-reason').textContent = (scene.reason || job.reason || job.status).replaceAll('_', ' ');
  $('#refusal-message').textContent = scene.message || job.message || '';
  const details = scene.details || {};
  $('#refusal-details').innerHTML = Object.entries(details)
    .map(([k, v]) => `<tr><th>${esc(k)}</th><td>${esc(evidenceText(k, v))}</td></tr>`).join('') ||
    '<tr><td class="muted">no further evidence</td></tr>';
  const cfg = scene.configuration;
  const list = $('#refusal-contacts');
  list.innerHTML = '';
  if (cfg) {
    $('#refusal-config').textContent = `Shown below: ${scene.configuration_source}` +
      (cfg.closest && cfg.closest.pair ? `; closest pair ${cfg.closest.pair.join(' – ')}: ${mm(cfg.closest.distance_m)}` : '');
    for (const c of cfg.contacts) {
      const li = document.createElement('li');
      li.textContent = `${c.kind}: ${c.detail}`;
      list.appendChild(li);
    }
  } else {
    $('#refusal-config').textContent = scene.configuration_source || '';
  }
  $('#player').hidden = true;
  $('#figures').innerHTML = [
    row('status', job.status, ''),
    row('reason', scene.reason || job.reason || '–', ''),
    row('requested clearance', mm(scene.clearance_m)),
    row('configuration valid', cfg ? (cfg.valid ? 'yes' : 'no') : '–', ''),
    row('contacts there', cfg ? String(cfg.contacts.length) : '–'),
  ].join('');
  provenance(scene.provenance || {});
  (async () => {
    if (cfg) {
      await buildScene(scene, scene.has_cabin);
      if (viewer3d) {
        const offending = new Set();
        for (const c of cfg.contacts) for (const b of c.bodies) offending.add(b);
        if (cfg.closest && cfg.closest.pair) for (const b of cfg.closest.pair) offending.add(b);
        viewer3d.showFrame(scene.frames, 0, { pair: [...offending], a: cfg.closest && cfg.closest.point_a_m, b: cfg.closest && cfg.closest.point_b_m });
      }
    }
    state.frame = 0;
    state.ready = true;
  })();
}

function row(label, value, cls = 'num') { return `<tr><th>${esc(label)}</th><td class="${cls}">${esc(value)}</td></tr>`; }

function figures(job, scene) {
  const r = job.result;
  const rep = r.report || {};
  const gate = rep.gate || {};
  const peaks = gate.peak_ratios || {};
  $('#figures').innerHTML = [
    row('duration', `${fmt(r.duration_s)} s`),
    row('samples', `${r.t.length} every ${fmt(1000 * r.sample_period_s, 1)} ms`),
    row('single-drive lower bound', `${fmt(rep.single_drive_lower_bound_s)} s`),
    row('duration / lower bound', fmt(rep.duration_ratio, 2)),
    row('staged lower bound ratio', fmt(rep.staged_duration_ratio, 2)),
    row('min clearance (every sample, exact)', mm(r.min_clearance_m)),
    row('min clearance (between samples, certified ≥)', mm(gate.min_clearance_bound_m)),
    row('closest', gate.min_clearance_at
      ? `${gate.min_clearance_at.bodies.join(' – ')}${gate.min_clearance_at.leg ? ` on ${gate.min_clearance_at.leg}` : ''} at ${fmt(gate.min_clearance_at.t_s, 2)} s` : '–', ''),
    row('min clearance (these frames)', mm(scene.min_clearance_m)),
    row('requested clearance', mm(scene.clearance_m)),
    ...(scene.certified_clearance_m > scene.clearance_m
      ? [row('certified (+ STEP tessellation)', mm(scene.certified_clearance_m))] : []),
    row('planning time', `${fmt(rep.planning_time_s, 2)} s`),
    row('gate', gate.passed ? `passed (${(gate.checks || []).length} checks)` : 'FAILED', ''),
    row('peak velocity / limit', `${fmt(100 * (peaks.velocity || 0), 1)} %`),
    row('peak acceleration / limit', `${fmt(100 * (peaks.acceleration || 0), 1)} %`),
    row('peak force / limit', `${fmt(100 * (peaks.effort || 0), 1)} %`),
  ].join('');
  provenance(r.provenance || job.provenance || {});
}

function provenance(p) {
  const code = p.code || {};
  $('#provenance').innerHTML = [
    row(p.cycle_sha256 ? 'cycle' : 'scenario', p.cycle_sha256 || p.scenario_sha256 || '–', 'hash'),
    row('robot description', p.robot_description_sha256 || '–', 'hash'),
    row('cabin mesh', p.cabin_mesh_sha256 || 'free space', 'hash'),
    row('cabin', p.cabin_source || '–', ''),
    row('planner source', code.source_sha256 ? `${code.version} ${code.source_sha256}` : '–', 'hash'),
  ].join('');
}

// ------------------------------------------------------------------------------------------- playback
function setupPlayer(duration, period) {
  const scrub = $('#scrub');
  scrub.min = '0';
  scrub.max = String(duration);
  scrub.step = String(period || 0.001);
  scrub.value = '0';
}

function nearestFrame(times, t) {
  let lo = 0;
  let hi = times.length - 1;
  while (hi - lo > 1) {
    const mid = (lo + hi) >> 1;
    if (times[mid] <= t) lo = mid; else hi = mid;
  }
  return Math.abs(times[hi] - t) < Math.abs(t - times[lo]) ? hi : lo;
}

function setTime(t) {
  const scene = state.scene;
  if (!scene || !scene.frames) return;
  const times = scene.frames.t_s;
  const duration = times[times.length - 1];
  t = Math.min(Math.max(Number(t) || 0, 0), duration);
  const i = nearestFrame(times, t);
  state.t = t;
  state.frame = i;
  $('#scrub').value = String(t);
  $('#time-readout').textContent = `t = ${times[i].toFixed(3)} s (frame ${i + 1}/${times.length})`;
  if (scene.kind === 'plan') {
    const c = scene.clearance;
    const pair = c.pair[i];
    if (viewer3d) viewer3d.showFrame(scene.frames, i, { pair: pair || [], a: c.point_a_m[i], b: c.point_b_m[i] });
    const text = pair ? `${pair[0]} – ${pair[1]}: ${mm(c.distance_m[i])}` : 'no cabin and no body pair';
    $('#closest-readout').textContent = `closest pair at t = ${times[i].toFixed(3)} s: ${text}`;
    $('#clearance-value').textContent = `clearance at t = ${times[i].toFixed(3)} s: ${mm(c.distance_m[i])}` +
      (pair ? ` (${pair[0]} – ${pair[1]})` : '');
    $('#clearance-value').dataset.distanceM = String(c.distance_m[i]);
  } else if (scene.kind === 'pprs6' && viewer3d) {
    viewer3d.showPprs6Frame(scene.frames, i);
  } else if (scene.kind === 'cycle' || scene.kind === 'campaign') {
    showTaskTime(scene, i, t);
  }
  if (clearanceChart) clearanceChart.cursor(times[i]);
  if (driveCharts) driveCharts.cursor(times[i]);
}

let lastTick = null;
function tick(now) {
  if (state.playing && state.scene && state.scene.frames) {
    const times = state.scene.frames.t_s;
    const dt = lastTick === null ? 0 : (now - lastTick) / 1000;
    let t = state.t + dt * state.speed;
    if (t >= times[times.length - 1]) { t = times[times.length - 1]; state.playing = false; $('#play').textContent = 'Play'; }
    setTime(t);
  }
  lastTick = now;
  requestAnimationFrame(tick);
}

// ----------------------------------------------------------------------------------------------- pprs6
async function submitPprs6(ev) {
  ev.preventDefault();
  resetPlanView('pprs6 pose path');
  $('#view-pprs6').hidden = false;
  const out = $('#pprs6-result');
  out.textContent = 'planning…';
  let body = {};
  const text = $('#pprs6-path').value.trim();
  try {
    if (text) body = { path: JSON.parse(text) };
  } catch (err) { out.textContent = `the path is not JSON: ${err.message}`; return; }
  let doc;
  try {
    doc = await api('/robots/pprs6/scene', {
      method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(body),
    });
  } catch (err) { out.textContent = describeError(err); return; }
  out.textContent = `${doc.profile.path.name || 'path'}: ${fmt(doc.profile.duration_s, 2)} s, ` +
    `${doc.profile.t.length} samples; workspace boundary: ${doc.scene.workspace.count} points`;
  state.mode = 'pprs6';
  state.scene = doc.scene;
  state.result = doc.profile;
  const v = ensure3d();
  if (v) { v.setPprs6(doc.scene); v.frameCamera(); }
  renderLegend(doc.scene);
  setupPlayer(doc.scene.frames.t_s[doc.scene.frames.t_s.length - 1], doc.profile.sample_period_s);
  $('#figures').innerHTML = [
    row('duration', `${fmt(doc.profile.duration_s)} s`),
    row('samples', `${doc.profile.t.length}`),
    row('waypoints', `${doc.profile.path.waypoints.length}`),
    row('workspace boundary points', `${doc.scene.workspace.count}`),
  ].join('');
  $('#provenance').innerHTML = row('robot description', doc.profile.provenance.robot_description_sha256, 'hash');
  $('#drive-panel').hidden = false;
  driveCharts = new DriveCharts($('#drive-charts'), $('#drive-select'), doc.profile, null, (t) => setTime(t));
  setTime(0);
  state.ready = true;
}

// --------------------------------------------------------------------------------- cycles and campaigns
const LEG_COLORS = {
  pre_grasp: '#2563eb', grasp_line: '#0891b2', grasp: '#16a34a', lift_off: '#65a30d', transit: '#7c3aed',
  insertion: '#c026d3', release: '#db2777', retract: '#ea580c', park: '#64748b',
};

async function openTask(kind, id) {
  resetPlanView(`${kind} ${id.slice(0, 12)}`);
  state.planId = id;
  state.jobPath = `/${kind}s/${id}`;
  if (!apiKey()) { showAuthProblem(new ApiError(401, null)); return; }
  let job;
  try { job = await api(state.jobPath); } catch (err) {
    if (err.status !== 401) status(describeError(err), true);
    return;
  }
  state.job = job;
  const name = (job[kind] && job[kind].name) || kind;
  $('#plan-title').textContent = `${kind} ${name} – ${job.status}`;
  const units = (job.result && job.result.units) || job.units;
  if (kind === 'campaign') renderUnits(units || [], null);
  if (job.status === 'queued' || job.status === 'running') {
    const box = $('#plan-progress');
    box.hidden = false;
    box.querySelector('progress').value = job.progress || 0;
    box.querySelector('span').textContent = `${job.status} ${job.stage || ''} ${Math.round(100 * (job.progress || 0))}%`;
    planTimer = setTimeout(() => openTask(kind, id), 1000);
    return;
  }
  state.result = job.result;
  let scene;
  try { scene = await api(`${state.jobPath}/scene`); } catch (err) { status(describeError(err), true); return; }
  state.scene = scene;
  if (scene.kind === 'refusal') { showTaskRefusal(kind, job, scene); return; }
  await showTask(kind, job, scene);
}

function renderUnits(units, scene) {
  const panel = $('#units-panel');
  panel.hidden = false;
  const body = $('#unit-table tbody');
  body.innerHTML = '';
  for (const [k, u] of units.entries()) {
    const tr = document.createElement('tr');
    tr.dataset.unit = u.id;
    tr.dataset.status = u.status;
    const dur = u.duration_s !== undefined && u.duration_s !== null ? `${fmt(u.duration_s, 1)} s` : '';
    tr.innerHTML = `<td>${u.position || k + 1}</td><td>${esc(u.id)}</td>` +
      `<td class="status-${esc(u.status)}" title="${esc(u.message || '')}">${esc(u.status.replaceAll('_', ' '))}</td><td>${dur}</td>`;
    if (scene) {
      const entry = scene.units.find((x) => x.id === u.id);
      if (entry && entry.cycle !== null && entry.cycle !== undefined) {
        tr.style.cursor = 'pointer';
        tr.addEventListener('click', () => setTime(scene.cycles[entry.cycle].t_start_s));
      }
    }
    body.appendChild(tr);
  }
  const planned = units.filter((u) => u.status === 'planned').length;
  $('#units-count').textContent = `${planned} of ${units.length} planned`;
}

function renderTimeline(scene) {
  const box = $('#timeline');
  box.hidden = false;
  const bands = box.querySelector('.bands');
  bands.innerHTML = '';
  const total = scene.duration_s;
  const pct = (t) => `${(100 * t) / total}%`;
  for (const c of scene.cycles) {
    const start = document.createElement('div');
    start.className = 'cycle-start';
    start.style.left = pct(c.t_start_s);
    start.title = `unit ${c.unit}`;
    bands.appendChild(start);
    for (const leg of c.legs) {
      const el = document.createElement('div');
      el.className = `band ${leg.kind}`;
      el.dataset.leg = leg.name;
      el.dataset.unit = c.unit;
      el.style.left = pct(leg.t_start_s);
      el.style.width = pct(Math.max(leg.t_end_s - leg.t_start_s, 0));
      el.style.background = LEG_COLORS[leg.name] || '#475569';
      el.title = `${c.unit}: ${leg.name} (${leg.kind}${leg.payload ? `, holding ${leg.payload}` : ''}) ` +
        `${fmt(leg.t_start_s, 2)}–${fmt(leg.t_end_s, 2)} s`;
      el.textContent = scene.cycles.length > 2 ? '' : leg.name.replace('_', ' ');
      bands.appendChild(el);
    }
    for (const e of c.events) {
      const el = document.createElement('div');
      el.className = `event ${e.kind}`;
      el.style.left = pct(e.t_s);
      el.title = `${e.kind} ${e.unit} at ${fmt(e.t_s, 3)} s, spring-back ${fmt(1000 * e.springback_m, 2)} mm`;
      bands.appendChild(el);
    }
  }
  box.onclick = (ev) => {
    const r = box.getBoundingClientRect();
    setTime(((ev.clientX - r.left) / r.width) * total);
  };
}

// The campaign's drive profile: its cycles' samples one after the other (times shifted, nothing computed).
function joinedProfile(kind, job) {
  if (kind === 'cycle') return job.result;
  const cycles = job.result.cycles.filter((c) => c.status === 'succeeded');
  const out = { drives: cycles[0].drives, units: cycles[0].units, t: [] };
  const keys = ['position', 'velocity', 'acceleration', 'jerk', 'effort'].filter((k) => cycles[0][k]);
  for (const k of keys) out[k] = [];
  let offset = 0;
  for (const c of cycles) {
    for (const t of c.t) out.t.push(t + offset);
    for (const k of keys) for (const row of c[k]) out[k].push(row);
    offset += c.t[c.t.length - 1];
  }
  return out;
}

async function showTask(kind, job, scene) {
  state.mode = kind;
  await buildScene(scene, scene.has_cabin);
  if (viewer3d) { viewer3d.setTask(scene); viewer3d.frameTask(); }
  $('#legend').innerHTML = [['#8fa3bf', 'robot bodies'], ['#f59e0b', 'unit'], ['#60a5fa', 'installed before'],
    ['#92400e', 'dock fixture'], ['#22c55e', 'bay'], ['#ef4444', 'closest pair'], ['#9ca3af', 'cabin']]
    .map(([c, t]) => `<div><span style="background:${c}"></span>${t}</div>`).join('');
  renderTimeline(scene);
  if (kind === 'campaign') renderUnits(job.result.units, scene);
  const r = job.result;
  const rows = kind === 'cycle'
    ? [
      row('cycle time', `${fmt(r.duration_s)} s`),
      row('samples', `${r.t.length} every ${fmt(1000 * r.sample_period_s, 1)} ms`),
      ...r.events.map((e) => row(`${e.kind} ${e.unit} spring-back`, `${fmt(1000 * e.springback_m, 3)} mm`)),
      row('min clearance (report)', mm(r.min_clearance_m)),
      row('requested clearance', mm(scene.clearance_m)),
      row('planning time', `${fmt((r.report || {}).planning_time_s, 2)} s`),
      row('gate', ((r.report || {}).gate || {}).passed ? 'passed' : 'FAILED', ''),
    ]
    : [
      row('status', r.status, ''),
      row('order', (r.order || []).join(' → ') || '–', ''),
      row('campaign time', r.campaign_duration_s === null ? '–' : `${fmt(r.campaign_duration_s, 1)} s`),
      row('cycles planned', String(r.cycles_planned)),
      row('cycles kept from an earlier run', String(r.cycles_cached)),
      row('min clearance (these frames)', mm(scene.min_clearance_m)),
      row('result', r.message, ''),
    ];
  $('#figures').innerHTML = rows.join('');
  provenance(r.provenance || {});
  if (kind === 'campaign') {
    $('#provenance').innerHTML = row('campaign', (job.campaign || {}).sha256 || '–', 'hash');
  }
  setupPlayer(scene.duration_s, 0.001);
  $('#clearance-panel').hidden = false;
  clearanceChart = new ClearanceChart($('#clearance-chart'), scene.clearance, scene.clearance_m, (t) => setTime(t));
  $('#drive-panel').hidden = false;
  driveCharts = new DriveCharts($('#drive-charts'), $('#drive-select'), joinedProfile(kind, job), scene, (t) => setTime(t));
  setTime(0);
  state.ready = true;
}

function showTaskRefusal(kind, job, scene) {
  state.mode = 'refusal';
  const box = $('#refusal');
  box.hidden = false;
  $('#refusal-reason').textContent = (job.reason || job.status).replaceAll('_', ' ');
  $('#refusal-message').textContent = job.message || '';
  const details = (job.result && job.result.details) || {};
  $('#refusal-details').innerHTML = Object.entries(details)
    .map(([k, v]) => `<tr><th>${esc(k)}</th><td>${esc(evidenceText(k, v))}</td></tr>`).join('') ||
    '<tr><td class="muted">no further evidence</td></tr>';
  $('#refusal-config').textContent = '';
  $('#player').hidden = true;
  if (kind === 'campaign') renderUnits((job.result && job.result.units) || job.units || [], null);
  state.ready = true;
}

function showTaskTime(scene, i, t) {
  const c = scene.clearance;
  const pair = c.pair[i];
  if (viewer3d) viewer3d.showTaskFrame(scene, i, { pair: pair || [], a: c.point_a_m[i], b: c.point_b_m[i] });
  const k = scene.frames.cycle[i];
  const cyc = scene.cycles[k];
  const leg = cyc.legs[scene.frames.leg[i]];
  const held = scene.frames.unit_held[i];
  $('#leg-readout').hidden = false;
  $('#leg-readout').textContent = `unit ${cyc.unit}, leg ${leg.name} (${leg.kind}` +
    `${held ? `, holding ${cyc.unit}` : ''}); closest pair: ${pair ? `${pair[0]} – ${pair[1]}: ${mm(c.distance_m[i])}` : '–'}`;
  $('#clearance-value').textContent = `clearance at t = ${scene.frames.t_s[i].toFixed(3)} s: ${mm(c.distance_m[i])}` +
    (pair ? ` (${pair[0]} – ${pair[1]})` : '');
  const cursor = $('#timeline .cursor');
  if (cursor) cursor.style.left = `${(100 * t) / scene.duration_s}%`;
  for (const tr of document.querySelectorAll('#unit-table tbody tr')) {
    const entry = scene.units.find((u) => u.id === tr.dataset.unit);
    tr.classList.toggle('current', !!entry && entry.cycle === k);
  }
}

// ------------------------------------------------------------------------------------------ test hook
function snapshot() {
  const s = state;
  const out = {
    view: s.view, mode: s.mode, planId: s.planId, ready: s.ready, webgl: s.webgl, error: s.error,
    authMessage: s.lastAuthMessage, t: s.t, frame: s.frame, sample: null, frameTime: null,
    bodies: viewer3d ? viewer3d.bodyCount() : 0, bodyNames: viewer3d ? viewer3d.bodyNames() : [],
    payload: null, highlighted: viewer3d ? viewer3d.highlighted() : [], clearanceCursor: null,
    renderedFrames: viewer3d ? viewer3d.renderCount : 0,
  };
  if (s.scene && s.scene.frames) {
    out.sample = s.scene.frames.sample[s.frame];
    out.frameTime = s.scene.frames.t_s[s.frame];
  }
  if (viewer3d) out.payload = viewer3d.payloadPose();
  if (s.scene && (s.scene.kind === 'cycle' || s.scene.kind === 'campaign')) {
    const f = s.scene.frames;
    const k = f.cycle[s.frame];
    out.cycle = k;
    out.leg = s.scene.cycles[k].legs[f.leg[s.frame]].name;
    out.units = viewer3d ? viewer3d.taskUnits() : {};
    out.unitRows = [...document.querySelectorAll('#unit-table tbody tr')].map((tr) => ({
      id: tr.dataset.unit, status: tr.dataset.status, current: tr.classList.contains('current'),
    }));
    out.legBands = document.querySelectorAll('#timeline .band').length;
    out.eventMarkers = document.querySelectorAll('#timeline .event').length;
    out.closest = { distance_m: s.scene.clearance.distance_m[s.frame], pair: s.scene.clearance.pair[s.frame] };
  }
  if (s.scene && s.scene.kind === 'plan') {
    const el = $('#clearance-value');
    out.clearanceCursor = {
      t: clearanceChart ? clearanceChart.cursorT : null,
      distance_m: s.scene.clearance.distance_m[s.frame],
      pair: s.scene.clearance.pair[s.frame],
      text: el.textContent,
    };
  }
  return JSON.parse(JSON.stringify(out));
}
Object.defineProperty(window, 'cabinplanViewer', {
  value: Object.freeze({ state: snapshot }), writable: false, configurable: false,
});

// ------------------------------------------------------------------------------------------------ wiring
$('#api-key').value = apiKey();
$('#key-form').addEventListener('submit', (ev) => {
  ev.preventDefault();
  sessionStorage.setItem(KEY_STORE, $('#api-key').value.trim());
  route();
});
$('#key-forget').addEventListener('click', () => { sessionStorage.removeItem(KEY_STORE); $('#api-key').value = ''; route(); });
$('#submit-form').addEventListener('submit', submitPlan);
$('#pprs6-form').addEventListener('submit', submitPprs6);
$('#scrub').addEventListener('input', (ev) => { state.playing = false; $('#play').textContent = 'Play'; setTime(Number(ev.target.value)); });
$('#speed').addEventListener('change', (ev) => { state.speed = Number(ev.target.value); });
$('#play').addEventListener('click', () => {
  if (!state.scene || !state.scene.frames) return;
  const times = state.scene.frames.t_s;
  if (!state.playing && state.t >= times[times.length - 1]) setTime(0);
  state.playing = !state.playing;
  $('#play').textContent = state.playing ? 'Pause' : 'Play';
});
window.addEventListener('hashchange', route);
loadExamples();
route();
requestAnimationFrame(tick);

// One readable line of a refusal's evidence record (the planner's planner.plan.goals.describe).
function describeEvidence(e) {
  if (!e || typeof e !== 'object') return String(e);
  if (e.cause === 'force') {
    return `${e.drive} needs ${(100 * e.force_ratio).toFixed(0)}% of its force limit ${e.where}` +
      ` (${(100 * e.allowed_ratio).toFixed(0)}% allowed)`;
  }
  if (e.cause === 'limit') {
    if (e.excess === null || e.excess === undefined) return `${e.limit} is not finite ${e.where}`;
    const g = (x) => Number(x).toPrecision(4);
    return `${e.limit} = ${g(e.value)} outside [${g(e.lower)}, ${g(e.upper)}] by ${Number(e.excess).toPrecision(3)} ${e.where}`;
  }
  if (e.cause === 'clearance' && Array.isArray(e.bodies)) {
    const other = e.bodies[1] === 'cabin' ? 'the cabin' : e.bodies[1];
    const what = e.distance_m <= 0 ? `in contact with ${other}` : `${(1e3 * e.distance_m).toFixed(1)} mm from ${other}`;
    return `${e.bodies[0]} ${what} ${e.where}, ${(1e3 * e.required_m).toFixed(1)} mm required`;
  }
  return JSON.stringify(e);
}

// A refusal detail as text: evidence records described, joint vectors rounded, long lists summarised.
function evidenceText(key, value) {
  if (key === 'best') return describeEvidence(value);
  if (key === 'candidates' && Array.isArray(value)) {
    const shown = value.slice(0, 4).map(describeEvidence).join('; ');
    return value.length > 4 ? `${value.length} candidates: ${shown}; …` : `${value.length} candidates: ${shown}`;
  }
  if (key === 'q' && Array.isArray(value)) return value.map((x) => Number(x).toFixed(4)).join(', ');
  return typeof value === 'object' ? JSON.stringify(value) : value;
}
