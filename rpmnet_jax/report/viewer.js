// The point-cloud viewer of rpmnet_jax's HTML reports: WebGL 1, no library, no network.
// Data (the JSON script "rpmnet-data"): clouds [{name, colour "#rrggbb", rows, drawn, points}] where points is
// base64 of little-endian uint16 (x, y, z) per point, quantised over the box of all clouds (extent [3], centred
// on the origin here); views [{title, clouds: [index], centre, radius}] drawn one at a time or side by side
// (in this order, left to right), each moved so that the centre of its own clouds' box (centre [3], from the
// box's centre) is at the origin, and each framed on the sphere about it that holds its clouds (radius); first:
// the view shown when the page opens; up: "y" or "z", the axis drawn upwards when it opens.
// Mouse: drag turns about the centre, wheel zooms, shift- or right-drag moves, double-click resets.
(function () {
  "use strict";
  var data = JSON.parse(document.getElementById("rpmnet-data").textContent);
  var canvas = document.getElementById("view");
  var state = { frames: 0, error: null };
  window.rpmnetViewer = state;  // read by tests: frames drawn, or why nothing is
  var gl = canvas.getContext("webgl", { antialias: true, preserveDrawingBuffer: true });
  if (!gl) {
    state.error = "WebGL is not available in this browser";
    document.getElementById("status").textContent = state.error;
    return;
  }

  var VERTEX = [
    "attribute vec3 q;",               // quantised position in [0, 1]
    "uniform vec3 extent, shift;",     // the box's size; the centre of the view's own clouds
    "uniform mat4 view, proj;",
    "uniform float size;",
    "uniform vec2 depth;",             // view depths of the nearest and farthest point of the box
    "varying float shade;",
    "void main() {",
    "  vec4 v = view * vec4((q - 0.5) * extent - shift, 1.0);",
    "  gl_Position = proj * v;",
    "  gl_PointSize = size;",
    "  shade = 1.0 - 0.55 * clamp((-v.z - depth.x) / (depth.y - depth.x), 0.0, 1.0);",
    "}"].join("\n");
  var FRAGMENT = [
    "precision mediump float;",
    "uniform vec3 colour;",
    "varying float shade;",
    "void main() {",
    "  vec2 c = 2.0 * gl_PointCoord - 1.0;",
    "  if (dot(c, c) > 1.0) discard;",  // round points
    "  gl_FragColor = vec4(colour * shade, 1.0);",
    "}"].join("\n");

  function shader(type, source) {
    var s = gl.createShader(type);
    gl.shaderSource(s, source);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
    return s;
  }
  var program = gl.createProgram();
  gl.attachShader(program, shader(gl.VERTEX_SHADER, VERTEX));
  gl.attachShader(program, shader(gl.FRAGMENT_SHADER, FRAGMENT));
  gl.linkProgram(program);
  if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(program));
  gl.useProgram(program);
  var at = {};
  ["extent", "shift", "view", "proj", "size", "depth", "colour"].forEach(function (n) {
    at[n] = gl.getUniformLocation(program, n);
  });
  var qAttribute = gl.getAttribLocation(program, "q");
  gl.enableVertexAttribArray(qAttribute);
  gl.enable(gl.DEPTH_TEST);
  gl.enable(gl.SCISSOR_TEST);
  gl.clearColor(0.086, 0.094, 0.114, 1.0);
  gl.uniform3fv(at.extent, data.extent);

  function rgb(hex) {
    var n = parseInt(hex.slice(1), 16);
    return [(n >> 16 & 255) / 255, (n >> 8 & 255) / 255, (n & 255) / 255];
  }
  var clouds = data.clouds.map(function (c) {
    var text = atob(c.points), bytes = new Uint8Array(text.length);
    for (var i = 0; i < text.length; i++) bytes[i] = text.charCodeAt(i);
    var buffer = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, buffer);
    gl.bufferData(gl.ARRAY_BUFFER, bytes, gl.STATIC_DRAW);
    return { name: c.name, colour: rgb(c.colour), hex: c.colour, rows: c.rows, count: c.drawn,
             buffer: buffer, shown: true };
  });
  var whole = 0.5 * Math.hypot(data.extent[0], data.extent[1], data.extent[2]) || 1;
  function radius(v) { return data.views[v].radius || whole; }  // one point, or none: the box of all

  // camera: orbit about target, yaw about the up axis, pitch above the horizon; each view at the distance that
  // fits its sphere into its part of the canvas, times zoom
  var camera, mode = data.first || 0, zUp = data.up === "z";  // mode: the view shown; views.length: side by side
  function reset() {
    camera = { yaw: 0.6, pitch: 0.35, zoom: 1, target: [0, 0, 0] };
    redraw();
  }
  var MARGIN = 0.92;  // the sphere's outline at most this share of the way from the middle to the nearer edge
  function distance(v, aspect) {  // eye to target that shows the sphere of view v whole, times zoom
    var p = projection(aspect, 1, 2), t = MARGIN / Math.max(p[0], p[5]);  // tan of the sphere's half-angle
    return camera.zoom * radius(v) * Math.sqrt(1 + 1 / (t * t));
  }
  function dot(a, b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
  function cross(a, b) { return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]; }
  function unit(a) { var n = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / n, a[1] / n, a[2] / n]; }
  function frame(distance) {  // eye, right, up (unit vectors) of the camera at distance from its target
    var cp = Math.cos(camera.pitch), sp = Math.sin(camera.pitch);
    var cy = Math.cos(camera.yaw), sy = Math.sin(camera.yaw);
    var back = zUp ? [cp * sy, -cp * cy, sp] : [cp * sy, sp, cp * cy];
    var eye = camera.target.map(function (t, i) { return t + distance * back[i]; });
    var right = unit(cross(zUp ? [0, 0, 1] : [0, 1, 0], back));
    return { eye: eye, back: back, right: right, up: cross(back, right) };
  }
  function viewMatrix(f) {  // column-major look-at
    var x = f.right, y = f.up, z = f.back, e = f.eye;
    return [x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0, -dot(x, e), -dot(y, e), -dot(z, e), 1];
  }
  function projection(aspect, near, far) {  // 45 degrees across the narrower side
    var f = Math.min(1, aspect) / Math.tan(Math.PI / 8), nf = 1 / (near - far);
    return [f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * nf, -1, 0, 0, 2 * far * near * nf, 0];
  }

  var pending = false;
  function redraw() {
    if (!pending) { pending = true; requestAnimationFrame(draw); }
  }
  function draw() {
    pending = false;
    var ratio = window.devicePixelRatio || 1;
    var w = Math.max(1, Math.round(canvas.clientWidth * ratio)), h = Math.max(1, Math.round(canvas.clientHeight * ratio));
    if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
    gl.uniform1f(at.size, parseFloat(document.getElementById("size").value) * ratio);
    gl.scissor(0, 0, w, h);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    var shown = shownViews();
    shown.forEach(function (v, k) {
      var x0 = Math.round(k * w / shown.length), x1 = Math.round((k + 1) * w / shown.length);
      var r = radius(v), d = distance(v, (x1 - x0) / h), f = frame(d);
      var middle = dot(f.eye, f.back);  // view depth of the view's centre (the origin)
      var near = Math.max(d * 0.005, middle - 3 * r), far = middle + 3 * r + d;
      gl.uniformMatrix4fv(at.view, false, viewMatrix(f));
      gl.uniform2f(at.depth, middle - r, middle + r);
      gl.viewport(x0, 0, x1 - x0, h);
      gl.scissor(x0, 0, x1 - x0, h);
      gl.uniformMatrix4fv(at.proj, false, projection((x1 - x0) / h, near, far));
      gl.uniform3fv(at.shift, data.views[v].centre);
      data.views[v].clouds.forEach(function (c) {
        var cloud = clouds[c];
        if (!cloud.shown || !cloud.count) return;
        gl.bindBuffer(gl.ARRAY_BUFFER, cloud.buffer);
        gl.vertexAttribPointer(qAttribute, 3, gl.UNSIGNED_SHORT, true, 0, 0);
        gl.uniform3fv(at.colour, cloud.colour);
        gl.drawArrays(gl.POINTS, 0, cloud.count);
      });
    });
    var titles = document.getElementById("titles");
    titles.innerHTML = "";
    shown.forEach(function (v) {
      var d = document.createElement("div");
      d.textContent = data.views[v].title;
      titles.appendChild(d);
    });
    state.frames++;
  }

  function shownViews() {
    return mode < data.views.length ? [mode] : data.views.map(function (v, i) { return i; });
  }

  // legend: one entry per cloud of the views, a click hides or shows it
  var legend = document.getElementById("legend"), COUNTED = 6;
  clouds.forEach(function (cloud) {
    var label = document.createElement("label"), box = document.createElement("input");
    box.type = "checkbox";
    box.checked = true;
    box.onchange = function () { cloud.shown = box.checked; label.className = box.checked ? "" : "off"; redraw(); };
    var swatch = document.createElement("span");
    swatch.className = "swatch";
    swatch.style.background = cloud.hex;
    label.appendChild(box);
    label.appendChild(swatch);
    var count = cloud.count ? cloud.count.toLocaleString("en") + (cloud.count < cloud.rows ? " of " +
      cloud.rows.toLocaleString("en") : "") + " points" : "not drawn";
    label.title = cloud.name + " (" + count + ")";  // many clouds: the names alone, the counts on hovering
    label.appendChild(document.createTextNode(clouds.length > COUNTED ? cloud.name : label.title));
    legend.appendChild(label);
  });

  // view buttons: each view, and side by side when there are several
  var viewButtons = document.getElementById("views"), buttons = [];
  var names = data.views.map(function (v) { return v.title; });
  if (names.length > 1) names.push("side by side");
  names.forEach(function (name, i) {
    var b = document.createElement("button");
    b.textContent = name;
    b.onclick = function () { mode = i; markView(); redraw(); };
    viewButtons.appendChild(b);
    buttons.push(b);
  });
  function markView() { buttons.forEach(function (b, i) { b.className = i === mode ? "on" : ""; }); }
  markView();
  var upButton = document.getElementById("up");
  upButton.textContent = zUp ? "z" : "y";
  upButton.onclick = function () { zUp = !zUp; upButton.textContent = zUp ? "z" : "y"; redraw(); };
  document.getElementById("size").oninput = redraw;
  document.getElementById("reset").onclick = reset;

  // mouse and touch: drag turns, shift-/right-drag moves, wheel zooms
  var drag = null;
  canvas.addEventListener("pointerdown", function (e) {
    drag = { x: e.clientX, y: e.clientY, move: e.shiftKey || e.button === 2 };
    canvas.setPointerCapture(e.pointerId);
  });
  canvas.addEventListener("pointermove", function (e) {
    if (!drag) return;
    var dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    drag.x = e.clientX;
    drag.y = e.clientY;
    if (drag.move) {
      var shown = shownViews(), aspect = canvas.clientWidth / shown.length / canvas.clientHeight;
      var d = distance(shown[0], aspect), f = frame(d), s = d / canvas.clientHeight;
      camera.target = camera.target.map(function (t, i) { return t - s * (dx * f.right[i] - dy * f.up[i]); });
    } else {
      camera.yaw -= dx * 0.008;
      camera.pitch = Math.max(-1.55, Math.min(1.55, camera.pitch + dy * 0.008));
    }
    redraw();
  });
  canvas.addEventListener("pointerup", function () { drag = null; });
  canvas.addEventListener("pointercancel", function () { drag = null; });
  canvas.addEventListener("contextmenu", function (e) { e.preventDefault(); });
  canvas.addEventListener("dblclick", reset);
  canvas.addEventListener("wheel", function (e) {
    e.preventDefault();
    camera.zoom = Math.max(0.05, Math.min(50, camera.zoom * Math.exp(e.deltaY * 0.0015)));
    redraw();
  }, { passive: false });
  window.addEventListener("resize", redraw);
  if (window.ResizeObserver) new ResizeObserver(redraw).observe(canvas);  // the bar or the banner may change size
  reset();
})();
