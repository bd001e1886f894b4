// Full-resolution view overlays: click a view to open it; wheel zooms about the cursor, drag pans,
// arrow keys step through the views, 0 fits, 1 shows 1:1 (one frame pixel per screen pixel), Esc closes.
(function () {
  "use strict";
  var box = document.getElementById("lightbox");
  if (!box) { return; }
  var stage = box.querySelector(".lb-stage"), caption = box.querySelector(".lb-caption"), zoomLabel = box.querySelector(".lb-zoom");
  var views = Array.prototype.slice.call(document.querySelectorAll(".view"));
  var cur = -1, sc = 1, tx = 0, ty = 0, W = 1, H = 1, drag = null;
  function apply() {
    var f = stage.firstChild;
    if (!f) { return; }
    f.style.transform = "translate(" + tx + "px," + ty + "px) scale(" + sc + ")";
    f.querySelector("img").style.imageRendering = sc >= 2 ? "pixelated" : "auto";
    f.querySelector("path").style.strokeWidth = String(1.5 / sc);  // 1.5 screen pixels at any zoom
    zoomLabel.textContent = Math.round(sc * 100) + " %";
  }
  function fit() {
    var r = box.getBoundingClientRect();
    sc = Math.min((r.width - 40) / W, (r.height - 80) / H);
    tx = (r.width - W * sc) / 2; ty = 40 + (r.height - 40 - H * sc) / 2;
    apply();
  }
  function zoomAt(f, x, y) { tx = x - (x - tx) * f; ty = y - (y - ty) * f; sc *= f; apply(); }
  function show(i) {
    cur = (i + views.length) % views.length;
    var v = views[cur];
    W = +v.dataset.width; H = +v.dataset.height;
    var frame = v.querySelector(".frame").cloneNode(true);
    frame.classList.add("full");
    frame.style.width = W + "px"; frame.style.height = H + "px";
    stage.textContent = "";
    stage.appendChild(frame);
    caption.textContent = v.querySelector("figcaption").textContent + "  (" + W + " \u00d7 " + H + " px)";
    box.hidden = false;
    fit();
  }
  function close() { box.hidden = true; stage.textContent = ""; if (views[cur]) { views[cur].focus(); } }
  views.forEach(function (v, i) {
    v.addEventListener("click", function () { show(i); });
    v.addEventListener("keydown", function (e) { if (e.key === "Enter" || e.key === " ") { e.preventDefault(); show(i); } });
  });
  box.querySelector(".lb-close").addEventListener("click", close);
  box.querySelector(".lb-prev").addEventListener("click", function () { show(cur - 1); });
  box.querySelector(".lb-next").addEventListener("click", function () { show(cur + 1); });
  box.querySelector(".lb-fit").addEventListener("click", fit);
  box.querySelector(".lb-one").addEventListener("click", function () {
    var r = box.getBoundingClientRect(); zoomAt(1 / sc, r.width / 2, r.height / 2);
  });
  box.addEventListener("wheel", function (e) { e.preventDefault(); zoomAt(Math.exp(-e.deltaY * 0.0015), e.clientX, e.clientY); }, { passive: false });
  box.addEventListener("pointerdown", function (e) {
    if (e.target.closest(".lb-bar")) { return; }
    drag = { x: e.clientX, y: e.clientY, tx: tx, ty: ty }; box.setPointerCapture(e.pointerId); box.style.cursor = "grabbing";
  });
  box.addEventListener("pointermove", function (e) {
    if (!drag) { return; }
    tx = drag.tx + e.clientX - drag.x; ty = drag.ty + e.clientY - drag.y; apply();
  });
  box.addEventListener("pointerup", function () { drag = null; box.style.cursor = ""; });
  document.addEventListener("keydown", function (e) {
    if (box.hidden) { return; }
    if (e.key === "Escape") { close(); } else if (e.key === "ArrowLeft") { show(cur - 1); } else if (e.key === "ArrowRight") { show(cur + 1); }
    else if (e.key === "0") { fit(); } else if (e.key === "1") { var r = box.getBoundingClientRect(); zoomAt(1 / sc, r.width / 2, r.height / 2); }
    else if (e.key === "+" || e.key === "=") { zoomAt(1.25, innerWidth / 2, innerHeight / 2); } else if (e.key === "-") { zoomAt(0.8, innerWidth / 2, innerHeight / 2); }
  });
})();
