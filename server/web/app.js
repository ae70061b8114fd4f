// Tacit dashboard: live from the server's event stream (SSE); no external assets.
"use strict";

const state = { token: localStorage.getItem("tacit-token") || "", role: null, vehicles: [], vehicleId: null,
  packets: [], commands: new Map(), timeline: [], streams: {}, series: [], channel: "env:temperature" };
const $ = (id) => document.getElementById(id);

async function api(path, options = {}) {
  const headers = { ...(options.headers || {}) };
  if (state.token) headers.Authorization = `Bearer ${state.token}`;
  if (options.body) headers["Content-Type"] = "application/json";
  const response = await fetch(`/api/v1${path}`, { ...options, headers });
  const body = response.headers.get("content-type")?.includes("json") ? await response.json() : null;
  if (!response.ok) throw Object.assign(new Error(body?.detail || response.statusText), { body, status: response.status });
  return body;
}

async function signIn(token) {
  state.token = token;
  try {
    state.role = (await api("/whoami")).role;
    localStorage.setItem("tacit-token", token);
  } catch (error) {
    state.role = null;
  }
  $("role").textContent = state.role === "write" ? "operator" : state.role === "read" ? "observer (read only)" : "not signed in";
  for (const el of document.querySelectorAll(".write")) el.disabled = state.role !== "write";
  if (state.role) await load();
}

async function load() {
  const config = await api("/config");
  state.streams = config.streams;
  if (config.map_port) {
    const url = `${location.protocol}//${location.hostname}:${config.map_port}`;
    $("map").src = url;
    $("map-link").href = url;
  }
  const select = $("stream-channel");
  select.innerHTML = "";
  for (const [stream, spec] of Object.entries(config.streams)) {
    spec.channels.forEach((channel) => select.add(new Option(`${stream}: ${channel}`, `${stream}:${channel}`)));
  }
  select.value = state.channel;
  state.vehicles = await api("/vehicles");
  state.vehicleId = state.vehicles[0]?.id ?? null;
  if (state.vehicleId !== null) {
    for (const c of await api(`/vehicles/${state.vehicleId}/commands?limit=20`)) state.commands.set(c.id, c);
  }
  const page = await api("/packets?limit=100");
  state.packets = page.items.map(packetRow).reverse();
  for (const p of state.packets) state.timeline.push({ at: p.at, kind: p.type === "checkpoint" ? "cp" : `p${p.priority}` });
  await loadSeries();
  renderAll();
  await refreshLink();
  connect();
}

function packetRow(p) {
  const name = p.vehicle ?? state.vehicles.find((v) => v.id === p.vehicle_id)?.name ?? p.vehicle_id;
  return { at: p.at, vehicle: name, type: p.type, seq: p.seq, priority: p.priority, size: p.size ?? 32, snr: p.snr };
}

async function loadSeries() {
  const [stream] = state.channel.split(":");
  if (state.vehicleId === null) return;
  const since = Date.now() / 1000 - 3600;
  const page = await api(`/telemetry?vehicle_id=${state.vehicleId}&stream=${stream}&since=${since}&limit=5000`);
  state.series = page.items.map((row) => ({ time: row.time, values: row.values, certain: row.certain }));
}

