// cipval experiment page: draws the lines the server computes and sends the mouse.
// Model displacement [-3, 3] <-> canvas pixel [1, 1200] (paper section 4.1).
"use strict";
const W = 1200, H = 600, RANGE = 3.0;
const COLORS = ["#c0392b", "#2471a3"], COLOR_NAMES = ["red", "blue"];
const LABEL = /^[A-Za-z0-9_.-]{1,32}$/;
const BOT_RANGES = { beta: [0, 2000], tau: [0.001, 1], nu: [0, 5] };
const params = new URLSearchParams(location.search);
const token = params.get("token") || "";
const code = params.get("code");
const $ = (id) => document.getElementById(id);
const canvas = $("screen"), ctx = canvas.getContext("2d");
let ws = null, seat = null, running = false, ended = false, lastX = null, lastT = null;
let sentX = null, frameMsg = null, seatInfo = [], drawnK = [], drawnT = [];
window.cipvalColors = COLORS;

function toPx(x) { return 1 + (x + RANGE) * (W - 1) / (2 * RANGE); }
function status(t) { $("status").textContent = t; }
function error(t) { $("error").textContent = t ? "Not accepted: " + t : ""; }
function send(o) { if (ws && ws.readyState === 1) ws.send(JSON.stringify(o)); }
function seatName(i) { return "seat " + (i + 1) + " (" + COLOR_NAMES[i] + ")"; }

function draw() {
  ctx.clearRect(0, 0, W, H);
  ctx.strokeStyle = "#ddd"; ctx.lineWidth = 1;
  ctx.beginPath(); ctx.moveTo(W / 2, 0); ctx.lineTo(W / 2, H); ctx.stroke();
  if (!frameMsg) return;
  const tips = frameMsg.tips, bases = frameMsg.bases;
  if (tips.length === 2) {  // the rigid rod between the upper ends
    ctx.strokeStyle = "#555"; ctx.lineWidth = 3; ctx.beginPath();
    ctx.moveTo(toPx(tips[0]), H / 2); ctx.lineTo(toPx(tips[1]), H / 2); ctx.stroke();
  }
  ctx.font = "15px sans-serif";
  for (let i = 0; i < tips.length; i++) {
    ctx.strokeStyle = COLORS[i];
    ctx.lineWidth = 10; ctx.beginPath();             // thick line: upper end
    ctx.moveTo(toPx(tips[i]), 0); ctx.lineTo(toPx(tips[i]), H); ctx.stroke();
    ctx.lineWidth = 2; ctx.beginPath();              // thin line: lower end (the mouse)
    ctx.moveTo(toPx(bases[i]), 0); ctx.lineTo(toPx(bases[i]), H); ctx.stroke();
  }
  for (let i = 0; i < tips.length; i++) {  // name tags on a white ground, beside the thin line
    const who = (seatInfo[i] ? seatInfo[i].label : "seat " + (i + 1)) + (i === seat ? " (you)" : "");
    const w = ctx.measureText(who).width, y = H - 14 - 22 * i;
    const x = i === 0 ? toPx(bases[i]) - w - 10 : toPx(bases[i]) + 10;
    ctx.fillStyle = "rgba(255,255,255,0.9)"; ctx.fillRect(x - 3, y - 15, w + 6, 20);
    ctx.fillStyle = COLORS[i]; ctx.fillText(who, x, y);
  }
  ctx.fillStyle = "#333"; ctx.font = "16px sans-serif";
  ctx.fillText(running ? "t = " + frameMsg.t.toFixed(2) + " s" : "not started", 10, 20);
  if (running && frameMsg.k !== undefined) {  // when each frame reached the screen
    drawnK.push(frameMsg.k); drawnT.push(performance.now());
  }
}

function clientInfo() {
  const zoom = window.outerWidth > 0 && window.innerWidth > 0 ?
    window.outerWidth / window.innerWidth : 1;
  return { type: "client", user_agent: navigator.userAgent.slice(0, 512),
           screen: [screen.width, screen.height], canvas: [canvas.clientWidth, canvas.clientHeight],
           window: [window.innerWidth, window.innerHeight],
           device_pixel_ratio: window.devicePixelRatio || 1,
           zoom: Math.min(Math.max(zoom, 0.01), 100), colors: COLORS.slice(0, seatInfo.length || 1) };
}

