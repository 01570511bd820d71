// mouthpiece live viewer: connects with protocol mouthpiece.v1 and draws every frame.
// No build step and no dependencies; served by the daemon at / (see docs/protocol.md).
"use strict";

(function () {
  const canvas = document.getElementById("view");
  const ctx = canvas.getContext("2d");
  const el = (id) => document.getElementById(id);

  // State the page shows (and tests read through window.mouthpiece).
  const state = {
    connected: false,
    hello: null,
    status: null,
    frame: null,
    frames: 0,
    lagged: 0,
    fps: 0,
    latencyMs: null,
    errors: [],
  };
  window.mouthpiece = state;

  const params = new URLSearchParams(location.search);
  const token = params.get("token");
  const scheme = location.protocol === "https:" ? "wss:" : "ws:";
  const url = `${scheme}//${location.host}/`;
  const protocols = ["mouthpiece.v1"];
  if (token) protocols.push("mouthpiece.token." + token);

  let arrivals = [];
  let retryMs = 500;

  function connect() {
    const ws = new WebSocket(url, protocols);
    ws.onopen = () => {
      state.connected = true;
      retryMs = 500;
      ws.send(JSON.stringify({ type: "subscribe", id: "viewer", fields: ["curve", "performer"] }));
      showHeader();
    };
    ws.onmessage = (event) => {
      if (typeof event.data !== "string") return;
      const msg = JSON.parse(event.data);
      switch (msg.type) {
        case "hello": state.hello = msg; break;
        case "status":
          if (msg.lagged) state.lagged += msg.lagged; else state.status = msg;
          showHeader();
          break;
        case "frame": onFrame(msg); break;
        case "error": state.errors.push(msg); console.warn("mouthpiece error", msg); break;
      }
    };
    ws.onclose = (event) => {
      state.connected = false;
      el("state").textContent = `disconnected${event.reason ? ": " + event.reason : ""}; retrying`;
      el("state").className = "disconnected";
      setTimeout(connect, retryMs);
      retryMs = Math.min(retryMs * 2, 5000);
    };
  }

  function onFrame(frame) {
    state.frame = frame;
    state.frames += 1;
    const now = performance.now();
    arrivals.push(now);
    while (arrivals.length && now - arrivals[0] > 1000) arrivals.shift();
    state.fps = arrivals.length;
    if (frame.wall_us) state.latencyMs = Date.now() - frame.wall_us / 1000;
  }

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

  function resize() {
    const dpr = window.devicePixelRatio || 1;
    const w = canvas.clientWidth, h = canvas.clientHeight;
    if (canvas.width !== Math.round(w * dpr) || canvas.height !== Math.round(h * dpr)) {
      canvas.width = Math.round(w * dpr);
      canvas.height = Math.round(h * dpr);
    }
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    return [w, h];
  }

  // Bounds of a point set (x, y), widened so the mouth can open without leaving the panel.
  function bounds(points) {
    let minX = Infinity, maxX = -Infinity, minY = Infinity, maxY = -Infinity;
    for (const p of points) {
      minX = Math.min(minX, p[0]); maxX = Math.max(maxX, p[0]);
      minY = Math.min(minY, p[1]); maxY = Math.max(maxY, p[1]);
    }
    const w = Math.max(maxX - minX, 1e-6), h = Math.max(maxY - minY, w * 0.4);
    const cx = (minX + maxX) / 2, cy = (minY + maxY) / 2;
    return { cx, cy, half: Math.max(w, h) * 0.9 };
  }

  // Draws points (mouth frame: x to the subject's left, y up) into a panel.
  function panel(x, y, w, h, title, points, confidence, curve, ref, colour) {
    ctx.strokeStyle = "#2a313a";
    ctx.strokeRect(x + 0.5, y + 0.5, w - 1, h - 1);
    ctx.fillStyle = "#8a94a0";
    ctx.font = "13px system-ui, sans-serif";
    ctx.fillText(title, x + 8, y + 18);
    if (!points || !points.length) return;
    const b = bounds(ref && ref.length ? ref : points);
    const scale = Math.min(w, h) / 2 / b.half;
    // The viewer looks at the subject: the subject's left (+x) is drawn on the right.
    const px = (p) => x + w / 2 + (p[0] - b.cx) * scale;
    const py = (p) => y + h / 2 - (p[1] - b.cy) * scale;
    if (curve && curve.length) {
      ctx.beginPath();
      curve.forEach((p, i) => (i ? ctx.lineTo(px(p), py(p)) : ctx.moveTo(px(p), py(p))));
      ctx.closePath();
      ctx.strokeStyle = colour;
      ctx.lineWidth = 2;
      ctx.stroke();
      ctx.lineWidth = 1;
    }
    points.forEach((p, i) => {
      const c = confidence ? confidence[i] : 1;
      ctx.beginPath();
      ctx.arc(px(p), py(p), 4, 0, 2 * Math.PI);
      ctx.fillStyle = c > 0.5 ? "#f5f7fa" : "#ff6b6b";
      ctx.fill();
    });
  }

  function headPanel(x, y, w, h, head) {
    ctx.strokeStyle = "#2a313a";
    ctx.strokeRect(x + 0.5, y + 0.5, w - 1, h - 1);
    ctx.fillStyle = "#8a94a0";
    ctx.fillText("head", x + 8, y + 18);
    if (!head) return;
    const [qw, qx, qy, qz] = head.rotation;
    // Rotation matrix columns: where the head's axes point (camera frame, y down).
    const R = [
      [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
      [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
      [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
    ];
    const cx = x + w / 2, cy = y + h / 2 + 8, len = Math.min(w, h) * 0.32;
    const axes = [["#ff6b6b", 0], ["#7bd88f", 1], ["#6cb6ff", 2]];
    for (const [colour, k] of axes) {
      ctx.beginPath();
      ctx.moveTo(cx, cy);
      ctx.lineTo(cx + R[0][k] * len, cy + R[1][k] * len);
      ctx.strokeStyle = colour;
      ctx.lineWidth = 3;
      ctx.stroke();
    }
    ctx.lineWidth = 1;
    const deg = (v) => (v * 180 / Math.PI).toFixed(1);
    const yaw = Math.atan2(R[0][2], R[2][2]);
    const pitch = Math.asin(Math.max(-1, Math.min(1, -R[1][2])));
    const roll = Math.atan2(R[1][0], R[1][1]);
    ctx.fillStyle = head.lost ? "#ff6b6b" : "#d8dde3";
    const t = head.translation.map((v) => (v * 100).toFixed(1)).join(", ");
    ctx.fillText(`yaw ${deg(yaw)}°  pitch ${deg(pitch)}°  roll ${deg(roll)}°`, x + 8, y + h - 26);
    ctx.fillText(`t [${t}] cm${head.lost ? "  (head lost)" : ""}`, x + 8, y + h - 10);
  }

  const palette = ["#ffb454", "#c792ea", "#7bd88f", "#6cb6ff"];

  function draw() {
    const [w, h] = resize();
    ctx.fillStyle = "#111418";
    ctx.fillRect(0, 0, w, h);
    const f = state.frame;
    const characters = f ? f.characters : [];
    const cols = 2 + characters.length;
    const pw = w / Math.max(cols, 1);
    panel(0, 0, pw, h, "performer (m)", f && f.performer ? f.performer.points : null,
      f && f.performer ? f.performer.confidence : null, null, null, "#ffffff");
    characters.forEach((c, i) => {
      const info = state.hello && state.hello.characters.find((k) => k.name === c.name);
      panel(pw * (i + 1), 0, pw, h, `${c.name}${info ? " (" + info.units + ")" : ""}`,
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

  connect();
  requestAnimationFrame(draw);
})();
