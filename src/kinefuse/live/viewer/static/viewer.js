// kinefuse viewer: WebSocket client and a small canvas renderer of our own (z-up world).
// Wire format: docs/viewer.md. No third-party code.
"use strict";

const PAGE_ID = Math.random().toString(36).slice(2);  // tests check the page never reloads
window.kinefusePageId = PAGE_ID;

// ---------------------------------------------------------------------------------------------
// state

const S = {
  hello: null,           // the server's hello message
  frame: null,           // last decoded frame {seq, t, latency, layers: [{kind, name, pos, status}]}
  status: null,          // last status message
  player: null,          // replay: {frame, t_s, playing, speed}
  shown: {},             // layer key -> bool
  showFrustums: true,
  frames: 0,             // frames received since load
  connects: 0,
  hoverJoint: -1,
};
const KIND_FUSED = 0, KIND_RAW = 1, KIND_TRUTH = 2, KIND_PERSON = 3;
const PERSON_COLOURS = ["#b2bec3", "#fab1a0", "#81ecec", "#ffeaa7", "#dfe6e9"];
const HEAD = 3;  // the joint a person's id is written beside
const SENSOR_COLOURS = ["#e8875b", "#c678dd", "#56b6c2", "#e06c9f", "#d19a66", "#98c379",
                        "#61afef", "#e5c07b", "#be5046", "#7f8c8d"];
const METHOD_COLOURS = ["#ffffff", "#ff9f43", "#a29bfe", "#74b9ff", "#fd79a8", "#55efc4"];
// status classes: tracked / inferred or single-sensor / predicted / missing (FusionStatus codes)
const CLASSES = [
  {name: "tracked", colour: "#3ecf6e", codes: [0, 1]},
  {name: "inferred / single sensor", colour: "#f0b429", codes: [2, 3, 4, 5, 6, 7, 8]},
  {name: "predicted", colour: "#6ea8fe", codes: [9]},
  {name: "missing", colour: "#f25c54", codes: [10]},
];
function statusClass(code) {
  for (let i = 0; i < CLASSES.length; i++) if (CLASSES[i].codes.includes(code)) return i;
  return 1;
}
const layerKey = (l) => l.kind + ":" + l.name;
const $ = (id) => document.getElementById(id);
const fmt = (x, d) => (x === null || x === undefined || !isFinite(x)) ? "–" : x.toFixed(d);

// ---------------------------------------------------------------------------------------------
// wire: binary frames (little-endian; see docs/viewer.md)

function decodeFrame(buf) {
  const dv = new DataView(buf);
  if (dv.getUint8(0) !== 1 || dv.getUint8(1) !== 1) throw new Error("unknown frame type/version");
  const n = dv.getUint16(2, true);
  const f = {seq: dv.getUint32(4, true), t: dv.getFloat64(8, true),
             latency: dv.getFloat32(16, true), layers: []};
  let o = 20;
  const dec = new TextDecoder();
  for (let k = 0; k < n; k++) {
    const kind = dv.getUint8(o), len = dv.getUint8(o + 1);
    const name = dec.decode(new Uint8Array(buf, o + 2, len));
    o += 2 + len;
    const hasStatus = dv.getUint8(o); o += 1;
    const pos = new Float32Array(75);
    for (let i = 0; i < 75; i++) pos[i] = dv.getFloat32(o + 4 * i, true);
    o += 300;
    let status = null;
    if (hasStatus) { status = new Int8Array(buf.slice(o, o + 25)); o += 25; }
    f.layers.push({kind, name, pos, status});
  }
  return f;
}

// ---------------------------------------------------------------------------------------------
// connection (reconnects by itself, every second, without reloading the page)

