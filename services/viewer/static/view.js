// PoseidonSLAM live view: polls /state.json (deltas against what it holds) and draws on canvases;
// a panel is drawn again only when what it shows changed (drawn: each panel's last signature).
"use strict";

const TRAIL_COLOURS = {dead_reckoning: "#f39c3d", odometry: "#b07cf0", truth: "#4fd18b"};
const view = {
  map: null, mapVersion: "", sonarVersion: "", cameraVersion: 0, provisional: [], sonar: {beams: new Map(), scan: []},
  drawn: {}, texts: {}, servicesHtml: "",
  activity: null, activityVersion: "",
  trails: {}, lvc: {epoch: -1, points: []}, state: null, yaw: 0.6, pitch: 0.9, dragging: null,
  mode: "", t: 0, playing: false, rate: 4, duration: 0, lastTick: 0, pending: false,
};

function $(id) { return document.getElementById(id); }

function setText(id, text) {
  // an element's text, written only when it changed (a write costs a style and layout pass)
  if (view.texts[id] === text) return;
  view.texts[id] = text;
  $(id).textContent = text;
}

function changed(panel, signature) {
  // whether `panel` must be drawn again: its signature differs from the one it was last drawn with
  if (view.drawn[panel] === signature) return false;
  view.drawn[panel] = signature;
  return true;
}

function trailSig(t) { return t ? t.epoch + "." + t.points.length : ""; }

function absorbSonar(s) {
  // the sweep's delta: beams [bin, angle, max range, base64 bins] written since the version held
  if (s.sonar) {
    if (s.sonar.full) view.sonar.beams = new Map();
    for (const [k, angle, , b64] of s.sonar.beams) {
      const raw = atob(b64), bins = new Uint8Array(raw.length);
      for (let i = 0; i < raw.length; i++) bins[i] = raw.charCodeAt(i);
      view.sonar.beams.set(k, [angle, bins]);
    }
    view.sonar.scan = s.sonar.scan;
  }
  view.sonarVersion = s.sonar_have || String(s.sonar_version);
}

function merge(holder, delta) {
  // a trail delta: points from `start` of epoch `epoch`
  if (!delta) return holder;
  if (!holder || holder.epoch !== delta.epoch || delta.start === 0) {
    return {epoch: delta.epoch, points: delta.points.slice()};
  }
  holder.points.length = delta.start;
  for (const p of delta.points) holder.points.push(p);
  return holder;
}

function haveQuery() {
  const q = new URLSearchParams();
  if (view.mapVersion) q.set("map", view.mapVersion);
  if (view.sonarVersion) q.set("sonar", view.sonarVersion);
  if (view.activityVersion) q.set("activity", view.activityVersion);
  if (view.cameraVersion) q.set("camera", String(view.cameraVersion));
  for (const [name, t] of Object.entries(view.trails)) q.set(name, t.epoch + "." + t.points.length);
  if (view.lvc.epoch >= 0) q.set("lvc", view.lvc.epoch + "." + view.lvc.points.length);
  if (view.mode === "recording") q.set("t", view.t.toFixed(2));
  return q.toString();
}

async function poll() {
  if (view.pending) return;
  view.pending = true;
  try {
    const r = await fetch("/state.json?" + haveQuery(), {cache: "no-store"});
    if (!r.ok) throw new Error("state " + r.status);
    const s = await r.json();
    absorb(s);
    if (!(s.view && s.view.aborted)) setText("status", "");
    draw();
  } catch (err) {
    setText("status", "no answer from the view server (" + err.message + "); retrying");
  } finally {
    view.pending = false;
  }
}

