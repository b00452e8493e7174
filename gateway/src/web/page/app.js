// rove browser console: pairs once, then speaks the local API (docs/api.md) over a WebSocket,
// with input frames at 50 Hz in between. The gateway decides everything that matters for
// safety (rove_core::remote): this page only reports honestly what the hands do.

const FRAME_MS = 20; // 50 Hz, the operator's stream rate
const AXIS = 32767;
const DEADZONE = 0.08; // gamepads rest slightly off centre
const CONFIRM_MS = 3000;
const TOKEN_KEY = "rove.token";

const $ = (id) => document.getElementById(id);
const state = {
  me: null, devices: new Map(), owner: new Map(), status: new Map(), standing: new Map(),
  streams: {}, selected: null, prompt: null, offlineAfter: 3000, tOffset: 0,
};
// For tests and the curious: the socket's state and when a finger last moved a stick.
// `drop()` closes the socket as a radio loss would (tests, diagnostics).
window.rove = { connected: false, frames: 0, touchWallMs: 0, sentWallMs: 0, state, drop: () => ws && ws.close() };

let ws = null;
let backoff = 250;

// ---- pairing ---------------------------------------------------------------------------------

function showPair(error) {
  $("app").hidden = true;
  $("pair").hidden = false;
  $("pair-error").textContent = error || "";
}

$("pair-form").addEventListener("submit", async (e) => {
  e.preventDefault();
  $("pair-error").textContent = "";
  try {
    const r = await fetch("/pair", {
      method: "POST", headers: { "content-type": "application/json" },
      body: JSON.stringify({ code: $("code").value.trim() }),
    });
    const body = await r.json();
    if (!r.ok) { showPair(body.error || `pairing refused (${r.status})`); return; }
    localStorage.setItem(TOKEN_KEY, body.token);
    $("code").value = "";
    connect();
  } catch (err) {
    showPair(`cannot reach the operator: ${err}`);
  }
});

// ---- the socket ------------------------------------------------------------------------------

function connect() {
  const token = localStorage.getItem(TOKEN_KEY);
  if (!token) { showPair(); return; }
  $("pair").hidden = true;
  $("app").hidden = false;
  banner("standby", "connecting…");
  ws = new WebSocket(`wss://${location.host}/ws`);
  ws.onopen = () => { ws.send(JSON.stringify({ auth: token })); };
  ws.onmessage = (m) => {
    let msg;
    try { msg = JSON.parse(m.data); } catch { return; }
    if (msg.code === "bad_token") {
      localStorage.removeItem(TOKEN_KEY);
      ws.onclose = null; ws.close();
      window.rove.connected = false;
      showPair(msg.error);
      return;
    }
    if (msg.code === "replaced") { ws.onclose = null; window.rove.connected = false; banner("standby", "another tab drives as this device"); return; }
    if (msg.event) { window.rove.connected = true; backoff = 250; onEvent(msg); }
    else if (msg.error) notice(msg.error);
  };
  ws.onclose = () => {
    window.rove.connected = false;
    banner("standby", "connection lost: reconnecting…");
    setTimeout(connect, backoff);
    backoff = Math.min(backoff * 2, 2000);
  };
}

function send(obj) {
  if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(obj));
}

function command(cmd, fields) { send({ cmd, ...fields }); }

// ---- events → state → view -------------------------------------------------------------------

