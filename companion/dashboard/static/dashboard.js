// M4 dashboard: the companion's feed (Server-Sent Events from /events) drawn on canvases.
// Frames as on the wire: world NED, body FRD, Euler ZYX in degrees; the view turns NED
// into east-north-up only to draw. No library, nothing fetched but this server's own files.
"use strict";

const WINDOW_S = 20;                 // time shown by every plot
const STALE_AFTER_S = 2;             // live: a feed silent this long is reported
const ROTOR_COLOURS = ["#4fa3e0", "#ff9f40", "#5cc46b", "#b48ae8"];
const AXIS_COLOURS = ["#e06c75", "#61afef", "#e5c07b"];
const FAULT_RED = "#d32f2f";
const DEG = Math.PI / 180;

const dash = window.m4dash = {events: 0, byTopic: {}, ended: false, faultText: "", t: null, paused: false};
let airframe = null;
let mode = "live";
let replay = null;                    // a replay's {start_s, end_s}: its controls pause and seek
let stream = null;                    // the EventSource of /events (closed while paused)
let pausedAt = null;                  // flight time a paused replay stands at
let lastEventWall = 0;
let latest = {};                      // topic -> newest payload
let hubs = null;                      // hub_frd_m of the newest state
let dirty = true;

// ---- small helpers ------------------------------------------------------------------
const $ = (id) => document.getElementById(id);
const isNum = (v) => typeof v === "number" && Number.isFinite(v);
const fmt = (v, digits, width) => (isNum(v) ? v.toFixed(digits) : "-").padStart(width || 0);
const fmtVec = (vs, digits, width) => (Array.isArray(vs) ? vs.map((v) => fmt(v, digits, width)).join(" ") : "-");

