// phri's episode replay: the robot's collision spheres among the scene's objects, the desired path
// and the plan being followed, the person's push as an arrow at the cup, and plots sharing one time
// cursor. Reads the replay from <script id="replay-data">; uses three.js (global THREE) only.
// URL: ?t=SECONDS (or #t=SECONDS) opens the replay at that time, paused.
// The replay data is JSON, gzip-compressed and base64-encoded (a fifth of the size: a study report
// holds one page per episode); DecompressionStream unpacks it (Chrome 80, Firefox 113, Safari 16.4).
(function () {
  "use strict";
  const packed = document.getElementById("replay-data").textContent.trim();
  function fail(message) {
    const view = document.getElementById("view");
    view.textContent = "phri view: " + message;
    view.style.padding = "2em";
    document.body.dataset.error = message;
  }
  if (typeof DecompressionStream === "undefined") {
    fail("this browser cannot unpack the replay (it needs DecompressionStream: Chrome 80, Firefox 113, " +
         "Safari 16.4 or later).");
    return;
  }
  const bytes = Uint8Array.from(atob(packed), function (c) { return c.charCodeAt(0); });
  new Response(new Blob([bytes]).stream().pipeThrough(new DecompressionStream("gzip"))).text()
    .then(function (text) { start(JSON.parse(text)); })
    .catch(function (e) { fail("the replay data is damaged (" + e + ")."); });

function start(data) {
  const frames = data.frames;
  const nFrames = frames.t.length;
  const COLORS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2"];
  document.getElementById("title").textContent = data.title;
  document.title = "phri · " + data.title;

  // --- the 3D scene -------------------------------------------------------------------------
  const view = document.getElementById("view");
  const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  renderer.setClearColor(0xf4f6f8);
  view.appendChild(renderer.domElement);
  const scene = new THREE.Scene();
  const camera = new THREE.PerspectiveCamera(45, 1, 0.01, 50);
  camera.up.set(0, 0, 1); // the robot's base frame: z up
  // Look at the middle of where the cup goes and the robot's base, from the front right.
  const box = new THREE.Box3().setFromPoints(
    frames.hand.concat(data.desired, [[0, 0, 0]]).map(function (p) { return new THREE.Vector3(p[0], p[1], p[2]); }));
  const target = box.getCenter(new THREE.Vector3());
  const reach = Math.max(box.getSize(new THREE.Vector3()).length(), 0.6);
  camera.position.set(target.x + 0.9 * reach, target.y - 1.5 * reach, target.z + 0.9 * reach);
  const controls = new THREE.OrbitControls(camera, renderer.domElement);
  controls.target.copy(target);
  controls.update();
  controls.addEventListener("change", render);
  scene.add(new THREE.HemisphereLight(0xffffff, 0x8899aa, 0.75));
  const sun = new THREE.DirectionalLight(0xffffff, 0.6);
  sun.position.set(1, -1, 2);
  scene.add(sun);
  const axes = new THREE.AxesHelper(0.15); // the base frame: x red, y green, z blue
  scene.add(axes);

  function poseMatrix(p) {
    const m = new THREE.Matrix4();
    m.set(p[0][0], p[0][1], p[0][2], p[0][3], p[1][0], p[1][1], p[1][2], p[1][3],
          p[2][0], p[2][1], p[2][2], p[2][3], p[3][0], p[3][1], p[3][2], p[3][3]);
    return m;
  }
  const OBJECT_COLORS = { furniture: 0xb08d68, person: 0x7aa6d8 };
  data.objects.forEach(function (o) {
    let geom = null;
    const d = o.dims;
    if (o.shape === "box") geom = new THREE.BoxBufferGeometry(d[0], d[1], d[2]);
    else if (o.shape === "cylinder") {
      geom = new THREE.CylinderBufferGeometry(d[0], d[0], d[1], 32);
      geom.rotateX(Math.PI / 2); // three's cylinders stand along y; the scene's along z
    } else if (o.shape === "sphere") geom = new THREE.SphereBufferGeometry(d[0], 24, 16);
    else if (o.shape === "plane") geom = new THREE.PlaneBufferGeometry(4, 4);
    if (!geom) return;
    const color = o.name === "table" ? 0xc8a27a : (o.kind === "person" ? OBJECT_COLORS.person : 0x555a60);
    const mat = new THREE.MeshLambertMaterial({
      color: color, transparent: o.kind === "person", opacity: o.kind === "person" ? 0.55 : 1.0,
    });
    const mesh = new THREE.Mesh(geom, mat);
    mesh.matrixAutoUpdate = false;
    mesh.matrix.copy(poseMatrix(o.pose));
    mesh.name = o.name;
    scene.add(mesh);
  });

  // The robot's stand, from the table's top to its base (as the simulated world has it).
  data.objects.forEach(function (o) {
    if (o.name !== "table" || o.shape !== "box") return;
    const top = o.pose[2][3] + o.dims[2] / 2;
    if (top >= 0) return;
    const stand = new THREE.Mesh(new THREE.BoxBufferGeometry(0.16, 0.16, -top),
                                 new THREE.MeshLambertMaterial({ color: 0x4d4d4d }));
    stand.position.set(0, 0, top / 2);
    scene.add(stand);
  });

  // The robot: one sphere mesh per collision sphere, moved at each frame.
  const armMat = new THREE.MeshLambertMaterial({ color: 0xff7f0e });
  const cupMat = new THREE.MeshLambertMaterial({ color: 0x2a6fdb });
  const wallMat = new THREE.MeshLambertMaterial({ color: 0xd62728 });
  const sphereGeom = new THREE.SphereBufferGeometry(1, 20, 14);
  const spheres = data.spheres.radius.map(function (r, i) {
    const m = new THREE.Mesh(sphereGeom, data.spheres.cup[i] ? cupMat : armMat);
    m.scale.set(r, r, r);
    scene.add(m);
    return m;
  });

  function path(points, color, dashed) {
    const pts = points.map(function (p) { return new THREE.Vector3(p[0], p[1], p[2]); });
    const geom = new THREE.BufferGeometry().setFromPoints(pts);
    const mat = dashed
      ? new THREE.LineDashedMaterial({ color: color, dashSize: 0.02, gapSize: 0.015 })
      : new THREE.LineBasicMaterial({ color: color });
    const line = new THREE.Line(geom, mat);
    if (dashed) line.computeLineDistances();
    scene.add(line);
    return line;
  }
  path(data.desired, 0x2ca02c, true); // what the person wants
  const planLines = data.plans.paths.map(function (p) {
    const l = path(p, 0x1f5fbf, false);
    l.visible = false;
    return l;
  });
  const trail = path(frames.hand, 0x333333, false); // where the cup went, drawn up to now
  const arrow = new THREE.ArrowHelper(new THREE.Vector3(1, 0, 0), new THREE.Vector3(), 0.1, 0xd62728, 0.04, 0.025);
  [arrow.line, arrow.cone].forEach(function (m) { m.material.depthTest = false; m.renderOrder = 10; });
  scene.add(arrow);

  // --- the plots ----------------------------------------------------------------------------
  const plotsEl = document.getElementById("plots");
  const plots = data.plots.map(function (p) {
    const box = document.createElement("div");
    box.className = "plot";
    const h = document.createElement("div");
    h.className = "plot-title";
    h.textContent = p.title;
    box.appendChild(h);
    const canvas = document.createElement("canvas");
    box.appendChild(canvas);
    const legend = document.createElement("div");
    legend.className = "legend";
    p.series.forEach(function (s, k) {
      const span = document.createElement("span");
      span.style.color = COLORS[k % COLORS.length];
      span.textContent = "— " + s.name + " ";
      legend.appendChild(span);
    });
    box.appendChild(legend);
    plotsEl.appendChild(box);
    let lo = Infinity, hi = -Infinity;
    p.series.forEach(function (s) {
      s.y.forEach(function (v) { if (v !== null) { lo = Math.min(lo, v); hi = Math.max(hi, v); } });
    });
    if (!isFinite(lo)) { lo = 0; hi = 1; }
    if (hi - lo < 1e-9) { hi += 0.5; lo -= 0.5; }
    canvas.addEventListener("click", function (ev) {
      const r = canvas.getBoundingClientRect();
      seek(data.t0 + (ev.clientX - r.left - 40) / (r.width - 48) * data.duration);
    });
    return { spec: p, canvas: canvas, lo: lo, hi: hi };
  });

  function drawPlot(pl, t) {
    const c = pl.canvas, w = c.clientWidth, h = c.clientHeight, dpr = window.devicePixelRatio || 1;
    if (c.width !== Math.round(w * dpr)) { c.width = Math.round(w * dpr); c.height = Math.round(h * dpr); }
    const g = c.getContext("2d");
    g.setTransform(dpr, 0, 0, dpr, 0, 0);
    g.clearRect(0, 0, w, h);
    const left = 40, right = 8, top = 4, bottom = 14;
    const X = function (x) { return left + (x - data.t0) / Math.max(data.duration, 1e-9) * (w - left - right); };
    const Y = function (y) { return top + (pl.hi - y) / (pl.hi - pl.lo) * (h - top - bottom); };
    g.strokeStyle = "#ccc"; g.lineWidth = 1;
    g.strokeRect(left, top, w - left - right, h - top - bottom);
    g.fillStyle = "#555"; g.font = "10px sans-serif";
    g.fillText(pl.hi.toPrecision(3), 2, top + 9);
    g.fillText(pl.lo.toPrecision(3), 2, h - bottom);
    g.fillText("0", left, h - 2);
    g.fillText(data.duration.toFixed(1) + " s", w - right - 30, h - 2);
    const ts = pl.spec.t;
    pl.spec.series.forEach(function (s, k) {
      g.strokeStyle = COLORS[k % COLORS.length];
      g.setLineDash(s.dashed ? [4, 3] : []);
      g.beginPath();
      let pen = false;
      for (let i = 0; i < ts.length; i++) {
        const v = s.y[i];
        if (v === null) { pen = false; continue; }
        if (!pen) { g.moveTo(X(ts[i]), Y(v)); pen = true; }
        else {
          if (pl.spec.step) g.lineTo(X(ts[i]), Y(s.y[i - 1]));
          g.lineTo(X(ts[i]), Y(v));
        }
      }
      g.stroke();
    });
    g.setLineDash([]);
    if (data.stop) {
      g.strokeStyle = "#d62728";
      g.beginPath(); g.moveTo(X(data.stop.t), top); g.lineTo(X(data.stop.t), h - bottom); g.stroke();
    }
    g.strokeStyle = "#000"; g.lineWidth = 1.5;
    g.beginPath(); g.moveTo(X(t), top); g.lineTo(X(t), h - bottom); g.stroke();
  }

  // --- time -----------------------------------------------------------------------------------
  const slider = document.getElementById("time");
  const label = document.getElementById("clock");
  const playBtn = document.getElementById("play");
  const speedSel = document.getElementById("speed");
  const status = document.getElementById("status");
  slider.max = String(data.duration);
  slider.step = "0.01";
  let now = data.t0, playing = false, last = null;

  function frameAt(t) { // the last frame at or before t
    let lo = 0, hi = nFrames - 1;
    while (lo < hi) { const mid = (lo + hi + 1) >> 1; if (frames.t[mid] <= t + 1e-9) lo = mid; else hi = mid - 1; }
    return lo;
  }
  function planAt(t) {
    let k = -1;
    for (let i = 0; i < data.plans.t.length; i++) if (data.plans.t[i] <= t + 1e-9) k = i;
    return k;
  }
  function resize() {
    const w = view.clientWidth, h = view.clientHeight;
    renderer.setSize(w, h, false);
    camera.aspect = w / Math.max(h, 1);
    camera.updateProjectionMatrix();
  }
  function render() { renderer.render(scene, camera); }

  function show(t) {
    now = Math.min(Math.max(t, data.t0), data.t0 + data.duration);
    const f = frameAt(now);
    const row = frames.spheres[f];
    const walled = frames.wall[f] > 0;
    for (let i = 0; i < spheres.length; i++) {
      const c = row[i];
      spheres[i].position.set(c[0], c[1], c[2]);
      if (!data.spheres.cup[i]) spheres[i].material = walled ? wallMat : armMat;
    }
    const k = planAt(now);
    planLines.forEach(function (l, i) { l.visible = i === k; });
    trail.geometry.setDrawRange(0, f + 1);
    const F = frames.push[f], mag = Math.hypot(F[0], F[1], F[2]);
    arrow.visible = mag > 0.5;
    if (arrow.visible) {
      const hand = frames.hand[f];
      arrow.position.set(hand[0], hand[1], hand[2]);
      arrow.setDirection(new THREE.Vector3(F[0] / mag, F[1] / mag, F[2] / mag));
      arrow.setLength(Math.min(0.02 + 0.02 * mag, 0.6), 0.04, 0.025); // 2 cm per newton
    }
    slider.value = String(now - data.t0);
    label.textContent = (now - data.t0).toFixed(2) + " / " + data.duration.toFixed(2) + " s";
    let text = mag > 0.5 ? "push " + mag.toFixed(1) + " N" : "";
    if (walled) text += (text ? " · " : "") + "safety wall " + frames.wall[f].toFixed(1) + " N";
    if (data.stop && now >= data.stop.t) text += (text ? " · " : "") + "stopped: " + data.stop.reason;
    status.textContent = text;
    plots.forEach(function (pl) { drawPlot(pl, now); });
    render();
    document.body.dataset.time = (now - data.t0).toFixed(3);
  }
  function seek(t) { show(t); }
  function tick(stamp) {
    if (!playing) return;
    if (last !== null) {
      const t = now + (stamp - last) / 1000 * parseFloat(speedSel.value);
      if (t >= data.t0 + data.duration) { show(data.t0 + data.duration); setPlaying(false); return; }
      show(t);
    }
    last = stamp;
    requestAnimationFrame(tick);
  }
  function setPlaying(on) {
    playing = on;
    playBtn.textContent = on ? "❚❚ pause" : "▶ play";
    last = null;
    if (on) {
      if (now >= data.t0 + data.duration - 1e-6) now = data.t0;
      requestAnimationFrame(tick);
    }
  }
  playBtn.addEventListener("click", function () { setPlaying(!playing); });
  slider.addEventListener("input", function () { setPlaying(false); show(data.t0 + parseFloat(slider.value)); });
  document.addEventListener("keydown", function (e) {
    if (e.key === " ") { e.preventDefault(); setPlaying(!playing); }
    else if (e.key === "ArrowRight") show(now + 0.1);
    else if (e.key === "ArrowLeft") show(now - 0.1);
  });
  window.addEventListener("resize", function () { resize(); show(now); });

  const query = new URLSearchParams(window.location.search || window.location.hash.replace(/^#/, "?"));
  const start = parseFloat(query.get("t"));
  resize();
  show(data.t0 + (isFinite(start) ? start : 0));
  window.phriReplay = { show: show, frames: nFrames, ready: true };
  document.body.dataset.ready = "1";
}
})();