function onEvent(e) {
  if (e.event === "input") {
    // At the stream rate while the sticks move: only the input line, no re-render.
    $("link").textContent = e.live ? "" : e.link;
    return;
  }
  switch (e.event) {
    case "hello":
      // A (re)connection: the snapshot that follows is the whole state.
      for (const m of [state.devices, state.owner, state.status, state.standing]) m.clear();
      state.offlineAfter = e.offline_after_ms; state.tOffset = performance.now() - e.t_ms; break;
    case "identity": state.me = e; $("me").textContent = `${e.name} (${e.id}) · ${e.level} ${e.class} · strength ${e.strength}`; break;
    case "device": state.devices.set(e.id, { ...e, seen: e.t_ms, gone: false }); if (e.kind === "vehicle") state.owner.set(e.id, e.owner); break;
    case "device_gone": { const d = state.devices.get(e.id); if (d) d.gone = true; break; }
    case "owner": state.owner.set(e.vehicle, e.to); break;
    case "vehicle_status": state.status.set(e.vehicle, e); break;
    case "standing": state.standing.set(e.vehicle, e); break;
    case "driving": state.streams = e; break;
    case "selected": state.selected = e.vehicle; break;
    case "request_incoming": state.prompt = { ...e, until: performance.now() + e.timeout_ms }; break;
    case "prompt_closed": if (state.prompt && state.prompt.vehicle === e.vehicle) state.prompt = null; notice(`request for ${label(e.vehicle)}: ${e.outcome}`); break;
    case "request_sent": notice(`asked ${label(e.owner)} for ${label(e.vehicle)}`); break;
    case "request_ended": notice(`request for ${label(e.vehicle)}: ${e.outcome}`); break;
    case "notice": notice(e.text); break;
    case "lagged": notice(`missed ${e.missed} updates`); break;
  }
  autoSelect();
  render();
}

// Nothing selected yet: the vehicle this device streams to (its `drive` list), else the only
// vehicle there is. Selecting moves nothing.
let selecting = false;
function autoSelect() {
  if (state.selected != null || selecting) return;
  const s = state.streams;
  const ours = [...(s.driving || []), ...(s.holding || []), ...(s.standby || []), ...(s.paused || [])];
  const vehicles = [...state.devices.values()].filter((d) => d.kind === "vehicle").map((d) => d.id);
  const pick = ours.find((v) => vehicles.includes(v)) ?? (vehicles.length === 1 ? vehicles[0] : null);
  if (pick != null) { selecting = true; command("select", { vehicle: pick }); setTimeout(() => { selecting = false; }, 1000); }
}

function label(id) {
  const d = state.devices.get(id);
  return d ? `${d.name} (${id})` : `${id}`;
}

function nowMs() { return performance.now() - state.tOffset; }

function online(d) { return !d.gone && nowMs() - d.seen < state.offlineAfter; }

function notice(text) { $("notice").textContent = text; }

function batteryText(id) {
  const h = (state.status.get(id) || {}).health;
  if (!h || !h.battery) return "";
  return h.battery_low ? `LOW ${h.battery}` : h.battery;
}

function banner(kind, text) {
  const b = $("banner");
  b.className = `banner ${kind}`;
  b.textContent = text;
}

