"use strict";
(function () {
const T0 = performance.now();
const D = JSON.parse(document.getElementById("graspd-data").textContent);
function bytes(s) {
  if (Uint8Array.fromBase64) return Uint8Array.fromBase64(s).buffer;
  const b = atob(s), u = new Uint8Array(b.length);
  for (let i = 0; i < b.length; i++) u[i] = b.charCodeAt(i);
  return u.buffer;
}
const P = new Float32Array(bytes(D.points)), L = new Uint8Array(bytes(D.labels));
const S = new Float32Array(bytes(D.segs)), SC = new Uint8Array(bytes(D.segColours));
const SR = new Int16Array(bytes(D.segRanks));
const NG = D.scores.length, visible = new Uint8Array(NG).fill(1);  // ranks the filters let through
let setVisible = null;
const T1 = performance.now();
const scene = document.getElementById("scene"), over = document.getElementById("labels");
const tip = document.getElementById("tip");
let canvas = document.getElementById("@@ID@@");

// vectors and column-major 4x4 matrices
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const add = (a, b, s) => [a[0] + s * b[0], a[1] + s * b[1], a[2] + s * b[2]];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const unit = a => { const n = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / n, a[1] / n, a[2] / n]; };
function mul(a, b) {
  const o = new Float32Array(16);
  for (let c = 0; c < 4; c++) for (let r = 0; r < 4; r++) {
    let s = 0;
    for (let k = 0; k < 4; k++) s += a[k * 4 + r] * b[c * 4 + k];
    o[c * 4 + r] = s;
  }
  return o;
}

// orbit camera about a target: yaw about "up", pitch above the horizontal basis (A, B)
const U = unit(D.up), A = unit(D.across), B = cross(U, A), FOV = 40 * Math.PI / 180;
function home() {
  let d = D.eye, r = Math.hypot(d[0], d[1], d[2]);
  if (r < 1e-6) { d = add(A, U, 0.5); r = 2 * D.extent; }
  d = unit(d);
  return { t: [0, 0, 0], r: r, yaw: Math.atan2(dot(d, B), dot(d, A)),
           pitch: Math.asin(Math.max(-1, Math.min(1, dot(d, U)))) };
}
let cam = home();
function view() {
  const cp = Math.cos(cam.pitch), sp = Math.sin(cam.pitch), cy = Math.cos(cam.yaw), sy = Math.sin(cam.yaw);
  const dir = [0, 1, 2].map(i => cp * (cy * A[i] + sy * B[i]) + sp * U[i]);
  const eye = add(cam.t, dir, cam.r), z = unit(dir);
  let x = cross(U, z);
  if (Math.hypot(x[0], x[1], x[2]) < 1e-6) x = A; else x = unit(x);
  const y = cross(z, x);
  const w = canvas.width, h = canvas.height, f = 1 / Math.tan(FOV / 2);
  const n = Math.max(cam.r * 0.005, 1e-4), far = cam.r + 4 * D.extent + 1;
  const proj = new Float32Array([f * h / w, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + n) / (n - far), -1,
                                 0, 0, 2 * far * n / (n - far), 0]);
  const look = new Float32Array([x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0,
                                 -dot(x, eye), -dot(y, eye), -dot(z, eye), 1]);
  return { m: mul(proj, look), x: x, y: y };
}
function project(m, p) {  // pixel position (css px) and whether in front
  const cx = m[0] * p[0] + m[4] * p[1] + m[8] * p[2] + m[12], cy = m[1] * p[0] + m[5] * p[1] + m[9] * p[2] + m[13];
  const cw = m[3] * p[0] + m[7] * p[1] + m[11] * p[2] + m[15];
  return [(cx / cw * 0.5 + 0.5) * scene.clientWidth, (0.5 - cy / cw * 0.5) * scene.clientHeight, cw > 0];
}

