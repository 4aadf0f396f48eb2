// The vessel view: each state pushed over /ws redraws every camera's plan, image and table.
// Plain JS and SVG, no library: the page must work with no network but the view server itself.
"use strict";

const SVG_NS = "http://www.w3.org/2000/svg";
const cameras = new Map();   // namespace -> {root, parts, view, state, image loading}
let socket = null;
let retryMs = 500;

function el(name, attrs, parent) {
  const node = document.createElementNS(SVG_NS, name);
  for (const [key, value] of Object.entries(attrs || {})) node.setAttribute(key, value);
  if (parent) parent.appendChild(node);
  return node;
}

function fmt(value, digits, unit) {
  return value === null || value === undefined ? "–" : value.toFixed(digits) + (unit || "");
}

function fmtTime(seconds) {
  if (seconds === null || seconds === undefined) return "–";
  const sign = seconds < 0 ? "-" : "";
  const s = Math.abs(Math.round(seconds));
  return `${sign}${Math.floor(s / 60)}:${String(s % 60).padStart(2, "0")}`;
}

function niceStep(span) {
  const raw = span / 4;
  const power = Math.pow(10, Math.floor(Math.log10(raw)));
  for (const m of [1, 2, 5, 10]) if (m * power >= raw) return m * power;
  return 10 * power;
}

function cameraFor(namespace) {
  let camera = cameras.get(namespace);
  if (camera) return camera;
  const root = document.getElementById("camera-template").content.firstElementChild.cloneNode(true);
  root.dataset.namespace = namespace;
  const parts = {};
  for (const node of root.querySelectorAll("[data-role]")) parts[node.dataset.role] = node;
  parts.title.textContent = namespace ? `camera ${namespace}` : "camera";
  camera = {root, parts, view: {auto: true, centre: [0, 0], halfSpan: 500}, loading: false, pending: null,
            imageUrl: null, shownUrl: null, state: null};
  parts.fit.addEventListener("click", () => { camera.view.auto = true; draw(camera); });
  parts["zoom-in"].addEventListener("click", () => zoom(camera, 0.5));
  parts["zoom-out"].addEventListener("click", () => zoom(camera, 2));
  parts.plan.addEventListener("wheel", (event) => {
    event.preventDefault();
    zoom(camera, event.deltaY > 0 ? 1.25 : 0.8);
  }, {passive: false});
  parts.image.classList.add("empty");
  parts.image.addEventListener("load", () => imageLoaded(camera));
  parts.image.addEventListener("error", () => imageLoaded(camera));
  document.getElementById("cameras").appendChild(root);
  cameras.set(namespace, camera);
  return camera;
}

function zoom(camera, factor) {
  camera.view.auto = false;
  camera.view.halfSpan = Math.min(50000, Math.max(20, camera.view.halfSpan * factor));
  draw(camera);
}

function fitView(camera) {
  const state = camera.state;
  const points = [[0, 0]];
  for (const v of state.vessels) {
    if (v.east_m === null) continue;
    points.push([v.east_m, v.north_m]);
    for (const p of v.track.slice(-20)) points.push(p);
  }
  if (points.length === 1 && state.camera) {
    const reach = Math.min(1500, state.camera.horizon_m || 1500);
    const h = (state.camera.heading_deg || 0) * Math.PI / 180;
    points.push([reach * Math.sin(h), reach * Math.cos(h)]);
  }
  const es = points.map((p) => p[0]);
  const ns = points.map((p) => p[1]);
  const [e0, e1, n0, n1] = [Math.min(...es), Math.max(...es), Math.min(...ns), Math.max(...ns)];
  camera.view.centre = [(e0 + e1) / 2, (n0 + n1) / 2];
  camera.view.halfSpan = Math.max(150, 0.6 * Math.max(e1 - e0, n1 - n0));
}

function projector(camera) {
  const svg = camera.parts.plan;
  const width = svg.clientWidth || 800;
  const height = svg.clientHeight || 560;
  const scale = Math.min(width, height) / (2 * camera.view.halfSpan);
  const [ce, cn] = camera.view.centre;
  return {width, height, scale,
          x: (e) => width / 2 + (e - ce) * scale,
          y: (n) => height / 2 - (n - cn) * scale};
}

