// The hapticpd viewer page: the scene from the viewer's WebSocket drawn with
// three.js (bodies, probes, contacts, forces, the PD target), a live plot
// and a status panel per device session. window.hapticpdView is the test
// contract (client/viewer/README.md "The page").
import * as THREE from 'three';
import { OrbitControls } from 'orbit-controls';
import { SessionPlot } from 'plot';

const token = new URLSearchParams(location.search).get('token');
const tokenQuery = token ? '?token=' + encodeURIComponent(token) : '';

const view = window.hapticpdView = {
  ready: false, connected: false, serverConnected: false,
  bodies: 0, bodyIds: [], sessions: 0, probes: {}, contacts: 0, plotSamples: 0,
  framesRendered: 0, wsConnects: 0, revision: 0, observers: 0,
  programs: 0,  // shader programs built (warmUp builds every kind before a session comes)
  lastPoseServerTimeNs: 0, lastPoseRenderedAt: 0,
  // Beyond the contract: what this browser lost, and the link's error.
  posesDropped: 0, batchesDropped: 0, serverFramesDropped: 0, serverBatchesDropped: 0,
  linkError: '', wsOpen: false, pingMs: null,
  // What the scene comes from: "server HOST:PORT" or "replay of FILE".
  source: '',
};

// ---------------------------------------------------------------- scene --
const canvas = document.getElementById('scene');
const renderer = new THREE.WebGLRenderer({ canvas, antialias: false });
renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
renderer.setClearColor(0x1d2126);
const scene = new THREE.Scene();
const camera = new THREE.PerspectiveCamera(45, 1, 0.001, 100);
camera.up.set(0, 0, 1);  // hapticpd's world is z-up
camera.position.set(0.35, -0.45, 0.3);
const controls = new OrbitControls(camera, canvas);
controls.target.set(0, 0, 0);
controls.update();
scene.add(new THREE.HemisphereLight(0xffffff, 0x404050, 0.75));
const sun = new THREE.DirectionalLight(0xffffff, 0.6);
sun.position.set(1, -1.5, 2);
scene.add(sun);
const grid = new THREE.GridHelper(1, 20, 0x4a525c, 0x30363d);
grid.rotation.x = Math.PI / 2;  // the xy plane
scene.add(grid);

function resize() {
  const w = window.innerWidth, h = window.innerHeight;
  renderer.setSize(w, h, false);
  camera.aspect = w / Math.max(1, h);
  camera.updateProjectionMatrix();
}
window.addEventListener('resize', resize);
resize();

function setPose(obj, pose) {
  obj.position.set(pose.p[0], pose.p[1], pose.p[2]);
  obj.quaternion.set(pose.q[1], pose.q[2], pose.q[3], pose.q[0]);  // three: x, y, z, w
}

// Penetration depth colour scale: green at 0 to red at depthMax (m); the
// scale grows in 1-2-5 steps to the deepest contact seen.
let depthMax = 0.005;
function depthColor(d, out) {
  const s = Math.min(1, Math.max(0, d / depthMax));
  return out.setHSL(0.33 * (1 - s), 0.9, 0.5);
}
function growDepthScale(d) {
  if (d <= depthMax) return;
  const e = Math.pow(10, Math.floor(Math.log10(d)));
  depthMax = [1, 2, 5, 10].map(m => m * e).find(v => v >= d);
  drawLegend();
}
function drawLegend() {
  const c = document.getElementById('legend-bar'), g = c.getContext('2d');
  const col = new THREE.Color();
  for (let x = 0; x < c.width; ++x) {
    depthColor(depthMax * x / (c.width - 1), col);
    g.fillStyle = col.getStyle();
    g.fillRect(x, 0, 1, c.height);
  }
  document.getElementById('legend-max').textContent = `${(depthMax * 1e3).toFixed(1)} mm`;
}
drawLegend();