let hl = -1, pinned = -1;
const dpr = window.devicePixelRatio || 1;
function size() {
  const w = Math.max(1, Math.round(scene.clientWidth * dpr)), h = Math.max(1, Math.round(scene.clientHeight * dpr));
  for (const c of [canvas, over]) if (c.width !== w || c.height !== h) { c.width = w; c.height = h; }
}

// WebGL: points by label, segments as screen-space quads (ranked grippers thicker when highlighted)
let gl = null;
// no multisampling: SwiftShader (headless, no GPU) takes about twice as long for the first frame with it
try { gl = canvas.getContext("webgl", { antialias: false, preserveDrawingBuffer: true }); } catch (e) { gl = null; }
const TC = performance.now();
let drawGL = null;
if (gl) {
  const prog = (vs, fs) => {
    const p = gl.createProgram();
    for (const [type, src] of [[gl.VERTEX_SHADER, vs], [gl.FRAGMENT_SHADER, fs]]) {
      const s = gl.createShader(type);
      gl.shaderSource(s, src); gl.compileShader(s);
      if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
      gl.attachShader(p, s);
    }
    gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(p));
    return p;
  };
  const FS = "precision mediump float; varying vec3 c; void main() { gl_FragColor = vec4(c, 1.0); }";
  const pp = prog("attribute vec3 p; attribute float l; uniform mat4 m; uniform vec3 k[4]; uniform float s;" +
    "varying vec3 c; void main() { gl_Position = m * vec4(p, 1.0); int i = int(l + 0.5);" +
    "c = i == 0 ? k[0] : i == 1 ? k[1] : i == 2 ? k[2] : k[3]; gl_PointSize = i == 0 ? 1.5 * s : s; }", FS);
  const lp = prog("attribute vec3 a; attribute vec3 b; attribute vec2 e; attribute vec3 q; attribute float r;" +
    "attribute float v; uniform mat4 m; uniform vec2 vp; uniform float h; uniform float s; varying vec3 c;" +
    "void main() { vec4 ca = m * vec4(a, 1.0), cb = m * vec4(b, 1.0); vec4 o = e.x < 0.5 ? ca : cb;" +
    "if (v < 0.5 || ca.w <= 0.0 || cb.w <= 0.0) { gl_Position = vec4(2.0, 2.0, 2.0, 1.0); c = q; return; }" +
    "vec2 d = (cb.xy / cb.w - ca.xy / ca.w) * vp; float n = length(d); d = n > 1e-6 ? d / n : vec2(1.0, 0.0);" +
    "float on = (h < -0.5 || r < -0.5) ? 1.0 : (abs(r - h) < 0.5 ? 2.0 : 0.0);" +
    "float w = s * (r < -0.5 ? 1.5 : on > 1.5 ? 4.5 : 2.2);" +
    "o.xy += vec2(-d.y, d.x) * e.y * w / vp * o.w; o.z -= (on > 1.5 ? 0.01 : 0.001) * o.w; gl_Position = o;" +
    "c = on < 0.5 ? mix(q, vec3(0.85), 0.75) : q; }", FS);
  const buf = (data, loc, n, type, norm) => {
    const bo = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, bo); gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
    return () => { gl.bindBuffer(gl.ARRAY_BUFFER, bo); gl.enableVertexAttribArray(loc);
                   gl.vertexAttribPointer(loc, n, type, norm, 0, 0); };
  };
  const ptsAttr = [buf(P, gl.getAttribLocation(pp, "p"), 3, gl.FLOAT, false),
                   buf(L, gl.getAttribLocation(pp, "l"), 1, gl.UNSIGNED_BYTE, false)];
  // six vertices (two triangles) per segment: both ends, both sides
  const ns = D.s, VA = new Float32Array(ns * 18), VB = new Float32Array(ns * 18), VE = new Float32Array(ns * 12);
  const VC = new Uint8Array(ns * 18), VR = new Float32Array(ns * 6);
  const corner = [[0, -1], [0, 1], [1, 1], [0, -1], [1, 1], [1, -1]];
  for (let i = 0; i < ns; i++) for (let j = 0; j < 6; j++) {
    const v = i * 6 + j;
    for (let k = 0; k < 3; k++) {
      VA[v * 3 + k] = S[i * 6 + k]; VB[v * 3 + k] = S[i * 6 + 3 + k]; VC[v * 3 + k] = SC[i * 3 + k];
    }
    VE[v * 2] = corner[j][0]; VE[v * 2 + 1] = corner[j][1]; VR[v] = SR[i];
  }
  const segAttr = [buf(VA, gl.getAttribLocation(lp, "a"), 3, gl.FLOAT, false),
                   buf(VB, gl.getAttribLocation(lp, "b"), 3, gl.FLOAT, false),
                   buf(VE, gl.getAttribLocation(lp, "e"), 2, gl.FLOAT, false),
                   buf(VC, gl.getAttribLocation(lp, "q"), 3, gl.UNSIGNED_BYTE, true),
                   buf(VR, gl.getAttribLocation(lp, "r"), 1, gl.FLOAT, false)];
  const VV = new Float32Array(ns * 6).fill(1), vvBuf = gl.createBuffer(), vvLoc = gl.getAttribLocation(lp, "v");
  setVisible = () => {
    for (let i = 0; i < ns; i++) VV.fill(SR[i] < 0 || visible[SR[i]] ? 1 : 0, i * 6, i * 6 + 6);
    gl.bindBuffer(gl.ARRAY_BUFFER, vvBuf); gl.bufferData(gl.ARRAY_BUFFER, VV, gl.DYNAMIC_DRAW);
  };
  setVisible();
  segAttr.push(() => { gl.bindBuffer(gl.ARRAY_BUFFER, vvBuf); gl.enableVertexAttribArray(vvLoc);
                       gl.vertexAttribPointer(vvLoc, 1, gl.FLOAT, false, 0, 0); });
  const colours = new Float32Array([].concat(...D.colours).map(v => v / 255));
  drawGL = (m) => {
    gl.viewport(0, 0, canvas.width, canvas.height);
    gl.clearColor(1, 1, 1, 1); gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.enable(gl.DEPTH_TEST); gl.depthFunc(gl.LEQUAL);
    gl.useProgram(pp); ptsAttr.forEach(f => f());
    gl.uniformMatrix4fv(gl.getUniformLocation(pp, "m"), false, m);
    gl.uniform3fv(gl.getUniformLocation(pp, "k"), colours);
    gl.uniform1f(gl.getUniformLocation(pp, "s"), 2 * dpr);
    gl.drawArrays(gl.POINTS, 0, D.n);
    for (let i = 0; i < 2; i++) gl.disableVertexAttribArray(i);
    if (ns) {
      gl.useProgram(lp); segAttr.forEach(f => f());
      gl.uniformMatrix4fv(gl.getUniformLocation(lp, "m"), false, m);
      gl.uniform2f(gl.getUniformLocation(lp, "vp"), canvas.width, canvas.height);
      gl.uniform1f(gl.getUniformLocation(lp, "h"), hl);
      gl.uniform1f(gl.getUniformLocation(lp, "s"), dpr);
      gl.drawArrays(gl.TRIANGLES, 0, ns * 6);
      for (let i = 0; i < 6; i++) gl.disableVertexAttribArray(i);
    }
  };
}
const T2 = performance.now();
if (!gl) {  // no WebGL: a fresh canvas (the failed one cannot give a 2D context in every browser)
  const c2 = document.createElement("canvas");
  c2.id = canvas.id; canvas.replaceWith(c2); canvas = c2;
}

