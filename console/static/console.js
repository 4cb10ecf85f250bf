// covswarm operator console: draws the state frames the server pushes over /ws and turns
// drags on S into steering requests (POST /api/steer). Plain JS and a canvas, no library:
// the console must work offline. World units are metres (y up); screen units CSS pixels.
"use strict";
(() => {
  const map = document.getElementById("map");
  const ctx = map.getContext("2d");
  const chart = document.getElementById("chart");
  const HANDLE_PX = 10; // hit radius of a handle, px
  const ROBOT_RADIUS = 0.07; // m, a Khepera IV's footprint
  const CLICK_PX = 3; // a press that moved less than this is not a drag
  const FIT = 0.5; // S's larger side fills this share of the view when centred
  const KEEP = 0.3; // following S: re-centre once its centroid is this share of the view off centre

  let state = null; // latest frame from the server
  const view = { cx: 0, cy: 0, scale: 100, ready: false }; // centre (m), px per m
  const follow = document.getElementById("follow"); // keep S in view (a manual pan stops it)
  let drag = null; // the gesture in progress
  let pending = null; // {polygon} previewed while the request is in flight
  const hooks = { frames: 0, shaded: 0, lastRequest: null, lastReply: null, roundTripMs: null }; // read by the browser tests

  // -- geometry (arrays of [x, y]) ---------------------------------------------------------
  const sub = (a, b) => [a[0] - b[0], a[1] - b[1]];
  const cross = (a, b) => a[0] * b[1] - a[1] * b[0];
  const norm = (a) => Math.hypot(a[0], a[1]);

  function area(poly) {
    let s = 0;
    for (let i = 0; i < poly.length; i++) s += cross(poly[i], poly[(i + 1) % poly.length]);
    return s / 2;
  }

  function centroid(poly) {
    const a = area(poly);
    if (Math.abs(a) < 1e-12) {
      const n = poly.length;
      return [poly.reduce((s, p) => s + p[0], 0) / n, poly.reduce((s, p) => s + p[1], 0) / n];
    }
    let x = 0, y = 0;
    for (let i = 0; i < poly.length; i++) {
      const p = poly[i], q = poly[(i + 1) % poly.length], w = cross(p, q);
      x += (p[0] + q[0]) * w;
      y += (p[1] + q[1]) * w;
    }
    return [x / (6 * a), y / (6 * a)];
  }

  // Strictly convex and simple: every turn has the same sign and they add up to one full
  // turn (a star polygon turns the same way at every vertex but winds twice).
  function isConvex(poly) {
    const n = poly.length;
    if (n < 3) return false;
    let sign = 0, turning = 0;
    for (let i = 0; i < n; i++) {
      const a = sub(poly[(i + 1) % n], poly[i]), b = sub(poly[(i + 2) % n], poly[(i + 1) % n]);
      if (norm(a) < 1e-6) return false;
      const c = cross(a, b);
      if (Math.abs(c) < 1e-12 * norm(a) * norm(b)) return false;
      if (sign === 0) sign = Math.sign(c);
      else if (Math.sign(c) !== sign) return false;
      turning += Math.atan2(c, a[0] * b[0] + a[1] * b[1]);
    }
    return Math.abs(Math.abs(turning) - 2 * Math.PI) < 1e-6;
  }

  function inside(poly, p) {
    let hit = false;
    for (let i = 0, j = poly.length - 1; i < poly.length; j = i++) {
      const a = poly[i], b = poly[j];
      if ((a[1] > p[1]) !== (b[1] > p[1]) &&
          p[0] < ((b[0] - a[0]) * (p[1] - a[1])) / (b[1] - a[1]) + a[0]) hit = !hit;
    }
    return hit;
  }

  const wrap = (a) => Math.atan2(Math.sin(a), Math.cos(a));
  const rotated = (poly, c, a) => poly.map((p) => {
    const d = sub(p, c), s = Math.sin(a), k = Math.cos(a);
    return [c[0] + k * d[0] - s * d[1], c[1] + s * d[0] + k * d[1]];
  });
  const scaled = (poly, c, f) => poly.map((p) => [c[0] + f * (p[0] - c[0]), c[1] + f * (p[1] - c[1])]);

  // -- view --------------------------------------------------------------------------------
  function size() {
    const r = map.getBoundingClientRect();
    return [r.width, r.height];
  }

  function toScreen(p) {
    const [w, h] = size();
    return [w / 2 + (p[0] - view.cx) * view.scale, h / 2 - (p[1] - view.cy) * view.scale];
  }

  function toWorld(s) {
    const [w, h] = size();
    return [view.cx + (s[0] - w / 2) / view.scale, view.cy - (s[1] - h / 2) / view.scale];
  }

  function centreOnS() {
    const poly = state && state.polygon;
    if (!poly || poly.length < 3) return false;
    const xs = poly.map((p) => p[0]), ys = poly.map((p) => p[1]);
    const [w, h] = size();
    const side = Math.max(Math.max(...xs) - Math.min(...xs), Math.max(...ys) - Math.min(...ys), 0.1);
    [view.cx, view.cy] = centroid(poly);
    view.scale = (FIT * Math.min(w, h)) / side;
    view.ready = true;
    return true;
  }

  // Following S: pan (zoom unchanged) when S's centroid drifts KEEP of the view off centre.
  function keepSInView() {
    const poly = state && state.polygon;
    if (!follow.checked || drag || !poly || poly.length < 3) return;
    const [w, h] = size(), [x, y] = toScreen(centroid(poly));
    if (Math.abs(x - w / 2) > KEEP * w || Math.abs(y - h / 2) > KEEP * h) {
      [view.cx, view.cy] = centroid(poly);
    }
  }

  // Handles of S on screen: vertices, a rotation knob above S, a scale square at the
  // bottom-right corner of S's bounding box.
  function handles(poly) {
    const c = centroid(poly);
    const radius = Math.max(...poly.map((p) => norm(sub(p, c))));
    const xs = poly.map((p) => p[0]), ys = poly.map((p) => p[1]);
    const off = 18 / view.scale;
    return {
      c,
      rotate: [c[0], c[1] + radius + 2 * off],
      scale: [Math.max(...xs) + off, Math.min(...ys) - off],
    };
  }

  // -- drawing -----------------------------------------------------------------------------
  function path(poly) {
    ctx.beginPath();
    poly.forEach((p, i) => {
      const [x, y] = toScreen(p);
      if (i === 0) ctx.moveTo(x, y);
      else ctx.lineTo(x, y);
    });
    ctx.closePath();
  }

  function grid(w, h) {
    const [x0, y1] = toWorld([0, 0]), [x1, y0] = toWorld([w, h]);
    const step = view.scale > 40 ? 1 : view.scale > 8 ? 5 : 25;
    ctx.lineWidth = 1;
    for (let x = Math.ceil(x0 / step) * step; x <= x1; x += step) {
      ctx.strokeStyle = x === 0 ? "#ccc" : "#eee";
      const [sx] = toScreen([x, 0]);
      ctx.beginPath(); ctx.moveTo(sx, 0); ctx.lineTo(sx, h); ctx.stroke();
    }
    for (let y = Math.ceil(y0 / step) * step; y <= y1; y += step) {
      ctx.strokeStyle = y === 0 ? "#ccc" : "#eee";
      const [, sy] = toScreen([0, y]);
      ctx.beginPath(); ctx.moveTo(0, sy); ctx.lineTo(w, sy); ctx.stroke();
    }
    ctx.fillStyle = "#999";
    ctx.font = "11px system-ui, sans-serif";
    ctx.fillText(`grid ${step} m`, 8, h - 8);
  }

  function errorColour(e) {
    if (e === null) return "#888";
    const u = Math.min(1, e / 0.2); // 0 m: green, >= 0.2 m: red
    return `hsl(${Math.round(120 * (1 - u))}, 70%, 40%)`;
  }

  // The density phi inside S, shaded darker where it is higher (state.density: see
  // console.model's snapshot). A coarse image stretched over S's bounding box (smoothed by
  // the canvas, so no seams): the bumps are smooth, and this runs per frame.
  const SHADE_CELLS = 48;
  const shade = document.createElement("canvas");
  shade.width = shade.height = SHADE_CELLS;
  const shadeCtx = shade.getContext("2d");
  function shadeDensity(poly, density) {
    const xs = poly.map((p) => p[0]), ys = poly.map((p) => p[1]);
    const x0 = Math.min(...xs), y1 = Math.max(...ys);
    const dx = (Math.max(...xs) - x0) / SHADE_CELLS, dy = (y1 - Math.min(...ys)) / SHADE_CELLS;
    const peak = density.bumps.reduce((sum, b) => sum + Math.max(b.weight, 0), 0);
    if (!(peak > 0)) return;
    const image = shadeCtx.createImageData(SHADE_CELLS, SHADE_CELLS);
    for (let row = 0; row < SHADE_CELLS; row++) { // row 0 at the top: highest y
      for (let col = 0; col < SHADE_CELLS; col++) {
        const qx = x0 + (col + 0.5) * dx, qy = y1 - (row + 0.5) * dy;
        let above = 0; // phi - floor
        for (const b of density.bumps) {
          const ux = qx - b.mean[0], uy = qy - b.mean[1], [[a, c], [, d]] = b.precision;
          above += b.weight * Math.exp(-0.5 * (a * ux * ux + 2 * c * ux * uy + d * uy * uy));
        }
        const k = 4 * (row * SHADE_CELLS + col);
        image.data.set([230, 120, 20, Math.round(115 * Math.min(Math.max(above / peak, 0), 1))], k);
      }
    }
    shadeCtx.putImageData(image, 0, 0);
    const [sx, sy] = toScreen([x0, y1]);
    ctx.save();
    path(poly);
    ctx.clip();
    ctx.imageSmoothingEnabled = true;
    ctx.drawImage(shade, sx, sy, SHADE_CELLS * dx * view.scale, SHADE_CELLS * dy * view.scale);
    ctx.restore();
    hooks.shaded += 1;
  }

  function draw() {
    const dpr = window.devicePixelRatio || 1;
    const [w, h] = size();
    if (map.width !== Math.round(w * dpr) || map.height !== Math.round(h * dpr)) {
      map.width = Math.round(w * dpr);
      map.height = Math.round(h * dpr);
    }
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.clearRect(0, 0, w, h);
    grid(w, h);
    if (!state) return;
    const poly = state.polygon;
    const robots = state.robots || [];
    if (state.density && poly.length >= 3) shadeDensity(poly, state.density);
    ctx.lineWidth = 1;
    ctx.strokeStyle = "#a9b8c8";
    for (const r of robots) if (r.cell && r.cell.length >= 3) { path(r.cell); ctx.stroke(); }
    if (poly.length >= 3) {
      path(poly);
      ctx.fillStyle = "rgba(70, 130, 180, 0.07)";
      ctx.fill();
      ctx.lineWidth = 2.5;
      ctx.strokeStyle = "steelblue";
      ctx.stroke();
    }
    const radius = Math.max(ROBOT_RADIUS * view.scale, 3);
    for (const r of robots) {
      const [x, y] = toScreen([r.x, r.y]);
      ctx.beginPath();
      ctx.arc(x, y, radius, 0, 2 * Math.PI);
      ctx.fillStyle = errorColour(r.error);
      ctx.fill();
      ctx.beginPath();
      ctx.moveTo(x, y);
      ctx.lineTo(x + radius * 1.6 * Math.cos(r.theta), y - radius * 1.6 * Math.sin(r.theta));
      ctx.lineWidth = Math.max(1.5, radius / 4);
      ctx.strokeStyle = "#222";
      ctx.stroke();
      if (robots.length <= 30 && radius >= 6) {
        ctx.fillStyle = "#222";
        ctx.font = "10px system-ui, sans-serif";
        ctx.fillText(String(r.id), x + radius + 2, y - radius - 2);
      }
    }
    if (poly.length >= 3) drawHandles(poly);
    const preview = (drag && drag.ghost) || (pending && pending.polygon);
    if (preview) {
      path(preview);
      ctx.setLineDash([7, 5]);
      ctx.lineWidth = 2;
      ctx.strokeStyle = drag && drag.clamped ? "#c0392b" : "#e67e22";
      ctx.stroke();
      ctx.setLineDash([]);
    }
    document.body.dataset.robotsDrawn = String(robots.length);
    document.getElementById("robots-drawn").textContent = String(robots.length);
  }

  function drawHandles(poly) {
    const hd = handles(poly);
    ctx.lineWidth = 1.5;
    ctx.strokeStyle = "steelblue";
    ctx.fillStyle = "#fff";
    for (const p of poly) {
      const [x, y] = toScreen(p);
      ctx.beginPath(); ctx.arc(x, y, 5, 0, 2 * Math.PI); ctx.fill(); ctx.stroke();
    }
    const [cx, cy] = toScreen(hd.c), [rx, ry] = toScreen(hd.rotate), [sx, sy] = toScreen(hd.scale);
    ctx.setLineDash([3, 3]);
    ctx.beginPath(); ctx.moveTo(cx, cy); ctx.lineTo(rx, ry); ctx.stroke();
    ctx.setLineDash([]);
    ctx.beginPath(); ctx.arc(rx, ry, 7, 0, 2 * Math.PI); ctx.fill(); ctx.stroke();
    ctx.fillRect(sx - 6, sy - 6, 12, 12);
    ctx.strokeRect(sx - 6, sy - 6, 12, 12);
    ctx.beginPath(); ctx.arc(cx, cy, 2, 0, 2 * Math.PI); ctx.fillStyle = "steelblue"; ctx.fill();
  }

  function drawChart() {
    const c = chart.getContext("2d");
    const w = chart.width, h = chart.height, pad = 4;
    c.clearRect(0, 0, w, h);
    const history = (state && state.error_history) || [];
    if (history.length < 2) {
      c.fillStyle = "#999";
      c.font = "11px system-ui, sans-serif";
      c.fillText("no e_a yet (mission not running)", 8, h / 2);
      return;
    }
    const tEnd = history[history.length - 1][0], tStart = tEnd - 60;
    const top = Math.max(...history.map((p) => p[1]), 1e-3) * 1.1;
    const X = (t) => pad + ((t - tStart) / 60) * (w - 2 * pad);
    const Y = (e) => h - pad - (e / top) * (h - 2 * pad - 12);
    c.beginPath();
    history.forEach(([t, e], i) => (i ? c.lineTo(X(t), Y(e)) : c.moveTo(X(t), Y(e))));
    c.strokeStyle = "steelblue";
    c.lineWidth = 1.5;
    c.stroke();
    c.fillStyle = "#666";
    c.font = "10px system-ui, sans-serif";
    c.fillText(`${top.toFixed(3)} m`, pad + 2, 11);
    c.fillText("−60 s", pad + 2, h - pad - 2);
    c.fillText("now", w - 26, h - pad - 2);
  }

  function text(id, value) {
    document.getElementById(id).textContent = value;
  }

  function panels() {
    const s = state;
    text("swarm", s.swarm);
    text("state", s.state);
    text("mission-time", s.t === null ? "–" : s.t.toFixed(1));
    text("error", s.error === null ? "–" : s.error.toFixed(4));
    text("alive-agents", s.alive.agents);
    text("alive-robots", s.alive.robots);
    text("alive-coordinator", s.alive.coordinator ? "up" : "down");
    const list = document.getElementById("steer-log");
    const recent = (s.steering || []).slice(-6).reverse();
    const signature = JSON.stringify(recent.map((o) => o.wall));
    if (list.dataset.signature !== signature) {
      list.dataset.signature = signature;
      list.replaceChildren(...recent.map((o) => {
        const li = document.createElement("li");
        const when = new Date(o.wall * 1000).toLocaleTimeString();
        li.textContent = `${when} ${o.what}: ${o.accepted ? "accepted" : "refused: " + o.reason}`;
        li.className = o.accepted ? "accepted" : "refused";
        return li;
      }));
    }
  }

  // -- steering ----------------------------------------------------------------------------
  function showResult(cls, message) {
    const p = document.getElementById("steer-result");
    p.className = cls;
    p.textContent = message;
  }

  async function steer(request, preview) {
    pending = preview ? { polygon: preview } : null;
    showResult("pending", `sending ${request.kind}…`);
    const sent = performance.now();
    hooks.lastRequest = request;
    let reply;
    try {
      const response = await fetch("/api/steer", {
        method: "POST",
        headers: { "Content-Type": "application/json" },
        body: JSON.stringify(request),
        credentials: "same-origin",
      });
      reply = await response.json();
      if (reply.accepted === undefined) reply = { accepted: false, reason: reply.error || `HTTP ${response.status}` };
    } catch (err) {
      reply = { accepted: false, reason: `console unreachable: ${err}` };
    }
    pending = null;
    hooks.roundTripMs = performance.now() - sent;
    hooks.lastReply = reply;
    if (reply.accepted) {
      const note = reply.reason ? ` (${reply.reason})` : "";
      showResult("accepted", `accepted ${request.kind}: S moves for ${Number(reply.duration).toFixed(1)} s${note}`);
    } else {
      showResult("refused", `refused: ${reply.reason}`);
    }
    draw();
    return reply;
  }

  function request(d) {
    const r = (v) => Math.round(v * 1e5) / 1e5; // 10 µm: no noise digits on the wire
    if (d.mode === "translate") return { kind: "translate", dx: r(d.delta[0]), dy: r(d.delta[1]) };
    if (d.mode === "rotate") return { kind: "rotate", angle: r(d.angle), about: d.c.map(r) };
    if (d.mode === "scale") return { kind: "scale", factor: r(d.factor), about: d.c.map(r) };
    return { kind: "polygon", polygon: d.ghost.map((p) => p.map(r)) };
  }

  // -- gestures ----------------------------------------------------------------------------
  function local(event) {
    const r = map.getBoundingClientRect();
    return [event.clientX - r.left, event.clientY - r.top];
  }

  function near(screenPoint, worldPoint) {
    return norm(sub(screenPoint, toScreen(worldPoint))) <= HANDLE_PX;
  }

  function startDrag(event) {
    const s = local(event);
    const poly = state && state.polygon && state.polygon.length >= 3 ? state.polygon.map((p) => p.slice()) : null;
    const base = { start: s, world: toWorld(s), poly, moved: false };
    if (!poly) return { ...base, mode: "pan", view: { ...view } };
    const hd = handles(poly);
    const vertex = poly.findIndex((p) => near(s, p));
    if (vertex >= 0) return { ...base, mode: "vertex", vertex, c: hd.c };
    if (near(s, hd.rotate)) return { ...base, mode: "rotate", c: hd.c, angle: 0, last: Math.atan2(...sub(toWorld(s), hd.c).reverse()) };
    if (near(s, hd.scale)) return { ...base, mode: "scale", c: hd.c, factor: 1, reach: norm(sub(toWorld(s), hd.c)) };
    if (inside(poly, toWorld(s))) return { ...base, mode: "translate", delta: [0, 0] };
    return { ...base, mode: "pan", view: { ...view } };
  }

  function moveDrag(d, s) {
    if (norm(sub(s, d.start)) >= CLICK_PX) d.moved = true;
    const m = toWorld(s);
    if (d.mode === "pan") {
      if (d.moved) follow.checked = false;
      view.cx = d.view.cx - (s[0] - d.start[0]) / view.scale;
      view.cy = d.view.cy + (s[1] - d.start[1]) / view.scale;
    } else if (d.mode === "translate") {
      d.delta = sub(m, d.world);
      d.ghost = d.poly.map((p) => [p[0] + d.delta[0], p[1] + d.delta[1]]);
    } else if (d.mode === "rotate") {
      const now = Math.atan2(...sub(m, d.c).reverse());
      d.angle += wrap(now - d.last); // unwrapped: a drag may turn S more than half a turn
      d.last = now;
      d.ghost = rotated(d.poly, d.c, d.angle);
    } else if (d.mode === "scale") {
      d.factor = Math.min(20, Math.max(0.05, norm(sub(m, d.c)) / Math.max(d.reach, 1e-9)));
      d.ghost = scaled(d.poly, d.c, d.factor);
    } else if (d.mode === "vertex") {
      const candidate = d.poly.map((p) => p.slice());
      candidate[d.vertex] = m;
      // Keep S convex: a vertex dragged too far stays at its last convex position.
      if (isConvex(candidate)) {
        d.ghost = candidate;
        d.clamped = false;
      } else {
        d.clamped = true;
        if (!d.ghost) d.ghost = d.poly;
      }
    }
  }

  map.addEventListener("pointerdown", (event) => {
    if (event.button !== 0) return;
    map.setPointerCapture(event.pointerId);
    drag = startDrag(event);
    map.style.cursor = drag.mode === "pan" ? "grabbing" : "move";
  });

  map.addEventListener("pointermove", (event) => {
    if (drag) {
      moveDrag(drag, local(event));
      draw();
      return;
    }
    if (!state || !state.polygon || state.polygon.length < 3) return;
    const s = local(event), poly = state.polygon, hd = handles(poly);
    map.style.cursor = poly.some((p) => near(s, p)) || near(s, hd.rotate) || near(s, hd.scale)
      ? "pointer" : inside(poly, toWorld(s)) ? "move" : "default";
  });

  map.addEventListener("pointerup", (event) => {
    const d = drag;
    drag = null;
    map.style.cursor = "default";
    if (!d) return;
    moveDrag(d, local(event));
    if (d.mode !== "pan" && d.moved && d.ghost) steer(request(d), d.ghost);
    draw();
  });

  map.addEventListener("pointercancel", () => { drag = null; draw(); });
  window.addEventListener("keydown", (event) => {
    if (event.key === "Escape" && drag) { drag = null; draw(); }
  });
  map.addEventListener("dblclick", () => { centreOnS(); follow.checked = true; draw(); });
  map.addEventListener("wheel", (event) => {
    event.preventDefault();
    const s = local(event), before = toWorld(s);
    view.scale = Math.min(5000, Math.max(2, view.scale * Math.exp(-event.deltaY * 0.0015)));
    const after = toWorld(s);
    view.cx += before[0] - after[0];
    view.cy += before[1] - after[1];
    draw();
  }, { passive: false });
  window.addEventListener("resize", draw);

  // -- state stream ------------------------------------------------------------------------
  function connect() {
    const scheme = location.protocol === "https:" ? "wss:" : "ws:";
    const ws = new WebSocket(`${scheme}//${location.host}/ws`);
    ws.onopen = () => text("link", "live");
    ws.onmessage = (event) => {
      state = JSON.parse(event.data);
      hooks.frames += 1;
      if (!view.ready) centreOnS();
      keepSInView();
      panels();
      draw();
      drawChart();
    };
    ws.onclose = () => {
      text("link", "lost: reconnecting…");
      setTimeout(connect, 1000);
    };
  }

  window.covswarm = {
    hooks,
    state: () => state,
    view: () => ({ ...view }),
    // Page (client) coordinates of a world point: what a test points the mouse at.
    clientXY: (x, y) => {
      const r = map.getBoundingClientRect(), s = toScreen([x, y]);
      return [r.left + s[0], r.top + s[1]];
    },
    handles: () => (state && state.polygon.length >= 3 ? handles(state.polygon) : null),
    steer,
    isConvex,
  };
  draw();
  connect();
})();