function showSeats(m) {
  seatInfo = m.seats;
  if (m.phase === "waiting" && m.preview && !running) {  // where the lines will start
    frameMsg = { tips: m.preview.tips, bases: m.preview.bases, t: 0 }; draw();
  }
  const parts = m.seats.map((s, i) =>
    '<span class="' + (i === seat ? "me" : "") + '"><span class="swatch" style="background:' +
    COLORS[i] + '"></span>' + COLOR_NAMES[i] + ": " + s.label + (s.kind === "bot" ? " (bot)" : "") +
    (i === seat ? " = you" : "") + "</span>");
  $("seats").innerHTML = parts.join(", ");
  $("yours").textContent = seat === null ? "You are watching." :
    "You are " + seatName(seat) + ": move the " + COLOR_NAMES[seat] + " thin line.";
  if (m.phase === "waiting") {
    const others = m.seats.map((s, i) => [s, i]).filter(([s, i]) => i !== seat);
    const waiting = others.filter(([s]) => !s.taken || !s.ready).map(([s, i]) =>
      s.label + " (" + COLOR_NAMES[i] + ") to " + (s.taken ? "press Ready" : "join"));
    $("waiting").textContent = waiting.length ? "Waiting for " + waiting.join(", ") + "." : "";
  } else {
    $("waiting").textContent = "";
  }
}

function finished() {
  running = false; ended = true; canvas.classList.remove("running");
  for (const id of ["ready", "abort", "create-box", "join-box"]) $(id).disabled = true;
}

function connect() {
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  ws = new WebSocket(proto + "//" + location.host + "/ws");
  ws.onopen = () => status(code ? "Enter your label and join." : "Choose the session and create it.");
  ws.onclose = () => {
    finished();
    status($("status").textContent + " (connection closed; reload the page)");
  };
  ws.onmessage = (ev) => {
    const m = JSON.parse(ev.data);
    if (m.type === "created" || m.type === "joined") {
      seat = m.seat; error("");
      $("ready").disabled = false; $("abort").disabled = false;
      $("create-box").disabled = true; $("join-box").disabled = true;  // settings are fixed now
      if (m.secret) {  // a reload of this tab takes the seat back (before the countdown)
        sessionStorage.setItem("cipval-seat-" + m.code, m.secret);
        if (!code) history.replaceState(null, "", "?token=" + encodeURIComponent(token) + "&code=" + m.code);
      }
      if (m.type === "created" && m.seats.some((s) => s.kind === "human" && !s.taken)) {
        $("link").textContent = location.origin + "/?code=" + m.code;
        $("share").classList.remove("hidden");
      }
      showSeats(m);
      status(seat === null ? "Watching the bots. Press Ready to start." :
             "You are " + seatName(seat) + ". Press Ready when set.");
      send(clientInfo());
    } else if (m.type === "session") {
      showSeats(m);
    } else if (m.type === "countdown") {
      frameMsg = { tips: m.tips, bases: m.bases, t: 0 }; draw();
      status("Starting in " + m.n + " ...  Put the pointer on your thin line" +
             (seat === null ? "." : " (" + COLOR_NAMES[seat] + ")."));
    } else if (m.type === "start") {
      running = true; canvas.classList.add("running");
      status("Running: keep the thick line" + (seat === null ? "s" : " (" + COLOR_NAMES[seat] + ")") +
             " balanced above the thin line.");
    } else if (m.type === "frame") {
      frameMsg = m; window.cipvalFramesSeen = (window.cipvalFramesSeen || 0) + 1;
      requestAnimationFrame(draw);
    } else if (m.type === "end") {
      finished();
      status("Trial ended: " + m.reason + (m.detail ? " (" + m.detail + ")" : "") +
             " at t = " + (m.time === null ? "?" : m.time.toFixed(2)) + " s, " + m.samples +
             " samples saved to " + m.file + ". Reload the page for another trial.");
      document.title = "ended: " + m.reason;
      if (token) history.replaceState(null, "", "?token=" + encodeURIComponent(token));  // reload: a new session
    } else if (m.type === "error") {
      error(m.error);
    }
  };
}

