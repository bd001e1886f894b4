// A small viewer of the measured mesh (no library, works from file://): drag rotates, shift-drag or
// right-drag pans, the wheel zooms, double-click or "side" resets. Orthographic projection, so the
// scale bar (micrometres) holds everywhere in the picture. Drawn with WebGL; where the browser offers
// none (or the page's address ends in #no-webgl), with a 2D canvas (painter's algorithm, slower).
(function () {
  "use strict";
  var canvas = document.getElementById("mesh-canvas");
  if (!canvas) { return; }
  var wrap = canvas.parentNode;
  function bytes(id) {
    var s = document.getElementById(id).textContent.replace(/\s+/g, ""), bin = atob(s), u = new Uint8Array(bin.length);
    for (var i = 0; i < bin.length; i++) { u[i] = bin.charCodeAt(i); }
    return u.buffer;
  }
  var V = new Float32Array(bytes("mesh-vertices"));
  var F = document.getElementById("mesh-faces").dataset.indexType === "u2" ? new Uint16Array(bytes("mesh-faces")) : new Uint32Array(bytes("mesh-faces"));
  var nv = V.length / 3, nf = F.length / 3, i, k;
  // centre and radius (µm); vertices centred
  var lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
  for (i = 0; i < nv; i++) { for (k = 0; k < 3; k++) { lo[k] = Math.min(lo[k], V[3 * i + k]); hi[k] = Math.max(hi[k], V[3 * i + k]); } }
  var c = [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2];
  var radius = 0.5 * Math.sqrt(Math.pow(hi[0] - lo[0], 2) + Math.pow(hi[1] - lo[1], 2) + Math.pow(hi[2] - lo[2], 2)) || 1;
  for (i = 0; i < nv; i++) { for (k = 0; k < 3; k++) { V[3 * i + k] -= c[k]; } }
  // face normals, and area-weighted vertex normals
  var FN = new Float32Array(3 * nf), N = new Float32Array(3 * nv);
  for (i = 0; i < nf; i++) {
    var a = F[3 * i], b = F[3 * i + 1], d = F[3 * i + 2];
    var ux = V[3 * b] - V[3 * a], uy = V[3 * b + 1] - V[3 * a + 1], uz = V[3 * b + 2] - V[3 * a + 2];
    var vx = V[3 * d] - V[3 * a], vy = V[3 * d + 1] - V[3 * a + 1], vz = V[3 * d + 2] - V[3 * a + 2];
    var n0 = uy * vz - uz * vy, n1 = uz * vx - ux * vz, n2 = ux * vy - uy * vx;
    FN[3 * i] = n0; FN[3 * i + 1] = n1; FN[3 * i + 2] = n2;
    [a, b, d].forEach(function (j) { N[3 * j] += n0; N[3 * j + 1] += n1; N[3 * j + 2] += n2; });
  }
  var L1 = [0.35, 0.55, 0.75], L2 = [-0.6, -0.3, 0.5], BASE = [0.86, 0.72, 0.55];
  [L1, L2].forEach(function (l) { var s = Math.hypot(l[0], l[1], l[2]); l[0] /= s; l[1] /= s; l[2] /= s; });

  // view state: rows of R = screen right, screen up, towards the viewer, in world coordinates (world x = rotation axis)
  var PRESETS = { side: [1, 0, 0, 0, -1, 0, 0, 0, -1], top: [1, 0, 0, 0, 0, 1, 0, -1, 0], end: [0, 0, 1, 0, -1, 0, 1, 0, 0] };
  var R = PRESETS.side.slice(), zoom = 1, pan = [0, 0];
  function mul(A, B) {
    var C = new Array(9);
    for (var r = 0; r < 3; r++) { for (var q = 0; q < 3; q++) { C[3 * r + q] = A[3 * r] * B[q] + A[3 * r + 1] * B[3 + q] + A[3 * r + 2] * B[6 + q]; } }
    return C;
  }
  function rotX(t) { var co = Math.cos(t), si = Math.sin(t); return [1, 0, 0, 0, co, -si, 0, si, co]; }
  function rotY(t) { var co = Math.cos(t), si = Math.sin(t); return [co, 0, si, 0, 1, 0, -si, 0, co]; }
  var fit = [radius, radius];  // half-extents (µm) of the mesh seen along the current preset direction
  function fitView() {
    var mx = 0, my = 0;
    for (var j = 0; j < nv; j++) {
      var x = V[3 * j], y = V[3 * j + 1], z = V[3 * j + 2];
      mx = Math.max(mx, Math.abs(R[0] * x + R[1] * y + R[2] * z)); my = Math.max(my, Math.abs(R[3] * x + R[4] * y + R[5] * z));
    }
    fit = [mx || radius, my || radius];
  }
  function halfExtents(w, h) {  // µm from the centre to the canvas edges: the fitted view with a margin, over the zoom
    var halfW = 1.1 * Math.max(fit[0], fit[1] * w / h) / zoom;
    return [halfW, halfW * h / w];
  }

  function webglRenderer() {
    if (/no-webgl/.test(location.hash)) { return null; }
    var gl = canvas.getContext("webgl", { antialias: true, preserveDrawingBuffer: true }) ||
             canvas.getContext("experimental-webgl", { preserveDrawingBuffer: true });
    if (!gl) { return null; }
    function shader(type, src) {
      var s = gl.createShader(type); gl.shaderSource(s, src); gl.compileShader(s);
      if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) { throw new Error(gl.getShaderInfoLog(s)); }
      return s;
    }
    var prog = gl.createProgram();
    gl.attachShader(prog, shader(gl.VERTEX_SHADER,
      "attribute vec3 p; attribute vec3 n; uniform mat3 R; uniform vec3 s; uniform vec2 pan; varying vec3 vn;" +
      "void main(){ vec3 q = R * p; vn = R * n; gl_Position = vec4(q.x * s.x + pan.x, q.y * s.y + pan.y, -q.z * s.z, 1.0); }"));
    gl.attachShader(prog, shader(gl.FRAGMENT_SHADER,
      "precision mediump float; varying vec3 vn; uniform vec3 l1; uniform vec3 l2;" +
      "void main(){ vec3 n = normalize(vn); if (n.z < 0.0) n = -n;" +
      " float d1 = max(dot(n, l1), 0.0); float d2 = max(dot(n, l2), 0.0);" +
      " vec3 col = vec3(0.86, 0.72, 0.55) * (0.22 + 0.68 * d1 + 0.25 * d2) + vec3(0.18) * pow(d1, 24.0);" +
      " gl_FragColor = vec4(min(col, vec3(1.0)), 1.0); }"));
    gl.linkProgram(prog);
    gl.useProgram(prog);
    // one position + normal per triangle corner (no index extension needed)
    var P = new Float32Array(9 * nf), NN = new Float32Array(9 * nf);
    for (var t = 0; t < nf; t++) {
      for (var m = 0; m < 3; m++) {
        var j = F[3 * t + m];
        for (var q = 0; q < 3; q++) { P[9 * t + 3 * m + q] = V[3 * j + q]; NN[9 * t + 3 * m + q] = N[3 * j + q]; }
      }
    }
    function attrib(name, data) {
      var buf = gl.createBuffer(), loc = gl.getAttribLocation(prog, name);
      gl.bindBuffer(gl.ARRAY_BUFFER, buf); gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
      gl.enableVertexAttribArray(loc); gl.vertexAttribPointer(loc, 3, gl.FLOAT, false, 0, 0);
    }
    attrib("p", P); attrib("n", NN);
    var uR = gl.getUniformLocation(prog, "R"), uS = gl.getUniformLocation(prog, "s"), uPan = gl.getUniformLocation(prog, "pan");
    gl.uniform3fv(gl.getUniformLocation(prog, "l1"), L1); gl.uniform3fv(gl.getUniformLocation(prog, "l2"), L2);
    gl.enable(gl.DEPTH_TEST);
    return function (w, h) {
      var e = halfExtents(w, h);
      gl.viewport(0, 0, canvas.width, canvas.height);
      gl.clearColor(0.953, 0.953, 0.953, 1); gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
      gl.uniformMatrix3fv(uR, false, [R[0], R[3], R[6], R[1], R[4], R[7], R[2], R[5], R[8]]);  // column-major
      gl.uniform3f(uS, 1 / e[0], 1 / e[1], 0.9 / radius);
      gl.uniform2f(uPan, pan[0], pan[1]);
      gl.drawArrays(gl.TRIANGLES, 0, 3 * nf);
    };
  }

  function canvas2dRenderer() {
    var ctx = canvas.getContext("2d");
    if (!ctx) { return null; }
    var X = new Float32Array(nv), Y = new Float32Array(nv), Z = new Float32Array(nv), depth = new Float32Array(nf);
    var order = new Uint32Array(nf);
    return function (w, h) {
      var e = halfExtents(w, h), sx = canvas.width / (2 * e[0]), sy = canvas.height / (2 * e[1]);
      var cx = canvas.width * (1 + pan[0]) / 2, cy = canvas.height * (1 - pan[1]) / 2, t, j;
      for (j = 0; j < nv; j++) {
        var x = V[3 * j], y = V[3 * j + 1], z = V[3 * j + 2];
        X[j] = cx + sx * (R[0] * x + R[1] * y + R[2] * z);
        Y[j] = cy - sy * (R[3] * x + R[4] * y + R[5] * z);
        Z[j] = R[6] * x + R[7] * y + R[8] * z;
      }
      for (t = 0; t < nf; t++) { order[t] = t; depth[t] = Z[F[3 * t]] + Z[F[3 * t + 1]] + Z[F[3 * t + 2]]; }
      order.sort(function (p, q) { return depth[p] - depth[q]; });  // far first
      ctx.fillStyle = "#f3f3f3"; ctx.fillRect(0, 0, canvas.width, canvas.height);
      ctx.lineWidth = 0.6; ctx.lineJoin = "round";
      for (var o = 0; o < nf; o++) {
        t = order[o];
        var n0 = FN[3 * t], n1 = FN[3 * t + 1], n2 = FN[3 * t + 2];
        var rx = R[0] * n0 + R[1] * n1 + R[2] * n2, ry = R[3] * n0 + R[4] * n1 + R[5] * n2, rz = R[6] * n0 + R[7] * n1 + R[8] * n2;
        var s = Math.hypot(rx, ry, rz) || 1; rx /= s; ry /= s; rz /= s;
        if (rz < 0) { rx = -rx; ry = -ry; rz = -rz; }
        var d1 = Math.max(rx * L1[0] + ry * L1[1] + rz * L1[2], 0), d2 = Math.max(rx * L2[0] + ry * L2[1] + rz * L2[2], 0);
        var f = 0.22 + 0.68 * d1 + 0.25 * d2, sp = 0.18 * Math.pow(d1, 24);
        var col = "rgb(" + Math.min(255, Math.round(255 * (BASE[0] * f + sp))) + "," + Math.min(255, Math.round(255 * (BASE[1] * f + sp))) + "," +
                  Math.min(255, Math.round(255 * (BASE[2] * f + sp))) + ")";
        var a = F[3 * t], b = F[3 * t + 1], dd = F[3 * t + 2];
        ctx.beginPath(); ctx.moveTo(X[a], Y[a]); ctx.lineTo(X[b], Y[b]); ctx.lineTo(X[dd], Y[dd]); ctx.closePath();
        ctx.fillStyle = col; ctx.strokeStyle = col; ctx.fill(); ctx.stroke();
      }
    };
  }

  var render = webglRenderer(), mode = "webgl";
  if (!render) { render = canvas2dRenderer(); mode = "canvas2d"; }
  if (!render) {
    var msg = document.createElement("div");
    msg.className = "nogl";
    msg.textContent = "This browser cannot draw on a canvas: the 3D view is not available (the mesh is in the session file; 'vastcal reconstruct --mesh' saves it).";
    wrap.replaceChild(msg, canvas);
    return;
  }
  var scaleBar = wrap.querySelector(".scale div"), scaleText = wrap.querySelector(".scale span");
  function niceLength(len) { var e = Math.pow(10, Math.floor(Math.log10(len))), f = len / e; return (f >= 5 ? 5 : f >= 2 ? 2 : 1) * e; }
  function draw() {
    var dpr = window.devicePixelRatio || 1, w = canvas.clientWidth || 800, h = canvas.clientHeight || 520;
    if (canvas.width !== Math.round(w * dpr) || canvas.height !== Math.round(h * dpr)) { canvas.width = Math.round(w * dpr); canvas.height = Math.round(h * dpr); }
    render(w, h);
    var pxPerUm = w / (2 * halfExtents(w, h)[0]), len = niceLength(0.25 * w / pxPerUm);
    scaleBar.style.width = Math.round(len * pxPerUm) + "px";
    scaleText.textContent = (len >= 1000 ? (len / 1000) + " mm" : len + " \u00b5m");
  }
  var drag = null, pending = false;
  function redraw() { if (!pending) { pending = true; requestAnimationFrame(function () { pending = false; draw(); }); } }
  canvas.addEventListener("pointerdown", function (e) {
    drag = { x: e.clientX, y: e.clientY, pan: e.shiftKey || e.button === 2 }; canvas.setPointerCapture(e.pointerId);
  });
  canvas.addEventListener("pointermove", function (e) {
    if (!drag) { return; }
    var dx = e.clientX - drag.x, dy = e.clientY - drag.y; drag.x = e.clientX; drag.y = e.clientY;
    if (drag.pan) { pan[0] += 2 * dx / canvas.clientWidth; pan[1] -= 2 * dy / canvas.clientHeight; }
    else { R = mul(mul(rotY(dx * 0.01), rotX(dy * 0.01)), R); }
    redraw();
  });
  canvas.addEventListener("pointerup", function () { drag = null; });
  canvas.addEventListener("contextmenu", function (e) { e.preventDefault(); });
  canvas.addEventListener("wheel", function (e) { e.preventDefault(); zoom *= Math.exp(-e.deltaY * 0.0015); redraw(); }, { passive: false });
  function preset(name) { R = PRESETS[name].slice(); zoom = 1; pan = [0, 0]; fitView(); redraw(); }
  canvas.addEventListener("dblclick", function () { preset("side"); });
  Array.prototype.forEach.call(wrap.querySelectorAll("button[data-view]"), function (b) {
    b.addEventListener("click", function () { preset(b.dataset.view); });
  });
  window.addEventListener("resize", redraw);
  R = mul(mul(rotY(-0.5), rotX(0.45)), R);  // open on an oblique view: depth visible at once
  fitView();
  draw();
  canvas.dataset.drawn = String(nf);
  canvas.dataset.renderer = mode;
})();
