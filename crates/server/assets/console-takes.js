// mouthpiece booth console, part two: the take player (image, dots and sound of a recorded
// take, fetched in chunks from /take) and the paint check (tune-colours run by the daemon).
// Shares window.mouthpiece with console.js; no build step, no dependencies.
"use strict";

(function () {
  const m = window.mouthpiece;
  const el = (id) => document.getElementById(id);
  const DOT_COLOURS = { tracked: "#3ddc84", predicted: "#ffd23f", lost: "#ff4d4d" };
  const CHUNK_SECONDS = 4;
  // Fetch the next chunk when less than this is buffered ahead of the playhead, seconds.
  const AHEAD_SECONDS = 3;

  // What the player did (tests read it through window.mouthpiece.player).
  const player = {
    file: null, playing: false, ended: false, error: null, notes: [],
    chunks: 0, framesShown: 0, lastT: null, dotsDrawn: 0, audio: [], clock: "none",
  };
  m.player = player;

  let session = 0;          // bumped on every play/close: late answers of an old run are dropped
  let frames = [];          // {t, blob, dots} of the buffered chunks, in time order
  let width = 0, height = 0;
  let fetchedTo = 0, fetching = false, lastChunk = false;
  let ctx = null, base = 0, usesAudioClock = false;
  let shownIndex = -1, decoding = false;

  const canvas = el("player-canvas");
  const pctx = canvas.getContext("2d");

  function now() {
    return usesAudioClock ? ctx.currentTime - base : performance.now() / 1000 - base;
  }

  function parseChunk(buffer) {
    const dv = new DataView(buffer);
    const magic = String.fromCharCode(dv.getUint8(0), dv.getUint8(1), dv.getUint8(2), dv.getUint8(3));
    if (magic !== "MPT1") throw new Error("not a take chunk");
    const len = dv.getUint32(4, true);
    const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 8, len)));
    const data = 8 + len;
    const slice = ([offset, length]) => new Uint8Array(buffer, data + offset, length);
    return { header, slice };
  }

  async function fetchChunk(run) {
    fetching = true;
    try {
      const q = new URLSearchParams({ file: player.file, from: fetchedTo.toFixed(3), seconds: String(CHUNK_SECONDS) });
      if (m.token) q.set("token", m.token);
      const r = await fetch(`/take?${q}`);
      if (!r.ok) throw new Error(`${r.status}: ${(await r.text()).trim()}`);
      const { header, slice } = parseChunk(await r.arrayBuffer());
      if (run !== session) return;
      width = header.width; height = header.height;
      for (const f of header.frames) {
        frames.push({ t: f.t, blob: new Blob([slice(f.image)], { type: "image/jpeg" }), dots: f.dots });
      }
      for (const n of header.notes || []) if (!player.notes.includes(n)) player.notes.push(n);
      if (header.audio) scheduleAudio(header.audio, slice(header.audio.data));
      player.chunks += 1;
      lastChunk = header.end;
      // A chunk that could not move on (nothing in it) ends the take too.
      fetchedTo = header.next_s > fetchedTo ? header.next_s : (lastChunk = true, fetchedTo);
      el("player-note").textContent = player.notes.join(" · ");
    } catch (e) {
      if (run !== session) return;
      player.error = String(e.message || e);
      el("player-note").textContent = `cannot play: ${player.error}`;
      lastChunk = true;
    } finally {
      if (run === session) fetching = false;
    }
  }

  // The sound of a chunk, at its place on the playhead's clock.
  function scheduleAudio(a, bytes) {
    const channels = a.channels, samples = Math.floor(bytes.byteLength / 2 / channels);
    const pcm = new DataView(bytes.buffer, bytes.byteOffset, samples * channels * 2);
    let sum = 0;
    const entry = { start_s: a.start_s, sample_rate: a.sample_rate, channels, samples, sum: 0, scheduled: false };
    if (ctx && samples > 0) {
      const buffer = ctx.createBuffer(channels, samples, a.sample_rate);
      for (let c = 0; c < channels; c++) {
        const out = buffer.getChannelData(c);
        for (let i = 0; i < samples; i++) {
          const v = pcm.getInt16((i * channels + c) * 2, true);
          out[i] = v / 32768;
          sum += Math.abs(v);
        }
      }
      const source = ctx.createBufferSource();
      source.buffer = buffer;
      source.connect(ctx.destination);
      const delay = a.start_s - now();
      if (delay >= 0) source.start(ctx.currentTime + delay);
      else if (-delay < buffer.duration) source.start(ctx.currentTime, -delay);
      entry.scheduled = true;
    }
    entry.sum = sum;
    player.audio.push(entry);
  }

  function draw(bitmap, f) {
    const dpr = window.devicePixelRatio || 1;
    const w = Math.round(canvas.clientWidth * dpr), h = Math.round(canvas.clientHeight * dpr);
    if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
    const scale = Math.min(w / width, h / height);
    const ox = (w - width * scale) / 2, oy = (h - height * scale) / 2;
    pctx.fillStyle = "#000";
    pctx.fillRect(0, 0, w, h);
    pctx.drawImage(bitmap, ox, oy, width * scale, height * scale);
    const r = 3 * dpr;
    for (const d of f.dots) {
      pctx.beginPath();
      pctx.arc(ox + d.x * scale, oy + d.y * scale, r, 0, 2 * Math.PI);
      pctx.fillStyle = DOT_COLOURS[d.state] || "#ffffff";
      pctx.fill();
    }
    player.toCanvas = (x, y) => [ox + x * scale, oy + y * scale];
    player.shownDots = f.dots;
    player.framesShown += 1;
    player.lastT = f.t;
    player.dotsDrawn += f.dots.length;
  }

  function tick(run) {
    if (run !== session || !player.playing) return;
    const t = now();
    // The newest frame at or before the playhead.
    let i = shownIndex;
    while (i + 1 < frames.length && frames[i + 1].t <= t) i++;
    if (i > shownIndex && !decoding) {
      const f = frames[i];
      decoding = true;
      createImageBitmap(f.blob).then((bitmap) => {
        decoding = false;
        if (run !== session) { bitmap.close(); return; }
        draw(bitmap, f);
        bitmap.close();
      }).catch((e) => { decoding = false; player.error = String(e); });
      // Frames already shown are let go.
      frames.splice(0, i);
      shownIndex = 0;
    }
    el("player-time").textContent = `${Math.max(0, t).toFixed(1)} s`;
    if (!fetching && !lastChunk && fetchedTo - t < AHEAD_SECONDS) fetchChunk(run);
    // Ended once the last picture is on screen, not while it is still being decoded.
    const done = lastChunk && !fetching && !decoding && (frames.length === 0 || (shownIndex === frames.length - 1 && t > frames[frames.length - 1].t));
    if (done) {
      player.playing = false;
      player.ended = true;
      el("player-time").textContent += " · end";
      return;
    }
    requestAnimationFrame(() => tick(run));
  }

  function play(file, title) {
    close();
    const run = ++session;
    Object.assign(player, { file, playing: true, ended: false, error: null, notes: [], chunks: 0,
      framesShown: 0, lastT: null, dotsDrawn: 0, audio: [] });
    frames = []; fetchedTo = 0; lastChunk = false; fetching = false; shownIndex = -1; decoding = false;
    const AC = window.AudioContext || window.webkitAudioContext;
    try { ctx = AC ? new AC() : null; } catch (e) { ctx = null; }
    if (ctx && ctx.state === "suspended") ctx.resume().catch(() => {});
    // The sound's clock drives the pictures when it runs; otherwise the page's clock.
    usesAudioClock = !!ctx && ctx.state === "running";
    player.clock = usesAudioClock ? "audio" : "page";
    el("player").hidden = false;
    el("player-title").textContent = title;
    el("player-note").textContent = "";
    fetchChunk(run).then(() => {
      if (run !== session) return;
      // Start the clock once the first chunk is in.
      base = usesAudioClock ? ctx.currentTime : performance.now() / 1000;
      requestAnimationFrame(() => tick(run));
    });
  }

  function close() {
    session += 1;
    player.playing = false;
    frames = [];
    if (ctx) { ctx.close().catch(() => {}); ctx = null; }
  }

  el("takes").addEventListener("click", (e) => {
    const b = e.target.closest && e.target.closest("button.play");
    if (!b) return;
    // The server wants the file's name only; the takes list gives it with its folder.
    const name = b.dataset.file.split(/[\\/]/).pop();
    play(name, b.parentElement.textContent.replace("▶ Play", "").split("·")[0].trim());
  });
  el("player-stop").addEventListener("click", () => { close(); el("player").hidden = true; });
  m.playTake = play;

  // ---- the paint check ---------------------------------------------------------------------

  const esc = (t) => String(t).replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" }[c]));
  const ranges = (r) => r.map(([a, b]) => `${a}–${b}`).join(", ");

  function rows(which, found) {
    return found.classes.map((c) =>
      `<tr><td>${which}</td><td>${esc(c.name)} (${esc(c.role)})</td><td>${ranges(c.hue)}</td>` +
      `<td>${c.saturation[0]}–${c.saturation[1]}</td><td>${c.value[0]}–${c.value[1]}</td>` +
      `<td>${c.per_frame.toFixed(1)}</td></tr>`).join("");
  }

  function total(which, found) {
    return `${which}: ${found.per_frame.toFixed(1)} of ${found.dots} dots per frame (${(found.share * 100).toFixed(0)} %)`;
  }

  function showTune(status) {
    const t = status.tune;
    if (!t) return;
    m.tuneReport = t;
    el("tune-say").textContent = t.message;
    el("tune-run").disabled = t.state === "sampling";
    let html = "";
    if (t.in_use || t.proposed) {
      html += "<table><tr><th></th><th>class</th><th>hue</th><th>saturation</th><th>value</th><th>dots / frame</th></tr>";
      if (t.in_use) html += rows("in use", t.in_use);
      if (t.proposed) html += rows("proposed", t.proposed);
      html += "</table>";
      html += `<div id="tune-totals">${t.in_use ? esc(total("in use", t.in_use)) : ""}` +
        `${t.proposed ? "<br>" + esc(total("proposed", t.proposed)) : ""}</div>`;
    }
    if (t.offered) {
      html += '<div class="row" style="margin-top:6px"><button id="tune-apply">Apply the proposed ranges</button></div>';
    } else if (t.proposed && t.state === "done") {
      html += '<div class="bad" id="tune-refused">Not offered: the proposed ranges find fewer dots than the ranges in use.</div>';
    }
    if (t.toml) html += `<details><summary>as [[detect.class]]</summary><pre>${esc(t.toml)}</pre></details>`;
    el("tune-result").innerHTML = html;
    const apply = el("tune-apply");
    if (apply) apply.addEventListener("click", () => m.request({ type: "tune_colours", action: "apply" }, "tune"));
  }

  m.statusHooks.push(showTune);
  el("tune-run").addEventListener("click", () => {
    el("tune-say").textContent = "asking…";
    m.request({ type: "tune_colours", action: "run" }, "tune");
  });
})();
