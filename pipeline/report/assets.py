"""The HTML page's inline style sheet and scripts (kept as strings so that the page has no
external resources and the package needs no data files)."""

from __future__ import annotations

#: Runs first: records script errors, failed resources and ``console.error`` calls into
#: ``<html data-errors="N">`` so a headless browser (and a reader) can see them.
ERROR_HOOK_JS = r"""
(function () {
  var errs = window.__treesimErrors = [];
  function note(msg) {
    errs.push(String(msg));
    document.documentElement.setAttribute("data-errors", String(errs.length));
    var box = document.getElementById("page-errors");
    if (box) { box.hidden = false; box.textContent = "Page error: " + errs.join(" | "); }
  }
  window.addEventListener("error", function (e) {
    var t = e.target;
    note(e.message || (t && (t.src || t.href) ? "could not load " + (t.src || t.href) : "error"));
  }, true);
  window.addEventListener("unhandledrejection", function (e) { note(e.reason); });
  var ce = console.error;
  console.error = function () {
    note(Array.prototype.join.call(arguments, " "));
    return ce.apply(console, arguments);
  };
  document.documentElement.setAttribute("data-errors", "0");
})();
"""

#: The 3D viewer's style (its colours are :data:`VIEWER_VARS`'s).
VIEWER_CSS = r"""
/* 3D viewer */
.viewer { display: grid; grid-template-columns: 1fr 210px; gap: 18px; }
@media (max-width: 860px) { .viewer { grid-template-columns: 1fr; } }
.viewer canvas { width: 100%; height: 560px; display: block; background: #fbfcfd;
  border: 1px solid var(--line); border-radius: 8px; cursor: grab; touch-action: none; }
.viewer canvas.dragging { cursor: grabbing; }
.controls { display: flex; flex-direction: column; gap: 14px; font-size: 13.5px; }
.controls .group { display: flex; flex-direction: column; gap: 6px; }
.controls .label { font-size: 12.5px; color: var(--muted); font-weight: 500; }
.seg { display: flex; flex-wrap: wrap; gap: 6px; }
button {
  font: inherit; font-size: 13px; border: 1px solid #cbd2d9; background: #fff; color: var(--ink);
  padding: 5px 10px; border-radius: 6px; cursor: pointer;
}
button:hover { border-color: var(--faint); background: #f7f9fb; }
button[aria-pressed="true"] { background: var(--ink); color: #fff; border-color: var(--ink); }
.legend { display: flex; gap: 10px; align-items: stretch; height: 190px; }
.legend .bar { width: 16px; border-radius: 4px; border: 1px solid var(--line); position: relative; }
.legend .ticks { position: relative; flex: 1; font-size: 12px; color: var(--muted);
  font-variant-numeric: tabular-nums; }
.legend .ticks span { position: absolute; left: 0; transform: translateY(-50%);
  white-space: nowrap; }
.legend .ticks span.tau { color: var(--tau); font-weight: 600; }
.legend .bar i { position: absolute; left: -3px; right: -3px; height: 2px; background: var(--tau); }
.hint { color: var(--muted); font-size: 12.5px; line-height: 1.45; }
input[type=range] { width: 100%; accent-color: var(--ink); }
"""

#: The colour variables the viewer's style uses (part of :data:`CSS`).
VIEWER_VARS = r"""
:root {
  --ink: #1f2933; --muted: #616e7c; --faint: #9aa5b1; --line: #e4e7eb;
  --tau: #b83232;
}
"""

