// RVS operator console: a map of the rover's world and the server's lines, live over a WebSocket.
// Every action is a command line sent to the server's dispatcher, exactly as telnet sends it;
// the page only draws what the server says, and the server decides what it accepts (the token,
// the mode). Map frame: x right, y up (the GeoTIFFs' east and north), metres; the rover's
// forward direction is its heading, counter-clockwise from +x.
"use strict";

const $ = (id) => document.getElementById(id);
const canvas = $("map");
const ctx = canvas.getContext("2d");

// A page's own tag prefix: two pages (or a reloaded one) never label their requests alike, so a
// page takes no other connection's line for the answer to its own request.
const PAGE = Math.random().toString(36).slice(2, 8);
// Overlays, bottom to top: check-move, plan, track. Colours no layer ramp or class uses.
const COLOUR = {
  track: "#1f6feb", plan: "#c026d3", goal: "#111111",
  check: { ok: "#15803d", not_traversable: "#dc2626" }, checkOther: "#d97706", measure: "#111111",
};
const HISTORY_KEY = "rvs.commands";
const HISTORY_MAX = 100;
// The arguments of the auth line a page was unlocked with (`-token ...` as the wire reads them),
// kept for its reloads and reconnects (each new WebSocket is a new connection the server asks
// the token of). sessionStorage, not localStorage: it stays with this tab and goes when the tab
// closes, so the key to driving the rover is not left on the disk for whoever opens the browser
// next, nor given to every tab opened later. For the same reason an auth line typed on the
// command line is kept out of the command history (localStorage).
const AUTH_KEY = "rvs.auth";
// A request line's own tag: "@tag command ...", as the server parses it.
const TAGGED = /^@(\S+)\s/;
// A request line's command word and the rest, after its tag if it has one.
const COMMAND = /^(?:@\S+\s+)?(\S+)\s*(.*)$/s;

const S = {
  state: null,          // the last state snapshot
  online: false,
  layers: {},           // name -> {wanted, bounds, unit, img, imgBounds, legend, ready, loading}
  visible: { dem: true, hazard: true },
  chosen: false,        // the operator changed the visible layers (no more defaults)
  opacity: {},          // name -> 0..1
  plan: [],             // waypoints [[x, y, heading], ...] of the last navigate leg
  hazards: [],          // hazard events with a position
  labels: [],           // the map's mark labels as placed: [{text, x, y, w, h}] (screen px)
  ticks: [],            // the grid's axis labels as drawn: [{axis, text, x, y, w, h}] (screen px)
  authed: false,
  authing: false,       // the stored token is being sent again (no unlock panel meanwhile)
  tagN: 0,
  pending: {},          // tag -> {onFinal}
  progress: null,       // the last PROGRESS fields
  bar: null,            // the running job's progress as a whole (jobBar)
  resultJob: null,      // the job whose final line the result box shows
  clock: 0,             // server time minus this page's time, seconds
  view: { cx: 0, cy: 0, scale: 60 },
  fitted: false,
  click: null,          // the map point of the open click menu
  measure: null,        // {a, b} while the distance tool is on
  commands: loadCommands(),
  commandAt: -1,        // position in the command history while browsing it with Up / Down
  cameras: {},          // name -> {v, loading, at}: the image each camera shows
};
let ws = null;

function loadCommands() {
  try { return JSON.parse(localStorage.getItem(HISTORY_KEY) || "[]"); } catch (e) { return []; }
}

// ------------------------------------------------------------------------------ connection