// ---------------------------------------------------------------- meshes --
// Fetched once per content hash and cached (the viewer serves them immutable).
const geometries = new Map();  // hash -> Promise<BufferGeometry | null>
function geometry(hash) {
  if (!hash) return Promise.resolve(null);
  if (!geometries.has(hash)) {
    geometries.set(hash, fetch(`/mesh/${hash}${tokenQuery}`)
      .then(r => { if (!r.ok) throw new Error(`mesh ${hash}: HTTP ${r.status}`); return r.arrayBuffer(); })
      .then(decodeMesh)
      .catch(e => { console.warn(e); geometries.delete(hash); return null; }));
  }
  return geometries.get(hash);
}
function decodeMesh(buf) {
  const head = new DataView(buf);
  const magic = String.fromCharCode(...new Uint8Array(buf, 0, 4));
  if (magic !== 'HPDM' || head.getUint32(4, true) !== 1) throw new Error('not a hapticpd mesh');
  const nv = head.getUint32(8, true), nt = head.getUint32(12, true);
  const g = new THREE.BufferGeometry();
  g.setAttribute('position', new THREE.BufferAttribute(new Float32Array(buf, 16, 3 * nv), 3));
  g.setIndex(new THREE.BufferAttribute(new Uint32Array(buf, 16 + 12 * nv, 3 * nt), 1));
  g.computeVertexNormals();
  g.computeBoundingSphere();
  return g;
}
/// A box standing in for a mesh not (yet) loaded: its bounding box.
function boxGeometry(info) {
  const lo = info && info.aabb_min || [-0.005, -0.005, -0.005];
  const hi = info && info.aabb_max || [0.005, 0.005, 0.005];
  const g = new THREE.BoxBufferGeometry(Math.max(1e-4, hi[0] - lo[0]), Math.max(1e-4, hi[1] - lo[1]),
                                        Math.max(1e-4, hi[2] - lo[2]));
  g.translate((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2);
  return g;
}

// ------------------------------------------------------------- materials --
// Every material the page draws comes from here, so that warmUp() below
// draws each kind once at load.
// Lit per vertex: software WebGL draws it at a fraction of Phong's cost.
const bodyMaterial = (color) => new THREE.MeshLambertMaterial({ color });
const placeholderMaterial = (color) => new THREE.MeshBasicMaterial({ color, wireframe: true });
const probeMaterial = (color) => new THREE.MeshPhongMaterial({ color, shininess: 40 });
const ghostMaterial = () => new THREE.MeshBasicMaterial({ color: 0x7fd7ff, transparent: true,
                                                          opacity: 0.25, depthWrite: false });
/// A force or torque arrow, drawn over the bodies: it starts inside the
/// probe, often inside a body.
function makeArrow(color) {
  const a = new THREE.ArrowHelper(new THREE.Vector3(0, 0, 1), new THREE.Vector3(), 0.01, color);
  a.visible = false;
  for (const part of [a.line, a.cone]) { part.material.depthTest = false; part.renderOrder = 3; }
  return a;
}

// ---------------------------------------------------------------- bodies --
const bodies = new Map();  // id -> {obj, mesh, hash, info}
const bodyPalette = [0x8c9bab, 0xb0a48c, 0x8cab97, 0xab8ca4, 0x9c8cab];
let pendingMeshes = 0;

function addBody(b) {
  removeBody(b.id);
  const obj = new THREE.Group();
  const color = bodyPalette[bodies.size % bodyPalette.length];
  const mat = bodyMaterial(color);
  const placeholder = new THREE.Mesh(boxGeometry(b.info), placeholderMaterial(color));
  obj.add(placeholder);
  setPose(obj, b.pose);
  scene.add(obj);
  const entry = { obj, hash: b.mesh, info: b.info, label: b.label };
  bodies.set(b.id, entry);
  if (b.mesh) {
    ++pendingMeshes;
    geometry(b.mesh).then(g => {
      --pendingMeshes;
      if (!g || bodies.get(b.id) !== entry) return;
      obj.remove(placeholder);
      obj.add(new THREE.Mesh(g, mat));
    });
  }
  updateBodyList();
}
function removeBody(id) {
  const e = bodies.get(id);
  if (!e) return;
  scene.remove(e.obj);
  bodies.delete(id);
  updateBodyList();
}
function updateBodyList() {
  view.bodyIds = [...bodies.keys()].sort();
  view.bodies = view.bodyIds.length;
}

// -------------------------------------------------------------- sessions --
const sessions = new Map();  // id -> Session
let sessionsFromServer = false;  // the server sends SessionsChanged (else: probes make sessions)
const MAX_ROWS = 512;
const contactPoints = new THREE.BufferGeometry();
contactPoints.setAttribute('position', new THREE.BufferAttribute(new Float32Array(3 * MAX_ROWS), 3));
contactPoints.setAttribute('color', new THREE.BufferAttribute(new Float32Array(3 * MAX_ROWS), 3));
const contactNormals = new THREE.BufferGeometry();
contactNormals.setAttribute('position', new THREE.BufferAttribute(new Float32Array(6 * MAX_ROWS), 3));
const pointsObj = new THREE.Points(contactPoints,
  new THREE.PointsMaterial({ size: 7, sizeAttenuation: false, vertexColors: THREE.VertexColors,
                             depthTest: false }));
const normalsObj = new THREE.LineSegments(contactNormals,
  new THREE.LineBasicMaterial({ color: 0xf2f2f2, depthTest: false }));
pointsObj.renderOrder = normalsObj.renderOrder = 2;
pointsObj.frustumCulled = normalsObj.frustumCulled = false;
scene.add(pointsObj, normalsObj);

// Arrow lengths saturate: a fraction of the scene's size, half of it at
// FORCE_REF_N (TORQUE_REF_NM), so that both a light touch and a hard press show.
const FORCE_REF_N = 2, TORQUE_REF_NM = 0.02;
let sceneRadius = 0.2;  // m, set when the scene is framed
const neutralProbe = new THREE.Color(0x5b8fd6);

class Session {
  constructor(id) {
    this.id = id;
    this.info = null;
    this.probe = null;    // the latest probe state from a pose frame
    this.status = null;   // the latest device telemetry
    this.server = null;   // the latest server-side telemetry figures
    this.obj = new THREE.Group();
    this.mat = probeMaterial(neutralProbe.clone());
    this.ghostMat = ghostMaterial();
    this.body = new THREE.Mesh(new THREE.SphereBufferGeometry(0.004, 16, 12), this.mat);
    this.obj.add(this.body);
    this.ghost = new THREE.Group();
    this.ghostMesh = new THREE.Mesh(this.body.geometry, this.ghostMat);
    this.ghost.add(this.ghostMesh);
    this.ghost.visible = false;
    this.forceArrow = makeArrow(0xff5a3c);
    this.torqueArrow = makeArrow(0xc266ff);
    scene.add(this.obj, this.ghost, this.forceArrow, this.torqueArrow);
    this.obj.visible = false;  // until its first pose
    this.makePanel();
  }

  setInfo(info) {
    this.info = info;
    this.panel.querySelector('.name').textContent =
      `${this.id}${info.mode ? ' · ' + info.mode : ''}` +
      `${info.client ? ' — ' + info.client : ''}`;
    const useGeometry = g => { this.body.geometry = g; this.ghostMesh.geometry = g; };
    useGeometry(boxGeometry(info.info));
    if (info.mesh) geometry(info.mesh).then(g => { if (g && this.info === info) useGeometry(g); });
  }

  setProbe(p, now) {
    this.probe = p;
    setPose(this.obj, p.pose);
    this.obj.visible = true;
    growDepthScale(p.depth);
    if (p.depth > 0) depthColor(p.depth, this.mat.color); else this.mat.color.copy(neutralProbe);
    if (p.target && p.depth > 0) {
      setPose(this.ghost, p.target);
      this.ghost.visible = true;
    } else {
      this.ghost.visible = false;
    }
    // Arrows from the probe's centre of mass (its mesh frame's origin when unknown).
    const com = new THREE.Vector3();
    if (this.info && this.info.info && this.info.info.com) com.fromArray(this.info.info.com);
    com.applyQuaternion(this.obj.quaternion).add(this.obj.position);
    arrow(this.forceArrow, com, p.force, FORCE_REF_N);
    arrow(this.torqueArrow, com, p.torque || [0, 0, 0], TORQUE_REF_NM);
    const f = Math.hypot(...p.force);
    this.plot.addPoseFrame(f, p.torque ? Math.hypot(...p.torque) : null, now);
  }

  makePanel() {
    const el = document.createElement('div');
    el.className = 'panel session';
    el.innerHTML = `<div class="name"></div><table><tbody></tbody></table>
      <canvas class="plot"></canvas>
      <div class="plot-key"><span class="key force">commanded |F|</span>
        <span style="color:#ffd166">- - server |F|</span>
        <span class="key torque">commanded |τ|</span> <span style="color:#7fd7ff">- - server |τ|</span></div>`;
    el.querySelector('.name').textContent = this.id;
    document.getElementById('sessions').appendChild(el);
    this.panel = el;
    this.plot = new SessionPlot(el.querySelector('canvas'));
  }

  remove() {
    scene.remove(this.obj, this.ghost, this.forceArrow, this.torqueArrow);
    this.panel.remove();
  }
}

function arrow(a, origin, v, ref) {
  const len = Math.hypot(v[0], v[1], v[2]);
  if (!(len > 1e-9)) { a.visible = false; return; }
  a.visible = true;
  a.position.copy(origin);
  a.setDirection(new THREE.Vector3(v[0] / len, v[1] / len, v[2] / len));
  const l = 0.6 * sceneRadius * (1 - Math.exp(-len * Math.LN2 / ref));
  a.setLength(Math.max(l, 0.02 * sceneRadius), 0.2 * Math.max(l, 0.05 * sceneRadius),
              0.08 * Math.max(l, 0.05 * sceneRadius));
}

function session(id) {
  let s = sessions.get(id);
  if (!s) { s = new Session(id); sessions.set(id, s); view.sessions = sessions.size; }
  return s;
}
function removeSession(id) {
  const s = sessions.get(id);
  if (!s) return;
  s.remove();
  sessions.delete(id);
  delete view.probes[id];
  view.sessions = sessions.size;
}

// ------------------------------------------------------------- messages --
let poseApplied = null;  // server_time_ns of a pose frame applied since the last render
let sceneSeen = false, sceneMeshesPending = false;

function applyScene(m) {
  document.getElementById('scene-id').textContent = `— scene '${m.scene_id}'`;
  view.source = m.source || '';
  const ids = new Set(m.bodies.map(b => b.id));
  for (const id of [...bodies.keys()]) if (!ids.has(id)) removeBody(id);
  for (const b of m.bodies) {
    const e = bodies.get(b.id);
    if (e && e.hash === b.mesh) setPose(e.obj, b.pose); else addBody(b);
  }
  sessionsFromServer = sessionsFromServer || m.sessions_announced || m.sessions.length > 0;
  const sids = new Set(m.sessions.map(s => s.id));
  for (const p of m.probes) sids.add(p.id);
  for (const id of [...sessions.keys()]) if (!sids.has(id)) removeSession(id);
  for (const s of m.sessions) session(s.id).setInfo(s);
  for (const [id, st] of Object.entries(m.status || {})) session(id).status = st;
  applyLink(m.server_connected, m.error);
  applyPoses({ bodies: [], probes: m.probes, server_time_ns: m.server_time_ns,
               revision: m.revision, observers: m.observers });
  if (!sceneSeen) frameScene();
  sceneSeen = true;
  sceneMeshesPending = true;
}

function applySessions(m) {
  sessionsFromServer = true;
  for (const id of m.removed) removeSession(id);
  for (const s of m.added) session(s.id).setInfo(s);
}

function applyPoses(m) {
  const now = performance.now();
  for (const bp of m.bodies) {
    const e = bodies.get(bp.id);
    if (e) setPose(e.obj, bp.pose);
  }
  const seen = new Set();
  const probes = {};
  let contacts = 0;
  for (const p of m.probes) {
    seen.add(p.id);
    const s = session(p.id);
    s.setProbe(p, now);
    const rows = p.rows || [];
    probes[p.id] = { position: p.pose.p.slice(), rows: rows.length, depth: p.depth };
    contacts += rows.length;
  }
  if (!sessionsFromServer) {  // an older server: the probes are the sessions
    for (const id of [...sessions.keys()]) if (!seen.has(id)) removeSession(id);
  }
  for (const [id, s] of sessions) if (!seen.has(id)) s.obj.visible = false;
  view.probes = probes;
  drawContacts(m.probes);
  view.contacts = contacts;
  if (m.revision !== undefined) view.revision = m.revision;
  if (m.observers !== undefined) view.observers = m.observers;
  if (m.poses_dropped !== undefined) view.posesDropped = m.poses_dropped;
  if (m.batches_dropped !== undefined) view.batchesDropped = m.batches_dropped;
  if (m.server_dropped !== undefined) view.serverFramesDropped = m.server_dropped;
  if (m.server_time_ns) poseApplied = m.server_time_ns;
}

const tmpColor = new THREE.Color();
function drawContacts(probes) {
  const pos = contactPoints.attributes.position.array, col = contactPoints.attributes.color.array;
  const nrm = contactNormals.attributes.position.array;
  let n = 0;
  for (const p of probes) {
    for (const r of p.rows || []) {
      if (n >= MAX_ROWS) break;
      growDepthScale(r.d);
      depthColor(r.d, tmpColor);
      pos.set(r.p, 3 * n);
      col.set([tmpColor.r, tmpColor.g, tmpColor.b], 3 * n);
      const len = 0.01 + 2 * r.d;
      nrm.set(r.p, 6 * n);
      nrm.set([r.p[0] + len * r.n[0], r.p[1] + len * r.n[1], r.p[2] + len * r.n[2]], 6 * n + 3);
      ++n;
    }
  }
  contactPoints.setDrawRange(0, n);
  contactNormals.setDrawRange(0, 2 * n);
  contactPoints.attributes.position.needsUpdate = contactPoints.attributes.color.needsUpdate = true;
  contactNormals.attributes.position.needsUpdate = true;
}

function applyTelemetry(m) {
  const now = performance.now();
  for (const t of m.sessions) {
    // A batch the bridge sends after the session's removal (announcements go
    // first) must not bring the ended session back.
    if (sessionsFromServer && !sessions.has(t.id)) continue;
    const s = session(t.id);
    if (t.device) s.status = t.device;
    s.server = { update_rate_hz: t.update_rate_hz, revision: t.revision };
    s.plot.addTelemetry(t, now);
  }
  if (m.revision !== undefined) view.revision = m.revision;
  if (m.observers !== undefined) view.observers = m.observers;
  if (m.poses_dropped !== undefined) view.posesDropped = m.poses_dropped;
  if (m.batches_dropped !== undefined) view.batchesDropped = m.batches_dropped;
  if (m.server_dropped !== undefined) view.serverBatchesDropped = m.server_dropped;
}

function applyLink(up, error) {
  view.serverConnected = !!up;
  view.linkError = error || '';
  updateConnected();
}
function updateConnected() {
  view.connected = view.wsOpen && view.serverConnected;
  const banner = document.getElementById('banner');
  const text = !view.wsOpen ? 'viewer disconnected — reconnecting…'
    : !view.serverConnected ? `server disconnected${view.linkError ? ': ' + view.linkError : ''} — reconnecting…`
    : '';
  banner.textContent = text;
  banner.classList.toggle('hidden', !text);
}

function handle(m) {
  switch (m.type) {
    case 'scene': applyScene(m); break;
    case 'bodies':
      for (const id of m.removed) removeBody(id);
      for (const b of m.added) addBody(b);
      if (m.revision !== undefined) view.revision = m.revision;
      break;
    case 'sessions': applySessions(m); break;
    case 'poses': applyPoses(m); break;
    case 'telemetry': applyTelemetry(m); break;
    case 'link': applyLink(m.server_connected, m.error); break;
    case 'pong': if (typeof m.t === 'number') view.pingMs = performance.now() - m.t; break;
    case 'error': console.warn('viewer:', m.message); break;
    default: break;  // a newer viewer's message
  }
}

// ------------------------------------------------------------ WebSocket --
let ws = null, backoffMs = 250, pingTimer = null;
function connect() {
  const url = `${location.protocol === 'https:' ? 'wss:' : 'ws:'}//${location.host}/ws${tokenQuery}`;
  ws = new WebSocket(url);
  ws.onopen = () => {
    ++view.wsConnects;
    view.wsOpen = true;
    backoffMs = 250;
    updateConnected();
    pingTimer = setInterval(() => {
      if (ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify({ type: 'ping', t: performance.now() }));
    }, 2000);
  };
  ws.onmessage = ev => {
    let m;
    try { m = JSON.parse(ev.data); } catch (e) { console.warn('viewer: bad message', e); return; }
    handle(m);
  };
  ws.onclose = () => {
    clearInterval(pingTimer);
    view.wsOpen = false;
    updateConnected();
    setTimeout(connect, backoffMs);
    backoffMs = Math.min(5000, backoffMs * 2);
  };
}
connect();

// --------------------------------------------------------------- camera --
function frameScene() {
  const box = new THREE.Box3();
  for (const e of bodies.values()) {
    const b = boxGeometry(e.info);
    b.computeBoundingBox();
    e.obj.updateMatrixWorld();
    box.union(b.boundingBox.clone().applyMatrix4(e.obj.matrixWorld));
  }
  if (box.isEmpty()) return;
  const c = box.getCenter(new THREE.Vector3()), r = Math.max(0.02, box.getSize(new THREE.Vector3()).length() / 2);
  sceneRadius = r;
  controls.target.copy(c);
  camera.position.copy(c).add(new THREE.Vector3(1.1, -1.6, 1.0).multiplyScalar(r * 1.4));
  camera.near = r / 100;
  camera.far = r * 100;
  camera.updateProjectionMatrix();
  grid.scale.setScalar(Math.max(0.1, Math.pow(10, Math.ceil(Math.log10(r * 4)))));
  grid.position.set(c.x, c.y, box.min.z);
  controls.update();
}

// --------------------------------------------------------------- panels --
const fmt = (x, d = 1) => (typeof x === 'number' && isFinite(x)) ? x.toFixed(d) : '–';
function row(label, value, cls = '') { return `<tr><td>${label}</td><td class="${cls}">${value}</td></tr>`; }
function escapeHtml(s) { return String(s).replace(/[&<>"']/g, c => `&#${c.charCodeAt(0)};`); }

function updatePanels() {
  document.getElementById('link').innerHTML =
    `browser link: <span class="${view.wsOpen ? 'ok' : 'bad'}">${view.wsOpen ? 'open' : 'closed'}</span>` +
    `${view.pingMs !== null ? ' (' + fmt(view.pingMs) + ' ms)' : ''}, ` +
    (view.source.startsWith('replay')
      ? `<span class="warn">${escapeHtml(view.source)}</span>`
      : `server: <span class="${view.serverConnected ? 'ok' : 'bad'}">${view.serverConnected ? 'linked' : 'disconnected'}</span>`);
  document.getElementById('scene-info').innerHTML =
    `revision ${view.revision}, observers ${view.observers}, bodies ${view.bodies}, sessions ${view.sessions}<br>` +
    `dropped here: ${view.posesDropped} pose frames, ${view.batchesDropped} telemetry batches; ` +
    `at the server: ${view.serverFramesDropped} frames, ${view.serverBatchesDropped} batches`;
  for (const s of sessions.values()) {
    const st = s.status, p = s.probe;
    let html = '';
    if (st) {
      const ticks = st.ticks_server + st.ticks_local + st.ticks_faded;
      const share = n => ticks > 0 ? `${Math.round(100 * n / ticks)}%` : '–';
      const fsClass = st.fail_safe === 'ok' ? 'ok' : st.fail_safe === 'stale' ? 'bad' : 'warn';
      html += row('servo rate', `${fmt(st.servo_rate_hz, 0)} Hz`);
      html += row('update rate', `${fmt(st.update_rate_hz, 0)} Hz (server ${fmt(s.server && s.server.update_rate_hz, 0)} Hz)`);
      html += row('round trip', `${fmt(st.round_trip_ms, 2)} ms`);
      html += row('IR age', `${fmt(st.ir_age_ms, 2)} ms`);
      html += row('emulated link', `${fmt(st.delay_ms)} ms ± ${fmt(st.jitter_ms)} ms, loss ${fmt(100 * st.loss)}%`);
      html += row('model (ticks)', `server ${share(st.ticks_server)}, local ${share(st.ticks_local)}, faded ${share(st.ticks_faded)}`);
      html += row('answered by', escapeHtml(st.source || '–'));
      html += row('fail-safe', escapeHtml(st.fail_safe || '–'), fsClass);
    } else {
      html += row('device telemetry', 'none yet', 'warn');
      if (s.server) html += row('update rate', `${fmt(s.server.update_rate_hz, 0)} Hz (server)`);
    }
    if (p) {
      html += row('depth', `${fmt(p.depth * 1e3, 2)} mm`);
      html += row('force', `${fmt(Math.hypot(...p.force), 3)} N`);
      if (p.torque) html += row('torque', `${fmt(Math.hypot(...p.torque), 4)} N m`);
      if (p.status) html += row('contact', escapeHtml(p.status));
    }
    html += row('scene revision', view.revision);
    html += row('observers', view.observers);
    s.panel.querySelector('tbody').innerHTML = html;
  }
}

// ------------------------------------------------------------- warm-up --
// Software WebGL (SwiftShader, what a headless or GPU-less browser has)
// builds a program, and its routines for each draw state, at the first draw
// that needs them: drawn on demand, the first session froze the page for
// about a second as its probe, ghost and arrows appeared, and again at its
// first contact. So the first frame also draws one object of each kind
// (the materials above, the contact points and normals), behind the camera
// where nothing of them shows; they stay in the scene, hidden, so that
// their programs stay built for the sessions that come.
const warmUpGroup = new THREE.Group();
function warmUp() {
  const tri = new THREE.BufferGeometry();
  tri.setAttribute('position', new THREE.BufferAttribute(new Float32Array([0, 0, 0, 1e-4, 0, 0, 0, 1e-4, 0]), 3));
  tri.computeVertexNormals();
  warmUpGroup.add(new THREE.Mesh(tri, bodyMaterial(0xffffff)),
                  new THREE.Mesh(tri, placeholderMaterial(0xffffff)),
                  new THREE.Mesh(tri, probeMaterial(0xffffff)),
                  new THREE.Mesh(tri, ghostMaterial()));
  const arrow = makeArrow(0xffffff);
  arrow.visible = true;
  warmUpGroup.add(arrow);
  // Behind the camera, looking at its target: clipped, but drawn.
  const behind = camera.position.clone().multiplyScalar(2).sub(controls.target);
  warmUpGroup.position.copy(behind);
  warmUpGroup.traverse((o) => { o.frustumCulled = false; });
  scene.add(warmUpGroup);
  contactPoints.attributes.position.array.set(behind.toArray());
  contactNormals.attributes.position.array.set([...behind.toArray(), ...behind.toArray()]);
  contactPoints.setDrawRange(0, 1);
  contactNormals.setDrawRange(0, 2);
  contactPoints.attributes.position.needsUpdate = contactNormals.attributes.position.needsUpdate = true;
  renderer.render(scene, camera);
  warmUpGroup.visible = false;
  contactPoints.setDrawRange(0, 0);
  contactNormals.setDrawRange(0, 0);
}
warmUp();

// ---------------------------------------------------------------- loop --
let lastPanels = 0, lastPlots = 0;
function frame() {
  requestAnimationFrame(frame);
  controls.update();
  renderer.render(scene, camera);
  const now = performance.now();
  ++view.framesRendered;
  view.programs = renderer.info.programs.length;
  if (poseApplied !== null) {
    view.lastPoseServerTimeNs = poseApplied;
    view.lastPoseRenderedAt = now;
    poseApplied = null;
  }
  if (sceneSeen && sceneMeshesPending && pendingMeshes === 0) {
    // Ready once the first whole scene (its meshes loaded or failed) is on screen.
    sceneMeshesPending = false;
    if (!view.ready) { view.ready = true; document.body.dataset.ready = '1'; }
  }
  if (now - lastPlots > 100) {
    lastPlots = now;
    let n = 0;
    for (const s of sessions.values()) { n += s.plot.samples(now); s.plot.draw(now); }
    view.plotSamples = n;
  }
  if (now - lastPanels > 250) { lastPanels = now; updatePanels(); }
}
requestAnimationFrame(frame);