function absorb(s) {
  view.state = s;
  if (view.mode !== s.mode) setMode(s);
  // version 0: nothing yet (a recording scrubbed back before the first message drops what it held)
  if (s.map) view.map = s.map; else if (s.map_version === 0) view.map = null;
  view.mapVersion = String(s.map_version);
  view.provisional = s.provisional || [];
  absorbSonar(s);
  if (s.activity) view.activity = s.activity; else if (s.activity_version === 0) view.activity = null;
  view.activityVersion = String(s.activity_version);
  for (const [name, delta] of Object.entries(s.trails || {})) view.trails[name] = merge(view.trails[name], delta);
  view.lvc = merge(view.lvc, s.lvc);
  if (s.camera_version !== view.cameraVersion) {
    view.cameraVersion = s.camera_version;
    if (s.camera_jpeg) $("camera").src = "data:image/jpeg;base64," + s.camera_jpeg;
  }
  if ($("camera").hidden !== (s.camera_version === 0)) $("camera").hidden = s.camera_version === 0;
  const c = s.counts;
  setText("time", s.t.toFixed(1));
  setText("nodes", String(c.nodes));
  setText("loops", String(c.loop_closures));
  setText("lvc", String(c.lvc));
  setText("last-lvc", c.last_lvc >= 0 ? String(c.last_lvc) : "-");
  setText("revisits", String(c.revisits));
  setText("events", String(c.events));
  setText("pose", c.pose ? c.pose.slice(0, 3).map(v => (Math.abs(v) < 0.05 ? 0 : v).toFixed(1)).join(", ") : "-");
  if (s.mode === "recording") {
    view.duration = s.duration_s;
    if ($("slider").max !== String(s.duration_s)) $("slider").max = s.duration_s;
    setText("slider-label", view.t.toFixed(1) + " / " + s.duration_s.toFixed(1) + " s");
  }
  services(s);
  notes(s);
}

function notes(s) {
  // a panel without data says why: the recording has no such stream, or nothing has arrived yet
  const st = s.streams || null, yet = s.mode === "recording" ? " at this time" : " yet";
  const none = (what, has) => has ? "" : st ? "no " + what + " in this run" : "";
  const sonar = (view.sonar.scan || []).length || view.sonar.beams.size;
  const laser = st ? st.scan && !st.sonar : (view.sonar.scan || []).length > 0;
  setText("sonar-title", laser ? "Laser scan" : "Sonar sweep");
  const pc = view.trails.posecells ? view.trails.posecells.points.length : 0;
  const text = {
    "map-note": view.map || view.provisional.length ? none("ground truth", st ? st.truth : true)
      : "no experience map" + yet,
    "camera-note": s.camera_version > 0 ? "" : none("camera", st ? st.camera : true) || "no camera frame" + yet,
    "sonar-note": sonar ? "" : none("sonar or laser scan", st ? st.sonar || st.scan : true) ||
      "no sonar beam or laser scan" + yet,
    "pc-act-note": view.activity ? activityCaption(view.activity) :
      none("pose-cell activity (recorded before the posecells service published it, or posecells." +
           "activity_period_s was 0)", st ? st.activity : true) || "no pose-cell activity" + yet,
    "pc-note": pc ? "" : "no experience event" + yet,
    "lvc-note": view.lvc.points.length ? "" : "no local view cells" + yet,
    "services-note": Object.keys(s.services || {}).length ? "" : s.mode === "recording"
      ? "per-service figures are measured on the bus: a live run only" : "no service seen yet",
  };
  for (const [id, t] of Object.entries(text)) setText(id, t);
}

function activityCaption(a) {
  const c = a.centroid;
  return "t " + a.t.toFixed(1) + " s, step " + a.steps + ": centroid x " + c[0].toFixed(2) + " y " +
    c[1].toFixed(2) + " z " + c[2].toFixed(2) + " m, yaw " + (c[3] * 180 / Math.PI).toFixed(0) + " deg";
}

function setMode(s) {
  view.mode = s.mode;
  $("mode").textContent = s.mode === "recording" ? "recording " + s.recording : "live";
  $("player").hidden = s.mode !== "recording";
}