function connect() {
  // fetch, not EventSource: it can send the Authorization header (tokens never go in URLs)
  const source = new EventTarget();
  (async function read() {
    try {
      const response = await fetch("/api/v1/events", { headers: { Authorization: `Bearer ${state.token}` } });
      if (!response.ok) throw new Error(response.statusText);
      const reader = response.body.pipeThrough(new TextDecoderStream()).getReader();
      let buffer = "";
      for (;;) {
        const { value, done } = await reader.read();
        if (done) break;
        buffer += value;
        const frames = buffer.split("\n\n");
        buffer = frames.pop();
        for (const frame of frames) {
          const kind = frame.match(/^event: (.*)$/m)?.[1], data = frame.match(/^data: (.*)$/m)?.[1];
          if (kind && data) source.dispatchEvent(new MessageEvent(kind, { data }));
        }
      }
    } catch (error) { /* fall through to reconnect */ }
    setBadge("events: reconnecting", "down");
    setTimeout(read, 3000);
  })();
  source.addEventListener("packet", (e) => {
    const p = JSON.parse(e.data);
    state.packets.push(packetRow(p));
    state.packets = state.packets.slice(-300);
    state.timeline.push({ at: p.at, kind: p.type === "checkpoint" ? "cp" : `p${p.priority}` });
    renderPackets(); renderTimeline();
  });
  source.addEventListener("command", (e) => {
    const c = JSON.parse(e.data);
    const known = state.commands.get(c.id) || { id: c.id, seq: c.seq, command: c.command || "", reason: "" };
    state.commands.set(c.id, { ...known, status: c.status, reason: c.reason ?? known.reason });
    if (c.status === "sent" && !known.timelined) { state.timeline.push({ at: c.at, kind: "ctl" }); known.timelined = true; }
    renderCommands(); renderTimeline();
  });
  source.addEventListener("vehicle", (e) => renderVehicle(JSON.parse(e.data).checkpoint));
  source.addEventListener("telemetry", (e) => {
    const t = JSON.parse(e.data);
    if (t.stream !== state.channel.split(":")[0]) return;
    t.values.forEach((values, i) => state.series.push({ time: t.first_time + i * t.period, values, certain: true }));
    renderPlot();
  });
  source.addEventListener("link", () => refreshLink());
}

async function refreshLink() {
  try {
    const link = await api("/link");
    setBadge(`modem: ${link.modem}`, link.modem === "ready" ? "ready" : "down");
    const rows = [];
    for (const [name, v] of Object.entries(link.vehicles)) {
      const heard = v.last_heard ? `${Math.round(Date.now() / 1000 - v.last_heard)} s ago` : "never";
      rows.push([`${name} last heard`, heard], ["SNR in / out (dB)", `${v.snr_in ?? "-"} / ${v.snr_out ?? "-"}`],
        ["range (m)", v.range_m?.toFixed(0) ?? "-"], ["packets per hour", v.packets_per_hour],
        ["bytes saved by compression", v.bytes_saved], ["duplicates dropped", v.duplicates]);
      if (v.checkpoint) renderVehicle(v.checkpoint);
    }
    const utilisation = link.counters.polls + link.counters.commands_sent;
    rows.push(["shore transmissions (polls + commands)", utilisation]);
    $("link-stats").tBodies[0].innerHTML = rows.map(([k, v]) => `<tr><th>${k}</th><td>${v}</td></tr>`).join("");
  } catch (error) { setBadge("link: ?", "down"); }
}

function setBadge(text, kind) { const b = $("link-badge"); b.textContent = text; b.className = `badge ${kind}`; }

function renderVehicle(cp) {
  if (!cp) return;
  $("vehicle-state").innerHTML = `<strong>${cp.state.replace("_", " ")}</strong> &mdash; mission ${cp.mission_id}, waypoint ${cp.waypoint}<br>
    north ${cp.north.toFixed(1)} m, east ${cp.east.toFixed(1)} m, depth ${cp.depth.toFixed(2)} m, heading ${cp.heading.toFixed(0)}&deg;<br>
    water ${cp.temperature.toFixed(2)} &deg;C, battery ${cp.battery.toFixed(1)} V`;
}

function renderPackets() {
  const rows = state.packets.slice(-100).reverse().map((p) => `<tr><td>${new Date(p.at * 1000).toLocaleTimeString()}</td>
    <td>${p.vehicle}</td><td>${p.type}</td><td>${p.seq}</td><td>${p.priority}</td><td>${p.size}</td><td>${p.snr ?? "-"}</td></tr>`);
  $("packets").tBodies[0].innerHTML = rows.join("");
}

function renderCommands() {
  const rows = [...state.commands.values()].sort((a, b) => b.id - a.id).slice(0, 10).map((c) =>
    `<tr><td>${c.id}</td><td>${c.seq}</td><td>${c.command}</td><td class="status-${c.status}">${c.status}</td><td>${c.reason || ""}</td></tr>`);
  $("commands").tBodies[0].innerHTML = rows.join("");
}