function number(id, lo, hi, whole) {
  const text = $(id).value.trim(), v = Number(text);
  if (text === "" || !Number.isFinite(v) || v < lo || v > hi || (whole && !Number.isInteger(v))) {
    throw new Error(id + " must be " + (whole ? "a whole number" : "a number") + " in [" + lo +
                    ", " + hi + "], got '" + text + "'");
  }
  return v;
}

function label(id) {
  const v = $(id).value;
  if (!LABEL.test(v)) throw new Error("the label must be 1-32 characters from A-Z a-z 0-9 _ . - (got '" + v + "')");
  return v;
}

function seatSpec(kind, labelId) {
  if (kind === "human") return { kind: "human", label: label(labelId) };
  return { kind: "bot", label: label(labelId), beta: number("beta", ...BOT_RANGES.beta),
           tau: number("tau", ...BOT_RANGES.tau), nu: number("nu", ...BOT_RANGES.nu),
           seed: number("seed", 0, 4294967295, true) };
}

function checked(build) {
  try { error(""); send(build()); } catch (e) { error(e.message); }
}

function updateControls() {  // the bot's settings only mean something when a seat is a bot
  const coupled = $("mode").value === "coupled";
  $("partner-box").classList.toggle("hidden", !coupled);
  const bot = $("me").value === "bot" || (coupled && $("partner").value === "bot");
  for (const id of ["beta", "tau", "nu", "seed"]) $(id).disabled = !bot;
}
for (const id of ["mode", "me", "partner"]) $(id).onchange = updateControls;
$("create").onclick = () => checked(() => {
  const mode = $("mode").value;
  const seats = [seatSpec($("me").value, "label")];
  if (mode === "coupled") seats.push(seatSpec($("partner").value, "plabel"));
  if (seats.length === 2 && seats[0].label === seats[1].label) throw new Error("the two labels must differ");
  return { type: "create", token: token, mode: mode, trial: number("trial", 1, 100000, true),
           seats: seats };
});
$("join").onclick = () => checked(() => {
  const msg = { type: "join", code: code, label: label("jlabel") };
  const secret = sessionStorage.getItem("cipval-seat-" + code);
  if (secret) msg.secret = secret;  // taking one's own seat back after a reload
  return msg;
});
$("ready").onclick = () => { send({ type: "ready" }); $("ready").disabled = true;
  if (seat !== null) status("You are " + seatName(seat) + ", ready."); };
$("abort").onclick = () => { if (!ended) send({ type: "abort" }); };
document.addEventListener("keydown", (e) => { if (e.key === "Escape" && !ended && seatInfo.length) send({ type: "abort" }); });

// the mouse: canvas pixel 1..1200 (fractional), sent at most every 10 ms with its event time
canvas.addEventListener("pointerdown", (e) => canvas.setPointerCapture(e.pointerId));
canvas.addEventListener("pointermove", (e) => {
  const r = canvas.getBoundingClientRect();  // the drawing area, inside the border
  lastX = 1 + (e.clientX - r.left - canvas.clientLeft) * (W - 1) / canvas.clientWidth;
  lastT = e.timeStamp;
});
setInterval(() => {
  if (seat !== null && lastX !== null && lastX !== sentX) {
    send({ type: "mouse", x: lastX, t: lastT }); sentX = lastX;
  }
}, 10);
setInterval(() => {  // frame draw times, twice a second
  if (drawnK.length) { send({ type: "drawn", k: drawnK.splice(0, 60), t: drawnT.splice(0, 60) }); }
}, 500);

updateControls();
if (code) { $("create-box").classList.add("hidden"); $("join-box").classList.remove("hidden"); }
draw();
connect();