function rotationNedFrd(eulerDeg) {   // R = Rz(yaw) Ry(pitch) Rx(roll), body FRD -> NED
  const [r, p, y] = eulerDeg.map((a) => a * DEG);
  const [cr, sr, cp, sp, cy, sy] = [Math.cos(r), Math.sin(r), Math.cos(p), Math.sin(p), Math.cos(y), Math.sin(y)];
  return [[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
          [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
          [-sp, cp * sr, cp * cr]];
}
const mul = (R, v) => [0, 1, 2].map((i) => R[i][0] * v[0] + R[i][1] * v[1] + R[i][2] * v[2]);
const enu = (ned) => [ned[1], ned[0], -ned[2]];

// ---- the 3D view ----------------------------------------------------------------------
const view = {az: 215, el: 22, distance_m: 1.7, drag: null};

function camera(canvas) {
  const az = view.az * DEG, el = view.el * DEG;
  const dir = [Math.cos(el) * Math.sin(az), Math.cos(el) * Math.cos(az), Math.sin(el)];  // target -> camera, ENU
  const right = [dir[1], -dir[0], 0].map((v) => v / Math.hypot(dir[0], dir[1]));
  const up = [right[1] * dir[2] - right[2] * dir[1], right[2] * dir[0] - right[0] * dir[2],
              right[0] * dir[1] - right[1] * dir[0]];
  const focal = 0.8 * canvas.width * view.distance_m;
  return (p) => {                     // ENU relative to the robot -> [x px, y px, depth m]
    const depth = view.distance_m - (p[0] * dir[0] + p[1] * dir[1] + p[2] * dir[2]);
    const x = p[0] * right[0] + p[1] * right[1] + p[2] * right[2];
    const y = p[0] * up[0] + p[1] * up[1] + p[2] * up[2];
    const d = Math.max(depth, 0.05);
    return [canvas.width / 2 + focal * x / d, canvas.height * 0.5 - focal * y / d, depth];
  };
}

function drawPosture() {
  const canvas = $("view3d"), ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const state = latest.state;
  if (!airframe || !state || !Array.isArray(state.euler_deg) || !state.euler_deg.every(isNum)) {
    ctx.fillStyle = "#6b7680";
    ctx.fillText("waiting for the state", 12, 20);
    return;
  }
  const project = camera(canvas);
  const R = rotationNedFrd(state.euler_deg);
  const body = (frd) => project(enu(mul(R, frd)));
  drawGround(ctx, project, state.pos_ned_m);
  drawPrediction(ctx, project, state.pos_ned_m);
  const items = boxFaces(body).concat(legItems(ctx, body, R));
  items.sort((a, b) => b.depth - a.depth).forEach((item) => item.draw(ctx));
  drawCompass(ctx, project, canvas);
}

function drawGround(ctx, project, pos) {
  if (!Array.isArray(pos) || !pos.every(isNum)) return;
  const step = 0.5, half = 3;
  const n0 = Math.round(pos[0] / step) * step, e0 = Math.round(pos[1] / step) * step;
  ctx.strokeStyle = "#26323e";
  ctx.lineWidth = 1;
  for (let k = -half; k <= half; k += step) {
    for (const [a, b] of [[[n0 + k, e0 - half], [n0 + k, e0 + half]], [[n0 - half, e0 + k], [n0 + half, e0 + k]]]) {
      const pa = project(enu([a[0] - pos[0], a[1] - pos[1], -pos[2]]));
      const pb = project(enu([b[0] - pos[0], b[1] - pos[1], -pos[2]]));
      if (pa[2] < 0.1 || pb[2] < 0.1) continue;
      line(ctx, pa, pb);
    }
  }
}

function drawPrediction(ctx, project, pos) {
  const predicted = latest.nmpc && latest.nmpc.predicted_p_ned_m;
  if (!Array.isArray(predicted) || !Array.isArray(pos) || !pos.every(isNum)) return;
  const pts = predicted.filter((p) => Array.isArray(p) && p.every(isNum))
    .map((p) => project(enu([p[0] - pos[0], p[1] - pos[1], p[2] - pos[2]])));
  ctx.strokeStyle = "#e5c07b";
  ctx.lineWidth = 2;
  ctx.beginPath();
  pts.forEach((p, i) => (i ? ctx.lineTo(p[0], p[1]) : ctx.moveTo(p[0], p[1])));
  ctx.stroke();
}

function boxFaces(body) {
  const [lx, ly, lz] = airframe.body_box_size_m.map((v) => v / 2);
  const corner = (i) => body([(i & 1 ? 1 : -1) * lx, (i & 2 ? 1 : -1) * ly, (i & 4 ? 1 : -1) * lz]);
  const faces = [[1, 3, 7, 5, "#8fa9c4"], [0, 2, 6, 4, "#4c5d6e"], [2, 3, 7, 6, "#5d7186"],
                 [0, 1, 5, 4, "#5d7186"], [0, 1, 3, 2, "#6d8399"], [4, 5, 7, 6, "#3d4b59"]];  // front, rear, right, left, top, bottom
  return faces.map(([a, b, c, d, colour]) => {
    const pts = [a, b, c, d].map(corner);
    return {depth: pts.reduce((s, p) => s + p[2], 0) / 4, draw: (ctx) => polygon(ctx, pts, colour, "#c5d3e0", 0.92)};
  });
}

function legItems(ctx, body, R) {
  const state = latest.state, fault = latest.fault;
  const ceilings = (fault && fault.thrust_max_estimate_n) || [];
  const points = hubs || airframe.nominal_hub_frd_m;
  return points.map((hub, i) => {
    const hip = body(airframe.hip_frd_m[i]), centre = body(hub);
    const dead = fault && fault.state === "confirmed" && fault.rotor === i + 1;
    const thrust = state.thrust_n && state.thrust_n[i];
    const disc = [];
    for (let k = 0; k < 24; k++) {
      const a = (2 * Math.PI * k) / 24;
      disc.push(body([hub[0] + airframe.wheel_radius_m * Math.cos(a), hub[1] + airframe.wheel_radius_m * Math.sin(a), hub[2]]));
    }
    const arrowLength = isNum(thrust) ? (0.35 * thrust) / airframe.thrust_max_n : 0;
    const tip = body([hub[0], hub[1], hub[2] - arrowLength]);
    const share = isNum(thrust) && isNum(ceilings[i]) && ceilings[i] > 0 ? Math.min(thrust / ceilings[i], 1) : 0;
    return {
      depth: centre[2],
      draw: (c) => {
        c.strokeStyle = "#aab6c2";
        c.lineWidth = 5;
        line(c, hip, centre);
        polygon(c, disc, dead ? FAULT_RED : ROTOR_COLOURS[i], dead ? FAULT_RED : "#e8eef4", 0.25 + 0.6 * share);
        c.strokeStyle = dead ? FAULT_RED : ROTOR_COLOURS[i];
        c.lineWidth = 3;
        line(c, centre, tip);
        c.fillStyle = "#ffffff";
        c.font = "bold 13px sans-serif";
        c.fillText(String(i + 1), centre[0] + 8, centre[1] - 8);
      },
    };
  });
}

function drawCompass(ctx, project, canvas) {
  const origin = project([0, 0, 0]);
  const x0 = 36, y0 = canvas.height - 30;
  for (const [label, v, colour] of [["N", [0, 0.15, 0], "#e06c75"], ["E", [0.15, 0, 0], "#61afef"], ["Up", [0, 0, 0.15], "#98c379"]]) {
    const p = project(v);
    const dx = p[0] - origin[0], dy = p[1] - origin[1], scale = 0.4;
    ctx.strokeStyle = ctx.fillStyle = colour;
    ctx.lineWidth = 2;
    line(ctx, [x0, y0], [x0 + dx * scale, y0 + dy * scale]);
    ctx.font = "11px sans-serif";
    ctx.fillText(label, x0 + dx * scale * 1.25 - 4, y0 + dy * scale * 1.25 + 4);
  }
}

function line(ctx, a, b) {
  ctx.beginPath();
  ctx.moveTo(a[0], a[1]);
  ctx.lineTo(b[0], b[1]);
  ctx.stroke();
}

function polygon(ctx, pts, fill, stroke, alpha) {
  ctx.beginPath();
  pts.forEach((p, i) => (i ? ctx.lineTo(p[0], p[1]) : ctx.moveTo(p[0], p[1])));
  ctx.closePath();
  ctx.globalAlpha = alpha;
  ctx.fillStyle = fill;
  ctx.fill();
  ctx.globalAlpha = 1;
  ctx.strokeStyle = stroke;
  ctx.lineWidth = 1;
  ctx.stroke();
}

function enableDrag() {          // drag the 3D view to turn it
  const canvas = $("view3d");
  canvas.addEventListener("pointerdown", (e) => { view.drag = [e.clientX, e.clientY, view.az, view.el]; });
  window.addEventListener("pointerup", () => { view.drag = null; });
  window.addEventListener("pointermove", (e) => {
    if (!view.drag) return;
    view.az = view.drag[2] - (e.clientX - view.drag[0]) * 0.5;
    view.el = Math.max(-80, Math.min(85, view.drag[3] + (e.clientY - view.drag[1]) * 0.5));
    dirty = true;
  });
}

// ---- the time series -----------------------------------------------------------------
class Plot {
  constructor(title, unit, series, range) {
    this.title = title;
    this.unit = unit;
    this.series = series.map((s) => ({...s, data: []}));
    this.range = range || {};        // fixed {min, max} that the data may widen
    this.canvas = document.createElement("canvas");
    this.canvas.className = "plot";
    this.canvas.dataset.title = title;
    $("plots").appendChild(this.canvas);
  }

  push(label, t, v) {
    const s = this.series.find((x) => x.label === label);
    if (!s || !isNum(t) || !isNum(v)) return;
    s.data.push([t, v]);
    if (s.data.length > 4 && s.data[0][0] < t - 2 * WINDOW_S) s.data.splice(0, s.data.length >> 2);
  }

  draw(tNow, marks) {
    const c = this.canvas, ctx = c.getContext("2d");
    const w = (c.width = c.clientWidth), h = (c.height = c.clientHeight);
    const left = 44, right = 8, top = 20, bottom = 18;
    if (!this.series.some((s) => s.data.length)) {
      ctx.font = "12px sans-serif";
      ctx.fillStyle = "#6b7680";
      ctx.fillText(`${this.title}: nothing received`, left, h / 2);
      return;
    }
    const first = Math.min(...this.series.map((s) => (s.data.length ? s.data[0][0] : Infinity)));
    const t0 = Math.max(Number.isFinite(first) ? first : tNow, tNow - WINDOW_S), t1 = Math.max(tNow, t0 + 2);
    let lo = this.range.min, hi = this.range.max;
    for (const s of this.series) for (const [t, v] of s.data) if (t >= t0) {
      lo = lo === undefined ? v : Math.min(lo, v);
      hi = hi === undefined ? v : Math.max(hi, v);
    }
    ctx.font = "11px sans-serif";
    ctx.fillStyle = "#c9d1d9";
    ctx.fillText(`${this.title} (${this.unit})`, left, 13);
    let x = left + ctx.measureText(`${this.title} (${this.unit})`).width + 10;
    for (const s of this.series.filter((x) => x.legend !== false)) {
      ctx.fillStyle = s.colour;
      const last = s.data.length ? fmt(s.data[s.data.length - 1][1], s.digits === undefined ? 1 : s.digits) : "-";
      const text = `${s.label} ${last}`;
      ctx.fillText(text, x, 13);
      x += ctx.measureText(text).width + 8;
    }
    if (lo === undefined) return;
    if (hi - lo < 1e-6) { lo -= 0.5; hi += 0.5; }
    const pad = 0.06 * (hi - lo);
    lo -= pad; hi += pad;
    const X = (t) => left + ((t - t0) / (t1 - t0)) * (w - left - right);
    const Y = (v) => top + ((hi - v) / (hi - lo)) * (h - top - bottom);
    ctx.strokeStyle = "#222c36";
    ctx.fillStyle = "#7d8893";
    ctx.lineWidth = 1;
    for (const v of ticks(lo, hi, 4)) {
      line(ctx, [left, Y(v)], [w - right, Y(v)]);
      ctx.fillText(String(+v.toPrecision(4)), 2, Y(v) + 4);
    }
    for (const t of ticks(t0, t1, 6)) {
      line(ctx, [X(t), top], [X(t), h - bottom]);
      ctx.fillText(`${+t.toPrecision(4)} s`, X(t) - 10, h - 4);
    }
    for (const mark of marks) {
      if (mark.t < t0) continue;
      ctx.strokeStyle = ctx.fillStyle = FAULT_RED;
      ctx.lineWidth = 2;
      line(ctx, [X(mark.t), top], [X(mark.t), h - bottom]);
      const width = ctx.measureText(mark.label).width;
      ctx.fillText(mark.label, X(mark.t) + width + 6 < w - right ? X(mark.t) + 3 : X(mark.t) - width - 3, top + 10);
    }
    ctx.save();
    ctx.beginPath();
    ctx.rect(left, top, w - left - right, h - top - bottom);
    ctx.clip();
    for (const s of this.series) {
      ctx.strokeStyle = s.colour;
      ctx.lineWidth = s.width || 1.6;
      ctx.setLineDash(s.dash || []);
      ctx.beginPath();
      let started = false;
      for (const [t, v] of s.data) {
        if (t < t0 - 1) continue;
        if (started) ctx.lineTo(X(t), Y(v)); else ctx.moveTo(X(t), Y(v));
        started = true;
      }
      ctx.stroke();
    }
    ctx.restore();
    ctx.setLineDash([]);
  }
}

function ticks(lo, hi, count) {
  const raw = (hi - lo) / count, mag = Math.pow(10, Math.floor(Math.log10(raw)));
  const step = [1, 2, 5, 10].map((m) => m * mag).find((s) => s >= raw);
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi; v += step) out.push(v);
  return out;
}

const perRotor = (prefix, extra) => [0, 1, 2, 3].map((i) => ({label: `${prefix}${i + 1}`, colour: ROTOR_COLOURS[i], ...extra}));
let plots = null;

function makePlots() {
  const thrustMax = airframe ? airframe.thrust_max_n : 30;
  plots = {
    attitude: new Plot("attitude", "deg", ["roll", "pitch", "yaw"].map((label, i) => ({label, colour: AXIS_COLOURS[i]}))),
    altitude: new Plot("altitude", "m", [{label: "alt", colour: "#98c379", digits: 2}]),
    thrust: new Plot("thrust, commanded dotted, ceiling dashed", "N", perRotor("T").concat(
      perRotor("cmd", {dash: [2, 3], width: 1.2, legend: false}),
      perRotor("max", {dash: [5, 4], width: 1.2, legend: false})), {min: 0, max: thrustMax}),
    hips: new Plot("hips, setpoint dashed", "deg", perRotor("q").concat(
      perRotor("set", {dash: [5, 4], width: 1.2, legend: false})),
      {min: airframe ? airframe.hip_min_deg : 0, max: airframe ? airframe.hip_max_deg : 90}),
    yawRate: new Plot("yaw rate", "rad/s", [{label: "r", colour: AXIS_COLOURS[2], digits: 2}]),
    velocity: new Plot("velocity NED", "m/s", ["vN", "vE", "vD"].map((label, i) => ({label, colour: AXIS_COLOURS[i], digits: 2}))),
    disturbance: new Plot("disturbance estimate NED", "N",
      ["dN", "dE", "dD"].map((label, i) => ({label, colour: AXIS_COLOURS[i]}))),
    solve: new Plot("NMPC solve time", "ms", [{label: "solve", colour: "#c678dd", digits: 2}], {min: 0}),
    link: new Plot("link: last message age, latency", "ms", [{label: "age", colour: "#56b6c2"}], {min: 0}),
  };
}

function latencySeries(link) {   // any published latency or delay field, shown in ms
  for (const [name, v] of Object.entries(link)) {
    const m = /^(.*(latency|delay).*)_(ms|s)$/.exec(name);
    if (!m || !isNum(v)) continue;
    if (!plots.link.series.find((s) => s.label === m[1])) {
      plots.link.series.push({label: m[1], colour: AXIS_COLOURS[plots.link.series.length % 3], data: []});
    }
    plots.link.push(m[1], link.t_s, m[3] === "s" ? v * 1000 : v);
  }
}

// ---- feed events ---------------------------------------------------------------------
const handlers = {
  state(p) {
    const t = p.t_s;
    (p.euler_deg || []).forEach((v, i) => plots.attitude.push(["roll", "pitch", "yaw"][i], t, v));
    if (Array.isArray(p.pos_ned_m)) plots.altitude.push("alt", t, -p.pos_ned_m[2]);
    (p.thrust_n || []).forEach((v, i) => plots.thrust.push(`T${i + 1}`, t, v));
    (p.hip_deg || []).forEach((v, i) => plots.hips.push(`q${i + 1}`, t, v));
    if (Array.isArray(p.rates_frd_rad_s)) plots.yawRate.push("r", t, p.rates_frd_rad_s[2]);
    (p.vel_ned_m_s || []).forEach((v, i) => plots.velocity.push(["vN", "vE", "vD"][i], t, v));
  },
  setpoint(p) {
    (p.hip_deg || []).forEach((v, i) => plots.hips.push(`set${i + 1}`, p.t_s, v));
    (p.thrust_n || []).forEach((v, i) => plots.thrust.push(`cmd${i + 1}`, p.t_s, v));
  },
  fault(p) {
    (p.thrust_max_estimate_n || []).forEach((v, i) => plots.thrust.push(`max${i + 1}`, p.t_s, v));
    showFault(p);
  },
  nmpc(p) {
    plots.solve.push("solve", p.t_s, p.solve_ms);
    (p.disturbance_force_ned_n || []).forEach((v, i) => plots.disturbance.push(["dN", "dE", "dD"][i], p.t_s, v));
  },
  link(p) {
    if (isNum(p.last_msg_age_s)) plots.link.push("age", p.t_s, p.last_msg_age_s * 1000);
    latencySeries(p);
  },
};

// What the fault is, the rotor's name added to the message's own parentheses (the fault's
// kind): "thrust loss rotor 4 (rear-right, motor)". The message stays word for word the
// STATUSTEXT the companion sent.
function faultWhat(p) {
  const what = p.message || (p.rotor ? `rotor ${p.rotor}` : "unknown rotor");
  if (!airframe || !p.rotor) return what;
  const name = airframe.rotor_names[p.rotor - 1];
  const kind = what.match(/^(.*) \((.+)\)$/);
  return kind ? `${kind[1]} (${name}, ${kind[2]})` : `${what} (${name})`;
}

function showFault(p) {
  const banner = $("banner");
  const state = ["healthy", "suspect", "confirmed"].includes(p.state) ? p.state : "waiting";
  let text = "no fault";
  if (state !== "healthy") {
    const when = isNum(p.detected_at_s) ? `, detected at t = ${p.detected_at_s.toFixed(2)} s` : "";
    text = `${state === "confirmed" ? "FAULT" : "SUSPECT"}: ${faultWhat(p)}${when}`
      + ` \u2014 thrust ceilings ${fmtVec(p.thrust_max_estimate_n, 1)} N`;
  }
  banner.className = state;
  banner.textContent = text;
  dash.faultText = text;
}

function faultMarks() {
  const f = latest.fault;
  return f && f.state !== "healthy" && isNum(f.detected_at_s)
    ? [{t: f.detected_at_s, label: `rotor ${f.rotor || "?"} detected`}] : [];
}

function onEvent(event) {
  const p = event.payload;
  latest[event.topic] = p;
  if (isNum(p.t_s)) dash.t = p.t_s;           // the newest instant received (drawn at the next frame)
  if (event.topic === "state") hubs = event.hub_frd_m || null;
  dash.events += 1;
  dash.byTopic[event.topic] = (dash.byTopic[event.topic] || 0) + 1;
  handlers[event.topic](p);
  lastEventWall = performance.now();
  dirty = true;
}

function updateReadouts() {
  const s = latest.state || {}, sp = latest.setpoint || {}, f = latest.fault || {}, n = latest.nmpc, l = latest.link;
  const t = [s, n || {}, sp].map((p) => p.t_s).find(isNum);
  $("clock").textContent = `t = ${fmt(t, 2)} s`;
  if (replay && isNum(t) && document.activeElement !== $("seek")) $("seek").value = t;
  $("r-pos").textContent = fmtVec(s.pos_ned_m, 2, 7);
  $("r-att").textContent = Array.isArray(s.euler_deg)
    ? `roll ${fmt(s.euler_deg[0], 1)}  pitch ${fmt(s.euler_deg[1], 1)}  yaw ${fmt(s.euler_deg[2], 1)}` : "-";
  $("r-thrust").textContent = fmtVec(s.thrust_n, 1, 6);
  $("r-thrust-set").textContent = fmtVec(sp.thrust_n, 1, 6) + (sp.thrust_cut ? "  THRUST CUT" : "");
  $("r-ceiling").textContent = fmtVec(f.thrust_max_estimate_n, 1, 6);
  $("r-hip").textContent = fmtVec(s.hip_deg, 1, 6);
  $("r-nmpc").textContent = n ? `${fmt(n.solve_ms, 2)} ms, ${n.iterations} it, ${n.status}${n.ok ? "" : " NOT OK"}${n.fallback ? " FALLBACK" : ""}` : "-";
  $("r-link").textContent = l ? `${l.connected ? "connected" : "LOST"}, ${fmt(l.msgs_per_s, 0)} msg/s, bad crc ${l.bad_crc}, bad signature ${l.bad_signature}` : "-";
  return t;
}

function setStatus(status, text) {
  document.body.dataset.status = status;
  $("status").textContent = text;
}

function frame() {
  if (dirty && plots) {
    dirty = false;
    const t = updateReadouts();
    drawPosture();
    const marks = faultMarks();
    for (const plot of Object.values(plots)) plot.draw(isNum(t) ? t : 0, marks);
    dash.drawn = (dash.drawn || 0) + 1;
  }
  requestAnimationFrame(frame);
}

function watchStaleness() {
  if (mode !== "live" || !lastEventWall) return;
  const silent = (performance.now() - lastEventWall) / 1000;
  if (silent > STALE_AFTER_S) setStatus("lost", `no feed for ${silent.toFixed(0)} s`);
  else setStatus("live", "live");
}

// ---- the replay's controls: pause closes the stream, play and seek open it at an instant --
function clearPlots() {
  for (const plot of Object.values(plots)) for (const series of plot.series) series.data = [];
  latest = {};
  hubs = null;
}

function openEvents(fromS) {
  if (stream) stream.close();
  if (isNum(fromS)) clearPlots();
  dash.ended = false;
  const source = stream = new EventSource(isNum(fromS) ? `events?from_s=${fromS}` : "events");
  source.onmessage = (msg) => {
    if (source !== stream) return;
    const event = JSON.parse(msg.data);
    onEvent(event);
    if (dash.paused && isNum(event.payload.t_s) && event.payload.t_s >= pausedAt) closeEvents();   // a seek while paused
    else if (document.body.dataset.status === "waiting") setStatus(mode === "live" ? "live" : "replaying", mode === "live" ? "live" : "replaying");
  };
  source.addEventListener("end", () => {
    source.close();
    if (source !== stream) return;
    stream = null;
    dash.ended = true;
    setStatus("ended", "replay ended");
  });
  source.onerror = () => { if (source === stream && !dash.ended) setStatus("lost", "connection to the dashboard lost, retrying"); };
}

function closeEvents() {
  if (stream) stream.close();
  stream = null;
}

function pause() {
  dash.paused = true;
  pausedAt = isNum(dash.t) ? dash.t : replay.start_s;
  closeEvents();
  $("pause").textContent = "play";
  setStatus("paused", `paused at t = ${pausedAt.toFixed(2)} s`);
}

function play() {
  dash.paused = false;
  $("pause").textContent = "pause";
  setStatus("replaying", "replaying");
  openEvents(dash.ended ? replay.start_s : pausedAt);
}

function seek(t) {
  pausedAt = t;
  openEvents(t);
  setStatus(dash.paused ? "paused" : "replaying", dash.paused ? `paused at t = ${t.toFixed(2)} s` : "replaying");
}

function showReplayControls(span) {
  replay = span;
  const slider = $("seek");
  slider.min = span.start_s;
  slider.max = span.end_s;
  slider.value = span.start_s;
  slider.addEventListener("change", () => seek(Number(slider.value)));
  $("pause").addEventListener("click", () => (dash.paused || dash.ended ? play() : pause()));
  $("replay-controls").hidden = false;
  dash.seek = seek;
}

async function start() {
  const config = await (await fetch("config.json")).json();
  airframe = config.airframe;
  mode = config.mode;
  $("source").textContent = `${config.vehicle}: ${config.mode}, ${config.source}`;
  makePlots();
  enableDrag();
  if (config.replay) showReplayControls(config.replay);
  openEvents(null);
  setInterval(watchStaleness, 500);
  window.addEventListener("resize", () => { dirty = true; });
  requestAnimationFrame(frame);
}

start();
