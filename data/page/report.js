// report.html's own script: draws a voxlat run from the report and the preview mesh inlined in
// the page (three.js and its OrbitControls are inlined before it). Opens offline: nothing is
// fetched. With the address ending in #check, it also checks itself (the 3D view's pixels, the
// layer view's marks) and writes what it found into <pre id="voxlat-check">, for the tests.
(function () {
  "use strict";
  const report = JSON.parse(document.getElementById("voxlat-report").textContent);
  const meshData = JSON.parse(document.getElementById("voxlat-mesh").textContent);
  const root = document.getElementById("voxlat-page");

  const COLORS = { island: "#e0201b", trap: "#1f6fe0", thin: "#f39a00", drain: "#19a34a" };

  const style = document.createElement("style");
  style.textContent = [
    "body{font:14px/1.4 system-ui,sans-serif;margin:0;color:#222;background:#fafafa}",
    "#voxlat-page{max-width:1100px;margin:0 auto;padding:12px 20px 40px}",
    "h1{font-size:20px;margin:8px 0}h2{font-size:16px;margin:22px 0 6px;border-bottom:1px solid #ccc}",
    "table{border-collapse:collapse;margin:4px 0}td,th{border:1px solid #ddd;padding:2px 8px;text-align:right}",
    "th{background:#eee}td.l,th.l{text-align:left}canvas{background:#fff;border:1px solid #ccc;display:block}",
    ".row{display:flex;gap:16px;flex-wrap:wrap;align-items:flex-start}.muted{color:#777}",
    ".warn{background:#fff4e0;border-left:4px solid #f39a00;padding:4px 8px;margin:4px 0}",
    ".key span{display:inline-block;width:12px;height:12px;margin:0 4px 0 12px;vertical-align:middle;border-radius:6px}",
    "button.go{font-size:12px;padding:0 6px;margin-left:6px}",
  ].join("\n");
  document.head.appendChild(style);

  function el(tag, attrs, ...children) {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (k === "text") e.textContent = v;
      else e.setAttribute(k, v);
    }
    for (const c of children) if (c) e.appendChild(typeof c === "string" ? document.createTextNode(c) : c);
    root.appendChild(e);
    return e;
  }
  function section(title) {
    el("h2", { text: title });
  }
  function fmt(v, digits) {
    if (typeof v !== "number") return String(v);
    if (v === 0) return "0";
    const a = Math.abs(v);
    if (a >= 1e5 || a < 1e-3) return v.toExponential(digits || 3);
    return String(Number(v.toPrecision(digits || 4)));
  }
  function table(head, rows, target) {
    const t = document.createElement("table");
    if (head) {
      const tr = document.createElement("tr");
      for (const h of head) tr.appendChild(Object.assign(document.createElement("th"), { textContent: h }));
      t.appendChild(tr);
    }
    for (const r of rows) {
      const tr = document.createElement("tr");
      r.forEach((c, i) => {
        const td = document.createElement("td");
        if (i === 0) td.className = "l";
        if (c instanceof Node) td.appendChild(c);
        else td.textContent = typeof c === "number" ? fmt(c) : String(c);
        tr.appendChild(td);
      });
      t.appendChild(tr);
    }
    (target || root).appendChild(t);
    return t;
  }
  function decode(base64, Type) {
    const bytes = Uint8Array.from(atob(base64), (c) => c.charCodeAt(0));
    return new Type(bytes.buffer);
  }
  // How many different vertex colours (to 1/64 of each channel) a colour array holds.
  function distinctColours(colors) {
    const seen = new Set();
    for (let i = 0; i < colors.length; i += 3)
      seen.add(Math.round(64 * colors[i]) + "," + Math.round(64 * colors[i + 1]) + "," + Math.round(64 * colors[i + 2]));
    return seen.size;
  }
  // Perceptual colour ramp (viridis, 5 stops), t in [0, 1].
  function ramp(t) {
    const stops = [[0.267, 0.005, 0.329], [0.229, 0.322, 0.546], [0.128, 0.567, 0.551], [0.369, 0.789, 0.383], [0.993, 0.906, 0.144]];
    t = Math.min(1, Math.max(0, t)) * (stops.length - 1);
    const i = Math.min(stops.length - 2, Math.floor(t)), f = t - i;
    return stops[i].map((a, k) => a + (stops[i + 1][k] - a) * f);
  }

  // ---- heading --------------------------------------------------------------------------------
  el("h1", { text: "voxlat: " + (report.recipe || "run") });
  const summary = [];
  if (report.voxlat_version) summary.push("voxlat " + report.voxlat_version);
  if (report.result && typeof report.result.volume_mm3 === "number") summary.push("volume " + fmt(report.result.volume_mm3) + " mm³");
  if (report.result && typeof report.result.volume_fraction === "number") summary.push("relative density " + fmt(report.result.volume_fraction, 3));
  // A slice-only job has no result volume: the first slices output's exposed volume instead.
  const sliced = Array.isArray(report.slices) && report.slices.length ? report.slices[0] : null;
  if (!(report.result && typeof report.result.volume_mm3 === "number") && sliced && typeof sliced.exposed_volume_mm3 === "number")
    summary.push("exposed volume " + fmt(sliced.exposed_volume_mm3) + " mm³ (" + (sliced.layers || 0) + " layers of " + (sliced.file || "the slices") + ")");
  if (report.domain && report.domain.voxel) summary.push("voxel " + fmt(report.domain.voxel) + " mm");
  el("p", { class: "muted", text: summary.join(" · ") });
  if (Array.isArray(report.outputs) && report.outputs.length) el("p", { text: "Outputs: " + report.outputs.join(", ") });

  // ---- the mesh -------------------------------------------------------------------------------
  const points = meshData.vertices ? decode(meshData.points, Float32Array) : new Float32Array(0);
  const indices = meshData.triangles ? decode(meshData.indices, Uint32Array) : new Uint32Array(0);
  const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
  for (let i = 0; i < points.length; i += 3)
    for (let a = 0; a < 3; ++a) {
      lo[a] = Math.min(lo[a], points[i + a]);
      hi[a] = Math.max(hi[a], points[i + a]);
    }

  // The first graded field's slabs colour the part by achieved density.
  let graded = null;
  if (report.fields)
    for (const [name, f] of Object.entries(report.fields))
      if (f && f.slabs && Array.isArray(f.slabs.slabs) && f.slabs.slabs.length) {
        graded = { name: name, axis: "xyz".indexOf(f.slabs.axis), slabs: f.slabs.slabs };
        break;
      }

  const view = { pixels: 0 };
  section("The result in 3D");
  if (indices.length === 0) {
    el("p", { class: "muted", text: "No surface to show (the result is empty)." });
  } else {
    const canvas = el("canvas", { id: "view3d", width: 860, height: 520 });
    const caption = el("p", { class: "muted" });
    const renderer = new THREE.WebGLRenderer({ canvas: canvas, antialias: true, preserveDrawingBuffer: true });
    renderer.setClearColor(0xffffff, 1);
    const scene = new THREE.Scene();
    const geometry = new THREE.BufferGeometry();
    const attribute = THREE.Float32BufferAttribute ? THREE.Float32BufferAttribute : THREE.BufferAttribute;
    geometry.setAttribute
      ? geometry.setAttribute("position", new attribute(points, 3))
      : geometry.addAttribute("position", new attribute(points, 3));
    geometry.setIndex(new THREE.BufferAttribute(indices, 1));
    geometry.computeVertexNormals();
    const material = { side: THREE.DoubleSide, shininess: 20 };
    // Colours: the walls measured at each vertex (a recipe that grades them), else the achieved
    // density of the first graded field's slab the vertex lies in.
    let values = null, legend = null;
    if (meshData.colour && meshData.colour.values) {
      values = decode(meshData.colour.values, Float32Array);
      const sorted = Array.from(values).sort((a, b) => a - b);
      // The 2nd to 98th percentile spans the ramp (a few chords where walls meet read long).
      legend = { by: meshData.colour.by + " of `" + meshData.colour.field + "`", unit: meshData.colour.unit,
                 lo: sorted[Math.floor(0.02 * (sorted.length - 1))], hi: sorted[Math.floor(0.98 * (sorted.length - 1))],
                 note: meshData.colour.note };
    } else if (graded) {
      values = new Float32Array(points.length / 3);
      let dmin = Infinity, dmax = -Infinity;
      for (const s of graded.slabs) {
        dmin = Math.min(dmin, s.achieved);
        dmax = Math.max(dmax, s.achieved);
      }
      for (let v = 0; v < points.length / 3; ++v) {
        const x = points[3 * v + graded.axis];
        let slab = graded.slabs[graded.slabs.length - 1];
        for (const s of graded.slabs)
          if (x < s.to_mm) {
            slab = s;
            break;
          }
        values[v] = slab.achieved;
      }
      legend = { by: "achieved relative density of `" + graded.name + "`", unit: "", lo: dmin, hi: dmax,
                 note: "per slab along " + "xyz"[graded.axis] + " (report.json's slabs)" };
    }
    if (values) {
      const colors = new Float32Array(points.length);
      const span = legend.hi > legend.lo ? legend.hi - legend.lo : 1;
      for (let v = 0; v < values.length; ++v) colors.set(ramp((values[v] - legend.lo) / span), 3 * v);
      geometry.setAttribute
        ? geometry.setAttribute("color", new attribute(colors, 3))
        : geometry.addAttribute("color", new attribute(colors, 3));
      material.vertexColors = THREE.VertexColors !== undefined ? THREE.VertexColors : true;
      // The legend: the ramp from its low end to its high end, labelled.
      const box = el("div", { id: "voxlat-legend", class: "row" });
      const bar = document.createElement("canvas");
      bar.width = 240;
      bar.height = 14;
      const g = bar.getContext("2d");
      for (let x = 0; x < bar.width; ++x) {
        const c = ramp(x / (bar.width - 1));
        g.fillStyle = "rgb(" + c.map((a) => Math.round(255 * a)).join(",") + ")";
        g.fillRect(x, 0, 1, bar.height);
      }
      const unit = legend.unit ? " " + legend.unit : "";
      box.appendChild(document.createTextNode(legend.by + ": " + fmt(legend.lo, 3) + unit));
      box.appendChild(bar);
      box.appendChild(document.createTextNode(fmt(legend.hi, 3) + unit));
      canvas.parentNode.insertBefore(box, canvas);
      caption.textContent = "Coloured by the " + legend.by + ", " + legend.note + ". ";
      view.legend = { by: legend.by, lo: legend.lo, hi: legend.hi, colours: distinctColours(colors) };
      view.values = values;
      view.points = points;
    } else {
      material.color = 0x8fa6c8;
    }
    caption.textContent += "Preview mesh of " + meshData.triangles + " triangles. Drag to turn, scroll to zoom, right-drag to pan.";
    scene.add(new THREE.Mesh(geometry, new THREE.MeshPhongMaterial(material)));
    scene.add(new THREE.AmbientLight(0x606060));
    const light = new THREE.DirectionalLight(0xffffff, 0.8);
    scene.add(light);
    const centre = new THREE.Vector3((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2);
    const size = Math.max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2], 1e-6);
    const camera = new THREE.PerspectiveCamera(35, canvas.width / canvas.height, size / 100, size * 100);
    camera.up.set(0, 0, 1);
    camera.position.set(centre.x + 1.6 * size, centre.y - 1.9 * size, centre.z + 1.2 * size);
    const controls = new THREE.OrbitControls(camera, canvas);
    controls.target.copy(centre);
    function render() {
      light.position.copy(camera.position);
      renderer.render(scene, camera);
    }
    controls.addEventListener("change", render);
    controls.update();
    render();
    view.render = render;
    view.countPixels = function () {
      render();
      const gl = renderer.getContext();
      const w = gl.drawingBufferWidth, h = gl.drawingBufferHeight;
      const data = new Uint8Array(w * h * 4);
      gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, data);
      let drawn = 0;
      for (let i = 0; i < data.length; i += 4) if (data[i] < 250 || data[i + 1] < 250 || data[i + 2] < 250) ++drawn;
      return { drawn: drawn, total: w * h };
    };
  }

  // ---- the layers -----------------------------------------------------------------------------
  const slices = Array.isArray(report.slices) && report.slices.length ? report.slices[0] : null;
  const found = slices && slices.printability ? slices.printability : null;
  const layers = { count: 0 };
  if (indices.length || slices) {
    section("Layers");
    let height, first, count;
    if (slices) {
      height = slices.layer_height_mm;
      first = slices.first_layer_z_mm;
      count = slices.layers;
    } else {
      count = 100;
      height = (hi[2] - lo[2]) / count;
      first = lo[2] + height / 2;
    }
    layers.count = count;
    const marks = [];  // {layer, x, y, r (mm), kind, text}
    if (found) {
      for (const i of found.islands || [])
        marks.push({ layer: i.layer, x: i.x, y: i.y, r: Math.sqrt(i.area_mm2 / Math.PI), kind: "island",
                     text: "island, " + fmt(i.area_mm2, 3) + " mm²" });
      for (const t of found.resin_traps || []) {
        const span = Array.isArray(t.layers) ? t.layers : [Math.round((t.z - first) / height), Math.round((t.z - first) / height)];
        for (let l = span[0]; l <= span[1]; ++l)
          marks.push({ layer: l, x: t.x, y: t.y, r: 0, kind: "trap",
                       text: "resin trap, " + fmt(t.volume_mm3, 3) + " mm³ (drain point " + fmt(t.drain_mm, 3) + " mm away)" });
      }
      for (const t of (found.thin && found.thin.first) || [])
        marks.push({ layer: t.layer, x: t.x, y: t.y, r: 0, kind: "thin", text: "thin feature" });
    }
    // Drain holes (report.drain.NAME.holes): a channel from `position` along `direction`.
    const channels = [];
    for (const field of Object.values(report.drain || {}))
      for (const h of (field && field.holes) || [])
        if (Array.isArray(h.position) && Array.isArray(h.direction))
          channels.push({ a: h.position, b: h.position.map((p, k) => p + h.direction[k] * (h.length_mm || 0)), diameter: field.diameter_mm });
    for (const d of channels) {
      const a = d.a, b = d.b;
      const z0 = Math.min(a[2], b[2]), z1 = Math.max(a[2], b[2]);
      const l0 = Math.max(0, Math.floor((z0 - first) / height)), l1 = Math.min(count - 1, Math.ceil((z1 - first) / height));
      for (let l = l0; l <= l1; ++l) {
        const z = first + l * height, f = Math.abs(b[2] - a[2]) > 1e-9 ? (z - a[2]) / (b[2] - a[2]) : 0.5;
        const fc = Math.min(1, Math.max(0, f));
        marks.push({ layer: l, x: a[0] + fc * (b[0] - a[0]), y: a[1] + fc * (b[1] - a[1]), r: (d.diameter || 0) / 2,
                     kind: "drain", text: "drain hole" });
      }
    }
    const box = slices && slices.part_box ? slices.part_box : { min: lo, max: hi };
    const xlo = Math.min(box.min[0], lo[0]), xhi = Math.max(box.max[0], hi[0]);
    const ylo = Math.min(box.min[1], lo[1]), yhi = Math.max(box.max[1], hi[1]);
    const slider = el("input", { type: "range", id: "layer", min: 0, max: Math.max(0, count - 1), value: 0, step: 1, style: "width:860px" });
    const label = el("p", {});
    const canvas = el("canvas", { id: "layers", width: 860, height: 520 });
    const key = el("p", { class: "key" });
    for (const [k, c] of Object.entries(COLORS)) {
      const s = document.createElement("span");
      s.style.background = c;
      key.appendChild(s);
      key.appendChild(document.createTextNode(k === "trap" ? "resin trap" : k === "thin" ? "thin feature" : k === "drain" ? "drain hole" : "island"));
    }
    const notes = el("div", {});
    const ctx = canvas.getContext("2d", { willReadFrequently: true });
    const scale = Math.min((canvas.width - 40) / Math.max(xhi - xlo, 1e-6), (canvas.height - 40) / Math.max(yhi - ylo, 1e-6));
    const X = (x) => 20 + (x - xlo) * scale, Y = (y) => canvas.height - 20 - (y - ylo) * scale;
    // The first slices output's own layers, kept small (a few dozen, spread from the first to the
    // last; every layer where they fit): each one's exposed pixels averaged over cells, row 0 at
    // the least y. A kept layer shows them; another one the preview mesh cut at its height.
    const keptNode = slices ? document.getElementById("voxlat-layers") : null;
    const kept = keptNode ? JSON.parse(keptNode.textContent) : null;
    const keptAt = new Map();
    if (kept) kept.layers.forEach((l, k) => keptAt.set(l, k));
    const keptCanvases = [];
    function keptCanvas(k) {
      if (keptCanvases[k]) return keptCanvases[k];
      const w = kept.size[0], h = kept.size[1], bytes = atob(kept.images[k]);
      const c = document.createElement("canvas");
      c.width = w;
      c.height = h;
      const cc = c.getContext("2d");
      const image = cc.createImageData(w, h);
      for (let r = 0; r < h; ++r)
        for (let x = 0; x < w; ++x) {
          const v = bytes.charCodeAt((h - 1 - r) * w + x) / 255, o = 4 * (r * w + x);
          image.data[o] = 255 - v * 203;  // exposed resin #34405c, the rest white
          image.data[o + 1] = 255 - v * 191;
          image.data[o + 2] = 255 - v * 163;
          image.data[o + 3] = 255;
        }
      cc.putImageData(image, 0, 0);
      return (keptCanvases[k] = c);
    }
    function nearestKept(layer) {
      let best = kept.layers[0];
      for (const l of kept.layers) if (Math.abs(l - layer) < Math.abs(best - layer)) best = l;
      return best;
    }
    function draw(layer) {
      const z = first + layer * height;
      ctx.fillStyle = "#ffffff";
      ctx.fillRect(0, 0, canvas.width, canvas.height);
      const k = kept ? keptAt.get(layer) : undefined;
      const image = k !== undefined && typeof kept.images[k] === "string" && kept.images[k].length > 0;
      if (image) {
        const w = kept.size[0], h = kept.size[1], o = kept.origin_mm, c = kept.cell_mm;
        ctx.drawImage(keptCanvas(k), X(o[0]), Y(o[1] + h * c[1]), w * c[0] * scale, h * c[1] * scale);
      }
      ctx.strokeStyle = "#ccc";
      ctx.strokeRect(X(box.min[0]), Y(box.max[1]), (box.max[0] - box.min[0]) * scale, (box.max[1] - box.min[1]) * scale);
      // Else the preview mesh cut at the layer's height.
      ctx.strokeStyle = "#333";
      ctx.lineWidth = 1;
      ctx.beginPath();
      for (let t = 0; !image && t < indices.length; t += 3) {
        const cut = [];
        for (let e = 0; e < 3; ++e) {
          const p = 3 * indices[t + e], q = 3 * indices[t + (e + 1) % 3];
          const zp = points[p + 2] - z, zq = points[q + 2] - z;
          if ((zp < 0) !== (zq < 0)) {
            const f = zp / (zp - zq);
            cut.push([points[p] + f * (points[q] - points[p]), points[p + 1] + f * (points[q + 1] - points[p + 1])]);
          }
        }
        if (cut.length === 2) {
          ctx.moveTo(X(cut[0][0]), Y(cut[0][1]));
          ctx.lineTo(X(cut[1][0]), Y(cut[1][1]));
        }
      }
      ctx.stroke();
      // Islands last: on top of a thin feature or drain at the same place.
      const order = { drain: 0, thin: 1, trap: 2, island: 3 };
      const here = marks.filter((m) => m.layer === layer).sort((a, b) => order[a.kind] - order[b.kind]);
      for (const m of here) {
        ctx.strokeStyle = ctx.fillStyle = COLORS[m.kind];
        ctx.lineWidth = 3;
        ctx.beginPath();
        ctx.arc(X(m.x), Y(m.y), Math.max(7, m.r * scale + 4), 0, 2 * Math.PI);
        ctx.stroke();
        ctx.beginPath();
        ctx.arc(X(m.x), Y(m.y), 3, 0, 2 * Math.PI);
        ctx.fill();
      }
      const how = !slices ? " (the preview mesh cut; no slices output)"
        : image ? " (the slice, its pixels averaged over " + fmt(kept.cell_mm[0], 3) + " mm cells)"
        : kept ? " (the preview mesh cut: slices kept for " + kept.layers.length + " of " + count + " layers, the nearest layer " + (nearestKept(layer) + 1) + ")"
        : " (the preview mesh cut)";
      label.textContent = "Layer " + (layer + 1) + " of " + count + " at z " + fmt(z) + " mm" + how +
        (here.length ? ": " + here.map((m) => m.text).join("; ") : "");
      layers.shown = layer;
      layers.imageShown = image;
      layers.marksShown = here.length;
    }
    slider.addEventListener("input", () => draw(Number(slider.value)));
    layers.setLayer = function (layer) {
      slider.value = String(layer);
      slider.dispatchEvent(new Event("input"));
    };
    layers.marks = marks;
    layers.kept = kept ? kept.layers.length : 0;
    layers.countColour = function (hex) {
      const want = [1, 3, 5].map((i) => parseInt(hex.substr(i, 2), 16));
      const data = ctx.getImageData(0, 0, canvas.width, canvas.height).data;
      let n = 0;
      for (let i = 0; i < data.length; i += 4)
        if (Math.abs(data[i] - want[0]) < 24 && Math.abs(data[i + 1] - want[1]) < 24 && Math.abs(data[i + 2] - want[2]) < 24) ++n;
      return n;
    };
    layers.countDark = function () {
      const data = ctx.getImageData(0, 0, canvas.width, canvas.height).data;
      let n = 0;
      for (let i = 0; i < data.length; i += 4) if (data[i] < 160 && data[i + 1] < 160 && data[i + 2] < 160) ++n;
      return n;
    };
    draw(0);
    if (found) {
      const rows = [];
      const go = (layer) => {
        const b = document.createElement("button");
        b.className = "go";
        b.textContent = "show";
        b.addEventListener("click", () => layers.setLayer(layer));
        return b;
      };
      for (const i of found.islands || []) rows.push(["island", i.layer + 1, fmt(i.z) + " mm", fmt(i.x) + ", " + fmt(i.y), fmt(i.area_mm2, 3) + " mm²", go(i.layer)]);
      for (const t of found.resin_traps || []) {
        const l = Array.isArray(t.layers) ? t.layers[0] : 0;
        rows.push(["resin trap", l + 1, fmt(t.z) + " mm", fmt(t.x) + ", " + fmt(t.y), fmt(t.volume_mm3, 3) + " mm³", go(l)]);
      }
      for (const t of (found.thin && found.thin.first) || []) rows.push(["thin feature", t.layer + 1, t.z === undefined ? "" : fmt(t.z) + " mm", fmt(t.x) + ", " + fmt(t.y), t.pixels === undefined ? "" : t.pixels + " px", go(t.layer)]);
      const p = document.createElement("p");
      p.textContent = (found.island_count || 0) + " islands, " + (found.resin_traps_above_crumb || 0) + " resin traps, " +
        ((found.thin && found.thin.pixels) || 0) + " thin pixels" + (rows.length ? " (listed: the first or largest)" : "") + ".";
      notes.appendChild(p);
      if (rows.length) table(["finding", "layer", "z", "x, y (mm)", "size", ""], rows, notes);
    }
  }

  // ---- density per slab -----------------------------------------------------------------------
  if (report.fields) {
    const all = Object.entries(report.fields).filter(([, f]) => f && f.slabs && Array.isArray(f.slabs.slabs) && f.slabs.slabs.length);
    if (all.length) section("Density per slab against its target");
    for (const [name, f] of all) {
      const s = f.slabs.slabs;
      el("p", { text: name + ": along " + f.slabs.axis + ", largest difference " + fmt(f.slabs.max_abs_error, 3) });
      const canvas = el("canvas", { width: 600, height: 260 });
      const c = canvas.getContext("2d");
      const top = Math.max(...s.map((r) => Math.max(r.target, r.achieved))) * 1.1 || 1;
      const x0 = s[0].from_mm, x1 = s[s.length - 1].to_mm;
      const PX = (x) => 50 + ((x - x0) / Math.max(x1 - x0, 1e-9)) * 530, PY = (v) => 230 - (v / top) * 210;
      c.strokeStyle = "#999";
      c.strokeRect(50, 20, 530, 210);
      c.fillStyle = "#555";
      c.font = "11px sans-serif";
      c.fillText(fmt(top, 2), 8, 24);
      c.fillText("0", 36, 232);
      c.fillText(fmt(x0) + " mm", 50, 248);
      c.fillText(fmt(x1) + " mm", 540, 248);
      for (const r of s) {
        c.fillStyle = "#8fa6c8";
        c.fillRect(PX(r.from_mm) + 1, PY(r.achieved), PX(r.to_mm) - PX(r.from_mm) - 2, 230 - PY(r.achieved));
        c.strokeStyle = "#e0201b";
        c.lineWidth = 2;
        c.beginPath();
        c.moveTo(PX(r.from_mm), PY(r.target));
        c.lineTo(PX(r.to_mm), PY(r.target));
        c.stroke();
      }
      el("p", { class: "muted", text: "Bars: achieved relative density per slab; red lines: the target's mean over the slab." });
      table(["slab (mm)", "target", "achieved"], s.map((r) => [fmt(r.from_mm) + " – " + fmt(r.to_mm), r.target, r.achieved]));
    }
  }

  // ---- properties -----------------------------------------------------------------------------
  const P = report.properties;
  if (P && typeof P === "object") {
    section("Properties");
    const facts = [];
    if (typeof P.relative_density === "number") facts.push(["relative density", P.relative_density]);
    if (Array.isArray(P.E_MPa)) facts.push(["E x, y, z (MPa)", P.E_MPa.map((v) => fmt(v)).join(", ")]);
    if (Array.isArray(P.G_MPa)) facts.push(["G yz, xz, xy (MPa)", P.G_MPa.map((v) => fmt(v)).join(", ")]);
    if (Array.isArray(P.nu)) facts.push(["Poisson's ratios", P.nu.map((v) => fmt(v, 3)).join(", ")]);
    if (P.material && P.material.name) facts.push(["material", P.material.name + " (E " + fmt(P.material.E_MPa) + " MPa)"]);
    if (facts.length) table(null, facts);
    const C = P.C_MPa;
    if (Array.isArray(C) && C.length === 6) {
      el("p", { text: "Homogenized stiffness C^H (MPa, Voigt order xx yy zz yz xz xy):" });
      table(["", "xx", "yy", "zz", "yz", "xz", "xy"], C.map((row, i) => [["xx", "yy", "zz", "yz", "xz", "xy"][i]].concat(row)));
      const S = invert6(C);
      if (S) modulusSurface(S);
    }
    const curve = findCurve(P);
    if (curve) densityChart(curve);
  }

  function invert6(C) {
    const n = 6, a = C.map((r, i) => r.concat([0, 0, 0, 0, 0, 0].map((_, j) => (i === j ? 1 : 0))));
    for (let c = 0; c < n; ++c) {
      let p = c;
      for (let r = c + 1; r < n; ++r) if (Math.abs(a[r][c]) > Math.abs(a[p][c])) p = r;
      if (!(Math.abs(a[p][c]) > 0)) return null;
      [a[c], a[p]] = [a[p], a[c]];
      const d = a[c][c];
      for (let k = 0; k < 2 * n; ++k) a[c][k] /= d;
      for (let r = 0; r < n; ++r)
        if (r !== c) {
          const f = a[r][c];
          for (let k = 0; k < 2 * n; ++k) a[r][k] -= f * a[c][k];
        }
    }
    return a.map((r) => r.slice(n));
  }
  // Young's modulus along a unit direction from the compliance S (engineering shear strains).
  function youngs(S, l, m, n) {
    const a = [l * l, m * m, n * n, m * n, l * n, l * m];
    let s = 0;
    for (let i = 0; i < 6; ++i) for (let j = 0; j < 6; ++j) s += a[i] * S[i][j] * a[j];
    return s > 0 ? 1 / s : 0;
  }
  function modulusSurface(S) {
    el("p", { text: "Directional Young's modulus: the distance from the centre along a direction is E in that direction." });
    const canvas = el("canvas", { id: "modulus", width: 420, height: 360 });
    const geometry = new THREE.SphereBufferGeometry ? new THREE.SphereBufferGeometry(1, 64, 48) : new THREE.SphereGeometry(1, 64, 48);
    const pos = geometry.attributes.position;
    const values = [];
    for (let i = 0; i < pos.count; ++i) values.push(youngs(S, pos.getX(i), pos.getY(i), pos.getZ(i)));
    const emax = Math.max(...values), emin = Math.min(...values);
    const colors = new Float32Array(3 * pos.count);
    for (let i = 0; i < pos.count; ++i) {
      const r = values[i] / emax;
      pos.setXYZ(i, pos.getX(i) * r, pos.getY(i) * r, pos.getZ(i) * r);
      colors.set(ramp(emax > emin ? (values[i] - emin) / (emax - emin) : 1), 3 * i);
    }
    geometry.setAttribute
      ? geometry.setAttribute("color", new THREE.BufferAttribute(colors, 3))
      : geometry.addAttribute("color", new THREE.BufferAttribute(colors, 3));
    geometry.computeVertexNormals();
    const renderer = new THREE.WebGLRenderer({ canvas: canvas, antialias: true, preserveDrawingBuffer: true });
    renderer.setClearColor(0xffffff, 1);
    const scene = new THREE.Scene();
    scene.add(new THREE.Mesh(geometry, new THREE.MeshPhongMaterial({
      vertexColors: THREE.VertexColors !== undefined ? THREE.VertexColors : true, side: THREE.DoubleSide })));
    scene.add(new THREE.AxesHelper(1.3));
    scene.add(new THREE.AmbientLight(0x707070));
    const light = new THREE.DirectionalLight(0xffffff, 0.7);
    scene.add(light);
    const camera = new THREE.PerspectiveCamera(35, canvas.width / canvas.height, 0.01, 100);
    camera.up.set(0, 0, 1);
    camera.position.set(2.6, -3.2, 2.2);
    const controls = new THREE.OrbitControls(camera, canvas);
    const render = () => {
      light.position.copy(camera.position);
      renderer.render(scene, camera);
    };
    controls.addEventListener("change", render);
    controls.update();
    render();
    el("p", { class: "muted", text: "E from " + fmt(emin) + " MPa (dark) to " + fmt(emax) + " MPa (yellow); axes x red, y green, z blue." });
  }
  function findCurve(P) {
    for (const v of Object.values(P)) {
      if (v && Array.isArray(v.curve) && v.curve.length) return v;
    }
    return Array.isArray(P.curve) && P.curve.length ? { curve: P.curve } : null;
  }
  function densityChart(c) {
    const pts = c.curve.filter((p) => typeof p.relative_density === "number" && Array.isArray(p.E_MPa));
    if (!pts.length) return;
    el("p", { text: "E against relative density (x red, y green, z blue, log-log):" });
    const canvas = el("canvas", { width: 520, height: 300 });
    const g = canvas.getContext("2d");
    const rho = pts.map((p) => p.relative_density), E = pts.flatMap((p) => p.E_MPa).filter((v) => v > 0);
    if (!E.length) return;
    const lx0 = Math.log10(Math.min(...rho)), lx1 = Math.log10(Math.max(...rho)), ly0 = Math.log10(Math.min(...E)), ly1 = Math.log10(Math.max(...E));
    const PX = (x) => 60 + ((Math.log10(x) - lx0) / Math.max(lx1 - lx0, 1e-9)) * 440, PY = (y) => 270 - ((Math.log10(y) - ly0) / Math.max(ly1 - ly0, 1e-9)) * 250;
    g.strokeStyle = "#999";
    g.strokeRect(60, 20, 440, 250);
    g.fillStyle = "#555";
    g.font = "11px sans-serif";
    g.fillText(fmt(Math.pow(10, ly1)) + " MPa", 2, 24);
    g.fillText(fmt(Math.pow(10, ly0)), 2, 270);
    g.fillText("ρ " + fmt(Math.pow(10, lx0), 3), 60, 290);
    g.fillText(fmt(Math.pow(10, lx1), 3), 470, 290);
    ["#e0201b", "#19a34a", "#1f6fe0"].forEach((colour, a) => {
      g.strokeStyle = g.fillStyle = colour;
      g.beginPath();
      pts.forEach((p, k) => {
        if (!(p.E_MPa[a] > 0)) return;
        k ? g.lineTo(PX(p.relative_density), PY(p.E_MPa[a])) : g.moveTo(PX(p.relative_density), PY(p.E_MPa[a]));
      });
      g.stroke();
      for (const p of pts) if (p.E_MPa[a] > 0) g.fillRect(PX(p.relative_density) - 2, PY(p.E_MPa[a]) - 2, 4, 4);
    });
    if (c.gibson_ashby && Array.isArray(c.gibson_ashby.n))
      el("p", { class: "muted", text: "Gibson-Ashby fit E/Es = C ρ^n: n = " + c.gibson_ashby.n.map((v) => fmt(v, 3)).join(", ") +
        "; C = " + c.gibson_ashby.C.map((v) => fmt(v, 3)).join(", ") });
  }

  // ---- warnings, timings, memory --------------------------------------------------------------
  section("Warnings");
  if (Array.isArray(report.warnings) && report.warnings.length)
    for (const w of report.warnings) el("div", { class: "warn", text: w.code + ": " + w.message });
  else el("p", { class: "muted", text: "None." });
  section("Timings and memory");
  const rows = [];
  if (report.timings_s && typeof report.timings_s === "object")
    for (const [stage, s] of Object.entries(report.timings_s)) rows.push([stage, typeof s === "number" ? fmt(s, 3) + " s" : JSON.stringify(s)]);
  if (typeof report.peak_memory_mb === "number") rows.push(["peak memory", fmt(report.peak_memory_mb, 4) + " MB"]);
  if (typeof report.threads === "number") rows.push(["threads", report.threads]);
  if (rows.length) table(["stage", "time"], rows);

  // ---- the page checks itself (tests) ---------------------------------------------------------
  window.voxlatPage = { view: view, layers: layers };
  if (location.hash === "#check") {
    const result = { mesh_triangles: meshData.triangles, layers: layers.count, coloured_by: graded ? graded.name : null };
    if (view.legend) {
      result.legend = view.legend;
      result.legend_shown = !!document.getElementById("voxlat-legend");
      if (meshData.colour) result.coloured_by = meshData.colour.field;
      // The colouring values' median over the lowest and highest tenth of the part along x.
      const xs = [];
      for (let v = 0; v < view.values.length; ++v) xs.push([view.points[3 * v], view.values[v]]);
      xs.sort((a, b) => a[0] - b[0]);
      const median = (part) => part.map((p) => p[1]).sort((a, b) => a - b)[Math.floor(part.length / 2)];
      const tenth = Math.max(1, Math.floor(xs.length / 10));
      result.values_low_x = median(xs.slice(0, tenth));
      result.values_high_x = median(xs.slice(xs.length - tenth));
    }
    if (view.countPixels) result.view3d = view.countPixels();
    if (layers.setLayer) {
      const island = (layers.marks || []).find((m) => m.kind === "island");
      if (island) {
        layers.setLayer(island.layer);
        result.island_layer = island.layer;
        result.island_marks = layers.marksShown;
        result.island_pixels = layers.countColour(COLORS.island);
      }
      layers.setLayer(0);
      result.layers_kept = layers.kept;
      result.first_layer_image = !!layers.imageShown;
      result.first_layer_dark = layers.countDark();
      layers.setLayer(Math.floor(layers.count / 2));
      result.outline_pixels = layers.countDark();
    }
    const pre = document.createElement("pre");
    pre.id = "voxlat-check";
    pre.textContent = JSON.stringify(result);
    document.body.appendChild(pre);
  }
})();