function draw2D(m) {  // the same picture without depth test: environment, then object points, then grippers
  const ctx = canvas.getContext("2d"), w = canvas.width, h = canvas.height;
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0); ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, w, h);
  for (const label of [1, 2, 3, 0]) {
    const k = D.colours[label], s = label === 0 ? 3 : 2;
    ctx.fillStyle = "rgb(" + k.join(",") + ")";
    for (let i = 0; i < D.n; i++) if (L[i] === label) {
      const q = project(m, [P[3 * i], P[3 * i + 1], P[3 * i + 2]]);
      if (q[2]) ctx.fillRect(q[0] - s / 2, q[1] - s / 2, s, s);
    }
  }
  for (let i = 0; i < D.s; i++) {
    const a = project(m, [S[6 * i], S[6 * i + 1], S[6 * i + 2]]);
    const b = project(m, [S[6 * i + 3], S[6 * i + 4], S[6 * i + 5]]);
    if (!a[2] || !b[2]) continue;
    const r = SR[i], dim = hl >= 0 && r >= 0 && r !== hl;
    if (r >= 0 && !visible[r]) continue;
    ctx.strokeStyle = dim ? "#e0c8c8" : "rgb(" + SC[3 * i] + "," + SC[3 * i + 1] + "," + SC[3 * i + 2] + ")";
    ctx.lineWidth = r < 0 ? 1.5 : r === hl ? 4.5 : 2.2;
    ctx.beginPath(); ctx.moveTo(a[0], a[1]); ctx.lineTo(b[0], b[1]); ctx.stroke();
  }
}