function render() {
  const me = state.me ? state.me.id : null;
  const list = $("devices");
  list.replaceChildren();
  const ids = [...state.devices.keys()].sort((a, b) => a - b);
  for (const id of ids) {
    const d = state.devices.get(id);
    const li = document.createElement("li");
    li.dataset.id = id;
    li.className = `${d.kind}${online(d) ? "" : " offline"}${state.selected === id ? " selected" : ""}`;
    const name = document.createElement("span");
    name.textContent = `${d.name} (${id})`;
    const st = document.createElement("span");
    st.className = "state";
    let text = online(d) ? "online" : "offline";
    if (d.kind === "vehicle") {
      // Where it stands, in the operator's words (the `standing` event; docs/api.md).
      const where = online(d) ? state.standing.get(id) : null;
      if (where) { text = where.text; li.classList.toggle("offline", where.state === "offline"); }
      const battery = batteryText(id);
      if (battery) text += ` · ${battery}`;
      onTap(li, () => command("select", { vehicle: id }));
    } else if (id === me) {
      text += " · this device";
    }
    st.textContent = text;
    li.append(name, st);
    list.append(li);
  }
  const v = state.selected;
  const where = v == null ? null : state.standing.get(v);
  if (v == null) banner("standby", "select a vehicle");
  else if (!where) banner("standby", `${label(v)}: …`);
  else banner(where.state === "driving" ? "drive" : where.safe ? "failsafe" : "standby", `${label(v)}: ${where.text}`);
  // Every low battery the operator can see, as the terminal's header says it.
  const shown = (s) => state.devices.has(s.vehicle) && online(state.devices.get(s.vehicle))
    && (state.standing.get(s.vehicle) || {}).state !== "offline";
  const low = [...state.status.values()].filter((s) => s.health && s.health.battery_low && shown(s))
    .map((s) => `LOW BATTERY ${label(s.vehicle)}: ${s.health.battery}`);
  $("warn").hidden = low.length === 0;
  $("warn").textContent = low.join(" · ");
  const h = v == null ? null : (state.status.get(v) || {}).health;
  $("health").textContent = h ? [h.battery && `battery ${h.battery}`, h.autopilot && `autopilot ${h.autopilot}`].filter(Boolean).join(" · ") : "";
  if (!window.rove.connected) banner("standby", "connecting…");
  const p = state.prompt;
  $("prompt").hidden = !p;
  if (p) $("prompt-text").textContent = `${label(p.from)} asks for ${label(p.vehicle)}`;
  const mode = state.status.get(v);
  for (const b of document.querySelectorAll("#modes button")) b.classList.toggle("on", !!mode && mode.mode === b.dataset.mode);
  for (const b of document.querySelectorAll("#actions button")) b.disabled = v == null;
}

setInterval(() => {
  const p = state.prompt;
  if (p) {
    const left = Math.max(0, Math.ceil((p.until - performance.now()) / 1000));
    $("countdown").textContent = `(${left} s)`;
  }
}, 250);
setInterval(render, 1000); // online → offline as time passes

// ---- buttons: what moves a vehicle is confirmed with a second tap naming it -------------------

// A tap: pointer down and up on the element. Not `click`: browsers make no click of a tap while
// another finger is down, and a thumb holds a stick (the deadman) while the other taps Accept.
// Keyboard activation (a click with no pointer) counts too.
function onTap(el, action) {
  let down = null;
  el.addEventListener("pointerdown", (e) => { down = e.pointerId; });
  el.addEventListener("pointerup", (e) => {
    if (e.pointerId !== down) return;
    down = null;
    const r = el.getBoundingClientRect();
    if (e.clientX >= r.left && e.clientX <= r.right && e.clientY >= r.top && e.clientY <= r.bottom) action(e);
  });
  el.addEventListener("pointercancel", () => { down = null; });
  el.addEventListener("click", (e) => { if (e.detail === 0) action(e); });
}

function armed(button, text, action) {
  onTap(button, () => {
    if (button.classList.contains("armed")) {
      button.classList.remove("armed");
      button.textContent = button.dataset.label;
      action();
      return;
    }
    button.dataset.label = button.dataset.label || button.textContent;
    button.classList.add("armed");
    button.textContent = text();
    setTimeout(() => { button.classList.remove("armed"); button.textContent = button.dataset.label; }, CONFIRM_MS);
  });
}

armed($("drive"), () => `Drive ${label(state.selected)}?`, () => command("drive", { vehicle: state.selected }));
armed($("request"), () => `Ask for ${label(state.selected)}?`, () => command("request", { vehicle: state.selected }));
onTap($("finish"), () => command("finish", { vehicle: state.selected }));
onTap($("release"), () => command("release", { vehicle: state.selected }));
for (const b of document.querySelectorAll("#modes button")) {
  armed(b, () => `${b.dataset.mode}?`, () => command("mode", { mode: b.dataset.mode }));
}
onTap($("accept"), () => { if (state.prompt) command("accept", { vehicle: state.prompt.vehicle }); });
onTap($("refuse"), () => { if (state.prompt) command("refuse", { vehicle: state.prompt.vehicle }); });

// ---- sticks: each follows one finger from where it touched (so a touch starts centred) --------

