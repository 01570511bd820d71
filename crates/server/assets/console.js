// mouthpiece booth console: the camera image with the tracked dots, the daemon's status,
// calibrate and record controls, and every character's mouth. Protocol mouthpiece.v1
// (docs/protocol.md); no build step, no dependencies, nothing loaded from elsewhere.
"use strict";

(function () {
  const el = (id) => document.getElementById(id);
  const view = el("view");
  const vctx = view.getContext("2d");
  const camera = el("camera");
  const cctx = camera.getContext("2d");

  // What the page knows (tests read it through window.mouthpiece).
  const state = {
    connected: false,
    hello: null,
    status: null,
    health: null,
    frame: null,
    frames: 0,
    lagged: 0,
    fps: 0,
    latencyMs: null,
    // The last capture-to-page latencies, ms (for measurements: bench/console_latency.py).
    latencyLog: [],
    errors: [],
    access: null,
    preview: { images: 0, overlay: null, width: 0, height: 0, toCanvas: null, drawnAt: null },
    calibration: { phase: "idle", message: "" },
    lastResult: null,
    // The microphone meter: the peak held for holdMs, the clip warning for clipHoldMs.
    audio: { state: "off", text: "", level: -Infinity, heldPeak: -Infinity, heldAt: 0, clipAt: -Infinity,
      clipShown: false, holdMs: 2000, clipHoldMs: 3000 },
    // The zoomed mouth: its scale (inset pixels per source pixel), dots and label boxes.
    inset: null,
    token: null,
    // Called with every status message (console-takes.js); `request` sends a control request.
    statusHooks: [],
    request: null,
  };
  window.mouthpiece = state;

  const params = new URLSearchParams(location.search);
  const token = params.get("token");
  state.token = token;
  const countdownFrom = Math.max(0, parseInt(params.get("countdown") || "3", 10) || 0);
  const scheme = location.protocol === "https:" ? "wss:" : "ws:";
  const url = `${scheme}//${location.host}/`;
  const protocols = ["mouthpiece.v1"];
  if (token) protocols.push("mouthpiece.token." + token);

  const DOT_COLOURS = { tracked: "#3ddc84", predicted: "#ffd23f", lost: "#ff4d4d" };

  let ws = null;
  let retryMs = 500;
  let arrivals = [];
  let latencies = [];
  let nextId = 1;
  const pending = new Map(); // request id -> what it was

  function send(msg) {
    if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(msg));
  }

  function request(msg, what) {
    const id = `console-${nextId++}`;
    pending.set(id, what);
    send(Object.assign({ id }, msg));
    return id;
  }

  function previewWidth() {
    const dpr = window.devicePixelRatio || 1;
    return Math.max(320, Math.min(640, Math.round(camera.clientWidth * dpr)));
  }

  function connect() {
    ws = new WebSocket(url, protocols);
    ws.binaryType = "arraybuffer";
    ws.onopen = () => {
      state.connected = true;
      retryMs = 500;
      send({ type: "subscribe", id: "console", fields: ["curve", "performer", "health"] });
      send({ type: "preview", id: "console-preview", max_rate: 10, max_width: previewWidth() });
      showHeader();
    };
    ws.onmessage = (event) => {
      if (typeof event.data !== "string") { onBinary(event.data); return; }
      const msg = JSON.parse(event.data);
      switch (msg.type) {
        case "hello": onHello(msg); break;
        case "status":
          if (msg.lagged) state.lagged += msg.lagged; else onStatus(msg);
          break;
        case "health": state.health = msg; showStatus(); break;
        case "frame": onFrame(msg); break;
        case "result": onResult(msg); break;
        case "error": onError(msg); break;
      }
    };
    ws.onclose = (event) => {
      state.connected = false;
      el("state").textContent = `disconnected${event.reason ? ": " + event.reason : ""}; retrying`;
      el("state").className = "disconnected";
      el("camera-note").textContent = "disconnected: reconnecting…";
      el("camera-note").hidden = false;
      pending.clear();
      if (state.calibration.phase !== "idle" && state.calibration.phase !== "done") {
        setCalibration("idle", "connection lost during calibration; calibrate again");
      }
      setTimeout(connect, retryMs);
      retryMs = Math.min(retryMs * 2, 5000);
    };
  }

  function onHello(msg) {
    state.hello = msg;
    state.access = msg.access;
    const control = msg.access === "control";
    el("controls").hidden = !control;
    el("readonly").hidden = control;
    el("tune").hidden = !control;
    showStatus();
  }

  function onStatus(msg) {
    const before = state.status;
    state.status = msg;
    const c = state.calibration;
    if ((c.phase === "sent" || c.phase === "waiting") && msg.calibration &&
        (!c.before || msg.calibration.wall_us > c.before) && !msg.calibrating) {
      setCalibration("done", calibrationText(msg.calibration));
    } else if (c.phase === "sent" && msg.calibrating) {
      setCalibration("waiting", "Hold still: measuring the neutral face…");
    }
    if (before && before.recording && !msg.recording) {
      const last = (msg.takes || [])[msg.takes.length - 1];
      if (last && last.error) showError(`take ${last.take} stopped: ${last.error}`);
    }
    showHeader();
    showStatus();
    showTakes();
    showRecord();
    showAudio();
    for (const hook of state.statusHooks) hook(msg);
  }

  function onResult(msg) {
    state.lastResult = msg;
    const what = pending.get(msg.id);
    pending.delete(msg.id);
    if (!what) return;
    if (what === "calibrate") {
      if (state.calibration.phase === "sent") setCalibration("waiting", "Hold still: measuring the neutral face…");
      maybeCalibrated();
    } else if (what === "record-start") {
      showError("");
      if (msg.detail && msg.detail.take != null) el("take").value = msg.detail.take;
    } else if (what === "record-stop") {
      showError("");
      if (msg.detail && msg.detail.take != null) el("take").value = msg.detail.take + 1;
    }
  }

  function onError(msg) {
    state.errors.push(msg);
    const what = msg.id ? pending.get(msg.id) : null;
    if (msg.id) pending.delete(msg.id);
    if (what === "calibrate") setCalibration("idle", "");
    if (what === "tune") { el("tune-say").textContent = msg.message || msg.code; return; }
    showError(msg.message || msg.code);
    console.warn("mouthpiece error", msg);
  }

  function showError(text) { el("error").textContent = text; }

  function onFrame(frame) {
    state.frame = frame;
    state.frames += 1;
    const now = performance.now();
    arrivals.push(now);
    while (arrivals.length && now - arrivals[0] > 1000) arrivals.shift();
    state.fps = arrivals.length;
    if (frame.wall_us) {
      const latency = Date.now() - frame.wall_us / 1000;
      state.latencyLog.push(latency);
      if (state.latencyLog.length > 3000) state.latencyLog.shift();
      latencies.push([now, latency]);
      while (latencies.length && now - latencies[0][0] > 1000) latencies.shift();
      const sorted = latencies.map((l) => l[1]).sort((a, b) => a - b);
      state.latencyMs = sorted[Math.floor(sorted.length / 2)];
    }
  }

  // Preview message: "MPP1", u16 version, u16 flags, u64 seq, f64 t, u64 capture_us,
  // i64 wall_us, u16 width, height, source width, source height, u32 JSON length,
  // u32 JPEG length, the overlay JSON, the JPEG (docs/protocol.md).
  function onBinary(buffer) {
    const dv = new DataView(buffer);
    if (buffer.byteLength < 56) return;
    const magic = String.fromCharCode(dv.getUint8(0), dv.getUint8(1), dv.getUint8(2), dv.getUint8(3));
    if (magic !== "MPP1") return;
    const jsonLen = dv.getUint32(48, true);
    const jpegLen = dv.getUint32(52, true);
    const overlay = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 56, jsonLen)));
    const jpeg = new Blob([new Uint8Array(buffer, 56 + jsonLen, jpegLen)], { type: "image/jpeg" });
    createImageBitmap(jpeg).then((bitmap) => {
      state.preview.images += 1;
      drawCamera(bitmap, overlay);
      bitmap.close();
    }).catch((e) => console.warn("preview image", e));
  }

  function fitCanvas(canvas) {
    const dpr = window.devicePixelRatio || 1;
    const w = Math.round(canvas.clientWidth * dpr), h = Math.round(canvas.clientHeight * dpr);
    if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
    return [w, h, dpr];
  }

  function drawCamera(bitmap, overlay) {
    const [w, h, dpr] = fitCanvas(camera);
    const sw = overlay.source_width, sh = overlay.source_height;
    const scale = Math.min(w / sw, h / sh);
    const ox = (w - sw * scale) / 2, oy = (h - sh * scale) / 2;
    const toCanvas = (x, y) => [ox + x * scale, oy + y * scale];
    cctx.setTransform(1, 0, 0, 1, 0, 0);
    cctx.fillStyle = "#000";
    cctx.fillRect(0, 0, w, h);
    cctx.imageSmoothingEnabled = true;
    cctx.drawImage(bitmap, ox, oy, sw * scale, sh * scale);
    for (const s of overlay.search || []) {
      const [x0, y0] = toCanvas(s.x, s.y);
      cctx.setLineDash([6 * dpr, 4 * dpr]);
      cctx.strokeStyle = "#ff9f43";
      cctx.lineWidth = 1.5 * dpr;
      cctx.strokeRect(x0, y0, s.width * scale, s.height * scale);
      cctx.setLineDash([]);
    }
    const r = 4 * dpr;
    cctx.font = `${Math.round(11 * dpr)}px system-ui, sans-serif`;
    cctx.textBaseline = "middle";
    // Labels first, then the dots over them: a dot is never hidden by a neighbour's label.
    // The lip dots are too close together here to label: the zoomed mouth labels them.
    for (const d of overlay.dots) {
      if (isLip(d)) continue;
      const [x, y] = toCanvas(d.x, d.y);
      cctx.fillStyle = DOT_COLOURS[d.state] || "#ffffff";
      cctx.fillText(d.name, x + r + 3 * dpr, y - r - 2 * dpr);
    }
    // Dark rims first, then every dot's colour over them: close dots never hide each
    // other's centre behind a rim.
    cctx.fillStyle = "#000";
    for (const d of overlay.dots) {
      const [x, y] = toCanvas(d.x, d.y);
      cctx.beginPath();
      cctx.arc(x, y, r + 1.5 * dpr, 0, 2 * Math.PI);
      cctx.fill();
    }
    for (const d of overlay.dots) {
      const [x, y] = toCanvas(d.x, d.y);
      cctx.beginPath();
      cctx.arc(x, y, r, 0, 2 * Math.PI);
      cctx.fillStyle = DOT_COLOURS[d.state] || "#ffffff";
      cctx.fill();
    }
    state.preview.overlay = overlay;
    state.preview.width = overlay.width;
    state.preview.height = overlay.height;
    state.preview.toCanvas = toCanvas;
    state.preview.drawnAt = Date.now();
    el("camera-note").hidden = true;
    drawInset(bitmap, overlay);
  }

  function isLip(d) { return /^D\d+$/.test(d.name); }

  // The mouth enlarged: the lip dots' box with room around it, every dot with its label
  // placed outwards from the mouth's centre (nudged further out until no label overlaps
  // another label or a dot).
  const zoom = el("mouth-zoom");
  const zctx = zoom.getContext("2d");
  function drawInset(bitmap, overlay) {
    const [w, h, dpr] = fitCanvas(zoom);
    zctx.setTransform(1, 0, 0, 1, 0, 0);
    zctx.fillStyle = "#000";
    zctx.fillRect(0, 0, w, h);
    const lips = overlay.dots.filter(isLip);
    if (!lips.length || !w || !h) { state.inset = null; return; }
    let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
    for (const d of lips) { x0 = Math.min(x0, d.x); x1 = Math.max(x1, d.x); y0 = Math.min(y0, d.y); y1 = Math.max(y1, d.y); }
    const cx = (x0 + x1) / 2, cy = (y0 + y1) / 2;
    // Room for the labels: the mouth fills about half the inset.
    const span = Math.max((x1 - x0) * 2.0, (y1 - y0) * 2.0 * w / h, 24);
    const scale = w / span;
    const toInset = (x, y) => [w / 2 + (x - cx) * scale, h / 2 + (y - cy) * scale];
    const sw = overlay.source_width, sh = overlay.source_height;
    const [ix, iy] = toInset(0, 0);
    zctx.imageSmoothingEnabled = true;
    zctx.drawImage(bitmap, 0, 0, bitmap.width, bitmap.height, ix, iy, sw * scale, sh * scale);
    const r = 5 * dpr;
    const dots = lips.map((d) => { const [x, y] = toInset(d.x, d.y); return { name: d.name, state: d.state, x, y }; });
    zctx.font = `600 ${Math.round(13 * dpr)}px system-ui, sans-serif`;
    zctx.textBaseline = "middle";
    zctx.textAlign = "left";
    const labels = [];
    const overlaps = (a, b) => a.x < b.x + b.w && b.x < a.x + a.w && a.y < b.y + b.h && b.y < a.y + a.h;
    const hitsDot = (box) => dots.some((p) => p.x + r > box.x && p.x - r < box.x + box.w && p.y + r > box.y && p.y - r < box.y + box.h);
    for (const p of dots) {
      let dx = p.x - w / 2, dy = p.y - h / 2;
      const n = Math.hypot(dx, dy) || 1;
      dx /= n; dy /= n;
      const tw = zctx.measureText(p.name).width, th = 14 * dpr;
      let box = null;
      for (let k = 0; k < 40; k++) {
        const dist = r + 4 * dpr + k * 3 * dpr;
        const ax = p.x + dx * dist, ay = p.y + dy * dist;
        // The label's box sits on the side the direction points to.
        const bxl = dx > 0.35 ? ax : dx < -0.35 ? ax - tw : ax - tw / 2;
        const byl = dy > 0.35 ? ay : dy < -0.35 ? ay - th : ay - th / 2;
        box = { name: p.name, x: bxl, y: byl, w: tw, h: th };
        if (!labels.some((l) => overlaps(l, box)) && !hitsDot(box)) break;
      }
      labels.push(box);
    }
    // Dark plates, then the labels, then the dots.
    zctx.fillStyle = "rgba(0, 0, 0, 0.6)";
    for (const b of labels) zctx.fillRect(b.x - 2 * dpr, b.y, b.w + 4 * dpr, b.h);
    for (const [i, b] of labels.entries()) {
      zctx.fillStyle = DOT_COLOURS[dots[i].state] || "#ffffff";
      zctx.fillText(b.name, b.x, b.y + b.h / 2);
    }
    zctx.fillStyle = "#000";
    for (const p of dots) { zctx.beginPath(); zctx.arc(p.x, p.y, r + 1.5 * dpr, 0, 2 * Math.PI); zctx.fill(); }
    for (const p of dots) {
      zctx.beginPath();
      zctx.arc(p.x, p.y, r, 0, 2 * Math.PI);
      zctx.fillStyle = DOT_COLOURS[p.state] || "#ffffff";
      zctx.fill();
    }
    state.inset = { scale, width: w, height: h, radius: r, dots, labels };
  }

  // ---- microphone ------------------------------------------------------------------------

  const METER_FLOOR_DB = -60;
  function dbfs(v) { return typeof v === "number" && Number.isFinite(v) ? v : -Infinity; }
  function meterShare(db) { return Math.max(0, Math.min(1, (db - METER_FLOOR_DB) / -METER_FLOOR_DB)); }

  // The timecode's source and state: LTC locked is good; free-running and lost want the
  // technician's eye (docs/daemon.md, Timecode).
  const TIMECODE_STATES = {
    system: ["time of day (host clock)", "muted"],
    locked: ["LTC locked", "good"],
    free_running: ["LTC free-running (no LTC on the input)", "warn"],
    lost: ["LTC lost (none read yet): time of day", "bad"],
  };
  function showTimecode() {
    const t = state.status && state.status.timecode;
    if (!t) return;
    const [text, cls] = TIMECODE_STATES[t.state] || [t.state, "muted"];
    const s = el("timecode-state");
    s.textContent = `${text} · ${t.rate}`;
    s.className = cls;
  }

  function showAudio() {
    showTimecode();
    const a = (state.status && state.status.audio) || { state: "off" };
    const m = state.audio;
    const now = performance.now();
    m.state = a.state;
    const live = a.state === "live" || a.state === "replay";
    let text;
    const why = state.status && state.status.audio_message;
    if (a.state === "no_device") {
      text = `no microphone: ${a.device || "the device"} cannot be opened (retrying)${why ? ": " + why : ""}`;
    } else if (!live) {
      text = "no microphone (audio is off in the configuration)";
    } else {
      const fmt = `${a.sample_rate} Hz · ${a.channels === 1 ? "mono" : a.channels + " channels"}`;
      text = `${a.state === "replay" ? "replay " : ""}${a.device} · ${fmt}`;
      if (a.overruns || a.dropped_blocks) text += ` · overruns ${a.overruns || 0}, dropped ${a.dropped_blocks || 0}`;
    }
    m.text = text;
    const peak = live ? dbfs(a.peak_dbfs) : -Infinity;
    m.level = live ? dbfs(a.level_dbfs) : -Infinity;
    if (!live) { m.heldPeak = -Infinity; m.clipAt = -Infinity; }
    if (peak >= m.heldPeak || now - m.heldAt > m.holdMs) { m.heldPeak = peak; m.heldAt = now; }
    if (live && (a.clip || peak >= -1)) m.clipAt = now;
    m.clipShown = now - m.clipAt <= m.clipHoldMs;
    const s = el("mic-state");
    s.textContent = text;
    s.title = text;
    s.className = live ? "" : "bad";
    el("meter-level").style.width = `${(meterShare(m.level) * 100).toFixed(1)}%`;
    el("meter").style.setProperty("--meter-width", `${el("meter").clientWidth}px`);
    const held = el("meter-peak");
    held.hidden = !live || !(m.heldPeak > METER_FLOOR_DB);
    held.style.left = `${(meterShare(m.heldPeak) * 100).toFixed(1)}%`;
    el("meter-clip").hidden = !m.clipShown;
  }

  // ---- status --------------------------------------------------------------------------

  function showHeader() {
    const s = el("state");
    s.textContent = state.connected ? "connected" : "connecting…";
    s.className = state.connected ? "connected" : "disconnected";
    const st = state.status;
    el("source").textContent = st
      ? `source ${st.source}${st.calibrating ? " · calibrating" : ""}${st.message ? " · " + st.message : ""}`
      : "";
    el("rec").textContent = st && st.recording ? `● REC ${st.recording.slate} take ${st.recording.take}` : "";
  }

  function fmtTime(us) {
    return new Date(us / 1000).toLocaleTimeString();
  }

  function fmtElapsed(ms) {
    const s = Math.max(0, Math.floor(ms / 1000));
    return `${Math.floor(s / 60)}:${String(s % 60).padStart(2, "0")}`;
  }

  function calibrationText(c) {
    const wobble = Number.isFinite(c.lip_wobble_mm) ? c.lip_wobble_mm.toFixed(2) + " mm" : "–";
    return `Calibrated at ${fmtTime(c.wall_us)}: mouth width ${c.mouth_width_mm.toFixed(1)} mm, ` +
      `lip wobble ${wobble} (${c.frames} frames)`;
  }

  // `title` (plain text) is shown in full on hover when the value is cut short.
  function tile(key, value, cls, title) {
    const t = title == null ? "" : ` title="${esc(title)}"`;
    return `<div class="tile"><span class="k">${key}</span><span class="v ${cls || ""}"${t}>${value}</span></div>`;
  }

  function esc(text) {
    return String(text).replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" }[c]));
  }

  function showStatus() {
    const st = state.status, h = state.health, hello = state.hello;
    const tiles = [];
    if (st) {
      const mode = h && h.image ? `${h.image[0]}×${h.image[1]}` : "";
      const rate = hello && hello.frame_rate ? ` @ ${hello.frame_rate.toFixed(0)} fps` : "";
      tiles.push(tile("source", `${st.source}${mode ? " · " + mode + rate : ""}`, st.source === "up" ? "good" : "bad"));
    }
    if (hello) tiles.push(tile("device", esc(hello.source || "–"), "device", hello.source || ""));
    if (st) {
      const c = st.calibration;
      tiles.push(tile("calibration", st.calibrating ? "calibrating…" : c
        ? `${fmtTime(c.wall_us)} · width ${c.mouth_width_mm.toFixed(1)} mm · wobble ${Number.isFinite(c.lip_wobble_mm) ? c.lip_wobble_mm.toFixed(2) : "–"} mm`
        : "none yet", st.calibrating ? "warn" : c ? "" : "warn"));
    }
    if (h) {
      const found = h.dots_found * 100;
      tiles.push(tile("dots found (1 s)", `${found.toFixed(1)} %`, found >= 99 ? "good" : found >= 90 ? "warn" : "bad"));
      tiles.push(tile("frame rate", `${h.fps.toFixed(1)} fps · page ${state.fps}`));
    }
    tiles.push(tile("latency capture → page", state.latencyMs == null ? "–" : `${state.latencyMs.toFixed(1)} ms`));
    if (h) tiles.push(tile("clients", `${h.clients} (${h.preview_clients} with image)`));
    if (st) {
      const r = st.recording;
      tiles.push(tile("recording", r
        ? `● ${esc(r.slate)} take ${r.take}${r.started_wall_us ? " · " + fmtElapsed(Date.now() - r.started_wall_us / 1000) : ""}`
        : "stopped", r ? "bad" : ""));
    }
    if (h && h.disk_free_mb != null) {
      tiles.push(tile("free disk", h.disk_free_mb >= 1024 ? `${(h.disk_free_mb / 1024).toFixed(1)} GB` : `${h.disk_free_mb} MB`,
        h.disk_free_mb < 2048 ? "warn" : ""));
    }
    el("status").innerHTML = tiles.join("");
  }

  function showTakes() {
    const takes = (state.status && state.status.takes) || [];
    el("takes").innerHTML = takes.length
      ? takes.slice().reverse().map((t) =>
        `<li><button class="play" data-file="${esc(t.file)}" data-seconds="${t.seconds}">▶ Play</button>${esc(t.slate)} take ${t.take} · ${t.seconds.toFixed(1)} s · ${t.frames} frames` +
        `${t.error ? ` · <span class="bad">${esc(t.error)}</span>` : ""}<br><span class="muted">${esc(t.file)}</span></li>`).join("")
      : '<li class="muted">none yet</li>';
  }

  function showRecord() {
    const r = state.status && state.status.recording;
    const b = el("record");
    b.textContent = r ? "■ Stop" : "● Record";
    b.className = r ? "stop" : "";
    el("slate").disabled = !!r;
    el("take").disabled = !!r;
    el("elapsed").textContent = r && r.started_wall_us ? fmtElapsed(Date.now() - r.started_wall_us / 1000) : "";
  }

  // ---- controls ------------------------------------------------------------------------

  function canControl() { return state.connected && state.access === "control"; }

  function setCalibration(phase, message) {
    state.calibration.phase = phase;
    state.calibration.message = message;
    el("calib-say").textContent = message;
    el("calibrate").disabled = phase !== "idle" && phase !== "done";
    if (phase !== "countdown") el("countdown").textContent = "";
  }

  function maybeCalibrated() {
    const st = state.status, c = state.calibration;
    if (st && st.calibration && !st.calibrating && (!c.before || st.calibration.wall_us > c.before)) {
      setCalibration("done", calibrationText(st.calibration));
    }
  }

  function startCalibration() {
    const c = state.calibration;
    if (!canControl() || (c.phase !== "idle" && c.phase !== "done")) return;
    c.before = state.status && state.status.calibration ? state.status.calibration.wall_us : 0;
    setCalibration("countdown", "Relax your face, lips closed, look at the camera and hold still.");
    let n = countdownFrom;
    const tick = () => {
      if (!state.connected) { setCalibration("idle", "not connected"); return; }
      if (n > 0) {
        el("countdown").textContent = String(n);
        n -= 1;
        setTimeout(tick, 1000);
        return;
      }
      el("countdown").textContent = "";
      setCalibration("sent", "Hold still…");
      request({ type: "calibrate" }, "calibrate");
    };
    tick();
  }

  function toggleRecord() {
    if (!canControl()) return;
    if (state.status && state.status.recording) {
      request({ type: "record", action: "stop" }, "record-stop");
      return;
    }
    const msg = { type: "record", action: "start", slate: el("slate").value.trim() };
    const take = parseInt(el("take").value, 10);
    if (Number.isInteger(take) && take >= 0) msg.take = take;
    request(msg, "record-start");
  }

  state.request = (msg, what) => (canControl() ? request(msg, what) : null);
  el("calibrate").addEventListener("click", startCalibration);
  el("record").addEventListener("click", toggleRecord);
  document.addEventListener("keydown", (e) => {
    if (e.target && (e.target.tagName === "INPUT" || e.target.tagName === "TEXTAREA")) return;
    if (e.ctrlKey || e.metaKey || e.altKey) return;
    if (e.key === "c" || e.key === "C") { startCalibration(); e.preventDefault(); }
    if (e.key === "r" || e.key === "R") { toggleRecord(); e.preventDefault(); }
  });
  el("take").value = "";
  el("take").placeholder = "auto";

  // ---- mouths ----------------------------------------------------------------------------

  function bounds(points) {
    let minX = Infinity, maxX = -Infinity, minY = Infinity, maxY = -Infinity;
    for (const p of points) {
      minX = Math.min(minX, p[0]); maxX = Math.max(maxX, p[0]);
      minY = Math.min(minY, p[1]); maxY = Math.max(maxY, p[1]);
    }
    const w = Math.max(maxX - minX, 1e-6), h = Math.max(maxY - minY, w * 0.4);
    return { cx: (minX + maxX) / 2, cy: (minY + maxY) / 2, half: Math.max(w, h) * 0.9 };
  }

  // Points in a mouth frame (x to the subject's left, y up), drawn as the viewer sees them.
  function panel(x, y, w, h, title, points, confidence, curve, ref, colour) {
    vctx.strokeStyle = "#2a313a";
    vctx.strokeRect(x + 0.5, y + 0.5, w - 1, h - 1);
    vctx.fillStyle = "#8a94a0";
    vctx.font = "13px system-ui, sans-serif";
    vctx.fillText(title, x + 8, y + 18);
    if (!points || !points.length) return;
    const b = bounds(ref && ref.length ? ref : points);
    const scale = Math.min(w, h) / 2 / b.half;
    const px = (p) => x + w / 2 + (p[0] - b.cx) * scale;
    const py = (p) => y + h / 2 - (p[1] - b.cy) * scale;
    if (curve && curve.length) {
      vctx.beginPath();
      curve.forEach((p, i) => (i ? vctx.lineTo(px(p), py(p)) : vctx.moveTo(px(p), py(p))));
      vctx.closePath();
      vctx.strokeStyle = colour;
      vctx.lineWidth = 2;
      vctx.stroke();
      vctx.lineWidth = 1;
    }
    points.forEach((p, i) => {
      const c = confidence ? confidence[i] : 1;
      vctx.beginPath();
      vctx.arc(px(p), py(p), 4, 0, 2 * Math.PI);
      vctx.fillStyle = c > 0.5 ? "#f5f7fa" : "#ff6b6b";
      vctx.fill();
    });
  }

  function headPanel(x, y, w, h, head) {
    vctx.strokeStyle = "#2a313a";
    vctx.strokeRect(x + 0.5, y + 0.5, w - 1, h - 1);
    vctx.fillStyle = "#8a94a0";
    vctx.fillText("head", x + 8, y + 18);
    if (!head) return;
    const [qw, qx, qy, qz] = head.rotation;
    const R = [
      [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
      [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
      [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
    ];
    const cx = x + w / 2, cy = y + h / 2 + 8, len = Math.min(w, h) * 0.32;
    for (const [colour, k] of [["#ff6b6b", 0], ["#7bd88f", 1], ["#6cb6ff", 2]]) {
      vctx.beginPath();
      vctx.moveTo(cx, cy);
      vctx.lineTo(cx + R[0][k] * len, cy + R[1][k] * len);
      vctx.strokeStyle = colour;
      vctx.lineWidth = 3;
      vctx.stroke();
    }
    vctx.lineWidth = 1;
    const deg = (v) => (v * 180 / Math.PI).toFixed(1);
    const yaw = Math.atan2(R[0][2], R[2][2]);
    const pitch = Math.asin(Math.max(-1, Math.min(1, -R[1][2])));
    const roll = Math.atan2(R[1][0], R[1][1]);
    vctx.fillStyle = head.lost ? "#ff6b6b" : "#d8dde3";
    const t = head.translation.map((v) => (v * 100).toFixed(1)).join(", ");
    vctx.fillText(`yaw ${deg(yaw)}°  pitch ${deg(pitch)}°  roll ${deg(roll)}°`, x + 8, y + h - 26);
    vctx.fillText(`t [${t}] cm${head.lost ? "  (head lost)" : ""}`, x + 8, y + h - 10);
  }

  const palette = ["#ffb454", "#c792ea", "#7bd88f", "#6cb6ff"];

  function draw() {
    const [cw, ch, dpr] = fitCanvas(view);
    vctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    const w = cw / dpr, h = ch / dpr;
    vctx.fillStyle = "#111418";
    vctx.fillRect(0, 0, w, h);
    const f = state.frame;
    const characters = f ? f.characters : [];
    const cols = 2 + characters.length;
    const pw = w / Math.max(cols, 1);
    panel(0, 0, pw, h, "performer lips, stabilised (m)", f && f.performer ? f.performer.points : null,
      f && f.performer ? f.performer.confidence : null, null, null, "#ffffff");
    characters.forEach((c, i) => {
      const info = state.hello && state.hello.characters.find((k) => k.name === c.name);
      panel(pw * (i + 1), 0, pw, h, `${c.name}${info && info.units ? " (" + info.units + ")" : ""}`,
        c.points, c.confidence, c.curve, info ? info.neutral : null, palette[i % palette.length]);
    });
    headPanel(pw * (cols - 1), 0, pw, h, f ? f.head : null);
    if (f) {
      const lat = state.latencyMs == null ? "–" : state.latencyMs.toFixed(1) + " ms";
      el("stats").textContent =
        `frame ${f.seq} · ${f.timecode} · ${state.fps} fps · latency ${lat}` +
        (state.lagged ? ` · lost ${state.lagged}` : "");
    }
    requestAnimationFrame(draw);
  }

  setInterval(() => { showStatus(); showRecord(); showAudio(); }, 500);
  showAudio();
  connect();
  requestAnimationFrame(draw);
})();
