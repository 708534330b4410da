// cipval experiment page: draws the lines the server computes and sends the mouse.
// Model displacement [-3, 3] <-> canvas pixel [1, 1200] (paper section 4.1).
"use strict";
const W = 1200, H = 600, RANGE = 3.0;
const params = new URLSearchParams(location.search);
const token = params.get("token") || "";
const code = params.get("code");
const $ = (id) => document.getElementById(id);
const canvas = $("screen"), ctx = canvas.getContext("2d");
let ws = null, seat = null, running = false, lastX = null, sentX = null;
let offsets = [0], frameMsg = null;

function toPx(x) { return 1 + (x + RANGE) * (W - 1) / (2 * RANGE); }
function status(t) { $("status").textContent = t; }
function send(o) { if (ws && ws.readyState === 1) ws.send(JSON.stringify(o)); }

function draw() {
  ctx.clearRect(0, 0, W, H);
  ctx.strokeStyle = "#ddd"; ctx.lineWidth = 1;
  ctx.beginPath(); ctx.moveTo(W / 2, 0); ctx.lineTo(W / 2, H); ctx.stroke();
  if (!frameMsg) return;
  const colors = ["#c0392b", "#2471a3"];
  const tips = frameMsg.tips, bases = frameMsg.bases;
  if (tips.length === 2) {  // the rigid rod between the upper ends
    ctx.strokeStyle = "#555"; ctx.lineWidth = 3; ctx.beginPath();
    ctx.moveTo(toPx(tips[0]), H / 2); ctx.lineTo(toPx(tips[1]), H / 2); ctx.stroke();
  }
  for (let i = 0; i < tips.length; i++) {
    ctx.strokeStyle = colors[i];
    ctx.lineWidth = 10; ctx.beginPath();             // thick line: upper end
    ctx.moveTo(toPx(tips[i]), 0); ctx.lineTo(toPx(tips[i]), H); ctx.stroke();
    ctx.lineWidth = 2; ctx.beginPath();              // thin line: lower end (the mouse)
    ctx.moveTo(toPx(bases[i]), 0); ctx.lineTo(toPx(bases[i]), H); ctx.stroke();
  }
  ctx.fillStyle = "#333"; ctx.font = "16px sans-serif";
  ctx.fillText("t = " + frameMsg.t.toFixed(2) + " s", 10, 20);
}

function connect() {
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  ws = new WebSocket(proto + "//" + location.host + "/ws");
  ws.onopen = () => status(code ? "Enter your label and join." : "Choose the session and create it.");
  ws.onclose = () => { running = false; status($("status").textContent + " (connection closed)"); };
  ws.onmessage = (ev) => {
    const m = JSON.parse(ev.data);
    if (m.type === "created" || m.type === "joined") {
      seat = m.seat; $("ready").disabled = false; $("abort").disabled = false;
      $("create").disabled = true; $("join").disabled = true;
      if (m.type === "created" && m.seats.some((s) => s.kind === "human" && !s.taken)) {
        $("link").textContent = location.origin + "/?code=" + m.code;
        $("share").classList.remove("hidden");
      }
      status(seat === null ? "Watching the bots. Press Ready to start." :
             "Seat " + (seat + 1) + ". Press Ready when set.");
    } else if (m.type === "session") {
      if (m.phase === "waiting") {
        const waiting = m.seats.filter((s) => !s.taken || !s.ready).map((s) => s.label);
        if (waiting.length) status("Waiting for: " + waiting.join(", "));
      }
    } else if (m.type === "countdown") {
      status("Starting in " + m.n + " ...  (put the pointer on the canvas)");
    } else if (m.type === "start") {
      running = true; offsets = m.offsets; status("Running: keep the sticks upright.");
    } else if (m.type === "frame") {
      frameMsg = m; window.cipvalFramesSeen = (window.cipvalFramesSeen || 0) + 1;
      requestAnimationFrame(draw);
    } else if (m.type === "end") {
      running = false;
      status("Trial ended: " + m.reason + (m.detail ? " (" + m.detail + ")" : "") +
             " at t = " + (m.time === null ? "?" : m.time.toFixed(2)) + " s, " + m.samples +
             " samples saved to " + m.file);
      document.title = "ended: " + m.reason;
    } else if (m.type === "error") {
      status("Error: " + m.error);
    }
  };
}

function seatSpec(kind, label) {
  if (kind === "human") return { kind: "human", label: label };
  return { kind: "bot", label: label, beta: parseFloat($("beta").value),
           tau: parseFloat($("tau").value), nu: parseFloat($("nu").value),
           seed: parseInt($("seed").value, 10) };
}

$("mode").onchange = () => $("partner-box").classList.toggle("hidden", $("mode").value !== "coupled");
$("create").onclick = () => {
  const mode = $("mode").value;
  const seats = [seatSpec($("me").value, $("label").value)];
  if (mode === "coupled") seats.push(seatSpec($("partner").value, $("plabel").value));
  send({ type: "create", token: token, mode: mode, trial: parseInt($("trial").value, 10),
         seats: seats });
};
$("join").onclick = () => send({ type: "join", code: code, label: $("jlabel").value });
$("ready").onclick = () => { send({ type: "ready" }); $("ready").disabled = true; };
$("abort").onclick = () => send({ type: "abort" });
document.addEventListener("keydown", (e) => { if (e.key === "Escape") send({ type: "abort" }); });

// the mouse: canvas pixel 1..1200 (fractional), sent at most every 10 ms
canvas.addEventListener("pointerdown", (e) => canvas.setPointerCapture(e.pointerId));
canvas.addEventListener("pointermove", (e) => {
  const r = canvas.getBoundingClientRect();
  lastX = 1 + (e.clientX - r.left) * (W - 1) / r.width;
});
setInterval(() => {
  if (seat !== null && lastX !== null && lastX !== sentX) { send({ type: "mouse", x: lastX }); sentX = lastX; }
}, 10);

if (code) { $("create-box").classList.add("hidden"); $("join-box").classList.remove("hidden"); }
draw();
connect();