function drawGrid(camera, p) {
  const grid = camera.parts.grid;
  grid.replaceChildren();
  const step = niceStep(camera.view.halfSpan * 2);
  const far = Math.hypot(Math.abs(camera.view.centre[0]) + camera.view.halfSpan * 2,
                         Math.abs(camera.view.centre[1]) + camera.view.halfSpan * 2);
  for (let r = step, i = 0; r <= far && i < 60; r += step, i++) {
    el("circle", {class: "ring", cx: p.x(0), cy: p.y(0), r: r * p.scale}, grid);
    const label = el("text", {class: "ring-label", x: p.x(0) + 3, y: p.y(r) - 3}, grid);
    label.textContent = r >= 1000 ? `${r / 1000} km` : `${r} m`;
  }
  const north = el("text", {class: "north", x: 12, y: 20}, grid);
  north.textContent = "N ↑";
  el("line", {class: "ring", x1: 12, y1: p.height - 12, x2: 12 + step * p.scale, y2: p.height - 12}, grid);
  const scale = el("text", {class: "scale-label", x: 12, y: p.height - 16}, grid);
  scale.textContent = step >= 1000 ? `${step / 1000} km` : `${step} m`;
}

function drawChart(camera, p, chart) {
  const group = camera.parts.chart;
  group.replaceChildren();
  if (!chart) return;
  el("image", {href: chart.url, x: p.x(chart.west_m), y: p.y(chart.north_m), preserveAspectRatio: "none",
               width: (chart.east_m - chart.west_m) * p.scale, height: (chart.north_m - chart.south_m) * p.scale},
     group);
}

function drawCamera(camera, p, geometry) {
  const group = camera.parts.fov;
  group.replaceChildren();
  if (geometry) {
    el("polygon", {class: "fov", points: geometry.fov.map(([e, n]) => `${p.x(e)},${p.y(n)}`).join(" ")}, group);
    if (geometry.heading_deg !== null) {
      const h = geometry.heading_deg * Math.PI / 180;
      const r = geometry.horizon_m;
      el("line", {class: "heading", x1: p.x(0), y1: p.y(0), x2: p.x(r * Math.sin(h)), y2: p.y(r * Math.cos(h))},
         group);
    }
  }
  el("rect", {class: "camera-mark", x: p.x(0) - 5, y: p.y(0) - 5, width: 10, height: 10}, group);
}

function vesselLabel(v) {
  const course = v.course_deg === null ? "" : ` ${v.course_deg.toFixed(0)}°`;
  const speed = v.speed_kn === null ? "" : `${v.speed_kn.toFixed(1)} kn${course}`;
  return [`${v.id}${v.class ? " · " + v.class : ""}${v.is_target ? " · target" : ""}`, speed];
}

function drawVessel(group, p, v) {
  const x = p.x(v.east_m);
  const y = p.y(v.north_m);
  const classes = ["vessel", v.is_target ? "target" : "", v.cpa_alert ? "alert" : ""].join(" ").trim();
  const g = el("g", {class: classes, "data-vessel-id": v.id, "data-east": v.east_m, "data-north": v.north_m},
               group);
  if (v.track.length > 1) {
    el("polyline", {class: "track", points: v.track.map(([e, n]) => `${p.x(e)},${p.y(n)}`).join(" ")}, g);
  }
  if (v.ellipse) {
    el("ellipse", {class: "ellipse", cx: 0, cy: 0, rx: Math.max(1, v.ellipse.a_m * p.scale),
                   ry: Math.max(1, v.ellipse.b_m * p.scale),
                   transform: `translate(${x},${y}) rotate(${-v.ellipse.angle_deg})`}, g);
  }
  if (v.speed_mps !== null && v.course_deg !== null) {
    const c = v.course_deg * Math.PI / 180;
    const ahead = Math.max(v.speed_mps * 60 * p.scale, 0);  // one minute ahead
    el("line", {class: "velocity", x1: x, y1: y, x2: x + ahead * Math.sin(c), y2: y - ahead * Math.cos(c)}, g);
  }
  if (v.is_target) el("circle", {class: "target-ring", cx: x, cy: y, r: 10}, g);
  el("circle", {class: "marker", cx: x, cy: y, r: v.is_target ? 6 : 4.5}, g);
  const [first, second] = vesselLabel(v);
  const label = el("text", {x: x + 10, y: y - 4}, g);
  label.textContent = first;
  if (second) {
    const line = el("text", {x: x + 10, y: y + 9}, g);
    line.textContent = second;
  }
  if (v.cpa_m !== null) {
    const cpa = el("text", {x: x + 10, y: y + 22, class: v.cpa_alert ? "cpa-alert" : ""}, g);
    cpa.textContent = v.tcpa_s !== null && v.tcpa_s < 0
      ? `CPA ${v.cpa_m.toFixed(0)} m, passed ${fmtTime(-v.tcpa_s)} ago`
      : `CPA ${v.cpa_m.toFixed(0)} m in ${fmtTime(v.tcpa_s)}`;
  }
}