function services(s) {
  const body = $("services").tBodies[0];
  const rows = [];
  for (const [name, f] of Object.entries(s.services || {})) {
    const cells = [name, f.alive ? "yes" : (f.done ? "done" : "no"), f.rate_hz, f.lag_s === null ? "-" : f.lag_s,
                   f.gaps, f.restarts, f.p50_ms === null ? "-" : f.p50_ms, f.p99_ms === null ? "-" : f.p99_ms];
    rows.push("<tr>" + cells.map(v => "<td>" + String(v).replace(/[<>&]/g, "") + "</td>").join("") + "</tr>");
  }
  const html = rows.join("");
  if (html !== view.servicesHtml) { view.servicesHtml = html; body.innerHTML = html; }
  const v = s.view || {};
  if (v.aborted) setText("status", "run aborted: " + v.aborted);
  setText("view-figures", "view: " + (v.dropped !== undefined ? v.dropped + " updates dropped, " : "") +
    (v.bytes_sent !== undefined ? (v.bytes_sent / 1e6).toFixed(1) + " MB served" : ""));
}

// ---- drawing ----------------------------------------------------------------------------------
function bounds(lists) {
  let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
  for (const pts of lists) for (const p of pts) {
    if (p[0] < x0) x0 = p[0]; if (p[0] > x1) x1 = p[0];
    if (p[1] < y0) y0 = p[1]; if (p[1] > y1) y1 = p[1];
  }
  if (!isFinite(x0)) return [-1, 1, -1, 1];
  const pad = Math.max(1, 0.05 * Math.max(x1 - x0, y1 - y0));
  return [x0 - pad, x1 + pad, y0 - pad, y1 + pad];
}

function scaler(canvas, b) {
  const s = Math.min(canvas.width / (b[1] - b[0]), canvas.height / (b[3] - b[2]));
  const ox = (canvas.width - s * (b[1] - b[0])) / 2, oy = (canvas.height - s * (b[3] - b[2])) / 2;
  return p => [ox + (p[0] - b[0]) * s, canvas.height - (oy + (p[1] - b[2]) * s)];
}

function line(ctx, pts, f, colour, width) {
  if (pts.length < 2) return;
  ctx.strokeStyle = colour; ctx.lineWidth = width; ctx.beginPath();
  pts.forEach((p, i) => { const [x, y] = f(p); if (i) ctx.lineTo(x, y); else ctx.moveTo(x, y); });
  ctx.stroke();
}

function trailPoints(name) {
  // the truth lives in its own world frame: shifted so that it starts where dead reckoning starts
  const t = view.trails[name];
  if (!t) return [];
  const dr = view.trails.dead_reckoning;
  if (name !== "truth" || !dr || !dr.points.length || !t.points.length) return t.points;
  const d = [0, 1, 2].map(k => dr.points[0][k] - t.points[0][k]);
  return t.points.map(p => [p[0] + d[0], p[1] + d[1], p[2] + d[2]]);
}

function drawMap() {
  const canvas = $("map"), ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const nodes = view.map ? view.map.xyz : [];
  const lists = [nodes, view.provisional];
  for (const name of Object.keys(TRAIL_COLOURS)) lists.push(trailPoints(name));
  const f = scaler(canvas, bounds(lists));
  for (const [name, colour] of Object.entries(TRAIL_COLOURS)) {
    line(ctx, trailPoints(name), f, colour, name === "truth" ? 1.5 : 1.2);
  }
  if (view.map) {
    view.map.links.forEach((l, i) => {
      const loop = view.map.loop[i];
      ctx.strokeStyle = loop ? "#ff4040" : "#56616e"; ctx.lineWidth = loop ? 2 : 1;
      const a = f(nodes[l[0]]), b = f(nodes[l[1]]);
      ctx.beginPath(); ctx.moveTo(a[0], a[1]); ctx.lineTo(b[0], b[1]); ctx.stroke();
    });
    ctx.fillStyle = "#4aa3ff";
    for (const p of nodes) { const [x, y] = f(p); ctx.fillRect(x - 2, y - 2, 4, 4); }
  }
  ctx.strokeStyle = "#9fd3ff";
  for (const p of view.provisional) { const [x, y] = f(p); ctx.beginPath(); ctx.arc(x, y, 3, 0, 7); ctx.stroke(); }
  const pose = view.state && view.state.counts.pose;
  if (pose) {
    const [x, y] = f(pose);
    ctx.fillStyle = "#fff"; ctx.beginPath(); ctx.arc(x, y, 4, 0, 7); ctx.fill();
    ctx.strokeStyle = "#fff"; ctx.beginPath(); ctx.moveTo(x, y);
    ctx.lineTo(x + 14 * Math.cos(pose[3]), y - 14 * Math.sin(pose[3])); ctx.stroke();
  }
}