CSS = (
    r"""
:root {
  --ink: #1f2933; --muted: #616e7c; --faint: #9aa5b1; --line: #e4e7eb;
  --paper: #ffffff; --bg: #f3f5f8; --acc: #2c6e9b; --comp: #c2612d; --tau: #b83232;
  --ok: #2f7d4f; --warn: #b7791f;
}
* { box-sizing: border-box; }
html { -webkit-text-size-adjust: 100%; }
body {
  margin: 0; background: var(--bg); color: var(--ink);
  font: 15px/1.55 system-ui, -apple-system, "Segoe UI", Roboto, "Noto Sans", "DejaVu Sans",
    "Helvetica Neue", Arial, sans-serif;
}
.wrap { max-width: 1160px; margin: 0 auto; padding: 0 28px; }
header.top { background: #1f2933; color: #f5f7fa; padding: 30px 0 26px; }
header.top .eyebrow {
  text-transform: uppercase; letter-spacing: .12em; font-size: 12px; color: #9fb3c8;
}
header.top h1 { margin: 6px 0 6px; font-size: 28px; font-weight: 650; letter-spacing: -.01em; }
header.top h1 .vs { color: #9fb3c8; font-weight: 400; padding: 0 .25em; }
header.top .meta { margin: 0; color: #cbd2d9; font-size: 14px; }
main.wrap { padding-top: 26px; padding-bottom: 10px; }
section { margin: 0 0 26px; }
.panel {
  background: var(--paper); border: 1px solid var(--line); border-radius: 10px;
  padding: 20px 24px; box-shadow: 0 1px 2px rgba(31, 41, 51, .04);
}
h2 { font-size: 18px; margin: 0 0 4px; font-weight: 650; letter-spacing: -.005em; }
h3 { font-size: 15px; margin: 18px 0 6px; font-weight: 600; }
.lead { color: var(--muted); margin: 0 0 14px; font-size: 14px; }
.summary p { margin: 0; font-size: 16.5px; line-height: 1.65; max-width: 82ch; }
.summary { border-left: 4px solid var(--acc); }
.note { border-left: 4px solid var(--warn); background: #fffaf0; }
.note p { margin: 0; max-width: 90ch; }
.cards { display: grid; grid-template-columns: repeat(auto-fit, minmax(190px, 1fr)); gap: 14px; }
.card {
  background: var(--paper); border: 1px solid var(--line); border-radius: 10px;
  padding: 14px 16px 12px; border-top: 3px solid var(--faint);
}
.card.acc { border-top-color: var(--acc); }
.card.comp { border-top-color: var(--comp); }
.card.tau { border-top-color: var(--tau); }
.card .k { font-size: 13px; color: var(--muted); font-weight: 500; }
.card .v { font-size: 26px; font-weight: 650; margin: 2px 0 0; font-variant-numeric: tabular-nums; }
.card .s { font-size: 13px; color: var(--muted); }
table { border-collapse: collapse; width: 100%; font-size: 14px; }
th, td { padding: 7px 10px; border-bottom: 1px solid var(--line); text-align: left; }
th { font-weight: 600; color: var(--muted); font-size: 12.5px; text-transform: uppercase;
  letter-spacing: .04em; background: #fafbfc; }
td.n, th.n { text-align: right; font-variant-numeric: tabular-nums; }
tbody tr:hover { background: #f7f9fb; }
.dot { display: inline-block; width: 10px; height: 10px; border-radius: 50%; margin-right: 8px;
  vertical-align: 0; }
.dot.acc { background: var(--acc); } .dot.comp { background: var(--comp); }
.scroll { overflow-x: auto; }
table.kv td:first-child { white-space: nowrap; color: var(--muted); width: 1%;
  padding-right: 18px; }
table.kv td { vertical-align: top; }
figure { margin: 0 0 18px; }
figure img { display: block; width: 100%; height: auto; border-radius: 6px; }
figcaption { color: var(--muted); font-size: 13.5px; margin-top: 6px; max-width: 90ch; }
.two { display: grid; grid-template-columns: 1fr 1fr; gap: 22px; }
@media (max-width: 860px) { .two { grid-template-columns: 1fr; } }
dl.defs { display: grid; grid-template-columns: max-content 1fr; gap: 6px 18px; margin: 0;
  font-size: 14px; }
dl.defs dt { font-family: ui-monospace, "DejaVu Sans Mono", Menlo, Consolas, monospace;
  font-size: 13px; color: var(--ink); }
dl.defs dd { margin: 0; color: var(--muted); }
code { font-family: ui-monospace, "DejaVu Sans Mono", Menlo, Consolas, monospace;
  font-size: 13px; background: #f0f2f5; padding: 1px 5px; border-radius: 4px; }
footer { color: var(--muted); font-size: 13px; padding: 8px 0 40px; }
footer .versions { display: flex; flex-wrap: wrap; gap: 6px 16px; }
#page-errors { background: #fde8e8; color: #8a1c1c; border: 1px solid #f5b5b5; padding: 10px 14px;
  border-radius: 8px; margin: 16px 0; }
"""
    + VIEWER_CSS
)