function frame() {
  size();
  const v = view();
  if (drawGL) drawGL(v.m); else draw2D(v.m);
  const ctx = over.getContext("2d");
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0); ctx.clearRect(0, 0, over.width, over.height);
  ctx.font = "bold 11px sans-serif"; ctx.textAlign = "center"; ctx.textBaseline = "middle";
  ctx.lineWidth = 3; ctx.strokeStyle = "#fff"; ctx.fillStyle = "#000";
  D.tags.forEach((t, k) => {  // the first ranks' numbers, or only the highlighted one's
    if (!visible[k] || (hl >= 0 ? k !== hl : k >= D.labelled)) return;
    const q = project(v.m, t);
    if (q[2]) { ctx.strokeText(String(k + 1), q[0], q[1]); ctx.fillText(String(k + 1), q[0], q[1]); }
  });
  return v;
}
let queued = false;
function redraw() { if (!queued) { queued = true; requestAnimationFrame(() => { queued = false; frame(); }); } }

// the first frame, and when it is drawn (the browser tests and bench/viewer.py read data-drawn)
frame();
if (gl) gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, new Uint8Array(4));  // wait for the GPU
canvas.setAttribute("data-mode", gl ? "webgl" : "2d");
const T3 = performance.now();
const ms = x => x.toFixed(0);
canvas.setAttribute("data-timings", "script start " + ms(T0) + " ms, data decoded +" + ms(T1 - T0) +
  ", context +" + ms(TC - T1) + ", set up +" + ms(T2 - TC) + ", first frame +" + ms(T3 - T2));
canvas.setAttribute("data-drawn", String(T3));

// the side list: hovering or clicking a row highlights its gripper
const rows = document.querySelectorAll("#grasps tbody tr");
function highlight(k) {
  if (k === hl) return;
  hl = k; rows.forEach(r => r.classList.toggle("on", +r.dataset.rank === k)); redraw();
}
// the filters: least score (unscored grasps hidden once it is set), the first k ranks, one object
const minIn = document.getElementById("min-score"), topIn = document.getElementById("top-k");
const objIn = document.getElementById("object"), shownEl = document.getElementById("shown");
function applyFilters() {
  const lo = minIn && minIn.value !== "" ? +minIn.value : null;
  const top = topIn && topIn.value !== "" ? Math.max(1, +topIn.value) : NG;
  const obj = objIn ? +objIn.value : -1;
  let n = 0;
  for (let k = 0; k < NG; k++) {
    const sc = D.scores[k];
    visible[k] = k < top && (lo === null || (sc !== null && sc >= lo)) && (obj < 0 || D.objects[k] === obj) ? 1 : 0;
    n += visible[k];
  }
  rows.forEach(r => { r.hidden = !visible[+r.dataset.rank]; });
  if (shownEl) shownEl.textContent = n + " of " + NG + " grasps shown";
  if (pinned >= 0 && !visible[pinned]) pinned = -1;
  if (setVisible) setVisible();
  hl = -2; highlight(pinned);
}
for (const el of [minIn, topIn]) if (el) el.addEventListener("input", applyFilters);
if (objIn) objIn.addEventListener("change", applyFilters);
rows.forEach(r => {
  const k = +r.dataset.rank;
  r.addEventListener("mouseenter", () => highlight(k));
  r.addEventListener("mouseleave", () => highlight(pinned));
  r.addEventListener("click", () => { pinned = pinned === k ? -1 : k; highlight(pinned); });
});

