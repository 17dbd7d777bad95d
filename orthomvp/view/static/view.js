// orthomvp view: the map (Leaflet over the DEM's own frame), legend, hover readout and clicks.
// The configuration comes inlined from the server (or the export); map coordinates are the
// DEM CRS's (lng = x = easting, lat = y = northing), so nothing is reprojected here.
"use strict";
(function () {
  const cfg = JSON.parse(document.getElementById("config").textContent);
  const t = cfg.transformation;
  const crs = L.extend({}, L.CRS.Simple, {
    transformation: new L.Transformation(t[0], t[1], t[2], t[3]),
    infinite: true,
  });
  const map = L.map("map", {
    crs: crs, minZoom: -1, maxZoom: cfg.maxZoom, zoomSnap: 0.25, zoomDelta: 0.5,
    attributionControl: false,
  });
  map.fitBounds(cfg.bounds);
  const state = { layer: null, tiles: null, busy: false };
  window.orthomvpView = { map: map, cfg: cfg, state: state };

  // ------------------------------------------------------------------ layers and legend
  const layersDiv = document.getElementById("layers");
  cfg.layers.forEach((lay, i) => {
    const label = document.createElement("label");
    label.innerHTML = `<input type="radio" name="layer" value="${lay.id}"> `;
    label.appendChild(document.createTextNode(lay.title));
    label.title = lay.title;
    label.querySelector("input").addEventListener("change", () => showLayer(lay));
    layersDiv.appendChild(label);
  });
  const problems = document.getElementById("problems");
  cfg.problems.forEach(([path, reason]) => {
    const div = document.createElement("div");
    div.textContent = `not shown: ${reason}`;
    div.title = path;
    problems.appendChild(div);
  });

  function showLayer(lay) {
    if (state.tiles) map.removeLayer(state.tiles);
    state.layer = lay;
    state.tiles = L.tileLayer(`tiles/${lay.id}/{z}/{x}/{y}.png`, {
      tileSize: 256, noWrap: true, maxNativeZoom: cfg.maxNativeZoom, maxZoom: cfg.maxZoom,
      minNativeZoom: 0, bounds: cfg.bounds,
    }).addTo(map);
    state.tiles.bringToBack();
    layersDiv.querySelector(`input[value="${lay.id}"]`).checked = true;
    drawLegend(lay);
  }

  function fmt(v) {
    const a = Math.abs(v);
    return a >= 100 ? v.toFixed(0) : a >= 1 ? v.toFixed(1) : v.toPrecision(2);
  }

  function drawLegend(lay) {
    const g = lay.legend, div = document.getElementById("legend");
    div.innerHTML = "";
    if (g.type === "ramp") {
      div.innerHTML = `<div>${lay.title}: ${g.label} (${g.unit})</div>` +
        `<div class="ramp" style="background:linear-gradient(to right,${g.colours.join(",")})"></div>` +
        `<div class="ramp-labels"><span>${fmt(g.lo)} ${g.unit}</span>` +
        `<span>${fmt((g.lo + g.hi) / 2)}</span><span>${fmt(g.hi)} ${g.unit}</span></div>`;
      if (lay.kind === "relief" || lay.kind === "height")
        div.innerHTML += "<div>shaded from the north-west</div>";
    } else if (g.type === "classes") {
      g.items.forEach(([label, colour]) => {
        div.innerHTML += `<div><span class="swatch" style="background:${colour}"></span>${label}</div>`;
      });
    } else {
      div.innerHTML = `<div>image values, grey or RGB stretched from ${fmt(g.lo)} to ${fmt(g.hi)}</div>` +
        `<div><span class="swatch" style="background:#966ec8"></span>no value</div>`;
    }
  }
  showLayer(cfg.layers[0]);

  // ------------------------------------------------------------------ graticule, scale bar
  const grat = L.layerGroup().addTo(map);
  cfg.graticule.forEach((line) => {
    const pts = line.points.map(([x, y]) => [y, x]);
    if (pts.length < 2) return;
    L.polyline(pts, { color: "#fff", weight: 1, opacity: 0.55, interactive: false }).addTo(grat);
    const at = pts[0];
    L.marker(at, { interactive: false, icon: L.divIcon({ className: "grat-label",
      html: line.label, iconSize: null }) }).addTo(grat);
  });
  const Scale = L.Control.extend({
    options: { position: "bottomleft" },
    onAdd: function () {
      this.div = L.DomUtil.create("div", "scalebar");
      map.on("zoomend moveend", () => this.update());
      this.update();
      return this.div;
    },
    update: function () {
      const mpp = cfg.metresPerUnit / (t[0] * Math.pow(2, map.getZoom()));
      const target = 120 * mpp, p = Math.pow(10, Math.floor(Math.log10(target)));
      const m = [5, 2, 1].map((k) => k * p).find((v) => v <= target) || p;
      this.div.style.width = `${Math.round(m / mpp)}px`;
      this.div.textContent = m >= 1000 ? `${m / 1000} km` : `${m} m`;
      this.div.dataset.metres = m;
    },
  });
  new Scale().addTo(map);

  // ------------------------------------------------------------------ hover readout
  const readout = document.getElementById("readout");
  let pending = null, last = 0;
  map.on("mousemove", (e) => {
    pending = e.latlng;
    const now = Date.now();
    if (now - last > 80) { last = now; hover(); } else setTimeout(hover, 90);
  });
  function hover() {
    if (!pending) return;
    const ll = pending;
    pending = null;
    if (!cfg.live) { staticHover(ll); return; }
    fetch(`api/point?x=${ll.lng}&y=${ll.lat}`).then((r) => r.json()).then((d) => {
      if (d.error) { readout.textContent = d.error; return; }
      let html = `<table><tr><td>lon, lat</td><td id="lonlat">${d.lon.toFixed(6)}, ${d.lat.toFixed(6)}</td></tr>`;
      cfg.layers.forEach((lay) => {
        const v = d.values[lay.id];
        html += `<tr><td>${lay.title}</td><td data-layer="${lay.id}">${v === null ? "outside" : v}</td></tr>`;
      });
      readout.innerHTML = html + "</table>";
      readout.dataset.x = ll.lng; readout.dataset.y = ll.lat;
    });
  }

  // a static export: the values of the grid cell under the pointer (cfg.hover, see export.py)
  function staticHover(ll) {
    const h = cfg.hover;
    let html = `<table><tr><td>x, y</td><td>${ll.lng.toFixed(2)}, ${ll.lat.toFixed(2)}</td></tr>`;
    if (h) {
      const [l, b, r, t] = h.bounds;
      const i = Math.floor((ll.lng - l) / (r - l) * h.cols), j = Math.floor((t - ll.lat) / (t - b) * h.rows);
      const inside = i >= 0 && i < h.cols && j >= 0 && j < h.rows;
      cfg.layers.forEach((lay) => {
        const g = h.values[lay.id], k = inside ? g.cells[j * h.cols + i] : -1;
        const v = k < 0 ? null : g.words[k];
        html += `<tr><td>${lay.title}</td><td data-layer="${lay.id}">${v === null ? "outside" : v}</td></tr>`;
      });
      html += `<tr><td colspan="2" class="note">values on a ${h.cols} x ${h.rows} grid; the live viewer reads every post</td></tr>`;
    }
    readout.innerHTML = html + "</table>";
    readout.dataset.x = ll.lng; readout.dataset.y = ll.lat;
  }

  // ------------------------------------------------------------------ clicks
  const section = document.getElementById("clicksection");
  if (!cfg.live || cfg.views.length === 0) {
    section.querySelector("#controls").style.display = "none";
    document.getElementById("status").textContent = cfg.live
      ? "clicks need the views: give IMAGE CAMERA pairs after the DEM"
      : "a static export: the live objective needs orthomvp view";
  } else {
    const vs = document.getElementById("viewset");
    cfg.views.forEach((name, k) => {
      vs.innerHTML += `<label><input type="checkbox" class="view" value="${k}" checked> ${name}</label>`;
    });
    map.on("click", (e) => click(e.latlng));
  }
  let marker = null;
  function click(ll) {
    const status = document.getElementById("status");
    if (marker) map.removeLayer(marker);
    marker = L.circleMarker(ll, { radius: 6, color: "#ff4fd8", weight: 2 }).addTo(map);
    const views = Array.from(document.querySelectorAll("input.view"))
      .filter((c) => c.checked).map((c) => c.value).join(",");
    const q = new URLSearchParams({ x: ll.lng, y: ll.lat, views: views,
      hwin: document.getElementById("hwin").value, trange: document.getElementById("trange").value });
    const hr = document.getElementById("hrange").value;
    if (hr) q.set("hrange", hr);
    status.className = ""; status.textContent = "computing the objective...";
    state.busy = true;
    fetch(`api/click?${q}`).then((r) => r.json()).then((d) => {
      state.busy = false;
      showClick(d);
      if (!d.error || d.post) load3d(ll);
    }).catch((err) => { state.busy = false; status.className = "error"; status.textContent = String(err); });
  }
  function showClick(d) {
    const status = document.getElementById("status"), result = document.getElementById("result");
    const plots = document.getElementById("plots"), patches = document.getElementById("patches");
    plots.innerHTML = ""; patches.innerHTML = ""; result.innerHTML = "";
    if (d.error) { status.className = "error"; status.textContent = d.error; }
    else status.textContent = "";
    if (!d.post) return;
    let html = `<div>post (${d.post[0]}, ${d.post[1]}) at ${d.lon.toFixed(6)}, ${d.lat.toFixed(6)};` +
      ` DEM ${d.dem_height.toFixed(2)} m</div>`;
    if (d.fitted_file !== null)
      html += `<div>fitted DEM <span id="fitted">${d.fitted_file.toFixed(2)}</span> m` +
        (d.sigma_file !== null ? ` &plusmn; ${d.sigma_file.toFixed(2)} m` : "") + "</div>";
    if (d.rplot) {
      html += `<div>rplot minimum h = <span id="hmin">${d.rplot.h_min.toFixed(3)}</span> m` +
        ` (${d.rplot.local_minima} local minima); live fit ${d.fit.h.toFixed(2)} m in ${d.fit.steps} steps</div>`;
      if (d.fitted_file !== null)
        html += "<div class=\"note\">the live fit is this post's plane; orthomvp fit's DEM holds its plane" +
          " deconvolved with its neighbours' (--deconvolve), metres apart on steep or curved ground</div>";
    }
    html += "<table><tr><th>view</th><th>code</th><th>emission</th><th>used</th><th>corr</th></tr>";
    d.views.forEach((v) => {
      html += `<tr><td title="${v.name}">${v.name}</td><td>${v.code}</td><td>${v.emission.toFixed(1)}&deg;</td>` +
        `<td>${v.used ? "yes" : "no"}</td><td>${isNaN(v.loo) || v.loo === null ? "" : v.loo.toFixed(2)}</td></tr>`;
    });
    result.innerHTML = html + "</table>";
    if (d.rplot) {
      [["rplot", d.rplot.png], ["llplot", d.llplot.png], ["patches", d.patches.png]].forEach(([id, src]) => {
        const img = document.createElement("img");
        img.id = `plot-${id}`; img.src = src; img.alt = id;
        (id === "patches" ? patches : plots).appendChild(img);
      });
    }
  }
  function load3d(ll) {
    if (!window.orthomvp3d) return;
    const id = state.layer ? state.layer.id : "L0";
    fetch(`api/scene?x=${ll.lng}&y=${ll.lat}&layer=${id}`).then((r) => r.json()).then((s) => {
      if (!s.error) window.orthomvp3d.show(s);
    });
  }
})();