function drawTable(camera, vessels) {
  const rows = vessels.map((v) => {
    const tr = document.createElement("tr");
    tr.dataset.vesselId = v.id;
    if (v.is_target) tr.classList.add("target");
    if (v.cpa_alert) tr.classList.add("alert");
    const cells = [v.id, v.class || "–", fmt(v.distance_m, 0, " m"), fmt(v.bearing_deg, 0, "°"),
                   v.speed_kn === null ? "–" : `${v.speed_kn.toFixed(1)} kn`, fmt(v.course_deg, 0, "°"),
                   v.lat === null ? "no position" : `${v.lat.toFixed(5)}, ${v.lon.toFixed(5)}`,
                   fmt(v.cpa_m, 0, " m"),
                   v.tcpa_s !== null && v.tcpa_s < 0 ? `passed ${fmtTime(-v.tcpa_s)} ago` : fmtTime(v.tcpa_s)];
    for (const text of cells) {
      const td = document.createElement("td");
      td.textContent = text;
      tr.appendChild(td);
    }
    return tr;
  });
  camera.parts.table.replaceChildren(...rows);
}

function draw(camera) {
  const state = camera.state;
  if (!state) return;
  if (camera.view.auto) fitView(camera);
  const p = projector(camera);
  drawChart(camera, p, camera.chart);
  drawGrid(camera, p);
  drawCamera(camera, p, state.camera);
  const group = camera.parts.vessels;
  group.replaceChildren();
  const placed = state.vessels.filter((v) => v.east_m !== null);
  placed.sort((a, b) => Number(a.is_target) - Number(b.is_target));  // the target on top
  for (const v of placed) drawVessel(group, p, v);
}

function drawStatus(camera, state) {
  const status = camera.parts.status;
  const fix = state.fix;
  let fixText = "";
  if (fix) {
    fixText = fix.lat === null ? " · /vessel/fix: no fix"
      : ` · /vessel/fix ${fix.lat.toFixed(5)}, ${fix.lon.toFixed(5)}`;
  }
  status.textContent = state.status.line + fixText;
  status.className = `status ${state.status.level}`;
}

// A binary message is one camera's JPEG: a length byte, the camera's namespace, the image. The newest waits while
// the previous one is still being decoded, so a slow page skips images instead of queueing them.
function onImage(buffer) {
  const bytes = new Uint8Array(buffer);
  const namespace = new TextDecoder().decode(bytes.subarray(1, 1 + bytes[0]));
  const camera = cameras.get(namespace);
  if (!camera) return;
  camera.pending = new Blob([bytes.subarray(1 + bytes[0])], {type: "image/jpeg"});
  if (!camera.loading) showImage(camera);
}

function showImage(camera) {
  if (!camera.pending) return;
  camera.loading = true;
  camera.imageUrl = URL.createObjectURL(camera.pending);
  camera.pending = null;
  camera.parts.image.src = camera.imageUrl;
}

function imageLoaded(camera) {
  camera.loading = false;
  if (camera.shownUrl) URL.revokeObjectURL(camera.shownUrl);
  camera.shownUrl = camera.imageUrl;
  camera.parts.image.classList.remove("empty");
  camera.parts["image-placeholder"].classList.add("hidden");
  showImage(camera);
}

function onState(message) {
  for (const state of message.cameras) {
    const camera = cameraFor(state.namespace);
    camera.state = state;
    camera.chart = message.chart;
    draw(camera);
    drawStatus(camera, state);
    drawTable(camera, state.vessels);
  }
  const counts = Object.entries(message.counts || {}).map(([k, v]) => `${k} ${v}`).join(", ");
  document.getElementById("counts").textContent = counts;
  document.body.dataset.version = message.version;
}

function setConnection(text, className) {
  const node = document.getElementById("connection");
  node.textContent = text;
  node.className = `connection ${className}`;
}

function connect() {
  const scheme = location.protocol === "https:" ? "wss://" : "ws://";
  socket = new WebSocket(scheme + location.host + "/ws");
  socket.binaryType = "arraybuffer";
  socket.addEventListener("open", () => { retryMs = 500; setConnection("live", "live"); });
  socket.addEventListener("message", (event) => {
    if (typeof event.data !== "string") {
      onImage(event.data);
      return;
    }
    const message = JSON.parse(event.data);
    if (message.type === "state") onState(message);
  });
  socket.addEventListener("close", () => {
    setConnection("disconnected: retrying…", "down");
    setTimeout(connect, retryMs);
    retryMs = Math.min(retryMs * 2, 5000);
  });
}

window.addEventListener("resize", () => { for (const camera of cameras.values()) draw(camera); });
connect();
