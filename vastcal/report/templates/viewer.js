// A small WebGL viewer of the measured mesh (no library, works from file://): drag rotates,
// shift-drag or right-drag pans, the wheel zooms, double-click or "side" resets. Orthographic
// projection, so the scale bar (micrometres) holds everywhere in the picture.
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
  var nv = V.length / 3, nf = F.length / 3;
  // centre and radius (µm)
  var lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity], i, k;
  for (i = 0; i < nv; i++) { for (k = 0; k < 3; k++) { lo[k] = Math.min(lo[k], V[3 * i + k]); hi[k] = Math.max(hi[k], V[3 * i + k]); } }
  var c = [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2];
  var radius = 0.5 * Math.sqrt(Math.pow(hi[0] - lo[0], 2) + Math.pow(hi[1] - lo[1], 2) + Math.pow(hi[2] - lo[2], 2)) || 1;
  // area-weighted vertex normals, then one position + normal per triangle corner (no index extension needed)
  var N = new Float32Array(3 * nv), P = new Float32Array(9 * nf), NN = new Float32Array(9 * nf);
  for (i = 0; i < nf; i++) {
    var a = F[3 * i], b = F[3 * i + 1], d = F[3 * i + 2];
    var ux = V[3 * b] - V[3 * a], uy = V[3 * b + 1] - V[3 * a + 1], uz = V[3 * b + 2] - V[3 * a + 2];
    var vx = V[3 * d] - V[3 * a], vy = V[3 * d + 1] - V[3 * a + 1], vz = V[3 * d + 2] - V[3 * a + 2];
    var n0 = uy * vz - uz * vy, n1 = uz * vx - ux * vz, n2 = ux * vy - uy * vx;
    [a, b, d].forEach(function (j) { N[3 * j] += n0; N[3 * j + 1] += n1; N[3 * j + 2] += n2; });
  }
  for (i = 0; i < nf; i++) {
    for (var m = 0; m < 3; m++) {
      var j = F[3 * i + m];
      for (k = 0; k < 3; k++) { P[9 * i + 3 * m + k] = V[3 * j + k] - c[k]; NN[9 * i + 3 * m + k] = N[3 * j + k]; }
    }
  }
  var gl = canvas.getContext("webgl", { antialias: true, preserveDrawingBuffer: true }) ||
           canvas.getContext("experimental-webgl", { preserveDrawingBuffer: true });
  if (!gl) {
    var msg = document.createElement("div");
    msg.className = "nogl";
    msg.textContent = "This browser offers no WebGL: the 3D view cannot be drawn (the mesh is in the session file and can be saved with 'vastcal reconstruct --mesh').";
    wrap.replaceChild(msg, canvas);
    return;
  }
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
    "precision mediump float; varying vec3 vn;" +
    "void main(){ vec3 n = normalize(vn); if (n.z < 0.0) n = -n;" +
    " float d1 = max(dot(n, normalize(vec3(0.35, 0.55, 0.75))), 0.0); float d2 = max(dot(n, normalize(vec3(-0.6, -0.3, 0.5))), 0.0);" +
    " vec3 col = vec3(0.86, 0.72, 0.55) * (0.22 + 0.68 * d1 + 0.25 * d2) + vec3(0.18) * pow(d1, 24.0);" +
    " gl_FragColor = vec4(min(col, vec3(1.0)), 1.0); }"));
  gl.linkProgram(prog);
  gl.useProgram(prog);
  function attrib(name, data) {
    var buf = gl.createBuffer(), loc = gl.getAttribLocation(prog, name);
    gl.bindBuffer(gl.ARRAY_BUFFER, buf); gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
    gl.enableVertexAttribArray(loc); gl.vertexAttribPointer(loc, 3, gl.FLOAT, false, 0, 0);
  }
  attrib("p", P); attrib("n", NN);
  var uR = gl.getUniformLocation(prog, "R"), uS = gl.getUniformLocation(prog, "s"), uPan = gl.getUniformLocation(prog, "pan");
  gl.enable(gl.DEPTH_TEST);
  // view: rows = screen right, screen up, towards the viewer, in world coordinates (world x = rotation axis)
  var PRESETS = { side: [1, 0, 0, 0, -1, 0, 0, 0, -1], top: [1, 0, 0, 0, 0, 1, 0, -1, 0], end: [0, 0, 1, 0, -1, 0, 1, 0, 0] };
  var R = PRESETS.side.slice(), zoom = 1, pan = [0, 0];
  function mul(A, B) {
    var C = new Array(9);
    for (var r = 0; r < 3; r++) { for (var q = 0; q < 3; q++) { C[3 * r + q] = A[3 * r] * B[q] + A[3 * r + 1] * B[3 + q] + A[3 * r + 2] * B[6 + q]; } }
    return C;
  }
  function rotX(t) { var co = Math.cos(t), si = Math.sin(t); return [1, 0, 0, 0, co, -si, 0, si, co]; }
  function rotY(t) { var co = Math.cos(t), si = Math.sin(t); return [co, 0, si, 0, 1, 0, -si, 0, co]; }
  var scaleBar = wrap.querySelector(".scale div"), scaleText = wrap.querySelector(".scale span");
  function niceLength(len) { var e = Math.pow(10, Math.floor(Math.log10(len))), f = len / e; return (f >= 5 ? 5 : f >= 2 ? 2 : 1) * e; }
  function draw() {
    var dpr = window.devicePixelRatio || 1, w = canvas.clientWidth || 800, h = canvas.clientHeight || 520;
    if (canvas.width !== Math.round(w * dpr) || canvas.height !== Math.round(h * dpr)) { canvas.width = Math.round(w * dpr); canvas.height = Math.round(h * dpr); }
    gl.viewport(0, 0, canvas.width, canvas.height);
    gl.clearColor(0.953, 0.953, 0.953, 1); gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    var halfW = Math.max(1.02 * radius, 1.02 * radius * 0.5 * w / h) / zoom, halfH = halfW * h / w;  // µm from the centre to the edges
    gl.uniformMatrix3fv(uR, false, [R[0], R[3], R[6], R[1], R[4], R[7], R[2], R[5], R[8]]);  // column-major
    gl.uniform3f(uS, 1 / halfW, 1 / halfH, 0.9 / radius);
    gl.uniform2f(uPan, pan[0], pan[1]);
    gl.drawArrays(gl.TRIANGLES, 0, 3 * nf);
    var pxPerUm = w / (2 * halfW), L = niceLength(0.25 * w / pxPerUm);
    scaleBar.style.width = Math.round(L * pxPerUm) + "px";
    scaleText.textContent = (L >= 1000 ? (L / 1000) + " mm" : L + " \u00b5m");
  }
  var drag = null;
  canvas.addEventListener("pointerdown", function (e) {
    drag = { x: e.clientX, y: e.clientY, pan: e.shiftKey || e.button === 2 }; canvas.setPointerCapture(e.pointerId);
  });
  canvas.addEventListener("pointermove", function (e) {
    if (!drag) { return; }
    var dx = e.clientX - drag.x, dy = e.clientY - drag.y; drag.x = e.clientX; drag.y = e.clientY;
    if (drag.pan) { pan[0] += 2 * dx / canvas.clientWidth; pan[1] -= 2 * dy / canvas.clientHeight; }
    else { R = mul(mul(rotY(dx * 0.01), rotX(dy * 0.01)), R); }
    draw();
  });
  canvas.addEventListener("pointerup", function () { drag = null; });
  canvas.addEventListener("contextmenu", function (e) { e.preventDefault(); });
  canvas.addEventListener("wheel", function (e) { e.preventDefault(); zoom *= Math.exp(-e.deltaY * 0.0015); draw(); }, { passive: false });
  function preset(name) { R = PRESETS[name].slice(); zoom = 1; pan = [0, 0]; draw(); }
  canvas.addEventListener("dblclick", function () { preset("side"); });
  Array.prototype.forEach.call(wrap.querySelectorAll("button[data-view]"), function (b) {
    b.addEventListener("click", function () { preset(b.dataset.view); });
  });
  window.addEventListener("resize", draw);
  R = mul(mul(rotY(-0.5), rotX(0.45)), R);  // open on an oblique view: depth visible at once
  draw();
  canvas.dataset.drawn = String(nf);
})();
