// covswarm operator console: draws the state frames the server pushes over /ws and the arena
// (GET /api/world: workspace, obstacles, and the map's picture, GET /api/map.png), turns drags on S into steering requests and clicks
// in "Go to" mode into goto requests (POST /api/steer). A drag whose S would touch an
// obstacle or leave the workspace is drawn red and refused here (the coordinator checks every
// request again). Plain JS and a canvas, no library: the console must work offline. World
// units are metres (y up); screen units CSS pixels.
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
  let world = null; // the arena (GET /api/world), null before the coordinator sends one
  let worldFetching = false;
  let mapPicture = null; // the map's picture (GET /api/map.png) once loaded, for world.map
  let gotoMode = false; // "Go to": the next click on the map sends S's centroid there
  let pointer = null; // last pointer position on the map (px), for the goto preview
  const view = { cx: 0, cy: 0, scale: 100, ready: false, moved: false }; // centre (m), px per m; moved: by the operator
  const follow = document.getElementById("follow"); // keep S in view (a manual pan stops it)
  let drag = null; // the gesture in progress
  let pending = null; // {polygon} previewed while the request is in flight
  const hooks = { frames: 0, shaded: 0, lastRequest: null, lastReply: null, roundTripMs: null, dragContact: null }; // read by the browser tests

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

  // Convex hull (Andrew's monotone chain), CCW.
  function hull(points) {
    const p = points.slice().sort((a, b) => a[0] - b[0] || a[1] - b[1]);
    if (p.length < 3) return p;
    const half = (list) => {
      const out = [];
      for (const q of list) {
        while (out.length >= 2 && cross(sub(out[out.length - 1], out[out.length - 2]), sub(q, out[out.length - 1])) <= 0) out.pop();
        out.push(q);
      }
      out.pop();
      return out;
    };
    return half(p).concat(half(p.slice().reverse()));
  }

  // Whether two convex polygons overlap or touch (separating axis theorem: convex shapes are
  // apart exactly when some edge normal of one of them separates their projections).
  function touches(a, b) {
    for (const poly of [a, b]) {
      for (let i = 0; i < poly.length; i++) {
        const e = sub(poly[(i + 1) % poly.length], poly[i]), n = [-e[1], e[0]];
        const pa = a.map((p) => p[0] * n[0] + p[1] * n[1]), pb = b.map((p) => p[0] * n[0] + p[1] * n[1]);
        if (Math.max(...pa) < Math.min(...pb) || Math.max(...pb) < Math.min(...pa)) return false;
      }
    }
    return true;
  }

  // What a convex S touches, as covswarm.world.model.World.contact says it: the first
  // obstacle (in the world's order) it overlaps or touches, else "workspace" if a vertex is
  // outside the workspace box, else null.
  function contact(poly) {
    if (!world) return null;
    for (const o of world.obstacles) if (touches(poly, o.polygon)) return o.name;
    const w = world.workspace;
    if (w && poly.some(([x, y]) => x < w[0] || x > w[1] || y < w[2] || y > w[3])) return "workspace";
    return null;
  }

  // What S touches on its way from the drag's start to its ghost. A translation sweeps
  // exactly the hull of S's start and end; a scaling about a point inside S and a vertex
  // moved along a line stay within that hull too (so the check is exact or errs on the safe
  // side). A rotation is checked as the hulls of S at steps of at most 5 degrees, which
  // miss the arcs' bulge by under r (1 - cos 2.5 deg) ~ 1 mm per metre of S's radius.
  function sweepContact(d) {
    if (d.mode === "rotate") {
      const steps = Math.max(1, Math.ceil(Math.abs(d.angle) / (Math.PI / 36)));
      let before = d.poly;
      for (let k = 1; k <= steps; k++) {
        const next = rotated(d.poly, d.c, (d.angle * k) / steps);
        const hit = contact(hull(before.concat(next)));
        if (hit) return hit;
        before = next;
      }
      return null;
    }
    return contact(hull(d.poly.concat(d.ghost)));
  }

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

  // The arena in view (once, when it arrives), S kept in view by following it.
  function fitWorld() {
    const w = world && world.workspace;
    if (view.moved) return;
    if (!w) { centreOnS(); return; }
    const [sw, sh] = size();
    view.cx = (w[0] + w[1]) / 2;
    view.cy = (w[2] + w[3]) / 2;
    view.scale = 0.95 * Math.min(sw / (w[1] - w[0]), sh / (w[3] - w[2]));
    view.ready = true;
  }

  // Following S: pan (zoom unchanged) when S's centroid drifts KEEP of the view off centre.
  function keepSInView() {
    const poly = state && state.polygon;
    if (!follow.checked || drag || !poly || poly.length < 3) return;
    const [w, h] = size(), [x, y] = toScreen(centroid(poly));
    const keep = world && world.workspace ? 0.45 : KEEP; // the arena in view: only when S leaves it
    if (Math.abs(x - w / 2) > keep * w || Math.abs(y - h / 2) > keep * h) {
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

  // The map's picture (world.map: origin = its lower-left corner, m; resolution, m per
  // pixel; row 0 of the image is the top, the largest y), pixels kept sharp.
  function drawMapPicture() {
    const m = world && world.map;
    if (!m || !mapPicture || mapPicture.version !== world.version) return false;
    const [x0, y0] = toScreen([m.origin[0], m.origin[1] + m.height * m.resolution]);
    const side = m.resolution * view.scale;
    ctx.save();
    ctx.imageSmoothingEnabled = false;
    ctx.globalAlpha = 0.8;
    ctx.drawImage(mapPicture.image, x0, y0, m.width * side, m.height * side);
    ctx.restore();
    return true;
  }

  // The workspace (outside it shaded), the map's picture, the obstacles (filled, lighter
  // over a map's picture so that it shows through; named when they fit on screen).
  function drawArena(w, h) {
    const box = world && world.workspace;
    if (box) {
      const [x0, y0] = toScreen([box[0], box[3]]), [x1, y1] = toScreen([box[1], box[2]]);
      ctx.fillStyle = "#eceff1";
      ctx.fillRect(0, 0, w, h);
      ctx.clearRect(x0, y0, x1 - x0, y1 - y0);
    }
    const pictured = drawMapPicture();
    if (pictured) document.body.dataset.mapDrawn = String(world.version);
    else delete document.body.dataset.mapDrawn;
    grid(w, h);
    if (!world) return;
    if (box) {
      const [x0, y0] = toScreen([box[0], box[3]]), [x1, y1] = toScreen([box[1], box[2]]);
      ctx.lineWidth = 2;
      ctx.strokeStyle = "#455a64";
      ctx.strokeRect(x0, y0, x1 - x0, y1 - y0);
    }
    ctx.lineWidth = 1;
    ctx.fillStyle = pictured ? "rgba(154, 165, 173, 0.45)" : "#9aa5ad";
    ctx.strokeStyle = "#4f5b62";
    for (const o of world.obstacles) { path(o.polygon); ctx.fill(); ctx.stroke(); }
    if (world.obstacles.length <= 60) {
      ctx.fillStyle = "#1f2a30";
      ctx.font = "11px system-ui, sans-serif";
      ctx.textAlign = "center";
      for (const o of world.obstacles) {
        const xs = o.polygon.map((p) => toScreen(p)[0]), ys = o.polygon.map((p) => toScreen(p)[1]);
        const [cx, cy] = toScreen(centroid(o.polygon));
        if (Math.max(...xs) - Math.min(...xs) > ctx.measureText(o.name).width + 4 && Math.max(...ys) - Math.min(...ys) > 14) {
          ctx.fillText(o.name, cx, cy + 4);
        }
      }
      ctx.textAlign = "start";
    }
    document.body.dataset.obstaclesDrawn = String(world.obstacles.length);
  }

  // The route S follows (a goto from this page or any other client): S's centroid's stops
  // joined, a dot at each, and S's outline there (its shape at the start scaled by the
  // stop's scale, S shrinks for doors, and turned by its angle when the stop has one).
  function drawRoute(route) {
    if (route.shape && route.shape.length >= 3) {
      ctx.setLineDash([2, 4]);
      ctx.lineWidth = 1;
      ctx.strokeStyle = "rgba(142, 68, 173, 0.6)";
      for (const [x, y, s, a = 0] of route.waypoints) {
        const k = Math.cos(a), n = Math.sin(a);
        path(route.shape.map((p) => [x + s * (k * p[0] - n * p[1]), y + s * (n * p[0] + k * p[1])]));
        ctx.stroke();
      }
      ctx.setLineDash([]);
    }
    const points = route.waypoints.map(toScreen);
    ctx.beginPath();
    points.forEach(([x, y], i) => (i ? ctx.lineTo(x, y) : ctx.moveTo(x, y)));
    ctx.lineWidth = 2;
    ctx.strokeStyle = "#8e44ad";
    ctx.stroke();
    ctx.fillStyle = "#8e44ad";
    for (const [x, y] of points) { ctx.beginPath(); ctx.arc(x, y, 4, 0, 2 * Math.PI); ctx.fill(); }
    const [gx, gy] = toScreen(route.goal);
    ctx.beginPath();
    ctx.moveTo(gx - 7, gy - 7); ctx.lineTo(gx + 7, gy + 7); ctx.moveTo(gx - 7, gy + 7); ctx.lineTo(gx + 7, gy - 7);
    ctx.stroke();
    document.body.dataset.routePoints = String(points.length);
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
    drawArena(w, h);
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
    if (state.route) drawRoute(state.route);
    else delete document.body.dataset.routePoints;
    if (poly.length >= 3 && !gotoMode && steerable()) drawHandles(poly);
    let preview = (drag && drag.ghost) || (pending && pending.polygon), blocked = Boolean(drag && drag.hit);
    if (!preview && gotoMode && pointer && poly.length >= 3) {
      const c = centroid(poly), goal = toWorld(pointer);
      preview = poly.map((p) => [p[0] + goal[0] - c[0], p[1] + goal[1] - c[1]]);
      blocked = Boolean(contact(preview)); // S would not fit there (the planner refuses it)
    }
    if (preview) {
      path(preview);
      if (blocked) {
        ctx.fillStyle = "rgba(192, 57, 43, 0.25)";
        ctx.fill();
      }
      ctx.setLineDash([7, 5]);
      ctx.lineWidth = 2;
      ctx.strokeStyle = blocked || (drag && drag.clamped) ? "#c0392b" : "#e67e22";
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
      const via = reply.route ? ` via ${reply.route.length} waypoints` : "";
      showResult("accepted", `accepted ${request.kind}: S moves for ${Number(reply.duration).toFixed(1)} s${via}${note}`);
      if (request.kind === "goto" && reply.route && state) state.route = { goal: request.goal, waypoints: reply.route, shape: [] };
    } else {
      showResult("refused", `refused: ${reply.reason}`);
    }
    draw();
    return reply;
  }

  const r = (v) => Math.round(v * 1e5) / 1e5; // 10 µm: no noise digits on the wire

  // A drag whose S would touch something is not sent: the page says why, as the
  // coordinator would (its refusal reason "obstacle: ...").
  function refuseHere(req, hit) {
    // Worded as the coordinator's refusal (coordinator.steering), without its time.
    const reason = hit === "workspace" ? "outside-workspace: S would leave the workspace" : `obstacle: S would touch obstacle '${hit}'`;
    hooks.lastRequest = req;
    hooks.lastReply = { accepted: false, reason, local: true };
    showResult("refused", `refused: ${reason} (checked by the console, not sent)`);
  }

  function setGoto(on) {
    gotoMode = on;
    const button = document.getElementById("goto");
    button.classList.toggle("active", on);
    button.setAttribute("aria-pressed", String(on));
    map.style.cursor = on ? "crosshair" : "default";
    showResult("idle", on ? "Go to: click where S's centroid should go (Esc: cancel)" : "drag S to steer the swarm");
    draw();
  }

  // Whether S is moving now, or moved since the drag took hold of it.
  function sMoved(d) {
    const speeds = (state && state.velocities) || [];
    if (speeds.some((v) => Math.hypot(v[0], v[1]) > 1e-6)) return true;
    const now = (state && state.polygon) || [];
    return now.length !== d.poly.length || now.some((p, i) => Math.hypot(p[0] - d.poly[i][0], p[1] - d.poly[i][1]) > 1e-6);
  }

  function request(d) {
    // S on its way: the coordinator brakes it before a new motion, and a relative one (move
    // by, turn by) would then start from where S stops, past where the operator grabbed
    // it (0.38 m past the drop in one run). The outline dropped is sent as it is instead.
    if (d.mode !== "vertex" && sMoved(d)) return { kind: "polygon", polygon: d.ghost.map((p) => p.map(r)) };
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

  // Whether S can be steered: a mission not over, with a coordinator to answer.
  function steerable() {
    return !!state && state.state !== "done" && !!(state.alive && state.alive.coordinator);
  }

  function startDrag(event) {
    const s = local(event);
    const poly = state && state.polygon && state.polygon.length >= 3 ? state.polygon.map((p) => p.slice()) : null;
    const base = { start: s, world: toWorld(s), poly, moved: false };
    if (poly && !steerable()) {
      showResult("idle", state.state === "done" ? "the mission is over: S is not steered any more" : "no coordinator: S cannot be steered");
    }
    if (!poly || !steerable()) return { ...base, mode: "pan", view: { ...view } };
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
      if (d.moved) { follow.checked = false; view.moved = true; }
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
        d.clamped = "S stays convex: the vertex holds its last convex position";
        if (!d.ghost) d.ghost = d.poly;
      }
    }
    if (d.mode !== "pan" && d.ghost) {
      d.hit = sweepContact(d);
      hooks.dragContact = d.hit;
      if (d.hit) showResult("refused", `S would touch ${d.hit === "workspace" ? "the workspace's wall" : d.hit}: release refuses`);
      else if (d.moved && d.clamped) showResult("pending", `${d.clamped}; release to send`);
      else if (d.moved) showResult("pending", "release to send");
    }
  }

  map.addEventListener("pointerdown", (event) => {
    if (event.button !== 0) return;
    map.setPointerCapture(event.pointerId);
    if (gotoMode) {
      drag = { mode: "goto", start: local(event), moved: false };
      return;
    }
    drag = startDrag(event);
    map.style.cursor = drag.mode === "pan" ? "grabbing" : "move";
  });

  map.addEventListener("pointermove", (event) => {
    pointer = local(event);
    if (drag && drag.mode === "goto") {
      if (norm(sub(pointer, drag.start)) >= CLICK_PX) drag.moved = true;
      return;
    }
    if (drag) {
      moveDrag(drag, local(event));
      draw();
      return;
    }
    const here = toWorld(pointer);
    const over = world && world.obstacles.find((o) => inside(o.polygon, here));
    map.title = over ? over.name : "";
    document.getElementById("hover").textContent = over ? over.name : "–";
    if (gotoMode) { draw(); return; }
    if (!state || !state.polygon || state.polygon.length < 3 || !steerable()) { map.style.cursor = "default"; return; }
    const s = local(event), poly = state.polygon, hd = handles(poly);
    map.style.cursor = poly.some((p) => near(s, p)) || near(s, hd.rotate) || near(s, hd.scale)
      ? "pointer" : inside(poly, toWorld(s)) ? "move" : "default";
  });

  map.addEventListener("pointerup", (event) => {
    const d = drag;
    drag = null;
    map.style.cursor = "default";
    if (!d) return;
    if (d.mode === "goto") {
      if (!d.moved) {
        const goal = toWorld(local(event));
        setGoto(false);
        steer({ kind: "goto", goal: goal.map(r) }, null);
      }
      return;
    }
    moveDrag(d, local(event));
    if (d.mode !== "pan" && d.moved && d.ghost) {
      if (d.hit) refuseHere(request(d), d.hit);
      else steer(request(d), d.ghost);
    }
    draw();
  });

  map.addEventListener("pointercancel", () => { drag = null; draw(); });
  window.addEventListener("keydown", (event) => {
    if (event.key === "Escape" && drag) { drag = null; showResult("idle", "cancelled"); draw(); }
    else if (event.key === "Escape" && gotoMode) setGoto(false);
    else if ((event.key === "g" || event.key === "G") && !drag && !(event.target instanceof HTMLInputElement)) setGoto(!gotoMode);
  });
  document.getElementById("goto").addEventListener("click", () => setGoto(!gotoMode));
  map.addEventListener("dblclick", () => { if (!gotoMode) { centreOnS(); follow.checked = true; draw(); } });
  map.addEventListener("wheel", (event) => {
    event.preventDefault();
    const s = local(event), before = toWorld(s);
    view.moved = true;
    view.scale = Math.min(5000, Math.max(2, view.scale * Math.exp(-event.deltaY * 0.0015)));
    const after = toWorld(s);
    view.cx += before[0] - after[0];
    view.cy += before[1] - after[1];
    draw();
  }, { passive: false });
  window.addEventListener("resize", draw);

  // -- state stream ------------------------------------------------------------------------
  // The arena is fetched when the frame's world version differs from the one drawn.
  async function fetchWorld() {
    worldFetching = true;
    try {
      const response = await fetch("/api/world", { credentials: "same-origin" });
      if (response.ok) {
        const first = world === null;
        world = await response.json();
        if (first) fitWorld();
        if (world.map) loadMapPicture(world.version);
        draw();
      }
    } catch (err) {
      // the next frame asks again
    } finally {
      worldFetching = false;
    }
  }

  // The map's picture of arena document ``version`` (the URL names it: no stale cache).
  function loadMapPicture(version) {
    const image = new Image();
    image.onload = () => {
      if (world && world.version === version) { mapPicture = { image, version }; draw(); }
    };
    image.src = `/api/map.png?v=${version}`;
  }

  function connect() {
    const scheme = location.protocol === "https:" ? "wss:" : "ws:";
    const ws = new WebSocket(`${scheme}//${location.host}/ws`);
    ws.onopen = () => text("link", "live");
    ws.onmessage = (event) => {
      state = JSON.parse(event.data);
      hooks.frames += 1;
      // Opens on the arena when there is one (fetched first: the view does not jump), else on S.
      if (!view.ready && (!state.world || world)) centreOnS();
      if (state.world && (!world || world.version !== state.world.version) && !worldFetching) fetchWorld();
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
    touches,
    contact,
    world: () => world,
    gotoMode: () => gotoMode,
  };
  draw();
  connect();
})();