// orbit (drag), pan (right- or shift-drag), zoom (wheel); hovering a rank number names its grasp
let drag = null;
canvas.addEventListener("contextmenu", e => e.preventDefault());
canvas.addEventListener("pointerdown", e => {
  drag = { x: e.clientX, y: e.clientY, pan: e.button === 2 || e.shiftKey };
  try { canvas.setPointerCapture(e.pointerId); } catch (err) { /* a synthetic pointer */ }
  tip.style.display = "none";
});
canvas.addEventListener("pointerup", () => { drag = null; });
canvas.addEventListener("pointermove", e => {
  if (drag) {
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    drag.x = e.clientX; drag.y = e.clientY;
    if (drag.pan) {
      const v = view(), s = 2 * cam.r * Math.tan(FOV / 2) / scene.clientHeight;
      cam.t = add(add(cam.t, v.x, -dx * s), v.y, dy * s);
    } else {
      cam.yaw -= dx * 0.008;
      cam.pitch = Math.max(-1.55, Math.min(1.55, cam.pitch + dy * 0.008));
    }
    redraw(); return;
  }
  const box = canvas.getBoundingClientRect(), m = view().m;
  let best = -1, bd = 12;
  D.tags.forEach((t, k) => {
    if (!visible[k]) return;
    const q = project(m, t), d = Math.hypot(q[0] - (e.clientX - box.left), q[1] - (e.clientY - box.top));
    if (q[2] && d < bd) { bd = d; best = k; }
  });
  if (best >= 0) {
    tip.textContent = rows[best] ? rows[best].title : String(best + 1);
    tip.style.left = (e.clientX - box.left + 12) + "px"; tip.style.top = (e.clientY - box.top + 12) + "px";
    tip.style.display = "block";
  } else tip.style.display = "none";
  highlight(best >= 0 ? best : pinned);
});
canvas.addEventListener("wheel", e => {
  e.preventDefault(); cam.r *= Math.exp(Math.max(-0.5, Math.min(0.5, e.deltaY * 0.0015))); redraw();
}, { passive: false });
document.getElementById("reset").addEventListener("click", () => {
  cam = home(); pinned = -1; highlight(-1); redraw();
});
window.addEventListener("resize", redraw);
// picking an object: in the service's drop page (a frame) the page there sends the cloud again with
// target.object; a page of its own says how to ask (nothing is sent from here)
const ask = document.getElementById("ask");
document.querySelectorAll("#objects button[data-pick]").forEach(b => {
  b.addEventListener("click", () => {
    const k = parseInt(b.dataset.pick, 10);
    if (window.parent !== window) {
      window.parent.postMessage({ graspdTarget: k }, "*");
      if (ask) ask.textContent = k < 0 ? "asking again for every object ..." : "asking again for object " + k + " ...";
    } else if (ask) {
      ask.textContent = k < 0 ? "ask again without a target" :
        "ask again with target {\"object\": " + k + "} (graspd detect --target-object " + k + ")";
    }
  });
});
applyFilters();
})();