const sticks = {};
for (const el of document.querySelectorAll(".stick")) {
  const s = { el, knob: el.querySelector(".knob"), pointer: null, x0: 0, y0: 0, x: 0, y: 0 };
  sticks[el.id] = s;
  el.addEventListener("pointerdown", (e) => {
    if (s.pointer !== null) return;
    s.pointer = e.pointerId;
    el.setPointerCapture(e.pointerId);
    s.x0 = e.clientX; s.y0 = e.clientY; s.x = 0; s.y = 0;
    el.classList.add("held");
    window.rove.touchWallMs = performance.timeOrigin + e.timeStamp;
    draw(s);
    e.preventDefault();
  });
  // `pointerrawupdate` where the browser has it (Chrome, in a secure context): delivered as the
  // input arrives, where `pointermove` waits for the next animation frame (up to 16 ms).
  const move = "onpointerrawupdate" in window ? "pointerrawupdate" : "pointermove";
  el.addEventListener(move, (e) => {
    if (e.pointerId !== s.pointer) return;
    const r = el.getBoundingClientRect();
    const reach = Math.max(40, Math.min(r.width, r.height) / 2 - 32);
    s.x = clamp((e.clientX - s.x0) / reach);
    s.y = clamp((s.y0 - e.clientY) / reach);
    window.rove.touchWallMs = performance.timeOrigin + e.timeStamp;
    draw(s);
    sendFrame(); // a change leaves at once, not on the next 20 ms tick
    window.rove.sentWallMs = performance.timeOrigin + performance.now();
  });
  const up = (e) => {
    if (e.pointerId !== s.pointer) return;
    s.pointer = null; s.x = 0; s.y = 0;
    el.classList.remove("held");
    draw(s);
    sendFrame();
  };
  el.addEventListener("pointerup", up);
  el.addEventListener("pointercancel", up);
}

function clamp(v) { return Math.max(-1, Math.min(1, v)); }

function draw(s) {
  const r = s.el.getBoundingClientRect();
  const reach = Math.max(40, Math.min(r.width, r.height) / 2 - 32);
  s.knob.style.transform = `translate(${s.x * reach}px, ${-s.y * reach}px)`;
}

function gamepad() {
  const pads = navigator.getGamepads ? navigator.getGamepads() : [];
  for (const p of pads) {
    if (!p || p.axes.length < 4) continue;
    const dz = (v) => (Math.abs(v) < DEADZONE ? 0 : v);
    const held = [4, 5, 6, 7].some((i) => p.buttons[i] && p.buttons[i].pressed);
    return { lx: dz(p.axes[0]), ly: -dz(p.axes[1]), rx: dz(p.axes[2]), ry: -dz(p.axes[3]), held, id: p.id };
  }
  return null;
}

function frame() {
  const l = sticks.left, r = sticks.right;
  const touch = l.pointer !== null || r.pointer !== null;
  const pad = touch ? null : gamepad();
  $("pad").textContent = pad ? `gamepad: ${pad.id} (hold a shoulder button to drive)` : "";
  const v = pad ? [pad.ly, pad.rx, pad.ry, pad.lx] : [l.y, r.x, r.y, l.x];
  // throttle, roll, pitch, yaw
  return { in: v.map((a) => Math.round(a * AXIS)), dm: touch || (pad !== null && pad.held) };
}

function sendFrame() {
  if (document.visibilityState !== "visible") return;
  send(frame());
  window.rove.frames++;

}

setInterval(sendFrame, FRAME_MS);

// ---- a page that cannot be seen does not drive -----------------------------------------------

function letGo() {
  for (const s of Object.values(sticks)) { s.pointer = null; s.x = 0; s.y = 0; s.el.classList.remove("held"); draw(s); }
}

document.addEventListener("visibilitychange", () => {
  if (document.visibilityState !== "visible") {
    send({ lost: "page hidden" });
    letGo();
  }
});
window.addEventListener("pagehide", () => { send({ lost: "page closed" }); });

connect();