let ws = null;
function connect() {
  const url = (location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/ws";
  ws = new WebSocket(url);
  ws.binaryType = "arraybuffer";
  ws.onopen = () => {
    S.connects += 1;
    const c = $("conn");
    c.textContent = "connected"; c.className = "badge conn-ok";
    c.dataset.connects = String(S.connects);
  };
  ws.onmessage = (ev) => {
    if (typeof ev.data === "string") onText(JSON.parse(ev.data));
    else onFrame(decodeFrame(ev.data));
  };
  ws.onclose = () => {
    const c = $("conn");
    c.textContent = "reconnecting…"; c.className = "badge conn-wait";
    ws = null;
    setTimeout(connect, 1000);
  };
  ws.onerror = () => { /* onclose follows */ };
}
function send(cmd) { if (ws && ws.readyState === 1) ws.send(JSON.stringify(cmd)); }

// a server with a token asks for it first (docs/api.md): the HMAC where the browser can compute
// one (a secure context: https or 127.0.0.1), else the token itself; kept for this tab only
async function answerAuth(m) {
  let token = sessionStorage.getItem("kinefuse-token");
  if (token === null) token = window.prompt("This kinefuse server needs its token:") || "";
  sessionStorage.setItem("kinefuse-token", token);
  if (window.crypto && crypto.subtle) {
    const enc = new TextEncoder();
    const key = await crypto.subtle.importKey("raw", enc.encode(token),
      {name: "HMAC", hash: "SHA-256"}, false, ["sign"]);
    const mac = await crypto.subtle.sign("HMAC", key, enc.encode("kinefuse-live/1|" + m.nonce));
    const hex = Array.from(new Uint8Array(mac), (b) => b.toString(16).padStart(2, "0")).join("");
    send({type: "auth", mac: hex});
  } else {
    send({type: "auth", token});
  }
}

function onText(m) {
  if (m.type === "auth_required") answerAuth(m);
  else if (m.type === "error") { sessionStorage.removeItem("kinefuse-token"); }
  else if (m.type === "hello") onHello(m);
  else if (m.type === "status") { S.status = m; renderStatus(); dirty(); }
  else if (m.type === "player") { S.player = m; renderPlayer(); }
}

function onHello(m) {
  const first = S.hello === null;
  S.hello = m;
  const mode = $("mode");
  mode.textContent = m.mode === "live" ? "LIVE" : "REPLAY";
  mode.className = "badge " + m.mode;
  if (m.mode === "replay") {
    const r = m.replay;
    $("timeline").hidden = false;
    $("scrub").max = String(Math.max(r.n_frames - 1, 0));
    document.title = "kinefuse replay – " + r.name;
    $("truth-note").textContent = r.truth_note || "";
  }
  if (first) resetCamera();
}

function onFrame(f) {
  if (!S.framed) frameCamera(f);
  S.frame = f;
  S.frames += 1;
  let changed = false;
  for (const l of f.layers) {
    const k = layerKey(l);
    if (!(k in S.shown)) {
      // first fused result and the truth on; other results and raw skeletons off
      const fusedOn = l.kind === KIND_FUSED && !f.layers.some(
        (o) => o.kind === KIND_FUSED && layerKey(o) in S.shown && S.shown[layerKey(o)]);
      S.shown[k] = l.kind === KIND_TRUTH || l.kind === KIND_PERSON || fusedOn;
      changed = true;
    }
  }
  if (changed) renderLayers();
  $("frame-counter").textContent = String(f.seq);
  $("frame-time").textContent = f.t.toFixed(3);
  $("frame-latency").textContent = fmt(f.latency, 1);
  if (S.hello && S.hello.mode === "replay") {
    $("scrub").value = String(f.seq);
    const r = S.hello.replay;
    $("timeline-time").textContent = `${f.t.toFixed(3)} s  (${f.seq + 1}/${r.n_frames})`;
  }
  renderErrors();
  dirty();
}

// ---------------------------------------------------------------------------------------------
// side panels

function sensorColour(id) {
  const ids = sensorIds();
  const i = ids.indexOf(id);
  return SENSOR_COLOURS[(i < 0 ? 0 : i) % SENSOR_COLOURS.length];
}
function sensorIds() {
  if (S.status) return S.status.sensors.map((s) => s.id);
  return [];
}

function renderStatus() {
  const st = S.status;
  const cal = $("calibration");
  const grade = st.calibration_grade;
  let html = `state <b>${st.calibration_state}</b>` +
    (grade ? ` · grade <b class="grade-${grade}">${grade}</b>` : " · grade –");
  if (S.hello && S.hello.replay && S.hello.replay.calibration) {
    const r = S.hello.replay;
    html += ` · ${r.calibration}` + (r.calibration_rms_mm != null ?
      `, RMS ${r.calibration_rms_mm.toFixed(1)} mm` : "");
  }
  html += ` · method <b>${st.method}</b>` + (st.recording ? ` · ${st.recording}` : "");
  cal.innerHTML = html;
  // what the operator has to do about the calibration (text from the server: not HTML)
  const say = $("calibration-message");
  say.textContent = st.calibration_message || "";
  say.hidden = !st.calibration_message;
  $("fused-fps").textContent = fmt(st.fused_fps, 1);
  const body = $("sensors").tBodies[0];
  const esc = (t) => String(t).replace(/[&<>"']/g, (c) => `&#${c.charCodeAt(0)};`);
  const rows = st.sensors.map((s) => {
    // what the operator must act on: frames refused as stale, a floor the sensor cannot fit
    const warn = (s.stale_frames ? `<span class="note"> · ${s.stale_frames} stale</span>` : "") +
      (s.floor_error ? `<span class="note" title="${esc(s.floor_error)}"> · no floor</span>` : "") +
      // the client's body tracker: its achieved rate and the captures it dropped (its text)
      (s.tracker ? `<span class="note tracker"> · ${esc(s.tracker)}</span>` : "");
    const off = s.clock_offset_ms == null ? "–" :
      `${s.clock_offset_ms.toFixed(2)}<span class="note"> ±${fmt(s.clock_offset_sd_ms, 2)}</span>`;
    return `<tr class="sensor-row" data-sensor="${s.id}">` +
      `<td><span class="swatch" style="background:${sensorColour(s.id)}"></span>${esc(s.id)}` +
      `${warn}</td>` +
      `<td class="${s.connected ? "on" : "off"}">${s.connected ? "●" : "○"}</td>` +
      `<td>${fmt(s.rtt_ms, 2)}</td><td>${off}</td><td>${fmt(s.fps, 1)}</td>` +
      `<td>${fmt(s.latency_ms, 1)}</td>` +
      `<td>${s.tracked_fraction == null ? "–" : Math.round(100 * s.tracked_fraction) + " %"}</td></tr>`;
  });
  body.innerHTML = rows.join("");
}

function renderLayers() {
  const box = $("layers");
  const f = S.frame;
  if (!f) return;
  const groups = [["fused results", KIND_FUSED], ["people", KIND_PERSON],
                  ["truth", KIND_TRUTH], ["raw sensor skeletons", KIND_RAW]];
  let html = "";
  for (const [title, kind] of groups) {
    const ls = f.layers.filter((l) => l.kind === kind);
    if (!ls.length) continue;
    html += `<div class="group">${title}</div>`;
    for (const l of ls) {
      const k = layerKey(l);
      const person = l.kind === KIND_PERSON ?
        ` data-person="${l.name.split(" ")[0].slice(1)}"` +
        (isSubject(l) ? ` data-subject="1"` : "") : "";
      html += `<label${person}><input type="checkbox" data-layer="${k}" ` +
        `${S.shown[k] ? "checked" : ""}>` +
        `<span class="swatch" style="background:${layerColour(l)}"></span>${l.name}` +
        (l.kind === KIND_PERSON && !isSubject(l) && S.hello.mode === "live" ?
          ` <button class="pick-subject" data-pick="${l.name.slice(1)}">make subject</button>` :
          "") + `</label>`;
    }
  }
  html += `<div class="group">scene</div><label><input type="checkbox" id="show-frustums" ` +
    `${S.showFrustums ? "checked" : ""}> sensor frustums</label>`;
  box.innerHTML = html;
  for (const b of box.querySelectorAll("button[data-pick]")) {
    b.onclick = (e) => { e.preventDefault(); send({cmd: "subject", person: Number(b.dataset.pick)}); };
  }
  for (const cb of box.querySelectorAll("input[data-layer]")) {
    cb.onchange = () => { S.shown[cb.dataset.layer] = cb.checked; renderErrors(); dirty(); };
  }
  $("show-frustums").onchange = (e) => { S.showFrustums = e.target.checked; dirty(); };
}

const isSubject = (l) => l.kind === KIND_PERSON && l.name.endsWith(" subject");
function layerColour(l) {
  if (l.kind === KIND_RAW) return sensorColour(l.name);
  if (isSubject(l)) return METHOD_COLOURS[0];
  if (l.kind === KIND_PERSON) {
    return PERSON_COLOURS[Number(l.name.slice(1)) % PERSON_COLOURS.length];
  }
  if (l.kind === KIND_TRUTH) return "#e6e6e6";
  const fused = S.frame.layers.filter((o) => o.kind === KIND_FUSED);
  return METHOD_COLOURS[fused.indexOf(l) % METHOD_COLOURS.length];
}

function primaryLayer() {
  if (!S.frame) return null;
  return S.frame.layers.find((l) => l.kind === KIND_FUSED && S.shown[layerKey(l)]) || null;
}
function truthLayer() {
  return S.frame ? S.frame.layers.find((l) => l.kind === KIND_TRUTH) || null : null;
}
function jointError(p, t, j) {
  const dx = p.pos[3 * j] - t.pos[3 * j], dy = p.pos[3 * j + 1] - t.pos[3 * j + 1],
    dz = p.pos[3 * j + 2] - t.pos[3 * j + 2];
  return Math.sqrt(dx * dx + dy * dy + dz * dz);
}

function renderErrors() {
  const t = truthLayer(), p = primaryLayer();
  const sec = $("error-section");
  sec.hidden = !t;
  if (!t || !p || !S.hello) return;
  $("error-method").textContent = "(" + p.name + ")";
  const names = S.hello.joints;
  const errs = names.map((_, j) => jointError(p, t, j) * 1000);
  const ok = errs.filter((e) => isFinite(e));
  const mean = ok.length ? ok.reduce((a, b) => a + b, 0) / ok.length : NaN;
  $("error-mean").innerHTML = `mean <b id="error-mean-mm">${fmt(mean, 1)}</b> mm over ` +
    `${ok.length} joints`;
  const max = Math.max(50, ...ok);
  $("errors").tBodies[0].innerHTML = names.map((n, j) => {
    const e = errs[j];
    const w = isFinite(e) ? Math.round(120 * e / max) : 0;
    return `<tr class="${j === S.hoverJoint ? "hot" : ""}"><td>${n}</td><td>${fmt(e, 1)}</td>` +
      `<td style="width:125px;text-align:left"><span class="bar" style="width:${w}px"></span></td></tr>`;
  }).join("");
}

function renderPlayer() {
  const p = S.player;
  $("play").dataset.playing = p.playing ? "1" : "0";
}

function renderLegend(counts) {
  $("legend").innerHTML = CLASSES.map((c, i) =>
    `<div><span class="dot" style="background:${c.colour}"></span>${c.name}` +
    `<span class="note">&nbsp;${counts ? counts[i] : 0}</span></div>`).join("");
}

// ---------------------------------------------------------------------------------------------
// camera: orbit around a target, z up

const cam = {target: [0, 0, 0.9], az: -0.9, el: 0.45, dist: 7.5, fov: 45 * Math.PI / 180};
function resetCamera() {
  cam.target = [0, 0, 0.9]; cam.az = -0.9; cam.el = 0.45; cam.dist = 7.5; dirty();
}
// look at the rig's centre (the body's when no sensor pose is known) the first time a frame
// arrives, from far enough to see every sensor
function frameCamera(f) {
  const l = f.layers.find((o) => o.kind === KIND_FUSED);
  if (!l) return;
  let n = 0, sx = 0, sy = 0;
  for (let j = 0; j < 25; j++) {
    if (isFinite(l.pos[3 * j]) && isFinite(l.pos[3 * j + 1])) { sx += l.pos[3 * j]; sy += l.pos[3 * j + 1]; n++; }
  }
  if (!n) return;
  S.framed = true;
  const poses = (S.status ? S.status.sensors : []).filter((s) => s.pose);
  if (poses.length) {
    cam.target = [poses.reduce((a, s) => a + s.pose[3], 0) / poses.length,
                  poses.reduce((a, s) => a + s.pose[7], 0) / poses.length, 0.9];
  } else {
    cam.target = [sx / n, sy / n, 0.9];
  }
  let far = 1.5;
  for (const s of poses) {
    far = Math.max(far, Math.hypot(s.pose[3] - cam.target[0], s.pose[7] - cam.target[1]));
  }
  cam.dist = Math.min(20, 2.0 * far + 1.0);
  dirty();
}
function basis() {
  const ce = Math.cos(cam.el), se = Math.sin(cam.el);
  const eye = [cam.target[0] + cam.dist * ce * Math.cos(cam.az),
               cam.target[1] + cam.dist * ce * Math.sin(cam.az),
               cam.target[2] + cam.dist * se];
  const f = norm(sub(cam.target, eye));
  const r = norm(cross(f, [0, 0, 1]));
  const u = cross(r, f);
  return {eye, f, r, u};
}
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                         a[0] * b[1] - a[1] * b[0]];
const norm = (a) => { const n = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / n, a[1] / n, a[2] / n]; };

// ---------------------------------------------------------------------------------------------
// renderer

const canvas = $("scene");
const ctx = canvas.getContext("2d");
let W = 0, H = 0, B = null, FPX = 1;
const NEAR = 0.05;

function toView(p) {
  const v = sub(p, B.eye);
  return [dot(v, B.r), dot(v, B.u), dot(v, B.f)];
}
function toScreen(v) { return [W / 2 + FPX * v[0] / v[2], H / 2 - FPX * v[1] / v[2]]; }
function line(a, b, colour, width, dash) {
  let va = toView(a), vb = toView(b);
  if (va[2] < NEAR && vb[2] < NEAR) return;
  if (va[2] < NEAR || vb[2] < NEAR) {  // clip at the near plane
    const t = (NEAR - va[2]) / (vb[2] - va[2]);
    const c = [va[0] + t * (vb[0] - va[0]), va[1] + t * (vb[1] - va[1]), NEAR];
    if (va[2] < NEAR) va = c; else vb = c;
  }
  const sa = toScreen(va), sb = toScreen(vb);
  ctx.strokeStyle = colour; ctx.lineWidth = width;
  ctx.setLineDash(dash || []);
  ctx.beginPath(); ctx.moveTo(sa[0], sa[1]); ctx.lineTo(sb[0], sb[1]); ctx.stroke();
}
function label(p, text, colour) {
  const v = toView(p);
  if (v[2] < NEAR) return;
  const s = toScreen(v);
  ctx.fillStyle = colour; ctx.font = `${12 * devicePixelRatio}px system-ui, sans-serif`;
  ctx.fillText(text, s[0] + 4, s[1] - 4);
}
const P = (pos, j) => [pos[3 * j], pos[3 * j + 1], pos[3 * j + 2]];
const finite = (p) => isFinite(p[0]) && isFinite(p[1]) && isFinite(p[2]);

function drawGrid() {
  const n = 8, step = 0.5;
  for (let i = -n; i <= n; i++) {
    const x = i * step;
    const c = i === 0 ? "#3b4350" : (i % 2 === 0 ? "#2b313b" : "#232830");
    line([x, -n * step, 0], [x, n * step, 0], c, 1);
    line([-n * step, x, 0], [n * step, x, 0], c, 1);
  }
  const o = [0, 0, 0];
  line(o, [1, 0, 0], "#f25c54", 2.5 * devicePixelRatio);
  line(o, [0, 1, 0], "#3ecf6e", 2.5 * devicePixelRatio);
  line(o, [0, 0, 1], "#6ea8fe", 2.5 * devicePixelRatio);
  label([1.05, 0, 0], "x", "#f25c54"); label([0, 1.05, 0], "y", "#3ecf6e");
  label([0, 0, 1.05], "z", "#6ea8fe");
}

// Kinect v2 depth camera: 70.6 x 60 degrees; sensor frame x right, y down, z forward
const FRUSTUM_HX = Math.tan(35.3 * Math.PI / 180), FRUSTUM_HY = Math.tan(30 * Math.PI / 180);
function drawFrustums() {
  if (!S.status || !S.showFrustums) return;
  const depth = 0.6;
  for (const s of S.status.sensors) {
    if (!s.pose) continue;
    const m = s.pose;  // row-major 4x4 sensor -> world
    const T = (x, y, z) => [m[0] * x + m[1] * y + m[2] * z + m[3], m[4] * x + m[5] * y + m[6] * z + m[7],
                            m[8] * x + m[9] * y + m[10] * z + m[11]];
    const c = T(0, 0, 0);
    const corners = [[-1, -1], [1, -1], [1, 1], [-1, 1]].map(
      ([a, b]) => T(a * FRUSTUM_HX * depth, b * FRUSTUM_HY * depth, depth));
    const col = sensorColour(s.id);
    const w = 1.4 * devicePixelRatio;
    for (let i = 0; i < 4; i++) {
      line(c, corners[i], col, w);
      line(corners[i], corners[(i + 1) % 4], col, w);
    }
    line(corners[0], corners[1], col, 3 * devicePixelRatio);  // top edge (image up)
    line([c[0], c[1], 0], c, "#3a414d", 1, [4, 4]);           // stand
    label(c, s.id + (s.connected ? "" : " (offline)"), col);
  }
}

function drawSkeleton(l, colour, width, dash) {
  for (const [a, b] of S.hello.bones) {
    const pa = P(l.pos, a), pb = P(l.pos, b);
    if (finite(pa) && finite(pb)) line(pa, pb, colour, width, dash);
  }
}

let screenJoints = [];  // for hovering: [x, y, joint]
// where each drawn joint of the shown result is, in CSS pixels of the canvas (for tests)
window.kinefuseJoints = () => screenJoints.map(
  (q) => ({joint: q.j, x: q.s[0] / (devicePixelRatio || 1), y: q.s[1] / (devicePixelRatio || 1)}));
function drawPrimary(l) {
  drawSkeleton(l, "#dfe6ee", 3 * devicePixelRatio);
  const counts = [0, 0, 0, 0];
  const pts = [];
  for (let j = 0; j < 25; j++) {
    const code = l.status ? l.status[j] : 0;
    const cls = statusClass(code);
    counts[cls] += 1;
    const p = P(l.pos, j);
    if (!finite(p)) continue;
    const v = toView(p);
    if (v[2] < NEAR) continue;
    pts.push({s: toScreen(v), z: v[2], j, cls});
  }
  pts.sort((a, b) => b.z - a.z);
  screenJoints = pts;
  for (const q of pts) {
    const r = Math.max(3, 0.045 * FPX / q.z);
    ctx.setLineDash([]);
    ctx.fillStyle = CLASSES[q.cls].colour;
    ctx.strokeStyle = q.j === S.hoverJoint ? "#ffffff" : "#0b0d10";
    ctx.lineWidth = q.j === S.hoverJoint ? 2.5 : 1;
    ctx.beginPath(); ctx.arc(q.s[0], q.s[1], r, 0, 2 * Math.PI); ctx.fill(); ctx.stroke();
  }
  renderLegend(counts);
}

function draw() {
  needs = false;
  const dpr = devicePixelRatio || 1;
  const w = Math.round(canvas.clientWidth * dpr), h = Math.round(canvas.clientHeight * dpr);
  if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
  W = w; H = h; B = basis();
  FPX = 0.5 * H / Math.tan(cam.fov / 2);
  ctx.setLineDash([]);
  ctx.fillStyle = "#14171c"; ctx.fillRect(0, 0, W, H);
  drawGrid();
  drawFrustums();
  const f = S.frame;
  if (!f || !S.hello) { renderLegend(null); return; }
  for (const l of f.layers) {
    if (!S.shown[layerKey(l)]) continue;
    if (l.kind === KIND_RAW) drawSkeleton(l, sensorColour(l.name), 1.2 * dpr);
  }
  const t = truthLayer();
  if (t && S.shown[layerKey(t)]) drawSkeleton(t, "rgba(230,230,230,0.75)", 1.5 * dpr, [5 * dpr, 4 * dpr]);
  const prim = primaryLayer();
  for (const l of f.layers) {
    if (l.kind !== KIND_FUSED || l === prim || !S.shown[layerKey(l)]) continue;
    drawSkeleton(l, layerColour(l), 1.6 * dpr);
  }
  // every person: the subject is the fused skeleton above; the others in their colours; each
  // with its id beside the head
  for (const l of f.layers) {
    if (l.kind !== KIND_PERSON || !S.shown[layerKey(l)]) continue;
    if (!isSubject(l)) drawSkeleton(l, layerColour(l), 1.6 * dpr);
    const head = P(l.pos, HEAD);
    if (finite(head)) label(head, l.name, layerColour(l));
  }
  if (prim) drawPrimary(prim); else renderLegend(null);
  $("method-label").textContent = prim ? "showing " + prim.name : "";
}

let needs = true;
function dirty() { needs = true; }
function tick() { if (needs) draw(); requestAnimationFrame(tick); }

// ---------------------------------------------------------------------------------------------
// mouse: orbit (left), pan (right or shift+left), zoom (wheel), hover a joint

let drag = null;
canvas.addEventListener("contextmenu", (e) => e.preventDefault());
canvas.addEventListener("mousedown", (e) => {
  drag = {x: e.clientX, y: e.clientY, pan: e.button === 2 || e.shiftKey};
});
window.addEventListener("mouseup", () => { drag = null; });
window.addEventListener("mousemove", (e) => {
  if (drag) {
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    drag.x = e.clientX; drag.y = e.clientY;
    if (drag.pan) {
      const k = cam.dist * 0.0015;
      const b = basis();
      for (let i = 0; i < 3; i++) cam.target[i] += -dx * k * b.r[i] + dy * k * b.u[i];
    } else {
      cam.az -= dx * 0.008;
      cam.el = Math.min(1.5, Math.max(-0.2, cam.el + dy * 0.006));
    }
    dirty();
    return;
  }
  hover(e);
});
canvas.addEventListener("wheel", (e) => {
  e.preventDefault();
  cam.dist = Math.min(40, Math.max(0.5, cam.dist * Math.exp(e.deltaY * 0.001)));
  dirty();
}, {passive: false});
canvas.addEventListener("dblclick", () => { S.framed = false; if (S.frame) frameCamera(S.frame); });

function hover(e) {
  const rect = canvas.getBoundingClientRect();
  if (e.clientX < rect.left || e.clientX > rect.right || e.clientY < rect.top ||
      e.clientY > rect.bottom) return;
  const dpr = devicePixelRatio || 1;
  const x = (e.clientX - rect.left) * dpr, y = (e.clientY - rect.top) * dpr;
  let best = -1, bd = 12 * dpr;
  for (const q of screenJoints) {
    const d = Math.hypot(q.s[0] - x, q.s[1] - y);
    if (d < bd) { bd = d; best = q.j; }
  }
  const tip = $("tooltip");
  if (best !== S.hoverJoint) { S.hoverJoint = best; renderErrors(); dirty(); }
  if (best < 0 || !S.hello) { tip.hidden = true; return; }
  const p = primaryLayer(), t = truthLayer();
  const code = p.status ? p.status[best] : 0;
  const pos = P(p.pos, best);
  let html = `<b>${S.hello.joints[best]}</b> · ${S.hello.status_names[String(code)] || code}<br>` +
    `x ${pos[0].toFixed(3)}  y ${pos[1].toFixed(3)}  z ${pos[2].toFixed(3)} m`;
  if (t) html += `<br>error ${fmt(jointError(p, t, best) * 1000, 1)} mm`;
  tip.innerHTML = html;
  tip.style.left = (e.clientX - rect.left + 14) + "px";
  tip.style.top = (e.clientY - rect.top + 10) + "px";
  tip.hidden = false;
}

// ---------------------------------------------------------------------------------------------
// replay controls

$("play").onclick = () => send({cmd: S.player && S.player.playing ? "pause" : "play"});
$("step-back").onclick = () => send({cmd: "step", delta: -1});
$("step-fwd").onclick = () => send({cmd: "step", delta: 1});
$("scrub").oninput = (e) => send({cmd: "seek", frame: Number(e.target.value)});
$("speed").onchange = (e) => send({cmd: "speed", value: Number(e.target.value)});
window.addEventListener("keydown", (e) => {
  if (!S.hello || S.hello.mode !== "replay" || e.target.tagName === "SELECT") return;
  if (e.key === " ") { e.preventDefault(); $("play").click(); }
  else if (e.key === "ArrowRight") send({cmd: "step", delta: 1});
  else if (e.key === "ArrowLeft") send({cmd: "step", delta: -1});
});
window.addEventListener("resize", dirty);

renderLegend(null);
connect();
requestAnimationFrame(tick);