function renderTimeline() {
  const canvas = $("timeline"), ctx = canvas.getContext("2d");
  canvas.width = canvas.clientWidth;
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const now = Date.now() / 1000, span = 600, x = (t) => canvas.width * (1 - (now - t) / span);
  const rows = { ctl: 25, cp: 65, p0: 105, p1: 105, p2: 105, p3: 105 };
  const colours = { ctl: "#000", cp: "#0a0", p0: "#2a5ad8", p1: "#e0b000", p2: "#f08020", p3: "#d01010" };
  ctx.font = "14px system-ui"; ctx.fillStyle = "#333";
  ctx.fillText("control", 4, 20); ctx.fillText("check-point", 4, 60); ctx.fillText("priority", 4, 100);
  ctx.fillText("-10 min", 4, 145); ctx.fillText("now", canvas.width - 30, 145);
  for (const e of state.timeline.filter((e) => now - e.at < span)) {
    ctx.fillStyle = colours[e.kind]; ctx.beginPath();
    if (e.kind === "ctl") ctx.rect(x(e.at) - 5, rows.ctl, 10, 10); else ctx.arc(x(e.at), rows[e.kind] + 5, 6, 0, 2 * Math.PI);
    ctx.fill();
  }
}

function renderPlot() {
  const canvas = $("plot"), ctx = canvas.getContext("2d");
  canvas.width = canvas.clientWidth;
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const [stream, channel] = state.channel.split(":");
  const spec = state.streams[stream];
  if (!spec) return;
  const index = spec.channels.indexOf(channel), eps = spec.eps[index];
  const points = state.series.slice(-600);
  const values = points.filter((p) => p.certain).map((p) => p.values[index]);
  if (!values.length) { ctx.fillText("no data yet", 10, 20); return; }
  const lo = Math.min(...values) - eps, hi = Math.max(...values) + eps, t0 = points[0].time, t1 = points[points.length - 1].time;
  const x = (t) => 50 + (canvas.width - 60) * (t - t0) / Math.max(t1 - t0, 1), y = (v) => 10 + (canvas.height - 30) * (hi - v) / Math.max(hi - lo, 1e-9);
  ctx.fillStyle = "rgba(0, 64, 160, 0.18)";
  for (const p of points) if (p.certain) ctx.fillRect(x(p.time) - 1, y(p.values[index] + eps), 2, y(p.values[index] - eps) - y(p.values[index] + eps));
  ctx.strokeStyle = "#0040a0"; ctx.lineWidth = 2; ctx.beginPath();
  let pen = false;
  for (const p of points) {
    if (!p.certain) { pen = false; ctx.fillStyle = "rgba(200,0,0,0.35)"; ctx.fillRect(x(p.time) - 1, 10, 3, canvas.height - 30); continue; }
    pen ? ctx.lineTo(x(p.time), y(p.values[index])) : ctx.moveTo(x(p.time), y(p.values[index])); pen = true;
  }
  ctx.stroke();
  ctx.fillStyle = "#000"; ctx.font = "14px system-ui";
  ctx.fillText(hi.toFixed(2), 2, 20); ctx.fillText(lo.toFixed(2), 2, canvas.height - 20);
  ctx.fillText(`eps ${eps}`, canvas.width - 80, 20);
}

function renderAll() { renderPackets(); renderCommands(); renderTimeline(); renderPlot(); }

$("login").addEventListener("submit", (e) => { e.preventDefault(); signIn($("token").value.trim()); });
$("stream-channel").addEventListener("change", async (e) => { state.channel = e.target.value; await loadSeries(); renderPlot(); });
$("command-form").addEventListener("submit", async (e) => {
  e.preventDefault();
  if (state.vehicleId === null) { $("command-result").textContent = "no vehicle registered"; return; }
  const body = { command: $("cmd").value, distance: +$("distance").value, angle: +$("angle").value, depth: +$("depth").value,
    param_id: +$("param").value };
  try {
    const c = await api(`/vehicles/${state.vehicleId}/commands`, { method: "POST", body: JSON.stringify(body) });
    state.commands.set(c.id, c);
    $("command-result").textContent = `command ${c.command} seq ${c.seq}: ${c.status}`;
    renderCommands();
  } catch (error) {
    $("command-result").textContent = `refused: ${error.message}${error.body?.field ? ` (${error.body.field})` : ""}`;
  }
});
setInterval(() => { renderTimeline(); }, 5000);
setInterval(() => { if (state.role) refreshLink(); }, 10000);
if (state.token) signIn(state.token); else for (const el of document.querySelectorAll(".write")) el.disabled = true;
