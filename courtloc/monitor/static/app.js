// courtloc monitor page: draws the court once, then redraws pose, trail and readouts on every
// Server-Sent Event. No libraries: the pit laptop has no internet.
"use strict";

const canvas = document.getElementById("court");
const ctx = canvas.getContext("2d");
let court = null;
let courtImage = null; // the static court drawing, painted once into an offscreen canvas
let lastState = null;
let thumbId = null;

const $ = (id) => document.getElementById(id);
const fixed = (v, digits) => (v === null || v === undefined ? "-" : Number(v).toFixed(digits));

function view() {
  const [hx, hy] = court.floor_half_extent_m;
  const scale = Math.min(canvas.width / (2 * hx), canvas.height / (2 * hy));
  return {
    scale,
    // court metres (x right, y up) -> canvas pixels
    px: (x, y) => [canvas.width / 2 + x * scale, canvas.height / 2 - y * scale],
  };
}

function tracePolygon(c, v, points) {
  points.forEach(([x, y], i) => {
    const [u, w] = v.px(x, y);
    if (i === 0) c.moveTo(u, w); else c.lineTo(u, w);
  });
  c.closePath();
}

function drawCourt() {
  const off = document.createElement("canvas");
  off.width = canvas.width;
  off.height = canvas.height;
  const c = off.getContext("2d");
  const v = view();
  c.fillStyle = court.background;
  c.fillRect(0, 0, off.width, off.height);
  for (const el of court.elements) {
    c.beginPath();
    for (const p of el.exteriors) tracePolygon(c, v, p);
    for (const p of el.holes) tracePolygon(c, v, p);
    c.fillStyle = el.colour;
    c.fill("evenodd");
  }
  c.strokeStyle = "#ff9500";
  c.lineWidth = 3;
  for (const ring of court.rings) {
    const [u, w] = v.px(ring.x, ring.y);
    c.beginPath();
    c.arc(u, w, 0.23 * v.scale, 0, 2 * Math.PI);
    c.stroke();
  }
  courtImage = off;
}

function drawTrail(v, trail, colour) {
  if (!trail || trail.length < 2) return;
  ctx.strokeStyle = colour;
  ctx.lineWidth = 2;
  ctx.beginPath();
  trail.forEach(([x, y], i) => {
    const [u, w] = v.px(x, y);
    if (i === 0) ctx.moveTo(u, w); else ctx.lineTo(u, w);
  });
  ctx.stroke();
}

function drawRobot(v, pose, colour, filled) {
  if (!pose || pose.x === null || pose.y === null) return;
  const [u, w] = v.px(pose.x, pose.y);
  const r = Math.max(10, 0.35 * v.scale);
  ctx.save();
  ctx.translate(u, w);
  ctx.strokeStyle = colour;
  ctx.fillStyle = colour;
  ctx.lineWidth = 3;
  if (pose.yaw === null || pose.yaw === undefined) {
    ctx.beginPath();
    ctx.arc(0, 0, r * 0.6, 0, 2 * Math.PI);
    filled ? ctx.fill() : ctx.stroke();
  } else {
    ctx.rotate(-pose.yaw); // canvas y points down: counter-clockwise yaw is a negative rotation
    ctx.beginPath();
    ctx.moveTo(r, 0);
    ctx.lineTo(-r * 0.6, r * 0.55);
    ctx.lineTo(-r * 0.6, -r * 0.55);
    ctx.closePath();
    filled ? ctx.fill() : ctx.stroke();
  }
  ctx.restore();
}

function redraw() {
  if (!court) return;
  if (!courtImage) drawCourt();
  ctx.drawImage(courtImage, 0, 0);
  const s = lastState;
  if (!s) return;
  const v = view();
  drawTrail(v, s.truth_trail, "rgba(52,195,255,0.8)");
  drawTrail(v, s.trail, "rgba(255,59,48,0.9)");
  drawRobot(v, s.truth, "#34c3ff", false);
  drawRobot(v, s.shadow, "#ffcc00", false);
  drawRobot(v, s.pose, s.status === "live" ? "#ff3b30" : "#888888", true);
}

