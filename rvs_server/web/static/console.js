// RVS operator console: a map of the rover's world and the server's lines, live over a WebSocket.
// Every action is a command line sent to the server's dispatcher, exactly as telnet sends it;
// the page only draws what the server says. Map frame: x right, y up (the GeoTIFFs' east and
// north), metres; the rover's forward direction is its heading, counter-clockwise from +x.
"use strict";

const $ = (id) => document.getElementById(id);
const canvas = $("map");
const ctx = canvas.getContext("2d");

const S = {
  state: null,          // the last state snapshot
  layers: {},           // name -> {url, img, legend, bounds, ready}
  visible: { dem: true, hazard: true },
  plan: [],             // waypoints [[x, y, heading], ...] of the last navigate leg
  hazards: [],          // hazard events with a position
  check: null,          // the last check-move: {from, to, verdict}
  authed: false,
  tagN: 0,
  pending: {},          // tag -> callback for the final line
  progress: null,       // the last PROGRESS fields
  view: { cx: 0, cy: 0, scale: 60 },
  fitted: false,
  click: null,          // the map point of the open click menu
};
let ws = null;

// ------------------------------------------------------------------------------ connection

function connect() {
  ws = new WebSocket((location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/ws");
  ws.onopen = () => setLink(true);
  ws.onclose = () => { setLink(false); setTimeout(connect, 1500); };
  ws.onmessage = (ev) => {
    const m = JSON.parse(ev.data);
    if (m.type === "state") onState(m);
    else if (m.type === "reply") onReply(m);
  };
}

function setLink(up) {
  const el = $("link");
  el.textContent = up ? "live" : "offline";
  el.className = up ? "up" : "down";
}

function send(line, onFinal) {
  if (!ws || ws.readyState !== WebSocket.OPEN) { showResult("not connected", true); return; }
  const tag = "w" + (++S.tagN);
  S.pending[tag] = onFinal || null;
  ws.send(JSON.stringify({ line: "@" + tag + " " + line }));
}

function canAct() {
  return !!S.state && (!S.state.token || S.authed);
}

// ------------------------------------------------------------------------------ lines

function onReply(m) {
  const r = m.reply;
  logLine(m.text, r.status, m.own);
  if (r.status === "PROGRESS") {
    S.progress = r;
    showProgress();
  } else if (r.status === "EVENT") {
    if (r.kind === "mode") setMode(r.mode);
    if (r.kind === "waiting" && Array.isArray(r.waypoints)) S.plan = r.waypoints;
    if (r.kind === "hazard" && typeof r.x === "number") S.hazards.push({ x: r.x, y: r.y, level: r.level });
    draw();
  } else if (r.status === "OK" || r.status === "ERROR") {
    if (r.job !== undefined) S.progress = null;
    const cb = r.tag !== undefined ? S.pending[r.tag] : undefined;
    if (r.tag !== undefined && r.tag in S.pending) {
      delete S.pending[r.tag];
      showResult(m.text, r.status === "ERROR");
      if (cb) cb(r);
    }
    showProgress();
  }
}

function logLine(text, status, own) {
  const li = document.createElement("li");
  li.textContent = text;
  li.className = status + (own ? " mine" : "");
  const log = $("log");
  log.appendChild(li);
  while (log.children.length > 300) log.removeChild(log.firstChild);
  log.scrollTop = log.scrollHeight;
}

function showResult(text, error) {
  const el = $("result");
  el.textContent = text;
  el.className = error ? "error" : "";
}

function setMode(mode) {
  const el = $("mode");
  el.textContent = mode;
  el.dataset.mode = mode;
}

function showProgress() {
  const job = S.state && S.state.job;
  const p = S.progress;
  let done = 0, total = 0, phase = "", message = "";
  if (p && job && p.job === job.id) {
    done = p.done; total = p.total; phase = p.phase || ""; message = p.message || "";
  } else if (job) {
    done = job.done; total = job.total; phase = job.phase || "";
  }
  $("job").textContent = job ? `${job.command} (job ${job.id})` : "none";
  $("bar-fill").style.width = total > 0 ? `${Math.min(100, (100 * done) / total).toFixed(1)}%` : (job ? "3%" : "0");
  $("phase").textContent = job ? `${phase ? phase + " " : ""}${done}/${total} ${message}` : "";
}

// ------------------------------------------------------------------------------ state

function onState(st) {
  S.state = st;
  $("server").textContent = st.server + (st.scene ? ` · scene ${st.scene}` : "");
  setMode(st.mode);
  $("devices").textContent = Object.entries(st.devices).map(([k, v]) => `${k}:${v}`).join(" ");
  $("auth").hidden = !st.token || S.authed;
  document.querySelectorAll("button.act").forEach((b) => { b.disabled = !canAct(); });
  document.querySelectorAll(".simonly").forEach((el) => { el.hidden = !st.truth; });
  const p = st.pose;
  let pose = `pose x ${p.x.toFixed(2)} y ${p.y.toFixed(2)} heading ${p.heading.toFixed(1)}°`;
  if (st.truth) pose += `\ntruth x ${st.truth.x.toFixed(2)} y ${st.truth.y.toFixed(2)} heading ${st.truth.heading.toFixed(1)}°`;
  if (st.ptu) pose += `\nPTU pan ${st.ptu[0].toFixed(1)}° tilt ${st.ptu[1].toFixed(1)}°`;
  $("pose").textContent = pose;
  $("pose").style.whiteSpace = "pre";
  $("monitors").textContent = Object.entries(st.monitors || {}).map(([k, v]) => `${k}=${v}`).join(" ");
  updateLayers(st.maps || {});
  showProgress();
  draw();
}

function updateLayers(maps) {
  for (const [name, m] of Object.entries(maps)) {
    const have = S.layers[name];
    if (have && (have.url === m.url || have.loading === m.url)) continue;
    // the old image stays on the map until the new version has loaded: no blank map meanwhile
    const layer = { url: m.url, bounds: m.bounds, img: new Image(), legend: null, ready: false };
    if (have) have.loading = m.url; else S.layers[name] = layer;
    fetch(m.url).then((resp) => {
      if (!resp.ok) throw new Error(resp.statusText);
      layer.legend = JSON.parse(resp.headers.get("X-Legend") || "null");
      return resp.blob();
    }).then((blob) => {
      layer.img.onload = () => {
        layer.ready = true;
        const old = S.layers[name];
        if (old && old !== layer && old.img.src.startsWith("blob:")) URL.revokeObjectURL(old.img.src);
        S.layers[name] = layer;
        if (!S.fitted) fit();
        draw();
        drawLegend();
      };
      layer.img.src = URL.createObjectURL(blob);
    }).catch((err) => logLine(`layer ${name}: ${err}`, "ERROR", false));
  }
  for (const name of Object.keys(S.layers)) if (!(name in maps)) delete S.layers[name];
  const box = $("layers");
  const names = Object.keys(maps);
  if (box.dataset.names !== names.join(",")) {
    box.dataset.names = names.join(",");
    box.innerHTML = names.length ? "" : "<i>no map yet: run dem-full-tof</i>";
    for (const name of names) {
      const label = document.createElement("label");
      const cb = document.createElement("input");
      cb.type = "checkbox";
      cb.dataset.layer = name;
      cb.checked = !!S.visible[name];
      cb.onchange = () => { S.visible[name] = cb.checked; draw(); drawLegend(); };
      label.append(cb, " " + name);
      box.appendChild(label);
    }
  }
}

function drawLegend() {
  // the legend of the topmost visible layer with one: it matches what is drawn last
  const names = Object.keys(S.layers).filter((n) => S.visible[n] && S.layers[n].legend).reverse();
  const el = $("legend");
  if (!names.length) { el.hidden = true; return; }
  const name = names[0], lg = S.layers[name].legend;
  el.hidden = false;
  el.innerHTML = "";
  const title = document.createElement("div");
  title.innerHTML = `<b>${name}</b>`;
  el.appendChild(title);
  if (lg.kind === "ramp") {
    const ramp = document.createElement("div");
    ramp.className = "ramp";
    ramp.style.background = `linear-gradient(to right, ${lg.colours.map((c) => `rgb(${c.join(",")})`).join(",")})`;
    const scale = document.createElement("div");
    scale.textContent = `${fmt(lg.lo)} … ${fmt(lg.hi)} ${lg.unit}`;
    el.append(ramp, scale);
  } else if (lg.kind === "classes") {
    for (const [[r, g, b, a], label] of lg.entries) {  // the colours as drawn; alpha 0 shows hatched
      const row = document.createElement("div");
      const sw = document.createElement("span");
      sw.className = "swatch" + (a === 0 ? " transparent" : "");
      if (a > 0) sw.style.background = `rgba(${r},${g},${b},${a / 255})`;
      row.append(sw, label);
      el.appendChild(row);
    }
  } else {
    el.appendChild(document.createTextNode("image"));
  }
}

function fmt(v) {
  return Math.abs(v) >= 100 ? v.toFixed(0) : Math.abs(v) >= 1 ? v.toFixed(2) : v.toPrecision(2);
}

// ------------------------------------------------------------------------------ view

function size() {
  const r = canvas.getBoundingClientRect();
  const dpr = window.devicePixelRatio || 1;
  if (canvas.width !== Math.round(r.width * dpr) || canvas.height !== Math.round(r.height * dpr)) {
    canvas.width = Math.round(r.width * dpr);
    canvas.height = Math.round(r.height * dpr);
  }
  return { w: r.width, h: r.height, dpr };
}

function toScreen(x, y) {
  const { w, h } = size();
  return [w / 2 + (x - S.view.cx) * S.view.scale, h / 2 - (y - S.view.cy) * S.view.scale];
}

function toWorld(px, py) {
  const { w, h } = size();
  return [S.view.cx + (px - w / 2) / S.view.scale, S.view.cy - (py - h / 2) / S.view.scale];
}

function fit() {
  const boxes = Object.values(S.layers).filter((l) => l.ready).map((l) => l.bounds);
  const p = S.state ? (S.state.truth || S.state.pose) : { x: 0, y: 0 };
  let [x0, y0, x1, y1] = [p.x - 4, p.y - 4, p.x + 4, p.y + 4];
  for (const b of boxes) { x0 = Math.min(x0, b[0]); y0 = Math.min(y0, b[1]); x1 = Math.max(x1, b[2]); y1 = Math.max(y1, b[3]); }
  const { w, h } = size();
  S.view = { cx: (x0 + x1) / 2, cy: (y0 + y1) / 2, scale: 0.92 * Math.min(w / (x1 - x0), h / (y1 - y0)) };
  S.fitted = boxes.length > 0;
  draw();
}

function niceStep(raw) {
  const p = Math.pow(10, Math.floor(Math.log10(raw)));
  for (const m of [1, 2, 5, 10]) if (m * p >= raw) return m * p;
  return 10 * p;
}

// ------------------------------------------------------------------------------ drawing

function draw() {
  const { w, h, dpr } = size();
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.clearRect(0, 0, w, h);
  ctx.imageSmoothingEnabled = false;
  for (const [name, layer] of Object.entries(S.layers)) {
    if (!S.visible[name] || !layer.ready) continue;
    const [x0, y0, x1, y1] = layer.bounds;
    const [px, py] = toScreen(x0, y1);
    ctx.drawImage(layer.img, px, py, (x1 - x0) * S.view.scale, (y1 - y0) * S.view.scale);
  }
  drawGrid(w, h);
  const st = S.state;
  if (!st) return;
  if ($("show-track").checked) polyline(st.track, "#1f6feb", 2);
  if ($("show-plan").checked && S.plan.length) {
    polyline(S.plan, "#e67e22", 2.5, [6, 4]);
    for (const wp of S.plan) dot(wp[0], wp[1], 3.5, "#e67e22");
  }
  for (const hz of S.hazards) dot(hz.x, hz.y, 5, hz.level === "stop" ? "#d00" : "#f90");
  if (S.check) {
    const colour = S.check.verdict === "ok" ? "#1a8f3a" : S.check.verdict === "not_traversable" ? "#c0392b" : "#d68910";
    polyline([S.check.from, S.check.to], colour, 3);
    dot(S.check.to[0], S.check.to[1], 5, colour);
    const [px, py] = toScreen(S.check.to[0], S.check.to[1]);
    label(S.check.verdict, px + 8, py - 8, colour);
  }
  if (st.truth && Math.hypot(st.truth.x - st.pose.x, st.truth.y - st.pose.y) > 0.05) rover(st.truth, st, true);
  rover(st.pose, st, false);
  if (S.click) dot(S.click[0], S.click[1], 5, "#7d3cff");
  drawScale(w, h);
  drawNorth(w);
}

function polyline(points, colour, width, dash) {
  if (!points || points.length < 2) return;
  ctx.save();
  ctx.strokeStyle = colour;
  ctx.lineWidth = width;
  ctx.lineJoin = "round";
  if (dash) ctx.setLineDash(dash);
  ctx.beginPath();
  points.forEach((p, i) => { const [x, y] = toScreen(p[0], p[1]); if (i) ctx.lineTo(x, y); else ctx.moveTo(x, y); });
  ctx.stroke();
  ctx.restore();
}

function dot(x, y, r, colour) {
  const [px, py] = toScreen(x, y);
  ctx.beginPath();
  ctx.arc(px, py, r, 0, 2 * Math.PI);
  ctx.fillStyle = colour;
  ctx.fill();
  ctx.strokeStyle = "#fff";
  ctx.lineWidth = 1;
  ctx.stroke();
}

function label(text, x, y, colour) {
  ctx.font = "12px system-ui, sans-serif";
  ctx.lineWidth = 3;
  ctx.strokeStyle = "#fff";
  ctx.strokeText(text, x, y);
  ctx.fillStyle = colour || "#222";
  ctx.fillText(text, x, y);
}

function rover(pose, st, ghost) {
  const hd = (pose.heading * Math.PI) / 180;
  const [px, py] = toScreen(pose.x, pose.y);
  const L = st.rover.length * S.view.scale, W = st.rover.width * S.view.scale;
  if (!ghost && $("show-fov").checked && st.ptu) {  // the ToF's view wedge, 4.5 m (its kept range)
    const a = hd + (st.ptu[0] * Math.PI) / 180, half = ((st.tof_hfov / 2) * Math.PI) / 180;
    const r = 4.5 * S.view.scale;
    ctx.beginPath();
    ctx.moveTo(px, py);
    ctx.arc(px, py, r, -(a + half), -(a - half));
    ctx.closePath();
    ctx.fillStyle = "rgba(255, 200, 0, 0.16)";
    ctx.fill();
    ctx.strokeStyle = "rgba(200, 150, 0, 0.7)";
    ctx.stroke();
  }
  ctx.save();
  ctx.translate(px, py);
  ctx.rotate(-hd);
  ctx.fillStyle = ghost ? "rgba(0,0,0,0)" : "rgba(30, 40, 50, 0.85)";
  ctx.strokeStyle = ghost ? "#555" : "#fff";
  ctx.lineWidth = 1.5;
  if (ghost) ctx.setLineDash([4, 3]);
  ctx.fillRect(-L / 2, -W / 2, L, W);
  ctx.strokeRect(-L / 2, -W / 2, L, W);
  if (!ghost) {  // the forward arrow
    ctx.beginPath();
    ctx.moveTo(-L / 4, 0);
    ctx.lineTo(L / 2 + 14, 0);
    ctx.moveTo(L / 2 + 14, 0);
    ctx.lineTo(L / 2 + 6, -5);
    ctx.moveTo(L / 2 + 14, 0);
    ctx.lineTo(L / 2 + 6, 5);
    ctx.strokeStyle = "#ffd166";
    ctx.lineWidth = 2.5;
    ctx.stroke();
  }
  ctx.restore();
  if (ghost) label("simulator truth", px + 10, py + 16, "#555");
}

function drawGrid(w, h) {
  const step = niceStep(90 / S.view.scale);
  const [x0, y1] = toWorld(0, 0), [x1, y0] = toWorld(w, h);
  ctx.save();
  ctx.strokeStyle = "rgba(80, 90, 100, 0.25)";
  ctx.lineWidth = 1;
  ctx.font = "10px monospace";
  ctx.fillStyle = "#445";
  for (let x = Math.ceil(x0 / step) * step; x <= x1; x += step) {
    const [px] = toScreen(x, 0);
    ctx.beginPath(); ctx.moveTo(px, 0); ctx.lineTo(px, h); ctx.stroke();
    ctx.fillText(`${+x.toFixed(6)} m`, px + 2, h - 4);
  }
  for (let y = Math.ceil(y0 / step) * step; y <= y1; y += step) {
    const [, py] = toScreen(0, y);
    ctx.beginPath(); ctx.moveTo(0, py); ctx.lineTo(w, py); ctx.stroke();
    ctx.fillText(`${+y.toFixed(6)} m`, 2, py - 2);
  }
  ctx.restore();
}

function drawScale(w, h) {
  const metres = niceStep(120 / S.view.scale), px = metres * S.view.scale;
  const x = 14, y = h - 26;
  ctx.save();
  ctx.fillStyle = "rgba(255,255,255,0.85)";
  ctx.fillRect(x - 6, y - 18, px + 60, 30);
  ctx.strokeStyle = "#111";
  ctx.lineWidth = 2;
  ctx.beginPath();
  ctx.moveTo(x, y - 5); ctx.lineTo(x, y); ctx.lineTo(x + px, y); ctx.lineTo(x + px, y - 5);
  ctx.stroke();
  label(`${metres} m`, x + px + 6, y, "#111");
  ctx.restore();
}

function drawNorth(w) {
  const x = w - 30, y = 50;
  ctx.save();
  ctx.fillStyle = "#111";
  ctx.beginPath();
  ctx.moveTo(x, y - 24); ctx.lineTo(x - 8, y); ctx.lineTo(x + 8, y); ctx.closePath();
  ctx.fill();
  label("+y", x - 8, y + 14, "#111");
  label("x →", x - 60, y + 30, "#111");
  ctx.restore();
}

// ------------------------------------------------------------------------------ input

let drag = null;
canvas.addEventListener("mousedown", (e) => { drag = { x: e.clientX, y: e.clientY, cx: S.view.cx, cy: S.view.cy, moved: false }; });
window.addEventListener("mouseup", () => { setTimeout(() => { drag = null; }, 0); });
canvas.addEventListener("mousemove", (e) => {
  const r = canvas.getBoundingClientRect();
  const [wx, wy] = toWorld(e.clientX - r.left, e.clientY - r.top);
  $("cursor").textContent = `x ${wx.toFixed(2)} m  y ${wy.toFixed(2)} m`;
  if (drag && e.buttons) {
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    if (Math.abs(dx) + Math.abs(dy) > 3) drag.moved = true;
    S.view.cx = drag.cx - dx / S.view.scale;
    S.view.cy = drag.cy + dy / S.view.scale;
    draw();
  }
});
canvas.addEventListener("wheel", (e) => {
  e.preventDefault();
  const r = canvas.getBoundingClientRect();
  zoomAt(e.clientX - r.left, e.clientY - r.top, e.deltaY < 0 ? 1.2 : 1 / 1.2);
}, { passive: false });
canvas.addEventListener("click", (e) => {
  if (drag && drag.moved) return;
  const r = canvas.getBoundingClientRect();
  openMenu(toWorld(e.clientX - r.left, e.clientY - r.top), e.clientX - r.left, e.clientY - r.top);
});

function zoomAt(px, py, factor) {
  const [wx, wy] = toWorld(px, py);
  S.view.scale = Math.max(2, Math.min(2000, S.view.scale * factor));
  const [nx, ny] = toWorld(px, py);
  S.view.cx += wx - nx;
  S.view.cy += wy - ny;
  draw();
}

function navLine() {
  const [x, y] = S.click;
  let line = `navigate -goal ${x.toFixed(2)},${y.toFixed(2)} -sensor ${$("nav-sensor").value} -tolerance ${$("nav-tol").value}`;
  if (S.state && S.state.truth && $("nav-auto").checked) line += " -auto true";
  return line;
}

function checkLine() {
  const [x, y] = S.click;
  return `check-move -to ${x.toFixed(2)},${y.toFixed(2)}`;
}

function openMenu(point, px, py) {
  S.click = point;
  const menu = $("clickmenu");
  menu.hidden = false;
  menu.style.left = `${Math.min(px + 12, canvas.clientWidth - 270)}px`;
  menu.style.top = `${Math.min(py + 12, canvas.clientHeight - 200)}px`;
  menu.querySelector(".where").textContent = `x ${point[0].toFixed(2)} m, y ${point[1].toFixed(2)} m`;
  menu.querySelector(".cmdline").textContent = navLine();
  draw();
}

function closeMenu() {
  $("clickmenu").hidden = true;
  S.click = null;
  draw();
}

["nav-sensor", "nav-auto", "nav-tol"].forEach((id) => $(id).addEventListener("change", () => {
  if (S.click) $("clickmenu").querySelector(".cmdline").textContent = navLine();
}));
$("go-nav").onclick = () => { S.plan = []; send(navLine()); closeMenu(); };
$("go-check").onclick = () => {
  const to = S.click.slice(), st = S.state, from = st ? [st.pose.x, st.pose.y] : [0, 0];
  send(checkLine(), (r) => { if (r.status === "OK") { S.check = { from, to, verdict: r.verdict }; draw(); } });
  closeMenu();
};
$("go-cancel").onclick = closeMenu;
$("fit").onclick = fit;
$("zoomin").onclick = () => zoomAt(canvas.clientWidth / 2, canvas.clientHeight / 2, 1.5);
$("zoomout").onclick = () => zoomAt(canvas.clientWidth / 2, canvas.clientHeight / 2, 1 / 1.5);
$("btn-dem").onclick = () => send("dem-full-tof");
$("btn-break").onclick = () => send("break");
$("btn-continue").onclick = () => send("continue");
$("btn-reset").onclick = () => send("reset");
$("cmdform").onsubmit = (e) => {
  e.preventDefault();
  const line = $("cmd").value.trim();
  if (line) send(line);
};
$("authform").onsubmit = (e) => { e.preventDefault(); send(`auth -token ${$("token").value}`, (r) => {
  if (r.status === "OK") { S.authed = true; $("token").value = ""; onState(S.state); }
}); };
window.addEventListener("resize", draw);
window.addEventListener("keydown", (e) => { if (e.key === "Escape") closeMenu(); });

connect();
