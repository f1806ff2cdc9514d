// The dfc viewer: OpenSeadragon on the server's IIIF images, a scale bar in input pixels, the file's curves as an
// overlay, a cursor readout (domain coordinate and decoded value) and a side-by-side view of the input raster
// (upsampled bicubically by the server), both viewers locked together. window.dfcViewer exposes the state and
// zoomTo(zoom, x, y) (zoom: screen pixels per input pixel, centre in domain units) for scripts and tests.
"use strict";
(function () {
  const params = new URLSearchParams(location.search);
  const byId = (id) => document.getElementById(id);
  const state = { file: null, left: null, right: null, curves: null };
  window.dfcViewer = state;

  function options(id) {
    return {
      id, prefixUrl: "/static/images/", drawer: "canvas", showNavigator: false, showRotationControl: false,
      maxZoomPixelRatio: 4, minZoomImageRatio: 0.5, visibilityRatio: 0.1, animationTime: 0.5,
      preserveImageSizeOnResize: true,  // showing or hiding the input raster halves or doubles a pane: keep the zoom
      gestureSettingsMouse: { clickToZoom: false },
    };
  }

  // screen pixels per input pixel in viewer v
  function inputZoom(v) {
    return v.viewport.viewportToImageZoom(v.viewport.getZoom(true)) * state.file.scale;
  }

  function domainToGrid(x, y) {
    const [x0, y0, x1, y1] = state.file.domain;
    return new OpenSeadragon.Point((x - x0) * state.file.width / (x1 - x0), (y - y0) * state.file.height / (y1 - y0));
  }

  function gridToDomain(p) {
    const [x0, y0, x1, y1] = state.file.domain;
    return [x0 + p.x * (x1 - x0) / state.file.width, y0 + p.y * (y1 - y0) / state.file.height];
  }

  function niceNumber(target) {  // the largest 1, 2 or 5 × 10^k not above target
    const p = Math.pow(10, Math.floor(Math.log10(target)));
    return [5, 2, 1].map((m) => m * p).find((v) => v <= target) || p;
  }

  function formatNumber(v) {
    return Math.abs(v) >= 1e4 || Math.abs(v) < 1e-3 && v !== 0 ? v.toExponential(3) : String(+v.toPrecision(6));
  }

  function updateBar() {
    const z = inputZoom(state.left);
    byId("zoom").textContent = `${formatNumber(+z.toPrecision(3))}×`;
    const length = niceNumber(120 / z);
    byId("bar").style.width = `${Math.round(length * z)}px`;
    byId("barlabel").textContent = `${formatNumber(length)} input px`;
  }

  function drawCurves() {
    const canvas = byId("overlay"), element = state.left.element;
    canvas.width = element.clientWidth;
    canvas.height = element.clientHeight;
    canvas.style.top = `${element.offsetTop}px`;
    const ctx = canvas.getContext("2d");
    ctx.clearRect(0, 0, canvas.width, canvas.height);
    if (!byId("curves").checked || !state.curves) return;
    const at = (x, y) => state.left.viewport.imageToViewerElementCoordinates(domainToGrid(x, y));
    ctx.strokeStyle = "rgba(255, 40, 200, 0.9)";
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    for (const [ax, ay, bx, by] of state.curves.segments) {
      const a = at(ax, ay), b = at(bx, by);
      ctx.moveTo(a.x, a.y);
      ctx.lineTo(b.x, b.y);
    }
    for (const c of state.curves.cubics) {
      const p = [0, 2, 4, 6].map((k) => at(c[k], c[k + 1]));
      ctx.moveTo(p[0].x, p[0].y);
      ctx.bezierCurveTo(p[1].x, p[1].y, p[2].x, p[2].y, p[3].x, p[3].y);
    }
    ctx.stroke();
  }

  function update() {
    updateBar();
    drawCurves();
  }

  let pending = null, busy = false;
  function readout(event, viewer) {
    const rect = viewer.element.getBoundingClientRect();
    const point = new OpenSeadragon.Point(event.clientX - rect.left, event.clientY - rect.top);
    pending = gridToDomain(viewer.viewport.viewerElementToImageCoordinates(point));
    if (!busy) next();
  }

  function next() {
    if (!pending) return;
    const [x, y] = pending;
    pending = null;
    busy = true;
    fetch(`/api/value/${encodeURIComponent(state.file.id)}?x=${x}&y=${y}`).then((r) => r.json()).then((d) => {
      const values = d.channels.map((c, k) => `${c} ${d.value[k].toFixed(4)}`).join(" ");
      byId("readout").textContent = `x ${formatNumber(x)}  y ${formatNumber(y)}  ${d.inside ? values : "(outside)"}`;
    }).catch(() => {}).finally(() => { busy = false; next(); });
  }

  // the input raster's viewer (state.right, while shown) and the file's (state.left) show the same view: each
  // follows the other's viewport (the panes are equally wide)
  let syncing = false;
  function follow(src, dst) {
    if (syncing || !src || !dst) return;
    syncing = true;
    dst.viewport.zoomTo(src.viewport.getZoom(), null, true);
    dst.viewport.panTo(src.viewport.getCenter(), true);
    syncing = false;
  }

  function showCompare(on) {
    const file = state.file;
    byId("rightpane").hidden = !on;
    if (on && !state.right) {
      byId("righttitle").textContent = `${file.compare.name} (input raster, bicubic)`;
      const right = state.right = OpenSeadragon(options("right"));
      right.addHandler("open", () => follow(state.left, right));
      right.addHandler("viewport-change", () => follow(right, state.left));
      right.open(file.compare.info);
    } else if (!on && state.right) {  // a hidden viewer has no size to follow: closed, and opened again when shown
      state.right.destroy();
      state.right = null;
    }
    setTimeout(update, 0);
  }

  state.zoomTo = function (zoom, x, y) {
    const v = state.left.viewport;
    v.zoomTo(v.imageToViewportZoom(zoom / state.file.scale), null, true);
    v.panTo(v.imageToViewportCoordinates(domainToGrid(x, y)), true);
    state.left.forceRedraw();
    if (state.right) state.right.forceRedraw();
  };

  state.fullyLoaded = function () {
    return [state.left, state.right].every((v) => !v || (v.world.getItemCount() > 0 && v.world.getItemAt(0).getFullyLoaded()));
  };

  function start(files) {
    const select = byId("file");
    for (const f of files) select.add(new Option(f.name, f.id));
    const file = files.find((f) => f.id === params.get("file")) || files[0];
    select.value = file.id;
    select.addEventListener("change", () => { location.search = `?file=${encodeURIComponent(select.value)}`; });
    state.file = file;
    byId("lefttitle").textContent = `${file.name} (dfc)`;
    state.left = OpenSeadragon(options("left"));
    state.left.open(file.info);
    for (const name of ["animation", "update-viewport", "resize", "open"]) state.left.addHandler(name, update);
    state.left.addHandler("viewport-change", () => follow(state.left, state.right));
    state.left.element.addEventListener("mousemove", (e) => readout(e, state.left));
    byId("right").addEventListener("mousemove", (e) => { if (state.right) readout(e, state.right); });
    fetch(`/api/curves/${encodeURIComponent(file.id)}`).then((r) => r.json()).then((c) => { state.curves = c; update(); });
    byId("curves").addEventListener("change", update);
    const compare = byId("compare");
    byId("comparelabel").hidden = !file.compare;
    compare.addEventListener("change", () => showCompare(compare.checked));
    if (file.compare && params.get("compare") === "1") {
      compare.checked = true;
      showCompare(true);
    }
  }

  fetch("/api/files").then((r) => r.json()).then(start);
})();