function setStatus(status) {
  const badge = $("status");
  badge.textContent = status;
  badge.className = "badge status-" + status;
}

function degrees(rad) {
  return rad === null || rad === undefined ? null : (rad * 180) / Math.PI;
}

function update(s) {
  if (s.error) { // the monitor itself failed to build the state: say so instead of freezing
    setStatus("error");
    $("last-error").textContent = s.error;
    return;
  }
  lastState = s;
  $("robot-id").textContent = s.robot_id;
  setStatus(s.status);
  const p = s.pose;
  $("pose-x").textContent = p ? fixed(p.x, 2) : "-";
  $("pose-y").textContent = p ? fixed(p.y, 2) : "-";
  $("heading").textContent = p ? fixed(degrees(p.yaw), 1) : "-";
  $("quality").textContent = p ? fixed(p.quality, 2) + (p.valid ? "" : " (invalid)") : "-";
  $("pose-age").textContent = p && p.age_s !== null ? fixed(p.age_s, 1) + " s" : "-";
  $("model").textContent = p ? `model ${p.model_name} v${p.model_version}` : "model -";
  const sol = s.solution;
  $("distance").textContent = sol ? fixed(sol.distance_m, 2) : "-";
  $("rpm").textContent = sol ? fixed(sol.rpm, 0) : "-";
  $("command").textContent = sol ? sol.command + (sol.reason ? ` (${sol.reason})` : "") : "-";
  $("truth").textContent = s.truth ? `${fixed(s.truth.x, 2)}, ${fixed(s.truth.y, 2)}` : "-";
  $("error").textContent = s.error_m_median === null ? "-" : fixed(s.error_m_median, 3) + " m";
  $("e2e").textContent = s.e2e_ms_p50 === null ? "-" : fixed(s.e2e_ms_p50, 1) + " ms";
  $("shadow").textContent = s.shadow ? `${s.shadow.model_name} v${s.shadow.model_version}` : "-";
  updateStages(s.stages);
  updateThumb(s.thumb);
  redraw();
}

function updateStages(stages) {
  const body = $("stages");
  const rows = stages.map((st) => {
    const tr = document.createElement("tr");
    tr.id = "stage-" + st.name;
    if (!st.alive) tr.className = "dead";
    const cells = [
      st.name,
      st.alive ? (st.silent ? "silent" : "yes") : "no", // alive but no health for 3 s: stuck?
      st.rate_out_hz === undefined ? "-" : fixed(st.rate_out_hz, 1),
      st.latency_ms_p50 === undefined ? "-" : fixed(st.latency_ms_p50, 2),
      st.latency_ms_p99 === undefined ? "-" : fixed(st.latency_ms_p99, 2),
      st.rejected === undefined ? "-" : String(st.rejected),
      st.dropped === undefined ? "-" : String(st.dropped),
    ];
    cells.forEach((text, i) => {
      const td = document.createElement("td");
      td.textContent = text;
      if (i === 1) td.className = st.alive ? "alive-yes" : "alive-no";
      tr.appendChild(td);
    });
    return tr;
  });
  body.replaceChildren(...rows);
  const errors = stages.filter((st) => st.last_error).map((st) => `${st.name}: ${st.last_error}`);
  $("last-error").textContent = errors.join(" | ");
}

function updateThumb(thumb) {
  if (!thumb) return;
  if (thumb.id !== thumbId) {
    thumbId = thumb.id;
    $("thumb").src = "/thumb.jpg?id=" + thumb.id;
  }
  $("thumb-caption").textContent = `frame ${thumb.seq} (${thumb.source}, ${thumb.n_hits} hits, ${fixed(thumb.age_s, 1)} s ago)`;
}

function connect() {
  const events = new EventSource("/events");
  events.onmessage = (e) => update(JSON.parse(e.data));
  // The browser retries by itself; meanwhile say that the monitor, not the robot, is gone.
  events.onerror = () => setStatus("offline");
}

fetch("/api/court")
  .then((r) => r.json())
  .then((c) => {
    court = c;
    redraw();
  });
fetch("/api/state")
  .then((r) => r.json())
  .then((s) => { if (s.stages) update(s); });
connect();