function drawMap3d() {
  const canvas = $("map3d"), ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const nodes = view.map ? view.map.xyz : [];
  const trails = Object.keys(TRAIL_COLOURS).map(trailPoints);
  const all = nodes.concat(...trails);
  if (!all.length) return;
  const c = [0, 1, 2].map(k => all.reduce((s, p) => s + p[k], 0) / all.length);
  const r = Math.max(1, ...all.map(p => Math.hypot(p[0] - c[0], p[1] - c[1], p[2] - c[2])));
  const cy = Math.cos(view.yaw), sy = Math.sin(view.yaw), cp = Math.cos(view.pitch), sp = Math.sin(view.pitch);
  const s = 0.45 * Math.min(canvas.width, canvas.height) / r;
  const f = p => {
    const x = p[0] - c[0], y = p[1] - c[1], z = p[2] - c[2];
    const x1 = cy * x - sy * y, y1 = sy * x + cy * y;      // yaw about z
    const y2 = cp * y1 - sp * z;                              // pitch about x (screen up = z when level)
    return [canvas.width / 2 + s * x1, canvas.height / 2 + s * y2];
  };
  Object.values(TRAIL_COLOURS).forEach((colour, i) => line(ctx, trails[i], f, colour, 1));
  if (view.map) {
    view.map.links.forEach((l, i) => {
      ctx.strokeStyle = view.map.loop[i] ? "#ff4040" : "#56616e"; ctx.lineWidth = 1;
      const a = f(nodes[l[0]]), b = f(nodes[l[1]]);
      ctx.beginPath(); ctx.moveTo(a[0], a[1]); ctx.lineTo(b[0], b[1]); ctx.stroke();
    });
    ctx.fillStyle = "#4aa3ff";
    for (const p of nodes) { const [x, y] = f(p); ctx.fillRect(x - 1.5, y - 1.5, 3, 3); }
  }
}

function drawSonar() {
  const canvas = $("sonar"), ctx = canvas.getContext("2d");
  const w = canvas.width, h = canvas.height, cx = w / 2, cy = h / 2, R = Math.min(w, h) / 2 - 4;
  ctx.fillStyle = "#0b1016"; ctx.fillRect(0, 0, w, h);
  const scan = view.sonar.scan || [];
  if (scan.length) {
    const m = Math.max(1, ...scan.map(p => Math.hypot(p[0], p[1])));
    ctx.fillStyle = "#7fe0ff";
    for (const p of scan) ctx.fillRect(cx + p[0] / m * R - 1, cy - p[1] / m * R - 1, 2, 2);
    ctx.fillStyle = "#fff";  // the sensor, facing right (x forward)
    ctx.beginPath(); ctx.moveTo(cx + 8, cy); ctx.lineTo(cx - 5, cy - 5); ctx.lineTo(cx - 5, cy + 5); ctx.fill();
    ctx.fillStyle = "#8b97a5";
    ctx.fillText("sensor frame, x forward; " + m.toFixed(1) + " m to the edge", 4, h - 6);
    return;
  }
  // one 3 x 3 pixel square per echo, written into the canvas's pixels (not one fillRect each)
  const img = ctx.getImageData(0, 0, w, h), px = img.data;
  for (const [angle, bins] of view.sonar.beams.values()) {
    const ca = Math.cos(angle), sa = Math.sin(angle);
    for (let i = 0; i < bins.length; i++) {
      const v = bins[i];
      if (v < 20) continue;
      const rr = (i + 0.5) / bins.length * R;
      const x0 = Math.round(cx + rr * ca) - 1, y0 = Math.round(cy - rr * sa) - 1;
      for (let y = Math.max(0, y0); y < Math.min(h, y0 + 3); y++) {
        for (let x = Math.max(0, x0); x < Math.min(w, x0 + 3); x++) {
          const o = 4 * (y * w + x);
          px[o] = v; px[o + 1] = Math.round(v * 0.8); px[o + 2] = 40; px[o + 3] = 255;
        }
      }
    }
  }
  ctx.putImageData(img, 0, 0);
  ctx.strokeStyle = "#2c3b4b"; ctx.beginPath(); ctx.arc(cx, cy, R, 0, 7); ctx.stroke();
}