function connect() {
  ws = new WebSocket((location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/ws");
  ws.onopen = () => {
    // a new connection: whatever the old one knew may be stale (another server, a new map)
    for (const l of Object.values(S.layers)) if (l.img) URL.revokeObjectURL(l.img.src);
    S.layers = {};
    S.cameras = {};
    S.pending = {};
    S.authed = false;
    S.authing = false;  // an auth the old connection did not answer is no one's now
    $("layers").dataset.names = "(reconnected)";
    setLink(true);
    const args = storedAuth();
    if (args) authenticate(args);
  };
  ws.onclose = () => { setLink(false); setTimeout(connect, 1500); };
  ws.onmessage = (ev) => {
    const m = JSON.parse(ev.data);
    if (m.type === "state") onState(m);
    else if (m.type === "reply") onReply(m, false);
    else if (m.type === "history") onHistory(m.lines);
  };
}

function setLink(up) {
  S.online = up;
  const el = $("link");
  el.textContent = up ? "live" : "offline";
  el.className = up ? "up" : "down";
  if (!up) {
    setMode("offline");
    $("legend").hidden = true;
    S.progress = null;
  }
  updateButtons();
  draw();
}

// A line the operator tagged keeps that tag (the server answers under it, and only this page
// gets the answer); any other line gets one of the page's own.
function send(line, handlers) {
  if (!ws || ws.readyState !== WebSocket.OPEN) { showResult("not connected: the server is offline", true); return; }
  const own = TAGGED.exec(line);
  const tag = own ? own[1] : `w${PAGE}-${++S.tagN}`;
  S.pending[tag] = handlers || {};
  ws.send(JSON.stringify({ line: own ? line : "@" + tag + " " + line }));
}

function storedAuth() {
  try { return sessionStorage.getItem(AUTH_KEY) || ""; } catch (e) { return ""; }
}

function commandWord(line) {
  const m = COMMAND.exec(line);
  return m ? [m[1].toLowerCase(), m[2]] : ["", ""];
}

// A token as one quoted value of the wire: spaces, quotes and backslashes in it stay its own.
function quoted(token) {
  return `"${token.replace(/[\\"]/g, (c) => "\\" + c)}"`;
}

// An auth line, from the panel or typed on the command line (``line``: sent as typed, its tag
// kept): the page unlocks when the server says OK, and keeps ``args`` for its reloads. A wrong
// token leaves an unlocked connection unlocked (the server's rule), and the page with it.
function authenticate(args, line) {
  S.authing = true;
  send(line || `auth ${args}`, { onFinal: (r) => {
    S.authing = false;
    try {
      if (r.status === "OK") sessionStorage.setItem(AUTH_KEY, args);
      else if (!S.authed) sessionStorage.removeItem(AUTH_KEY);  // refused (the server's token changed): ask again
    } catch (e) { /* storage off: unlocked until the page reloads */ }
    if (r.status === "OK") {
      S.authed = true;
      $("token").value = "";
    }
    if (S.state) onState(S.state);
  } });
}

function canAct() {
  return S.online && !!S.state && (!S.state.token || S.authed);
}

// ------------------------------------------------------------------------------ lines

function onReply(m, past) {
  const r = m.reply;
  if (!past && typeof m.t === "number") S.clock = m.t - Date.now() / 1000;
  // the greeting and PROGRESS (the bar shows it) are no news to count on the Events tab
  logLine(m.text, r.status, m.own, m.t, past, !past && r.status !== "PROGRESS" && r.kind !== "hello");
  if (r.status === "PROGRESS") {
    S.progress = r;
    jobBar(r);
    showProgress();
  } else if (r.status === "ACK" && !past) {
    // a new job, whoever started it: the result box's last job line is the previous job's
    if (S.resultJob !== null && S.resultJob !== r.job) markPrevious();
    if (m.own && r.tag in S.pending) {
      S.pending[r.tag].job = r.job;  // its final line is that job's result
      showResult(m.text, false);
    }
    if (r.module === "EGP-RVS-NAVIGATE") {
      S.plan = [];  // the old plan goes once the server took the new goal
      draw();
    }
  } else if (r.status === "EVENT") {
    if (r.kind === "mode" && !past) setMode(r.mode);
    if (r.kind === "waiting" && Array.isArray(r.waypoints)) S.plan = r.waypoints;
    if (r.kind === "hazard" && typeof r.x === "number") S.hazards.push({ x: r.x, y: r.y, level: r.level });
    draw();
  } else if (!past && m.own && (r.status === "OK" || r.status === "ERROR")) {
    // only this page's own lines answer its requests (m.own): another's job may use any tag;
    // an answer with no tag (a line whose tag the server could not read) is this page's too
    const handlers = r.tag !== undefined ? S.pending[r.tag] : {};
    if (handlers) {
      if (r.tag !== undefined) delete S.pending[r.tag];
      showResult(m.text, r.status === "ERROR");
      S.resultJob = handlers.job !== undefined ? handlers.job : null;
      if (handlers.onFinal) handlers.onFinal(r);
    }
  }
  if ((r.status === "OK" || r.status === "ERROR") && r.job !== undefined && r.module !== "EGP-RVS-STATUS" && !past) {
    S.progress = null;
    S.bar = null;
    // its final line ends the job here at once: the state says so up to a tick later, and until
    // then its job would come back as a bar begun again
    if (S.state && S.state.job && S.state.job.id === r.job) {
      S.state = { ...S.state, job: null };
      updateButtons();
    }
  }
  showProgress();
}

function markPrevious() {
  const el = $("result");
  if (!el.textContent || el.classList.contains("previous")) return;
  el.classList.add("previous");
  el.dataset.previous = `previous job ${S.resultJob}:`;
}

function onHistory(lines) {
  $("log").textContent = "";
  S.hazards = [];
  S.plan = [];
  for (const m of lines) onReply(m, true);
}

function clockText(t) {
  if (typeof t !== "number") return "";
  const d = new Date(t * 1000);
  return d.toTimeString().slice(0, 8);
}

function logLine(text, status, own, t, past, news) {
  const li = document.createElement("li");
  const time = document.createElement("time");
  time.textContent = clockText(t);
  if (typeof t === "number") time.dateTime = new Date(t * 1000).toISOString();
  li.append(time, text);
  li.className = status + (own ? " mine" : "") + (past ? " past" : "");
  const log = $("log");
  const atEnd = log.scrollTop + log.clientHeight >= log.scrollHeight - 4;
  log.appendChild(li);
  while (log.children.length > 600) log.removeChild(log.firstChild);
  if (atEnd || past) log.scrollTop = log.scrollHeight;
  if (news && $("pane-events").hidden) {  // lines not seen yet: counted on the tab
    const unread = $("tab-events").querySelector(".unread");
    unread.textContent = String((+unread.textContent || 0) + 1);
    unread.hidden = false;
    if (status === "ERROR") unread.classList.add("error");
  }
}

function showResult(text, error) {
  const el = $("result");
  el.textContent = text;
  el.className = error ? "error" : "";
  delete el.dataset.previous;
  S.resultJob = null;
}

function setMode(mode) {
  const el = $("mode");
  el.textContent = mode;
  el.dataset.mode = mode;
  updateButtons();
}

function seconds(s) {
  s = Math.max(0, Math.round(s));
  return s >= 60 ? `${Math.floor(s / 60)} min ${String(s % 60).padStart(2, "0")} s` : `${s} s`;
}

// The bar is the job's, not its phase's: a job reports a count per phase (docs/PROTOCOL.md), so
// each phase gets a share of what is left of the bar when it starts, its weight against the
// phases that follow it in its job, and fills that share as its count grows. The bar never goes
// back; a phase that ends early leaves its share filled. Weights: the share of a DEM's time
// each phase took (dem-full-tof of 18 views, drivers.ptu.time_scale=0.5: pointing 0.06 s,
// acquire 8.8 s, process 8.7 s, write 1.2 s); a navigate leg scans as a DEM, then plans and
// drives (its drive lasts as long as the GNC takes: a guess), and keeps a leg's weight in
// reserve for the next leg. A job of one count (move-ptu) or of phases not listed fills the
// whole bar with its count.
const DEM_PHASES = [["pointing", 0.3], ["acquire", 47], ["process", 46], ["write", 6]];
const LEG_PHASES = [...DEM_PHASES, ["plan", 5], ["drive", 40], ["stop", 1]];

function jobBar(r) {
  let b = S.bar;
  if (!b || b.job !== r.job) {
    b = S.bar = { job: r.job, key: null, f0: 0, span: 1, fraction: 0 };
    // met mid-job (a page opened, reloaded or reconnected while it runs): the phases before
    // this one as done, the bar where a page that watched them drew it
    for (const [leg, phase] of phasesBefore(r)) jobBar({ job: r.job, leg, phase, done: 1, total: 1 });
  }
  const key = `${r.leg || ""}/${r.phase || ""}`;
  if (b.key !== key) {
    if (b.key !== null) b.f0 += b.span;  // the phase before is over
    b.key = key;
    const order = r.leg !== undefined ? LEG_PHASES : DEM_PHASES;
    const at = order.findIndex(([name]) => name === (r.phase || ""));
    if (at < 0) b.span = 1 - b.f0;
    else {
      const after = order.slice(at + 1).reduce((sum, [, w]) => sum + w, 0);
      const reserve = r.leg !== undefined ? LEG_PHASES.reduce((sum, [, w]) => sum + w, 0) : 0;
      b.span = ((1 - b.f0) * order[at][1]) / (order[at][1] + after + reserve);
    }
  }
  const within = r.total > 0 ? Math.min(1, r.done / r.total) : 0;
  b.fraction = Math.max(b.fraction, Math.min(1, b.f0 + b.span * within));
}

// The phases a job went through before ``r``'s, as [leg, phase]: a navigate's earlier legs whole.
function phasesBefore(r) {
  const order = r.leg !== undefined ? LEG_PHASES : DEM_PHASES;
  const at = order.findIndex(([name]) => name === (r.phase || ""));
  const before = [];
  for (let leg = 1; r.leg !== undefined && leg < r.leg; leg++) for (const [name] of order) before.push([leg, name]);
  for (const [name] of order.slice(0, Math.max(0, at))) before.push([r.leg, name]);
  return before;
}

function showProgress() {
  const job = S.online && S.state && S.state.job;
  const p = S.progress;
  let done = 0, total = 0, phase = "", message = "";
  if (p && job && p.job === job.id) {
    done = p.done; total = p.total; phase = p.phase || ""; message = p.message || "";
  } else if (job) {
    done = job.done; total = job.total; phase = job.phase || "";
    if (total > 0) jobBar({ job: job.id, leg: job.leg, phase, done, total });  // a page opened while the job ran
  }
  const fraction = job && S.bar && S.bar.job === job.id ? S.bar.fraction : null;
  $("job").textContent = job ? `${job.command} (job ${job.id})` : "none";
  $("bar-fill").style.width = fraction !== null ? `${(100 * fraction).toFixed(1)}%` : (job ? "3%" : "0");
  $("bar-fill").dataset.fraction = fraction !== null ? fraction.toFixed(4) : "";
  $("phase").textContent = job ? `${phase ? phase + " " : ""}${done}/${total} ${message}` : "";
  $("times").textContent = job ? jobTimes(job, fraction) : "";
}

// The estimate is the job's: the time it has taken so far against how much of the bar it filled.
function jobTimes(job, fraction) {
  // the server's clock for both ends: the page's clock may be off
  const elapsed = Date.now() / 1000 + S.clock - job.started;
  let text = `elapsed ${seconds(elapsed)}`;
  if (fraction !== null && fraction >= 0.02 && fraction < 1 && elapsed >= 1) {
    text += ` · about ${seconds((elapsed * (1 - fraction)) / fraction)} left`;
  }
  return text;
}

setInterval(() => { if (S.state && S.state.job) showProgress(); }, 1000);

// ------------------------------------------------------------------------------ state

function onState(st) {
  S.state = st;
  $("server").textContent = st.server + (st.scene ? ` · scene ${st.scene}` : "");
  setMode(st.mode);
  $("devices").textContent = Object.entries(st.devices).map(([k, v]) => `${k}:${v}`).join(" ");
  $("auth").hidden = !st.token || S.authed || S.authing;
  $("open-commands").textContent = (st.open_commands || []).join(", ");
  document.querySelectorAll(".simonly").forEach((el) => { el.hidden = !st.truth; });
  const p = st.pose;
  let pose = `pose x ${p.x.toFixed(2)} y ${p.y.toFixed(2)} heading ${p.heading.toFixed(1)}°`;
  if (st.truth) pose += `\ntruth x ${st.truth.x.toFixed(2)} y ${st.truth.y.toFixed(2)} heading ${st.truth.heading.toFixed(1)}°`;
  if (st.ptu) pose += `\nPTU pan ${st.ptu[0].toFixed(1)}° tilt ${st.ptu[1].toFixed(1)}°`;
  $("pose").textContent = pose;
  $("pose").style.whiteSpace = "pre";
  $("monitors").textContent = Object.entries(st.monitors || {}).map(([k, v]) => `${k}=${v}`).join(" ");
  updateLayers(st.maps || {});
  updateProducts(st.products || []);
  updateCameras();
  showProgress();
  updateButtons();
  draw();
}

function updateButtons() {
  const st = S.state, can = canAct();
  const mode = S.online && st ? st.mode : "offline";
  const job = S.online && st ? st.job : null;
  const set = (id, ok, why) => { const b = $(id); b.disabled = !ok; b.title = ok ? "" : why; };
  const lock = !S.online ? "the server is offline" : !can ? "read-only: unlock with the token" : "";
  set("btn-dem", can && mode === "ready", lock || `mode ${mode}: a scan needs ready`);
  set("btn-break", can && !!job, lock || "no job to break");
  set("btn-continue", can && !job && ["break", "standby", "fault"].includes(mode), lock || "continue leaves break, standby or fault");
  set("btn-reset", can && !job, lock || "a job runs: break it first");
  set("go-nav", can && mode === "ready", lock || `mode ${mode}: navigate needs ready`);
  set("go-check", can && !!(st && st.maps && st.maps.traversability), lock || "no traversability map yet");
  // the command line stays open while locked: the server answers its open commands (auth among them)
  set("cmd-go", S.online, "the server is offline");
  set("auth-go", S.online, "the server is offline");
  $("cmd").disabled = !S.online;
}

function updateLayers(maps) {
  const names = Object.keys(maps);  // the server's order: bottom first
  if (!S.chosen && names.length && !names.some((n) => !n.startsWith("global_") && S.visible[n])) {
    for (const n of names) if (n.startsWith("global_")) S.visible[n] = true;  // a global map alone
  }
  for (const [name, m] of Object.entries(maps)) {
    const l = S.layers[name] || (S.layers[name] = { img: null, legend: null, ready: false, loading: null });
    l.wanted = m.url;
    l.bounds = m.bounds;
    l.unit = m.unit || "";
  }
  for (const name of Object.keys(S.layers)) {
    if (!(name in maps)) {
      if (S.layers[name].img) URL.revokeObjectURL(S.layers[name].img.src);
      delete S.layers[name];
    }
  }
  for (const name of names) if (S.visible[name]) loadLayer(name);
  if (!S.fitted && names.some((n) => S.visible[n])) fit();
  const box = $("layers");
  if (box.dataset.names !== names.join(",")) {
    box.dataset.names = names.join(",");
    box.innerHTML = names.length ? "" : "<i>no map yet: run dem-full-tof</i>";
    for (const name of names.slice().reverse()) {
      const row = document.createElement("div");
      row.className = "layer";
      const label = document.createElement("label");
      const cb = document.createElement("input");
      cb.type = "checkbox";
      cb.dataset.layer = name;
      cb.checked = !!S.visible[name];
      cb.onchange = () => {
        S.chosen = true;
        S.visible[name] = cb.checked;
        if (cb.checked) loadLayer(name);
        draw();
        drawLegend();
      };
      label.append(cb, ` ${name}${S.layers[name].unit ? ` (${S.layers[name].unit})` : ""}`);
      const op = document.createElement("input");
      op.type = "range";
      op.min = "0"; op.max = "1"; op.step = "0.05";
      op.value = String(opacity(name));
      op.dataset.opacity = name;
      op.title = `${name} opacity`;
      op.oninput = () => { S.opacity[name] = parseFloat(op.value); draw(); };
      row.append(label, op);
      box.appendChild(row);
    }
  }
  drawLegend();
}

function opacity(name) {
  return name in S.opacity ? S.opacity[name] : 1;
}

// A layer's image is fetched when it is shown, not before: a page that shows two layers loads two.
function loadLayer(name) {
  const l = S.layers[name];
  if (!l || l.url === l.wanted || l.loading === l.wanted) return;
  const url = l.wanted, bounds = l.bounds;
  l.loading = url;
  let legend = null;
  fetch(url).then((resp) => {
    if (!resp.ok) throw new Error(resp.statusText);
    legend = JSON.parse(resp.headers.get("X-Legend") || "null");
    return resp.blob();
  }).then((blob) => {
    const img = new Image();
    img.onload = () => {
      const cur = S.layers[name];
      if (cur !== l || l.loading !== url) { URL.revokeObjectURL(img.src); return; }
      // the old image stays on the map until the new version has loaded: no blank map meanwhile
      if (l.img) URL.revokeObjectURL(l.img.src);
      Object.assign(l, { img, imgBounds: bounds, legend, url, ready: true, loading: null });
      if (!S.fitted) fit();
      draw();
      drawLegend();
    };
    img.src = URL.createObjectURL(blob);
  }).catch((err) => { l.loading = null; logLine(`layer ${name}: ${err}`, "ERROR", false, undefined, false, true); });
}

function updateProducts(products) {
  const box = $("products");
  const key = products.map((p) => p.name).join(",");
  if (box.dataset.key === key) return;
  box.dataset.key = key;
  box.textContent = "";
  for (const p of products) {
    const li = document.createElement("li");
    const a = document.createElement("a");
    a.href = p.url;
    a.download = p.name;
    a.textContent = p.name;
    li.appendChild(a);
    box.appendChild(li);
  }
  $("downloads").hidden = !products.length;
}

// ------------------------------------------------------------------------------ cameras

// The newest frame of each camera, from what the server's devices grabbed anyway. Fetched only
// while the panel is open, only when the state names a newer frame than the one shown, one
// request per camera at a time and at most one a second (the hazard monitor grabs at video
// rate; the page needs a glance, not a stream).
const CAMERA_EVERY_MS = 1000;

function updateCameras() {
  const list = (S.state && S.state.cameras) || [];
  const box = $("camera-list");
  const key = list.map((c) => c.name).join(",");
  if (box.dataset.key !== key) {
    box.dataset.key = key;
    box.textContent = "";
    for (const c of list) {
      const fig = document.createElement("figure");
      fig.dataset.camera = c.name;
      const img = document.createElement("img");
      img.alt = c.label;
      const cap = document.createElement("figcaption");
      fig.append(img, cap);
      box.appendChild(fig);
    }
  }
  for (const c of list) {
    const fig = box.querySelector(`figure[data-camera="${c.name}"]`);
    const cam = S.cameras[c.name] || (S.cameras[c.name] = { v: null, loading: false, at: 0 });
    if (!c.url) {
      fig.querySelector("img").removeAttribute("src");
      setCaption(fig, c.label, `no frame yet: ${c.hint}`);
      continue;
    }
    if (!camerasShown() || !S.online || cam.v === c.v || cam.loading || Date.now() - cam.at < CAMERA_EVERY_MS) continue;
    loadCamera(c, cam, fig);
  }
}

function setCaption(fig, label, text) {
  const cap = fig.querySelector("figcaption");
  cap.textContent = "";
  const b = document.createElement("b");
  b.textContent = label;
  cap.append(b, " " + text);
}

function loadCamera(c, cam, fig) {
  cam.loading = true;
  cam.at = Date.now();
  let caption = "";
  fetch(c.url).then((r) => {
    if (!r.ok) throw new Error(`HTTP ${r.status}`);
    caption = r.headers.get("X-Caption") || "";
    cam.v = +(r.headers.get("X-Version") || c.v);
    return r.blob();
  }).then((blob) => {
    const img = fig.querySelector("img");
    const old = img.src;
    img.onload = () => {
      if (old.startsWith("blob:")) URL.revokeObjectURL(old);
      img.dataset.v = cam.v;
      cam.loading = false;
    };
    img.onerror = () => { cam.loading = false; };
    img.src = URL.createObjectURL(blob);
    setCaption(fig, c.label, caption);
  }).catch((err) => { cam.loading = false; setCaption(fig, c.label, `unavailable: ${err.message}`); });
}

function camerasShown() {
  return !$("pane-cameras").hidden;
}

// a frame newer than the one shown may have come within the last second: look again
setInterval(() => { if (camerasShown()) updateCameras(); }, CAMERA_EVERY_MS);

// ------------------------------------------------------------------------------ tabs

// Job and Actions stay in sight; the rest is one tab at a time, each a click away.
function showTab(name) {
  for (const tab of document.querySelectorAll("#tabs [role=tab]")) {
    const on = tab.dataset.tab === name;
    tab.setAttribute("aria-selected", String(on));
    $(`pane-${tab.dataset.tab}`).hidden = !on;
  }
  if (name === "events") {
    const unread = $("tab-events").querySelector(".unread");
    unread.hidden = true;
    unread.textContent = "";
    unread.classList.remove("error");
    $("log").scrollTop = $("log").scrollHeight;
  }
  if (name === "cameras") updateCameras();
}
for (const tab of document.querySelectorAll("#tabs [role=tab]")) tab.onclick = () => showTab(tab.dataset.tab);

// One legend per visible layer, top first, as the layers list.
function drawLegend() {
  const el = $("legend");
  const names = Object.keys(S.layers).filter((n) => S.visible[n] && S.layers[n].legend).reverse();
  const hidden = !S.online || !names.length;
  const key = names.map((n) => `${n}@${S.layers[n].url}`).join(",");
  if (el.dataset.key === key && el.hidden === hidden) return;  // the state comes 5 times a second: rebuild only on change
  el.hidden = hidden;
  el.dataset.key = key;
  el.textContent = "";
  for (const name of names) el.appendChild(legendOf(name, S.layers[name]));
  draw();  // the legend's strip took its height from the map's (a resized canvas is blank)
}

function legendOf(name, layer) {
  const lg = layer.legend;
  const box = document.createElement("div");
  box.className = "lg";
  box.dataset.layer = name;
  const title = document.createElement("b");
  title.textContent = name + (lg.unit || layer.unit ? ` (${lg.unit || layer.unit})` : "");
  box.appendChild(title);
  if (lg.kind === "ramp") {
    const ramp = document.createElement("div");
    ramp.className = "ramp";
    ramp.style.background = `linear-gradient(to right, ${lg.colours.map((c) => `rgb(${c.join(",")})`).join(",")})`;
    const ends = document.createElement("div");
    ends.className = "ends";
    const lo = document.createElement("span"), hi = document.createElement("span");
    lo.textContent = fmt(lg.lo);
    hi.textContent = fmt(lg.hi);
    ends.append(lo, hi);
    box.append(ramp, ends);
    for (const [value, what] of lg.marks || []) {  // a threshold: where the hazard map says hazardous
      const mark = document.createElement("div");
      mark.className = "mark";
      mark.dataset.value = value;
      mark.style.left = `${(100 * (value - lg.lo)) / (lg.hi - lg.lo)}%`;
      mark.title = `${what} ${fmt(value)} ${lg.unit}`;
      ramp.appendChild(mark);
      const caption = document.createElement("div");
      caption.className = "threshold";
      caption.textContent = `| ${what} ${fmt(value)} ${lg.unit}: hazardous above`;
      box.appendChild(caption);
    }
  } else if (lg.kind === "classes") {
    for (const [[r, g, b, a], label] of lg.entries) {  // the colours as drawn; alpha 0 shows hatched
      const row = document.createElement("div");
      const sw = document.createElement("span");
      sw.className = "swatch" + (a === 0 ? " transparent" : "");
      if (a > 0) sw.style.background = `rgba(${r},${g},${b},${a / 255})`;
      row.append(sw, label);
      box.appendChild(row);
    }
  } else {
    box.appendChild(document.createTextNode(" image"));
  }
  if (lg.meaning) {
    const meaning = document.createElement("div");
    meaning.className = "meaning";
    meaning.textContent = lg.meaning.split(":")[0];
    meaning.title = lg.meaning;
    box.appendChild(meaning);
  }
  return box;
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

// The visible layers' bounds (known from the state before any image loads) and the rover.
function fit() {
  const names = Object.keys(S.layers);
  const shown = names.filter((n) => S.visible[n]);
  const boxes = (shown.length ? shown : names).map((n) => S.layers[n].bounds).filter(Boolean);
  const p = S.state ? (S.state.truth || S.state.pose) : { x: 0, y: 0 };
  let [x0, y0, x1, y1] = [p.x - 4, p.y - 4, p.x + 4, p.y + 4];
  for (const b of boxes) { x0 = Math.min(x0, b[0]); y0 = Math.min(y0, b[1]); x1 = Math.max(x1, b[2]); y1 = Math.max(y1, b[3]); }
  const { w, h } = size();
  if (w < 2 || h < 2) return;
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

let hatch = null;
function hatchPattern() {
  // the legend's "unseen" swatch, drawn: where a local layer has nothing, the map says so
  if (!hatch) {
    const c = document.createElement("canvas");
    c.width = c.height = 8;
    const g = c.getContext("2d");
    g.strokeStyle = "rgba(90, 100, 110, 0.6)";
    g.lineWidth = 1.2;
    g.beginPath();
    g.moveTo(0, 8); g.lineTo(8, 0);
    g.moveTo(-2, 2); g.lineTo(2, -2);
    g.moveTo(6, 10); g.lineTo(10, 6);
    g.stroke();
    hatch = ctx.createPattern(c, "repeat");
  }
  return hatch;
}

function drawLayers() {
  const names = S.state ? Object.keys(S.state.maps || {}) : Object.keys(S.layers);  // bottom first
  let hatched = false;
  for (const name of names) {
    const l = S.layers[name];
    if (!l || !S.visible[name] || !l.ready) continue;
    if (!hatched && !name.startsWith("global_")) {
      hatched = true;
      ctx.save();
      ctx.fillStyle = hatchPattern();
      for (const n of names) {
        const k = S.layers[n];
        if (n.startsWith("global_") || !k || !S.visible[n] || !k.ready) continue;
        const [x0, y0, x1, y1] = k.imgBounds;
        const [px, py] = toScreen(x0, y1);
        ctx.fillRect(px, py, (x1 - x0) * S.view.scale, (y1 - y0) * S.view.scale);
      }
      ctx.restore();
    }
    const [x0, y0, x1, y1] = l.imgBounds;
    const [px, py] = toScreen(x0, y1);
    ctx.globalAlpha = opacity(name);
    ctx.drawImage(l.img, px, py, (x1 - x0) * S.view.scale, (y1 - y0) * S.view.scale);
    ctx.globalAlpha = 1;
  }
}

function draw() {
  const { w, h, dpr } = size();
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.clearRect(0, 0, w, h);
  ctx.imageSmoothingEnabled = false;
  drawLayers();
  drawGrid(w, h);
  const st = S.state;
  marks = [];
  if (st) {
    const check = st.check;  // the last check-move, whoever asked: every page draws it
    if (check && $("show-check").checked) {
      const colour = COLOUR.check[check.verdict] || COLOUR.checkOther;
      polyline([check.from, check.to], colour, 2, [2, 4]);
      dot(check.to[0], check.to[1], 4, colour);
      const [px, py] = toScreen(check.to[0], check.to[1]);
      mark(`check: ${check.verdict}`, px, py, colour);
    }
    if ($("show-plan").checked && S.plan.length) {
      polyline(S.plan, COLOUR.plan, 2.5, [8, 4]);
      for (const wp of S.plan) dot(wp[0], wp[1], 3, COLOUR.plan);
    }
    if ($("show-track").checked) polyline(st.track, COLOUR.track, 2.5);
    for (const hz of S.hazards) dot(hz.x, hz.y, 5, hz.level === "stop" ? "#d00" : "#f90");
    drawGoal();
    if (st.truth && Math.hypot(st.truth.x - st.pose.x, st.truth.y - st.pose.y) > 0.05) rover(st.truth, st, true);
    rover(st.pose, st, false);
  }
  placeMarks(st, w, h);
  if (S.click) dot(S.click[0], S.click[1], 5, "#7d3cff");
  drawMeasure();
  drawScale(w, h);
  drawNorth(w);
}

// The last navigate's goal as asked, whoever sent it (a cross in the tolerance circle) and, when
// the plan ends elsewhere (the server moved it out of a hazard, or drives toward it to judge it
// from closer), that end.
function drawGoal() {
  const g = S.state.goal;
  if (!g) return;
  const [px, py] = toScreen(g.x, g.y);
  ctx.save();
  ctx.strokeStyle = "#fff";
  ctx.lineWidth = 4;
  cross(px, py, 8);
  ctx.strokeStyle = COLOUR.goal;
  ctx.lineWidth = 2;
  cross(px, py, 8);
  ctx.setLineDash([3, 3]);
  ctx.beginPath();
  ctx.arc(px, py, Math.max(3, g.tolerance * S.view.scale), 0, 2 * Math.PI);
  ctx.stroke();
  ctx.restore();
  mark("goal", px, py, COLOUR.goal);
  const end = S.plan.length ? S.plan[S.plan.length - 1] : null;
  if (end && Math.hypot(end[0] - g.x, end[1] - g.y) > 0.05) {
    const [ex, ey] = toScreen(end[0], end[1]);
    ctx.save();
    ctx.strokeStyle = COLOUR.plan;
    ctx.lineWidth = 2.5;
    ctx.beginPath();
    ctx.arc(ex, ey, 7, 0, 2 * Math.PI);
    ctx.stroke();
    ctx.restore();
    mark("planned end", ex, ey, COLOUR.plan);
  }
}

function cross(px, py, r) {
  ctx.beginPath();
  ctx.moveTo(px - r, py - r); ctx.lineTo(px + r, py + r);
  ctx.moveTo(px - r, py + r); ctx.lineTo(px + r, py - r);
  ctx.stroke();
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
  ctx.save();
  ctx.font = LABEL_FONT;
  ctx.lineWidth = 3;
  ctx.strokeStyle = "#fff";
  ctx.strokeText(text, x, y);
  ctx.fillStyle = colour || "#222";
  ctx.fillText(text, x, y);
  ctx.restore();
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
  if (ghost) mark("simulator truth", px, py, "#555");
}

// The labels of the map's marks (goal, check-move, planned end, simulator truth) are placed
// after everything is drawn, each where it covers neither the rover nor another label: the
// first free place on rings round the point it names, nearest first.
let marks = [];
const LABEL_H = 14;
const LABEL_FONT = "12px system-ui, sans-serif";

function mark(text, px, py, colour) {
  marks.push({ text, px, py, colour });
}

// The screen box of the rover's body and forward arrow.
function roverBox(pose, st) {
  const hd = (pose.heading * Math.PI) / 180, [px, py] = toScreen(pose.x, pose.y);
  const L = st.rover.length * S.view.scale, W = st.rover.width * S.view.scale;
  const c = Math.cos(hd), s = Math.sin(hd);
  const pts = [[-L / 2, -W / 2], [L / 2, -W / 2], [L / 2, W / 2], [-L / 2, W / 2], [L / 2 + 14, 0]]
    .map(([u, v]) => [px + u * c - v * s, py - (u * s + v * c)]);
  const xs = pts.map((p) => p[0]), ys = pts.map((p) => p[1]);
  return { x: Math.min(...xs) - 2, y: Math.min(...ys) - 2, w: Math.max(...xs) - Math.min(...xs) + 4,
           h: Math.max(...ys) - Math.min(...ys) + 4 };
}

function overlaps(a, b) {
  return a.x < b.x + b.w && b.x < a.x + a.w && a.y < b.y + b.h && b.y < a.y + a.h;
}

function placeMarks(st, w, h) {
  const taken = [];
  if (st) {
    taken.push(roverBox(st.pose, st));
    if (st.truth) taken.push(roverBox(st.truth, st));
  }
  ctx.save();
  ctx.font = LABEL_FONT;
  S.labels = [];
  for (const m of marks) {
    const tw = ctx.measureText(m.text).width + 4;
    let best = null;
    for (const r of [10, 24, 44, 70, 100, 140, 190]) {
      for (const [dx, dy] of [[1, -1], [1, 1], [-1, -1], [-1, 1], [0, -1], [0, 1], [1, 0], [-1, 0]]) {
        const cx = m.px + dx * r, cy = m.py + dy * r;  // the label's nearest corner or edge there
        const box = { x: dx > 0 ? cx : dx < 0 ? cx - tw : cx - tw / 2,
                      y: dy > 0 ? cy : dy < 0 ? cy - LABEL_H : cy - LABEL_H / 2, w: tw, h: LABEL_H };
        const inside = box.x >= 0 && box.y >= 0 && box.x + box.w <= w && box.y + box.h <= h;
        if (inside && !taken.some((t) => overlaps(t, box))) { best = box; break; }
        if (!best) best = { ...box, blocked: true };
      }
      if (best && !best.blocked) break;
    }
    taken.push(best);
    S.labels.push({ text: m.text, x: best.x, y: best.y, w: best.w, h: best.h });
    const nx = Math.max(best.x, Math.min(m.px, best.x + best.w)), ny = Math.max(best.y, Math.min(m.py, best.y + best.h));
    if (Math.hypot(nx - m.px, ny - m.py) > 16) {  // pushed away: a thin line says what it names
      ctx.strokeStyle = m.colour;
      ctx.lineWidth = 1;
      ctx.beginPath();
      ctx.moveTo(m.px, m.py);
      ctx.lineTo(nx, ny);
      ctx.stroke();
    }
    label(m.text, best.x + 2, best.y + LABEL_H - 3, m.colour);
  }
  ctx.restore();
}

// Grid lines every nice step, 60 to 150 px apart (the scale bar is one step long): on a phone's
// map too each axis keeps at least two labels. The labels inside the map with a halo, clear of
// the buttons (left) and of the scale bar (bottom left), so none is hidden or cut off.
const STEP_PX = 60;

function drawGrid(w, h) {
  const scale = scaleBox(h), scaleRight = scale.x + scale.w, step = scale.metres;
  const [x0, y1] = toWorld(0, 0), [x1, y0] = toWorld(w, h);
  ctx.save();
  ctx.strokeStyle = "rgba(80, 90, 100, 0.25)";
  ctx.lineWidth = 1;
  const lines = [];
  for (let x = Math.ceil(x0 / step) * step; x <= x1; x += step) {
    const [px] = toScreen(x, 0);
    ctx.beginPath(); ctx.moveTo(px, 0); ctx.lineTo(px, h); ctx.stroke();
    lines.push(["x", `${+x.toFixed(6)} m`, px + 3, h - 5, px > scaleRight + 4 && px < w - 40]);
  }
  for (let y = Math.ceil(y0 / step) * step; y <= y1; y += step) {
    const [, py] = toScreen(0, y);
    ctx.beginPath(); ctx.moveTo(0, py); ctx.lineTo(w, py); ctx.stroke();
    lines.push(["y", `${+y.toFixed(6)} m`, 48, py - 3, py > 150 && py < h - 50]);  // below the buttons
  }
  ctx.font = LABEL_FONT;
  S.ticks = [];
  for (const [axis, text, x, y, clear] of lines) {
    if (!clear) continue;
    label(text, x, y, "#334");
    S.ticks.push({ axis, text, x, y: y - LABEL_H + 3, w: ctx.measureText(text).width, h: LABEL_H });
  }
  ctx.restore();
}

// The scale bar, one grid step long, and its white box at the map's bottom left (screen px).
function scaleBox(h) {
  const metres = niceStep(STEP_PX / S.view.scale), px = metres * S.view.scale;
  return { metres, px, x: 8, y: h - 44, w: px + 60, h: 30 };
}

function drawScale(w, h) {
  const box = scaleBox(h), { metres, px } = box;
  const x = 14, y = h - 26;
  ctx.save();
  ctx.fillStyle = "rgba(255,255,255,0.85)";
  ctx.fillRect(box.x, box.y, box.w, box.h);
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
  label("x →", x - 24, y + 30, "#111");
  ctx.restore();
}

// ------------------------------------------------------------------------------ distance tool

function measureText(a, b) {
  const dx = b[0] - a[0], dy = b[1] - a[1];
  const bearing = ((Math.atan2(dy, dx) * 180) / Math.PI + 360) % 360;
  return `distance ${Math.hypot(dx, dy).toFixed(2)} m · bearing ${bearing.toFixed(1)}° (counter-clockwise from +x, as the heading)`;
}

function drawMeasure() {
  const m = S.measure;
  if (!m || !m.a) return;
  dot(m.a[0], m.a[1], 4, COLOUR.measure);
  if (!m.b) return;
  polyline([m.a, m.b], COLOUR.measure, 2, [6, 3]);
  dot(m.b[0], m.b[1], 4, COLOUR.measure);
}

function setMeasuring(on) {
  S.measure = on ? { a: null, b: null } : null;
  $("measure").setAttribute("aria-pressed", String(on));
  $("mapbox").classList.toggle("measuring", on);
  $("measure-out").hidden = !on;
  $("measure-out").textContent = on ? "click the first point" : "";
  draw();
}

function measureClick(point) {
  const m = S.measure;
  if (!m.a || m.b) { m.a = point; m.b = null; $("measure-out").textContent = "click the second point"; }
  else { m.b = point; $("measure-out").textContent = measureText(m.a, m.b); }
  draw();
}

// ------------------------------------------------------------------------------ input: map

// Pointer events: a mouse drag or a one-finger drag pans; two fingers pinch-zoom about their
// midpoint; a press that does not move is a click.
const pointers = new Map();
let gesture = null;

function startGesture() {
  const pts = [...pointers.values()];
  const r = canvas.getBoundingClientRect();
  const mid = [pts.reduce((s, p) => s + p.x, 0) / pts.length - r.left, pts.reduce((s, p) => s + p.y, 0) / pts.length - r.top];
  gesture = {
    at: toWorld(mid[0], mid[1]), scale: S.view.scale, n: pts.length, start: mid,
    d: pts.length > 1 ? Math.hypot(pts[0].x - pts[1].x, pts[0].y - pts[1].y) : 0,
    moved: gesture ? gesture.moved : false,
  };
}

canvas.addEventListener("pointerdown", (e) => {
  if (e.pointerType === "mouse" && e.button !== 0) return;
  canvas.setPointerCapture(e.pointerId);
  pointers.set(e.pointerId, { x: e.clientX, y: e.clientY });
  if (pointers.size === 1) gesture = null;
  startGesture();
});

canvas.addEventListener("pointermove", (e) => {
  const r = canvas.getBoundingClientRect();
  if (!pointers.has(e.pointerId)) {
    if (e.pointerType === "mouse") hover(e.clientX - r.left, e.clientY - r.top);
    return;
  }
  pointers.set(e.pointerId, { x: e.clientX, y: e.clientY });
  const pts = [...pointers.values()];
  const mid = [pts.reduce((s, p) => s + p.x, 0) / pts.length - r.left, pts.reduce((s, p) => s + p.y, 0) / pts.length - r.top];
  const g = gesture;
  if (Math.hypot(mid[0] - g.start[0], mid[1] - g.start[1]) > 4 || pts.length > 1) g.moved = true;
  if (!g.moved) return;
  if (pts.length > 1 && g.d > 0) {
    const d = Math.hypot(pts[0].x - pts[1].x, pts[0].y - pts[1].y);
    S.view.scale = Math.max(2, Math.min(2000, (g.scale * d) / g.d));
  }
  const { w, h } = size();
  S.view.cx = g.at[0] - (mid[0] - w / 2) / S.view.scale;
  S.view.cy = g.at[1] + (mid[1] - h / 2) / S.view.scale;
  draw();
});

function pointerEnd(e) {
  if (!pointers.has(e.pointerId)) return;
  pointers.delete(e.pointerId);
  const g = gesture;
  if (pointers.size) { startGesture(); return; }
  gesture = null;
  if (e.type === "pointerup" && g && !g.moved && g.n === 1) {
    const r = canvas.getBoundingClientRect();
    mapClick(e.clientX - r.left, e.clientY - r.top);
  }
}
canvas.addEventListener("pointerup", pointerEnd);
canvas.addEventListener("pointercancel", pointerEnd);
canvas.addEventListener("pointerleave", (e) => { if (e.pointerType === "mouse" && !pointers.size) $("cursor").textContent = ""; });

canvas.addEventListener("wheel", (e) => {
  e.preventDefault();
  const r = canvas.getBoundingClientRect();
  zoomAt(e.clientX - r.left, e.clientY - r.top, e.deltaY < 0 ? 1.2 : 1 / 1.2);
}, { passive: false });

function mapClick(px, py) {
  const point = toWorld(px, py);
  if (S.measure) measureClick(point);
  else openMenu(point, px, py);
}

function zoomAt(px, py, factor) {
  const [wx, wy] = toWorld(px, py);
  S.view.scale = Math.max(2, Math.min(2000, S.view.scale * factor));
  const [nx, ny] = toWorld(px, py);
  S.view.cx += wx - nx;
  S.view.cy += wy - ny;
  draw();
}

// The hover readout: the cursor's position at once, the visible layers' values there once the
// cursor rests (one request at a time; the newest position wins).
let hoverAt = null, hoverTimer = null, hoverBusy = false;
function hover(px, py) {
  const [x, y] = toWorld(px, py);
  hoverAt = [x, y];
  $("cursor").textContent = `x ${x.toFixed(2)} m  y ${y.toFixed(2)} m`;
  clearTimeout(hoverTimer);
  hoverTimer = setTimeout(readValues, 120);
}

function readValues() {
  const names = Object.keys(S.layers).filter((n) => S.visible[n]).reverse();
  if (!hoverAt || !names.length || hoverBusy || !S.online) return;
  const [x, y] = hoverAt;
  hoverBusy = true;
  fetch(`/api/at?x=${x.toFixed(4)}&y=${y.toFixed(4)}&layers=${names.join(",")}`).then((r) => r.json()).then((res) => {
    hoverBusy = false;
    if (!hoverAt || hoverAt[0] !== x || hoverAt[1] !== y) { readValues(); return; }
    const parts = names.filter((n) => n in res.values).map((n) => `${n} ${valueText(res.values[n])}`);
    $("cursor").textContent = `x ${x.toFixed(2)} m  y ${y.toFixed(2)} m` + (parts.length ? "\n" + parts.join(" · ") : "");
  }).catch(() => { hoverBusy = false; });
}

function valueText(v) {
  if (v.class !== undefined) return v.class;
  if (v.value === null) return "unseen";
  const unit = v.unit && v.unit !== "class" ? ` ${v.unit}` : "";
  return `${fmt(v.value)}${unit}`;
}

// ------------------------------------------------------------------------------ input: menu

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
  menu.querySelector(".where").textContent = `x ${point[0].toFixed(2)} m, y ${point[1].toFixed(2)} m`;
  menu.querySelector(".cmdline").textContent = navLine();
  updateButtons();
  // beside the point, but inside the map whatever its size (measured as it is now filled in);
  // on the far side of the point where there is no room on the near one
  const mw = menu.offsetWidth, mh = menu.offsetHeight, W = canvas.clientWidth, H = canvas.clientHeight;
  const left = px + 12 + mw <= W ? px + 12 : px - 12 - mw;
  const top = py + 12 + mh <= H ? py + 12 : py - 12 - mh;
  menu.style.left = `${Math.max(0, Math.min(left, W - mw))}px`;
  menu.style.top = `${Math.max(0, Math.min(top, H - mh))}px`;
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
$("go-nav").onclick = () => {
  // the plan on the map stays until the server takes the new goal: a refused navigate keeps it
  send(navLine());
  closeMenu();
};
$("go-check").onclick = () => {
  send(checkLine());  // its answer comes back in the state, as every other page's check-moves
  closeMenu();
};
$("go-cancel").onclick = closeMenu;
$("fit").onclick = fit;
$("zoomin").onclick = () => zoomAt(canvas.clientWidth / 2, canvas.clientHeight / 2, 1.5);
$("zoomout").onclick = () => zoomAt(canvas.clientWidth / 2, canvas.clientHeight / 2, 1 / 1.5);
$("measure").onclick = () => setMeasuring(!S.measure);
["show-track", "show-plan", "show-check", "show-fov"].forEach((id) => $(id).addEventListener("change", draw));

// ------------------------------------------------------------------------------ input: commands

// What cannot be undone asks first: reset re-initialises every device, quit stops the server.
const CONFIRM = {
  reset: "Reset re-initialises all the hardware (the PTU homes). Reset now?",
  quit: "Quit stops the server for every client. Quit now?",
};

function confirmed(line) {
  const [word] = commandWord(line);
  return !(word in CONFIRM) || window.confirm(CONFIRM[word]);
}

function sendChecked(line) {
  if (confirmed(line)) send(line);
}

$("btn-dem").onclick = () => send("dem-full-tof");
$("btn-break").onclick = () => send("break");
$("btn-continue").onclick = () => send("continue");
$("btn-reset").onclick = () => sendChecked("reset");
$("cmdform").onsubmit = (e) => {
  e.preventDefault();
  const line = $("cmd").value.trim();
  if (!line) return;
  const [word, args] = commandWord(line);
  if (word !== "auth" && S.commands[S.commands.length - 1] !== line) S.commands.push(line);
  while (S.commands.length > HISTORY_MAX) S.commands.shift();
  try { localStorage.setItem(HISTORY_KEY, JSON.stringify(S.commands)); } catch (err) { /* private mode */ }
  S.commandAt = -1;
  $("cmd").value = "";
  if (word === "auth") authenticate(args, line);
  else sendChecked(line);
};
$("cmd").addEventListener("keydown", (e) => {
  if (e.key !== "ArrowUp" && e.key !== "ArrowDown") return;
  e.preventDefault();
  const n = S.commands.length;
  if (!n) return;
  if (e.key === "ArrowUp") S.commandAt = S.commandAt < 0 ? n - 1 : Math.max(0, S.commandAt - 1);
  else S.commandAt = S.commandAt < 0 || S.commandAt >= n - 1 ? -1 : S.commandAt + 1;
  $("cmd").value = S.commandAt < 0 ? "" : S.commands[S.commandAt];
});
$("authform").onsubmit = (e) => {
  e.preventDefault();
  authenticate(`-token ${quoted($("token").value)}`);
};
window.addEventListener("resize", draw);
window.addEventListener("keydown", (e) => {
  if (e.key === "Escape") { closeMenu(); if (S.measure) setMeasuring(false); }
});

updateButtons();
connect();