#: The interactive point viewer: canvas 2D, orthographic, z-buffered splats, depth shading.
VIEWER_JS = r"""
(function () {
  "use strict";
  var root = document.getElementById("viewer");
  var node = document.getElementById("viewer-data");
  if (!root || !node) return;
  var data = JSON.parse(node.textContent);
  function bytes(s) {
    var bin = atob(s), a = new Uint8Array(bin.length);
    for (var i = 0; i < bin.length; i++) a[i] = bin.charCodeAt(i);
    return a;
  }
  var lut = bytes(data.lut), size = data.bbox_size_m;
  var sets = data.datasets.map(function (d) {
    var raw = bytes(d.pos), dv = new DataView(raw.buffer), n = d.n, xyz = new Float32Array(n * 3);
    for (var i = 0; i < n * 3; i++) {
      var a = i % 3;
      xyz[i] = (dv.getUint16(2 * i, true) / 65535 - 0.5) * size[a];
    }
    return { meta: d, n: n, xyz: xyz, col: bytes(d.col) };
  });
  var canvas = root.querySelector("canvas"), ctx = canvas.getContext("2d");
  if (!ctx) {
    root.querySelector(".hint").textContent = "This browser cannot draw the view.";
    return;
  }
  var radius = 0.5 * Math.sqrt(size[0] * size[0] + size[1] * size[1] + size[2] * size[2]) || 1;
  var HOME = { yaw: -0.65, pitch: 0.22, zoom: 1, panx: 0, pany: 0 };
  var view = Object.assign({}, HOME), current = 0, ptSize = 2;
  var img = null, zbuf = null, W = 0, H = 0, pending = false, BG = 0xfffdfcfb;

  function resize() {
    var dpr = window.devicePixelRatio || 1, r = canvas.getBoundingClientRect();
    W = Math.max(1, Math.round(r.width * dpr)); H = Math.max(1, Math.round(r.height * dpr));
    canvas.width = W; canvas.height = H;
    img = ctx.createImageData(W, H); zbuf = new Float32Array(W * H);
    draw();
  }
  function draw() { if (!pending) { pending = true; requestAnimationFrame(render); } }
  function render() {
    pending = false;
    if (!img) return;
    var s = sets[current], xyz = s.xyz, col = s.col, n = s.n;
    var px = new Uint32Array(img.data.buffer);
    px.fill(BG); zbuf.fill(Infinity);
    var cyw = Math.cos(view.yaw), syw = Math.sin(view.yaw);
    var cp = Math.cos(view.pitch), sp = Math.sin(view.pitch);
    var scale = 0.47 * Math.min(W, H) / radius * view.zoom;
    var ox = W / 2 + view.panx * W, oy = H / 2 + view.pany * H;
    var dpr = window.devicePixelRatio || 1, k = Math.max(1, Math.round(ptSize * dpr));
    var h0 = k >> 1, drawn = 0;
    for (var i = 0; i < n; i++) {
      var x = xyz[3 * i], y = xyz[3 * i + 1], z = xyz[3 * i + 2];
      var sx = cyw * x - syw * y, d0 = syw * x + cyw * y;
      var up = sp * d0 + cp * z, depth = cp * d0 - sp * z;
      var u = Math.floor(ox + sx * scale) - h0, v = Math.floor(oy - up * scale) - h0;
      if (u >= W || v >= H || u + k <= 0 || v + k <= 0) continue;
      var shade = 1 - 0.38 * Math.min(1, Math.max(0, (depth + radius) / (2 * radius)));
      var c = 3 * col[i];
      var rgba = (0xff000000 | ((lut[c + 2] * shade) << 16) | ((lut[c + 1] * shade) << 8) |
        (lut[c] * shade)) >>> 0;
      drawn++;
      for (var dy = 0; dy < k; dy++) {
        var row = v + dy;
        if (row < 0 || row >= H) continue;
        for (var dx = 0; dx < k; dx++) {
          var col2 = u + dx;
          if (col2 < 0 || col2 >= W) continue;
          var p = row * W + col2;
          if (depth < zbuf[p]) { zbuf[p] = depth; px[p] = rgba; }
        }
      }
    }
    ctx.putImageData(img, 0, 0);
    root.setAttribute("data-drawn", String(drawn));
  }

  // legend
  function legend() {
    var m = sets[current].meta, bar = root.querySelector(".legend .bar");
    var ticks = root.querySelector(".legend .ticks"), stops = [];
    for (var i = 0; i <= 10; i++) {
      var c = 3 * Math.round(255 * i / 10);
      var rgb = "rgb(" + lut[c] + "," + lut[c + 1] + "," + lut[c + 2] + ")";
      stops.push(rgb + " " + (100 - 10 * i) + "%");
    }
    bar.style.background = "linear-gradient(to bottom, " + stops.reverse().join(", ") + ")";
    bar.innerHTML = ""; ticks.innerHTML = "";
    function tick(frac, text, cls) {
      var t = document.createElement("span");
      t.style.top = (100 * (1 - frac)) + "%"; t.textContent = text;
      if (cls) t.className = cls;
      ticks.appendChild(t);
    }
    var nt = 4;
    for (var j = 0; j <= nt; j++) {
      var val = m.vmax * j / nt;
      tick(j / nt, (j === nt ? "≥ " : "") + fmt(val) + " " + m.unit);
    }
    if (m.tau !== null && m.tau <= m.vmax) {
      var f = m.tau / m.vmax, mark = document.createElement("i");
      mark.style.top = (100 * (1 - f)) + "%"; bar.appendChild(mark);
      tick(f, "τ " + fmt(m.tau) + " " + m.unit, "tau");
    }
    root.querySelector(".legend-title").textContent = m.colour_label;
    root.querySelector(".count").textContent = m.caption;
  }
  function fmt(v) {
    if (v === 0) return "0";
    var a = Math.abs(v);
    if (a >= 100) return v.toFixed(0);
    if (a >= 10) return v.toFixed(1);
    return a >= 1 ? v.toFixed(2) : v.toPrecision(2);
  }

  // controls
  var setButtons = root.querySelectorAll("[data-set]");
  Array.prototype.forEach.call(setButtons, function (b) {
    b.addEventListener("click", function () {
      current = Number(b.getAttribute("data-set"));
      Array.prototype.forEach.call(setButtons, function (o) {
        o.setAttribute("aria-pressed", String(o === b));
      });
      legend(); draw();
    });
  });
  function setView(v) { Object.assign(view, v); draw(); }
  root.querySelector("[data-view=home]").addEventListener("click", function () { setView(HOME); });
  root.querySelector("[data-view=side]").addEventListener("click", function () {
    setView({ yaw: 0, pitch: 0, zoom: 1, panx: 0, pany: 0 });
  });
  root.querySelector("[data-view=top]").addEventListener("click", function () {
    setView({ yaw: 0, pitch: Math.PI / 2, zoom: 1, panx: 0, pany: 0 });
  });
  root.querySelector("input[type=range]").addEventListener("input", function (e) {
    ptSize = Number(e.target.value); draw();
  });

  var drag = null;
  canvas.addEventListener("pointerdown", function (e) {
    drag = { x: e.clientX, y: e.clientY, pan: e.button === 2 || e.shiftKey };
    canvas.setPointerCapture(e.pointerId); canvas.classList.add("dragging");
  });
  canvas.addEventListener("pointermove", function (e) {
    if (!drag) return;
    var dx = e.clientX - drag.x, dy = e.clientY - drag.y, r = canvas.getBoundingClientRect();
    drag.x = e.clientX; drag.y = e.clientY;
    if (drag.pan) { view.panx += dx / r.width; view.pany += dy / r.height; }
    else {
      view.yaw -= dx * 0.008;
      view.pitch = Math.max(-Math.PI / 2, Math.min(Math.PI / 2, view.pitch + dy * 0.008));
    }
    draw();
  });
  function endDrag() { drag = null; canvas.classList.remove("dragging"); }
  canvas.addEventListener("pointerup", endDrag);
  canvas.addEventListener("pointercancel", endDrag);
  canvas.addEventListener("contextmenu", function (e) { e.preventDefault(); });
  canvas.addEventListener("dblclick", function () { setView(HOME); });
  canvas.addEventListener("wheel", function (e) {
    e.preventDefault();
    view.zoom = Math.max(0.2, Math.min(80, view.zoom * Math.exp(-e.deltaY * 0.0015)));
    draw();
  }, { passive: false });

  if (window.ResizeObserver) new ResizeObserver(resize).observe(canvas);
  else window.addEventListener("resize", resize);
  legend(); resize();
  document.body.setAttribute("data-viewer", "ready");
})();
"""