function drawPoseCells() {
  const pts = view.trails.posecells ? view.trails.posecells.points : [];
  for (const [id, ix, iy] of [["pc-xy", 0, 1], ["pc-zyaw", 3, 2]]) {
    const canvas = $(id), ctx = canvas.getContext("2d");
    ctx.clearRect(0, 0, canvas.width, canvas.height);
    const proj = pts.map(p => [p[ix], p[iy]]);
    const f = scaler(canvas, bounds([proj]));
    line(ctx, proj, f, "#58708a", 1);
    if (proj.length) {
      const [x, y] = f(proj[proj.length - 1]);
      ctx.fillStyle = "#ffd84a"; ctx.beginPath(); ctx.arc(x, y, 4, 0, 7); ctx.fill();
    }
    ctx.fillStyle = "#8b97a5";
    ctx.fillText(ix === 0 ? "x-y (m)" : "yaw (rad) - z (m)", 6, 12);
  }
}

// dark blue -> magenta -> orange -> yellow
const HEAT = [[11, 16, 22], [40, 34, 96], [150, 42, 112], [232, 96, 60], [255, 224, 90]];

function heat(v) {
  const x = Math.max(0, Math.min(1, v)) * (HEAT.length - 1), i = Math.min(HEAT.length - 2, Math.floor(x)), f = x - i;
  return HEAT[i].map((c, k) => Math.round(c + f * (HEAT[i + 1][k] - c)));
}

function heatmap(canvas, img, across, mark, labels) {
  // img: row-major uint8 (shape [n0, n1]); `across` = the image axis drawn left to right, the other
  // bottom to top; mark: the centroid in cells along (across, up)
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const [n0, n1] = img.shape, bytes = atob(img.data);
  const w = across === 0 ? n0 : n1, h = across === 0 ? n1 : n0;
  const off = canvas.offscreen || (canvas.offscreen = document.createElement("canvas"));
  if (off.width !== w) off.width = w;
  if (off.height !== h) off.height = h;
  const octx = off.getContext("2d"), px = octx.createImageData(w, h);
  for (let i = 0; i < n0; i++) for (let j = 0; j < n1; j++) {
    const col = across === 0 ? i : j, up = across === 0 ? j : i;
    const o = 4 * ((h - 1 - up) * w + col), rgb = heat(bytes.charCodeAt(i * n1 + j) / 255);
    px.data[o] = rgb[0]; px.data[o + 1] = rgb[1]; px.data[o + 2] = rgb[2]; px.data[o + 3] = 255;
  }
  octx.putImageData(px, 0, 0);
  ctx.imageSmoothingEnabled = false;
  ctx.drawImage(off, 0, 0, canvas.width, canvas.height);
  const x = (mark[0] + 0.5) * canvas.width / w, y = canvas.height - (mark[1] + 0.5) * canvas.height / h;
  ctx.strokeStyle = "#3ff0ff"; ctx.lineWidth = 2;
  ctx.beginPath(); ctx.arc(x, y, 6, 0, 7); ctx.moveTo(x - 10, y); ctx.lineTo(x + 10, y);
  ctx.moveTo(x, y - 10); ctx.lineTo(x, y + 10); ctx.stroke();
  ctx.fillStyle = "#dde3ea";
  ctx.fillText(labels, 4, 12);
}

function drawActivity() {
  const a = view.activity;
  const xy = $("pc-act-xy"), zyaw = $("pc-act-zyaw");
  if (!a) {
    for (const c of [xy, zyaw]) c.getContext("2d").clearRect(0, 0, c.width, c.height);
    return;
  }
  const [nz, nyaw] = a.zyaw.shape, width = Math.max(48, Math.min(240, Math.round(240 * nyaw / nz)));
  if (zyaw.width !== width) zyaw.width = width;
  const c = a.centroid_cells;
  heatmap(xy, a.xy, 0, [c[0], c[1]], "x \u2192  y \u2191");
  heatmap(zyaw, a.zyaw, 1, [c[3], c[2]], "yaw \u2192  z \u2191");
}

function drawLvc() {
  const canvas = $("lvc-plot"), ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const pts = view.lvc.points;
  if (!pts.length) return;
  // time across, LVC id up, each axis filling the canvas (a run of hours has hundreds of ids)
  const t1 = Math.max(1, pts[pts.length - 1][0]), id1 = Math.max(1, ...pts.map(p => p[1])), m = 6;
  const f = p => [m + p[0] / t1 * (canvas.width - 2 * m), canvas.height - m - p[1] / id1 * (canvas.height - 2 * m)];
  ctx.fillStyle = "#8b97a5";
  ctx.fillText("0 - " + t1.toFixed(0) + " s, ids 0 - " + id1, 6, 12);
  for (const p of pts) {
    const [x, y] = f(p);
    ctx.fillStyle = p[2] ? "#ff4040" : "#4aa3ff";
    const s = p[2] ? 4 : 2;
    ctx.fillRect(x - s / 2, y - s / 2, s, s);
  }
}

function draw() {
  // each panel only when its data changed since it was last drawn
  const trails = Object.keys(TRAIL_COLOURS).map(name => trailSig(view.trails[name])).join(",");
  const pose = view.state && view.state.counts.pose;
  const mapSig = [view.mapVersion, view.map ? 1 : 0, view.provisional.length, trails].join("|");
  if (changed("map", mapSig + "|" + (pose ? pose.join(",") : ""))) drawMap();
  if (changed("map3d", mapSig)) drawMap3d();
  if (changed("sonar", view.sonarVersion + "|" + view.sonar.beams.size)) drawSonar();
  if (changed("activity", view.activityVersion + "|" + (view.activity ? 1 : 0))) drawActivity();
  if (changed("posecells", trailSig(view.trails.posecells))) drawPoseCells();
  if (changed("lvc", trailSig(view.lvc))) drawLvc();
}

// ---- interaction ----------------------------------------------------------------------------
function setup() {
  const c3 = $("map3d");
  c3.addEventListener("mousedown", e => { view.dragging = [e.clientX, e.clientY]; });
  window.addEventListener("mouseup", () => { view.dragging = null; });
  window.addEventListener("mousemove", e => {
    if (!view.dragging) return;
    view.yaw += (e.clientX - view.dragging[0]) * 0.01;
    view.pitch = Math.max(0, Math.min(Math.PI / 2, view.pitch + (e.clientY - view.dragging[1]) * 0.01));
    view.dragging = [e.clientX, e.clientY];
    drawMap3d();
  });
  $("slider").addEventListener("input", e => { view.t = parseFloat(e.target.value); poll(); });
  $("play").addEventListener("click", () => {
    view.playing = !view.playing;
    $("play").textContent = view.playing ? "Pause" : "Play";
    if (view.playing && view.t >= view.duration) view.t = 0;
  });
  $("rate").addEventListener("change", e => { view.rate = parseFloat(e.target.value); });
}

function tick(now) {
  if (view.playing && view.lastTick) {
    view.t = Math.min(view.duration, view.t + (now - view.lastTick) / 1000 * view.rate);
    $("slider").value = view.t;
    if (view.t >= view.duration) { view.playing = false; $("play").textContent = "Play"; }
  }
  view.lastTick = now;
}

function loop() {
  // one poll every 1 / update_hz s, counted from the start of the last one (not from its answer)
  const start = performance.now();
  tick(start);
  poll().finally(() => {
    const hz = view.state ? view.state.update_hz : 2;
    setTimeout(loop, Math.max(0, 1000 / hz - (performance.now() - start)));
  });
}

setup();
loop();
