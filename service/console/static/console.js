// chizu console: what the robot knows, drawn from the same REST API as every client.
// No framework and no build step; every value from the service reaches the page as text
// (textContent, setAttribute), never as markup.

const SVG = "http://www.w3.org/2000/svg";
const MAP_PX = 2048; // a map, committed or a run's, is drawn from at most this many px a side
const $ = (sel, root = document) => root.querySelector(sel);

// -- the API ------------------------------------------------------------------------
class Problem extends Error {
  constructor(status, body) {
    super(body && body.detail ? body.detail : `HTTP ${status}`);
    this.status = status;
    this.body = body || {};
  }
}

async function api(method, path, body) {
  const init = { method, headers: { accept: "application/json" } };
  if (body !== undefined) {
    init.headers["content-type"] = "application/json";
    init.body = JSON.stringify(body);
  }
  const r = await fetch(path, init);
  if (r.status === 204) return null;
  const type = r.headers.get("content-type") || "";
  const data = type.includes("json") ? await r.json() : await r.text();
  if (!r.ok) throw new Problem(r.status, typeof data === "object" ? data : { detail: data });
  return data;
}

const enc = encodeURIComponent;
const worldPath = (w, rest = "") => `/worlds/${enc(w)}${rest}`;

// -- small DOM helpers ----------------------------------------------------------------
function el(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "text") e.textContent = v;
    else if (k.startsWith("on")) e.addEventListener(k.slice(2), v);
    else e.setAttribute(k, v);
  }
  for (const c of children) e.append(c);
  return e;
}

function svg(tag, attrs = {}, text) {
  const e = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text !== undefined) e.textContent = text;
  return e;
}

function showProblem(target, err) {
  target.replaceChildren();
  const box = el("div", { class: "problem", role: "alert" });
  const b = err instanceof Problem ? err.body : {};
  box.append(el("strong", { text: `${b.title || "Error"} (${err.status || "?"})` }));
  box.append(el("span", { text: b.detail || err.message }));
  if (b.field) box.append(el("div", { text: `field: ${b.field}` }));
  target.append(box);
}

function status(text) { $("#status").textContent = text; }

// -- state ----------------------------------------------------------------------------
const state = {
  world: null,          // the world shown
  description: null,    // its WorldDescription
  pathEnds: [],         // landmark ids clicked for a path query
  view: { x: 0, y: 0, w: 10, h: 10 }, // the map's viewBox (SVG y = -world y)
};

// -- worlds ---------------------------------------------------------------------------
async function loadWorlds() {
  const worlds = await api("GET", "/worlds");
  state.summaries = Object.fromEntries(worlds.map((w) => [w.name, w]));
  const tbody = $("#worlds-table tbody");
  tbody.replaceChildren();
  for (const w of worlds) {
    const open = el("a", { href: "#/map", text: w.name, onclick: () => selectWorld(w.name) });
    const del = el("button", { type: "button", class: "secondary", text: "Delete",
      "aria-label": `Delete world ${w.name}` });
    del.addEventListener("click", async () => {
      if (!confirm(`Delete world ${w.name} and everything it holds?`)) return;
      try { await api("DELETE", worldPath(w.name)); status(`deleted ${w.name}`); }
      catch (e) { showProblem($("#status"), e); }
      await loadWorlds();
    });
    tbody.append(el("tr", {}, el("td", {}, open), el("td", { text: w.template || "—" }),
      el("td", { text: w.landmarks }), el("td", { text: w.walls }),
      el("td", { text: w.objects }), el("td", {}, del)));
  }
  const sel = $("#world-select");
  sel.replaceChildren(...worlds.map((w) => el("option", { value: w.name, text: w.name })));
  if (!worlds.some((w) => w.name === state.world)) {
    state.world = worlds.length ? (worlds.find((w) => w.name === "demo") || worlds[0]).name : null;
  }
  if (state.world) sel.value = state.world;
  return worlds;
}

async function loadTemplates() {
  // the built-in templates, as the OpenAPI lists them
  const spec = await api("GET", "/openapi.json");
  const schemas = spec.components.schemas;
  const t = schemas.WorldDescription.properties.template;
  const options = (t.anyOf || [t]).flatMap((s) => s.enum || (s.$ref ?
    schemas[s.$ref.split("/").pop()].enum || [] : []));
  $("#create-world select[name=template]").replaceChildren(
    el("option", { value: "", text: "(empty)" }),
    ...options.map((o) => el("option", { value: o, text: o })));
}

$("#create-world").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const f = new FormData(ev.target);
  const body = { name: f.get("name") };
  if (f.get("template")) body.template = f.get("template");
  try {
    await api("POST", "/worlds", body);
    status(`created ${body.name}`);
    state.world = body.name;
    await loadWorlds();
    ev.target.reset();
  } catch (e) { showProblem($("#status"), e); }
});

// -- live events (GET /worlds/{w}/events): one stream for the world shown ---------------
const live = { source: null, handlers: {} };

function on(kind, handler) { live.handlers[kind] = handler; }

function listen(world) {
  if (live.source) live.source.close();
  live.source = new EventSource(worldPath(world, "/events"));
  for (const kind of ["job", "slam_pose", "localization_pose", "mission_step", "artifact",
                      "world_deleted"]) {
    live.source.addEventListener(kind, (ev) => {
      const h = live.handlers[kind];
      if (h) h(JSON.parse(ev.data));
    });
  }
  live.source.addEventListener("open", () => { document.body.dataset.live = world; });
}

async function selectWorld(name) {
  state.world = name;
  listen(name);
  $("#world-select").value = name;
  for (const s of document.querySelectorAll(".world-name")) s.textContent = name;
  state.pathEnds = [];
  for (const id of ["#path-result", "#localize-result", "#status", "#mission-job", "#mission-steps"]) {
    $(id).replaceChildren();
  }
  await drawMap(true);
  document.body.dataset.world = name;
}

$("#world-select").addEventListener("change", (ev) => selectWorld(ev.target.value));

// -- the map ----------------------------------------------------------------------------
function setViewBox() {
  const v = state.view;
  $("#map").setAttribute("viewBox", `${v.x} ${v.y} ${v.w} ${v.h}`);
}

function fit(bounds) {
  const [x0, y0, x1, y1] = bounds;
  const pad = 0.05 * Math.max(x1 - x0, y1 - y0, 1);
  state.view = { x: x0 - pad, y: -y1 - pad, w: x1 - x0 + 2 * pad, h: y1 - y0 + 2 * pad };
  setViewBox();
}

function worldBounds(d) {
  const xs = [], ys = [];
  for (const w of d.walls) { xs.push(w.a[0], w.b[0]); ys.push(w.a[1], w.b[1]); }
  for (const l of d.landmarks) if (l.x !== null && l.x !== undefined) { xs.push(l.x); ys.push(l.y); }
  for (const o of d.objects) { xs.push(o.x); ys.push(o.y); }
  if (!xs.length) return [0, 0, 10, 10];
  return [Math.min(...xs), Math.min(...ys), Math.max(...xs), Math.max(...ys)];
}

function scale() { // metres per screen pixel
  const r = $("#map").getBoundingClientRect();
  return state.view.w / Math.max(r.width, 1);
}

function zoom(factor, cx, cy) {
  const v = state.view;
  cx = cx ?? v.x + v.w / 2;
  cy = cy ?? v.y + v.h / 2;
  state.view = { x: cx - (cx - v.x) * factor, y: cy - (cy - v.y) * factor,
                 w: v.w * factor, h: v.h * factor };
  setViewBox();
}

function clientToMap(ev) {
  const r = $("#map").getBoundingClientRect();
  const v = state.view;
  // preserveAspectRatio xMidYMid meet: one scale, centred
  const s = Math.max(v.w / r.width, v.h / r.height);
  const ox = v.x - (r.width * s - v.w) / 2, oy = v.y - (r.height * s - v.h) / 2;
  return [ox + (ev.clientX - r.left) * s, oy + (ev.clientY - r.top) * s];
}

function layer(name) { return $(`#layer-${name}`); }

async function drawMap(refit) {
  if (!state.world) return;
  const w = state.world;
  // the DRM is asked at once: on a large world its first answer after a change (the
  // relations' closure) is the slowest request of the page
  const drm = api("GET", worldPath(w, "/drm")).catch(() => null);
  const d = await api("GET", worldPath(w));
  state.description = d;
  // what the world holds, as listed (artifact events keep it current)
  const summary = state.summaries[w];
  const has = new Set(summary ? summary.artifacts : []);
  const ext = worldBounds(d);
  const size = Math.max(ext[2] - ext[0], ext[3] - ext[1], 1);
  const r = Math.max(0.06, size / 150); // a landmark's radius in metres
  if (refit) fit(ext);
  // redrawn from the world; what live events drew (trajectories, a localization) stays
  const kept = ["layer-trajectory", "layer-localization", "layer-runmap"];
  for (const g of document.querySelectorAll("#map-root > g")) {
    if (!kept.includes(g.id)) g.replaceChildren();
  }
  if (refit) {
    endSession();
    for (const id of kept) $(`#${id}`).replaceChildren();
    runs.shown = null;
    delete $("#slam-runs").dataset.shown;
  }

  const walls = layer("walls");
  for (const wall of d.walls) {
    walls.append(svg("line", { class: "wall", x1: wall.a[0], y1: -wall.a[1], x2: wall.b[0],
      y2: -wall.b[1], "stroke-width": 2, "vector-effect": "non-scaling-stroke" }));
  }
  const objects = layer("objects");
  for (const o of d.objects) {
    const [sx, sy] = o.size_m;
    const g = svg("g", { transform: `translate(${o.x} ${-o.y}) rotate(${-o.theta * 180 / Math.PI})` });
    g.append(svg("rect", { class: "object", x: -sx / 2, y: -sy / 2, width: sx, height: sy,
      "stroke-width": 1, "vector-effect": "non-scaling-stroke" }));
    g.append(svg("title", {}, `object ${o.id} (${o.type})`));
    objects.append(g);
  }
  const lms = layer("landmarks");
  const placed = {};
  for (const l of d.landmarks) {
    if (l.x === null || l.x === undefined) continue;
    placed[l.id] = [l.x, l.y];
    const g = svg("g", { class: "landmark", "data-id": l.id, tabindex: 0, role: "button",
      "aria-label": `landmark ${l.id}` });
    g.append(svg("circle", { cx: l.x, cy: -l.y, r }));
    g.append(svg("text", { x: l.x + 1.2 * r, y: -l.y - 1.2 * r, "font-size": 2.4 * r,
      "stroke-width": 0.6 * r }, l.id));
    g.append(svg("title", {}, `${l.id} (${l.x.toFixed(2)}, ${l.y.toFixed(2)})`));
    g.addEventListener("click", () => pickLandmark(l.id));
    g.addEventListener("keydown", (ev) => {
      if (ev.key === "Enter" || ev.key === " ") { ev.preventDefault(); pickLandmark(l.id); }
    });
    lms.append(g);
  }
  state.placed = placed;
  const ids = d.landmarks.map((l) => l.id);
  for (const sel of [$("#path-from"), $("#path-to")]) {
    const keep = sel.value;
    sel.replaceChildren(...ids.map((id) => el("option", { value: id, text: id })));
    if (ids.includes(keep)) sel.value = keep;
  }
  fillPlanRequest(d, ext);
  const info = [`${d.landmarks.length} landmarks, ${d.walls.length} walls, ${d.objects.length} objects`];
  await Promise.all([
    loadRuns(w),
    drawDrm(drm, placed, r).then((n) => info.push(`DRM: ${n} edges`)),
    has.has("saved_map") ? drawGrid(w).then((t) => info.push(t)) : null,
    has.has("eigenspace") ? drawEigen(w, r).then((t) => info.push(t)) : null,
  ]);
  $("#map-info").replaceChildren(...info.map((t) => el("p", { class: "hint", text: t })));
  applyLayerToggles();
}

async function drawDrm(pending, placed, r) {
  const drm = await pending;
  if (!drm) return 0;
  const g = layer("drm");
  for (const e of drm.edges) {
    const a = placed[e.from], b = placed[e.to];
    if (!a || !b) continue;
    const line = svg("line", { class: "drm-edge", x1: a[0], y1: -a[1], x2: b[0], y2: -b[1],
      "stroke-width": 0.5 + 2.5 * e.p, "stroke-opacity": 0.25 + 0.5 * e.p,
      "vector-effect": "non-scaling-stroke", "data-from": e.from, "data-to": e.to });
    line.append(svg("title", {}, `${e.from} → ${e.to}: p ${e.p.toFixed(3)}, ${e.method}`));
    g.append(line);
  }
  return drm.edges.length;
}

// a map_server image (base.png, placed by base.yaml) as an SVG image in the world frame
async function mapImage(base, query) {
  const yaml = await (await fetch(`${base}.yaml${query}`)).text();
  const res = parseFloat(/resolution:\s*([-\d.eE]+)/.exec(yaml)[1]);
  const origin = /origin:\s*\[\s*([-\d.eE]+)\s*,\s*([-\d.eE]+)/.exec(yaml);
  const img = new Image();
  img.src = `${base}.png${query}${query ? "&" : "?"}v=${Date.now()}`;
  await img.decode();
  const [ox, oy] = [parseFloat(origin[1]), parseFloat(origin[2])];
  const wm = img.naturalWidth * res, hm = img.naturalHeight * res;
  return svg("image", { href: img.src, x: ox, y: -(oy + hm), width: wm, height: hm,
    preserveAspectRatio: "none", style: "image-rendering: pixelated", opacity: 0.85 });
}

async function drawGrid(w) {
  const m = await api("GET", worldPath(w, "/map"));
  // a large map comes downsampled to what a screen shows (walls kept)
  layer("grid").append(await mapImage(worldPath(w, "/map"), `?max_px=${MAP_PX}`));
  // the unknown regions the knowledge base holds (what the viewpoint planner explores):
  // a circle of the region's area at its centre
  for (const u of m.regions) {
    const c = svg("circle", { class: "unknown-region", cx: u.x, cy: -u.y,
      r: Math.sqrt(u.area_m2 / Math.PI), "data-region": u.id, "stroke-width": 2,
      "stroke-dasharray": "5 3", "vector-effect": "non-scaling-stroke" });
    c.append(svg("title", {}, `unknown region ${u.id}: ${u.area_m2.toFixed(2)} m²`));
    layer("regions").append(c);
  }
  return `committed map: run ${m.run}, ${(100 * m.explored_fraction).toFixed(0)} % explored, ` +
    `${m.regions.length} unknown regions`;
}

// -- SLAM runs: listed per world; one shown with its trajectory and map, kept current as
// its scans arrive (the map at most every 2 s: a run's grid is redrawn on request) --------
const runs = { shown: null, refreshing: false, again: false, last: 0, timer: null, fit: false };

async function loadRuns(w) {
  const list = await api("GET", worldPath(w, "/slam-runs"));
  if (w !== state.world) return;
  const ul = $("#slam-runs");
  ul.replaceChildren(...list.map((r) => {
    const b = el("button", { type: "button", class: "secondary run", "data-run": r.id,
      "aria-pressed": String(runs.shown === r.id),
      text: `${r.id} · ${r.method} · ${r.scans ?? "?"} scans` });
    b.addEventListener("click", () => showRun(runs.shown === r.id ? null : r.id));
    return el("li", {}, b);
  }));
  if (!list.length) ul.append(el("li", { class: "hint", text: "none yet" }));
}

async function showRun(rid) {
  runs.shown = rid;
  for (const b of document.querySelectorAll("#slam-runs button")) {
    b.setAttribute("aria-pressed", String(b.dataset.run === rid));
  }
  layer("runmap").replaceChildren();
  delete $("#slam-runs").dataset.shown;
  runs.fit = Boolean(rid); // the view takes in the run's map once it is drawn
  if (rid) await refreshRun();
}

// the shown run's trajectory (the estimator's, corrected by its loop closures) and map
async function refreshRun() {
  const rid = runs.shown, w = state.world;
  if (!rid) return;
  if (runs.refreshing) { runs.again = true; return; }
  runs.refreshing = true;
  try {
    const base = worldPath(w, `/slam-runs/${enc(rid)}`);
    const [t, image] = await Promise.all([api("GET", `${base}/trajectory`),
      mapImage(`${base}/map`, `?max_px=${MAP_PX}`).catch(() => null)]); // no scan yet: no map
    if (runs.shown !== rid || state.world !== w) return;
    const line = trajectoryLine(rid, "SLAM");
    line.setAttribute("points", t.poses.map((p) => `${p[0]},${-p[1]}`).join(" "));
    line.dataset.scans = t.poses.length;
    layer("runmap").replaceChildren(...(image ? [image] : []));
    if (runs.fit && image) {
      runs.fit = false;
      const [x, y] = [+image.getAttribute("x"), -image.getAttribute("y")];
      const [w, h] = [+image.getAttribute("width"), +image.getAttribute("height")];
      const b = worldBounds(state.description);
      const empty = !state.description.walls.length && !state.description.landmarks.length;
      fit(empty ? [x, y - h, x + w, y] : [Math.min(b[0], x), Math.min(b[1], y - h),
        Math.max(b[2], x + w), Math.max(b[3], y)]);
    }
    $("#slam-runs").dataset.shown = rid;
    $("#slam-runs").dataset.scans = t.poses.length;
  } catch (e) { showProblem($("#status"), e); }
  finally {
    runs.refreshing = false;
    runs.last = Date.now();
    if (runs.again) { runs.again = false; scheduleRunRefresh(); }
  }
}

function scheduleRunRefresh() {
  if (runs.timer) return;
  runs.timer = setTimeout(() => { runs.timer = null; refreshRun(); },
    Math.max(0, runs.last + 2000 - Date.now()));
}

async function drawEigen(w, r) {
  const e = await api("GET", worldPath(w, "/eigenspace"));
  state.directions = e.directions;
  const g = layer("eigen");
  for (const p of e.points) {
    const c = svg("circle", { class: "eigen-point", cx: p.x, cy: -p.y, r: 0.6 * r });
    c.append(svg("title", {}, `learning point ${p.id}`));
    g.append(c);
  }
  {
    const cov = await api("GET", worldPath(w, "/eigenspace/coverage"));
    const cg = layer("coverage");
    cov.p_enter.forEach((row, i) => row.forEach((p, j) => {
      if (p === null || p <= 0) return;
      cg.append(svg("rect", { x: cov.origin.x + j * cov.cell_m,
        y: -(cov.origin.y + (i + 1) * cov.cell_m), width: cov.cell_m, height: cov.cell_m,
        fill: "#10b981", "fill-opacity": 0.6 * p }));
    }));
    return `eigenspace: ${e.points.length} learning points, ${e.triplet_list.length} triplets, ` +
      `${(100 * cov.share).toFixed(0)} % of the floor localizable`;
  }
}

function applyLayerToggles() {
  for (const box of document.querySelectorAll("#layers input")) {
    layer(box.dataset.layer).style.display = box.checked ? "" : "none";
  }
}
for (const box of document.querySelectorAll("#layers input")) {
  box.addEventListener("change", applyLayerToggles);
}

function pickLandmark(id) {
  state.pathEnds = state.pathEnds.length >= 2 ? [id] : [...state.pathEnds, id];
  const [from, to] = state.pathEnds;
  for (const g of document.querySelectorAll(".landmark")) {
    g.classList.toggle("from", g.dataset.id === from);
    g.classList.toggle("to", g.dataset.id === to);
  }
  if (from) $("#path-from").value = from;
  if (to) { $("#path-to").value = to; findPath(from, to); }
  else status(`path from ${from}: click the goal landmark`);
}

async function findPath(from, to) {
  const out = $("#path-result");
  layer("path").replaceChildren();
  try {
    const p = await api("GET", worldPath(state.world, `/path?from=${enc(from)}&to=${enc(to)}`));
    out.replaceChildren();
    if (!p.found) { out.append(el("p", { text: `no path: ${p.detail || ""}` })); return; }
    out.append(el("p", { text: `${p.path.join(" → ")} (p = ${p.probability.toFixed(3)})`,
      "data-testid": "path-summary" }));
    const list = el("ol", { class: "steps" });
    for (const s of p.steps) {
      list.append(el("li", { text: `${s.from} → ${s.to}: ${s.method}` +
        (s.via.length ? ` via ${s.via.join(", ")}` : "") + ` (p ${s.p.toFixed(3)})` }));
    }
    out.append(list);
    const pts = p.path.map((id) => state.placed[id]).filter(Boolean);
    if (pts.length > 1) {
      layer("path").append(svg("polyline", { class: "path-line", "data-path": p.path.join(","),
        points: pts.map(([x, y]) => `${x},${-y}`).join(" "), "stroke-width": 5,
        "vector-effect": "non-scaling-stroke" }));
    }
    status(`path ${from} → ${to}: ${p.steps.length} steps`);
  } catch (e) { showProblem(out, e); }
}

$("#path-form").addEventListener("submit", (ev) => {
  ev.preventDefault();
  state.pathEnds = [$("#path-from").value];
  pickLandmark($("#path-to").value);
});

// -- eigenspace localization (Maeda & Shirai): one turn, or a session of stops ------------
function formPose() {
  const f = new FormData($("#localize-form"));
  return { x: +f.get("x"), y: +f.get("y"), theta: +f.get("theta") };
}

async function renderTurn(pose) {
  const cam = await api("POST", worldPath(state.world, "/camera"),
    { pose, turn: state.directions || 72, format: "turn_png" });
  return cam.turn_png;
}

// a localization's answer on the map and in words: candidates, the estimate, the state
function showLocalization(loc, pose, out) {
  const g = layer("localization");
  for (const c of g.querySelectorAll(".candidate, .estimate")) c.remove();
  const r = Math.max(0.06, state.view.w / 120);
  for (const c of loc.candidates) {
    g.append(svg("circle", { class: "candidate", cx: c.pose.x, cy: -c.pose.y, r,
      "stroke-width": 2, "vector-effect": "non-scaling-stroke" }));
  }
  g.append(svg("circle", { class: "true-pose", cx: pose.x, cy: -pose.y, r: 0.5 * r,
    fill: "#111827" }));
  out.replaceChildren(el("p", { class: `state-${loc.state.state}`, "data-state": loc.state.state,
    text: `state ${loc.state.state.toUpperCase()} (${loc.outcome}), ` +
      `${loc.candidates.length} candidates` }));
  if (loc.pose) {
    g.append(svg("circle", { class: "estimate", cx: loc.pose.x, cy: -loc.pose.y, r }));
    const err = Math.hypot(loc.pose.x - pose.x, loc.pose.y - pose.y);
    out.append(el("p", { text: `estimate (${loc.pose.x.toFixed(2)}, ${loc.pose.y.toFixed(2)}), ` +
      `${err.toFixed(2)} m from the true pose` +
      (loc.answered_by ? `, answered by the ${loc.answered_by.replaceAll("_", " ")}` : "") }));
  } else if (loc.refused_by) {
    out.append(el("p", { text: `refused by ${loc.refused_by.test}` }));
  }
}

$("#localize-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  endSession();
  const pose = formPose();
  const out = $("#localize-result");
  out.replaceChildren(el("p", { text: "rendering and localizing…" }));
  layer("localization").replaceChildren();
  try {
    const loc = await api("POST", worldPath(state.world, "/localize"),
      { turn_png: await renderTurn(pose) });
    showLocalization(loc, pose, out);
  } catch (e) { showProblem(out, e); }
});

// A session: each stop is a turn at the pose in the form, with the odometry from the
// previous stop's pose in that pose's frame; Next move asks the movement strategy for the
// action (alpha, l, beta) maximising Q(Z) and moves the form's pose by it.
const session = { id: null, poses: [] };

function endSession() {
  session.id = null;
  session.poses = [];
  $("#session-stops").replaceChildren();
  $("#session-stop").disabled = $("#session-move").disabled = true;
}

function odometry(a, b) {
  const dx = b.x - a.x, dy = b.y - a.y, c = Math.cos(a.theta), s = Math.sin(a.theta);
  const dth = Math.atan2(Math.sin(b.theta - a.theta), Math.cos(b.theta - a.theta));
  return { dx: c * dx + s * dy, dy: -s * dx + c * dy, dtheta: dth };
}

$("#session-start").addEventListener("click", async () => {
  endSession();
  layer("localization").replaceChildren();
  const out = $("#localize-result");
  try {
    const s = await api("POST", worldPath(state.world, "/localization-sessions"));
    session.id = s.id;
    out.replaceChildren(el("p", { class: `state-${s.state.state}`, "data-state": s.state.state,
      text: `session started: state ${s.state.state.toUpperCase()}, no stop yet` }));
    $("#session-stop").disabled = false;
  } catch (e) { showProblem(out, e); }
});

$("#session-stop").addEventListener("click", async () => {
  const pose = formPose(), out = $("#localize-result");
  const prev = session.poses[session.poses.length - 1];
  const body = { turn_png: null };
  if (prev) body.odometry = odometry(prev, pose);
  out.replaceChildren(el("p", { text: "rendering and localizing…" }));
  try {
    body.turn_png = await renderTurn(pose);
    const loc = await api("POST",
      worldPath(state.world, `/localization-sessions/${enc(session.id)}/stops`), body);
    session.poses.push(pose);
    showLocalization(loc, pose, out);
    const route = layer("localization").querySelector("polyline.stops") ||
      layer("localization").appendChild(svg("polyline", { class: "stops traj",
        "stroke-dasharray": "4 3", "stroke-width": 2, "vector-effect": "non-scaling-stroke" }));
    route.setAttribute("points", session.poses.map((p) => `${p.x},${-p.y}`).join(" "));
    $("#session-stops").append(el("li", { "data-state": loc.state.state,
      text: `stop ${loc.stops}: state ${loc.state.state.toUpperCase()} (${loc.outcome}), ` +
        `${loc.candidates.length} candidates` }));
    $("#session-move").disabled = loc.state.state === "z";
  } catch (e) { showProblem(out, e); }
});

// how far the robot can drive from (x, y) along heading th before a wall, less the
// clearance the strategy's model of a move keeps (Maeda & Shirai §3.4)
function freeRun(x, y, th, clearance = 0.3) {
  const dx = Math.cos(th), dy = Math.sin(th);
  let best = Infinity;
  for (const w of state.description.walls) {
    const [ax, ay] = w.a, [bx, by] = w.b;
    const ex = bx - ax, ey = by - ay, den = dx * ey - dy * ex;
    if (Math.abs(den) < 1e-12) continue;
    const t = ((ax - x) * ey - (ay - y) * ex) / den;  // along the ray
    const u = ((ax - x) * dy - (ay - y) * dx) / den;  // along the wall
    if (t > 0 && u >= 0 && u <= 1) best = Math.min(best, t);
  }
  return Math.max(0, best - clearance);
}

$("#session-move").addEventListener("click", async () => {
  const out = $("#localize-result");
  try {
    const m = await api("GET",
      worldPath(state.world, `/localization-sessions/${enc(session.id)}/next-move`));
    if (!m.action) { out.append(el("p", { text: "localized: no move needed" })); return; }
    const { alpha_rad: a, l_m: l, beta_rad: b } = m.action;
    const p = formPose(), th = p.theta + a, run = Math.min(l, freeRun(p.x, p.y, th));
    const q = { x: p.x + run * Math.cos(th), y: p.y + run * Math.sin(th),
                theta: Math.atan2(Math.sin(th + b), Math.cos(th + b)) };
    const f = $("#localize-form");
    f.elements.x.value = q.x.toFixed(3);
    f.elements.y.value = q.y.toFixed(3);
    f.elements.theta.value = q.theta.toFixed(3);
    out.append(el("p", { "data-move": "true", text: `next move: turn ${a.toFixed(2)} rad, ` +
      `drive ${l.toFixed(2)} m${run < l ? ` (${run.toFixed(2)} m before a wall)` : ""}, ` +
      `turn ${b.toFixed(2)} rad; Q(Z) = ${m.q_z.toFixed(2)}. The pose above is where it ` +
      "leads: Add stop there." }));
  } catch (e) { showProblem(out, e); }
});

// -- viewpoint plan (Masuzawa & Miura): groups, entry poses, route, timeline ------------
// A request the user has edited for this world is theirs: a redraw (a new artifact, a
// world summary arriving after they typed) must not replace it.
$("#plan-body").addEventListener("input", () => { $("#plan-body").dataset.editedFor = state.world; });

function fillPlanRequest(d, ext) {
  if ($("#plan-body").dataset.editedFor === state.world) return;
  const types = [...new Set(d.objects.map((o) => o.type))];
  const start = d.landmarks.find((l) => l.x !== null && l.x !== undefined);
  const robot = start ? [start.x, start.y, 0] : [(ext[0] + ext[2]) / 2, (ext[1] + ext[3]) / 2, 0];
  const body = { robot, exit: robot.slice(0, 2), time_limit_s: 60, loss: "L2",
    object_types: types.map((t) => ({ name: t, value: 100, mean_count: 1 })),
    candidates: d.objects.map((o) => ({ id: o.id, type: o.type, x: o.x, y: o.y })) };
  $("#plan-body").value = JSON.stringify(body, null, 1);
}

function drawPlan(req, out) {
  const g = layer("plan");
  g.replaceChildren();
  const steps = out.plan.steps;
  const pts = [req.robot, ...steps.map((s) => s.pose)];
  g.append(svg("polyline", { class: "plan-route", "stroke-width": 2,
    "vector-effect": "non-scaling-stroke", points: pts.map((p) => `${p[0]},${-p[1]}`).join(" ") }));
  const r = Math.max(0.06, state.view.w / 150);
  steps.forEach((s, i) => {
    const [x, y, th] = s.pose;
    const m = svg("g", { "data-group": s.name });
    m.append(svg("circle", { class: "plan-pose", cx: x, cy: -y, r }));
    m.append(svg("line", { x1: x, y1: -y, x2: x + 3 * r * Math.cos(th), y2: -y - 3 * r * Math.sin(th),
      stroke: "#0e7490", "stroke-width": 2, "vector-effect": "non-scaling-stroke" }));
    m.append(svg("text", { x: x + 1.2 * r, y: -y + 3 * r, "font-size": 2.4 * r,
      class: "label", "stroke-width": 0.6 * r }, `${i + 1} ${s.name}`));
    g.append(m);
  });
}

function timeline(req, out) {
  const steps = out.plan.steps;
  const end = Math.max(req.time_limit_s || 0, ...steps.map((s) => s.done_at_s), 1);
  const bar = el("div", { class: "timeline", role: "img",
    "aria-label": `plan timeline: done at ${(out.plan.expected_time_s ?? 0).toFixed(1)} s ` +
      `against a limit of ${req.time_limit_s} s` });
  let t = 0;
  for (const s of steps) {
    for (const [kind, dt] of [["travel", s.travel_s], ["observe", s.observe_s]]) {
      const seg = el("div", { class: `seg ${kind}`, title: `${s.name}: ${kind} ${dt.toFixed(1)} s` });
      seg.style.left = `${(100 * t) / end}%`;
      seg.style.width = `${(100 * dt) / end}%`;
      bar.append(seg);
      t += dt;
    }
  }
  if (req.time_limit_s) {
    const lim = el("div", { class: "limit" }, el("span", { text: `limit ${req.time_limit_s} s` }));
    lim.style.left = `${(100 * req.time_limit_s) / end}%`;
    bar.append(lim);
  }
  return bar;
}

$("#plan-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const out = $("#plan-result");
  let req;
  try { req = JSON.parse($("#plan-body").value); } catch (e) {
    showProblem(out, new Problem(0, { title: "Not JSON", detail: e.message }));
    return;
  }
  try {
    const plan = await api("POST", worldPath(state.world, "/viewpoint-plan"), req);
    out.replaceChildren(
      el("p", { "data-testid": "plan-summary", text: `${plan.plan.groups.join(" → ") || "leave now"}` +
        ` — expected ${(plan.plan.expected_time_s ?? 0).toFixed(1)} s, utility ` +
        `${(plan.plan.utility ?? 0).toFixed(1)}` }),
      timeline(req, plan),
      el("ol", { class: "steps" }, ...plan.plan.steps.map((s) => el("li", {
        text: `${s.name}: travel ${s.travel_s.toFixed(1)} s, observe ${s.observe_s.toFixed(1)} s, ` +
          `done at ${s.done_at_s.toFixed(1)} s` }))),
      el("p", { class: "hint", text: `${plan.groups.length} groups: ` +
        plan.groups.map((g) => `${g.name} (${g.members.join(", ")})`).join("; ") }));
    drawPlan(req, plan);
  } catch (e) { showProblem(out, e); }
});

// pan (drag), zoom (wheel, buttons, keys)
(() => {
  const map = $("#map");
  let drag = null;
  map.addEventListener("pointerdown", (ev) => {
    if (ev.target.closest(".landmark")) return;
    drag = { x: ev.clientX, y: ev.clientY, view: { ...state.view } };
    map.setPointerCapture(ev.pointerId);
  });
  map.addEventListener("pointermove", (ev) => {
    if (!drag) return;
    const s = scale();
    state.view = { ...drag.view, x: drag.view.x - (ev.clientX - drag.x) * s,
                   y: drag.view.y - (ev.clientY - drag.y) * s };
    setViewBox();
  });
  map.addEventListener("pointerup", () => { drag = null; });
  map.addEventListener("wheel", (ev) => {
    ev.preventDefault();
    const [cx, cy] = clientToMap(ev);
    zoom(ev.deltaY > 0 ? 1.2 : 1 / 1.2, cx, cy);
  }, { passive: false });
  map.addEventListener("keydown", (ev) => {
    const v = state.view, step = 0.1;
    const moves = { ArrowLeft: [-step * v.w, 0], ArrowRight: [step * v.w, 0],
                    ArrowUp: [0, -step * v.h], ArrowDown: [0, step * v.h] };
    if (moves[ev.key]) {
      ev.preventDefault();
      state.view = { ...v, x: v.x + moves[ev.key][0], y: v.y + moves[ev.key][1] };
      setViewBox();
    } else if (ev.key === "+" || ev.key === "=") zoom(1 / 1.25);
    else if (ev.key === "-") zoom(1.25);
    else if (ev.key === "0" && state.description) fit(worldBounds(state.description));
  });
  $("#zoom-in").addEventListener("click", () => zoom(1 / 1.25));
  $("#zoom-out").addEventListener("click", () => zoom(1.25));
  $("#zoom-fit").addEventListener("click", () => state.description && fit(worldBounds(state.description)));
})();

// -- mission ------------------------------------------------------------------------------
function renderSteps(steps) {
  const list = $("#mission-steps");
  list.replaceChildren(...steps.map((s) => {
    const r = s.result || {};
    const bits = Object.entries(r).filter(([, v]) => v === null || typeof v !== "object")
      .slice(0, 6).map(([k, v]) => `${k}: ${typeof v === "number" ? +v.toFixed(3) : v}`);
    return el("li", { class: r.ok === false ? "problem" : "", "data-what": s.what,
      text: `${s.what}${bits.length ? " — " + bits.join(", ") : ""}` });
  }));
}

// a finished mission replayed: its recorded steps one after another, as they came live
async function showMission() {
  const list = $("#mission-steps");
  list.dataset.state = "replaying";
  mission.steps = [];
  renderSteps([]);
  let record;
  try { record = await api("GET", worldPath(state.world, "/mission")); }
  catch (e) { showProblem($("#mission-job"), e); delete list.dataset.state; return; }
  for (const dot of layer("trajectory").querySelectorAll("circle[data-step]")) dot.remove();
  for (const step of record.steps) {
    missionStep(step);
    await new Promise((r) => setTimeout(r, 150));
  }
  list.dataset.state = "replayed";
}

$("#mission-replay").addEventListener("click", showMission);

const mission = { job: null, bar: null, label: null, steps: [] };

$("#mission-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const f = new FormData(ev.target);
  const box = $("#mission-job");
  box.replaceChildren();
  mission.steps = [];
  renderSteps([]);
  layer("trajectory").replaceChildren();
  try {
    mission.job = await api("POST", worldPath(state.world, "/missions"),
      { seed: +f.get("seed"), max_stops: +f.get("max_stops") });
  } catch (e) { showProblem(box, e); return; }
  mission.bar = el("progress", { max: 1, value: 0, "aria-label": "mission progress" });
  mission.label = el("span", { text: " queued" });
  box.append(mission.bar, mission.label);
});

// a job's progress, as the world's events report it
on("job", (job) => {
  if (mission.job && job.id === mission.job.id) {
    mission.bar.value = job.progress;
    mission.label.textContent = ` ${job.status}: ${job.stage}`;
    if (job.error) $("#mission-job").append(el("div", { class: "problem", text: job.error.detail || "" }));
  }
});

// each step as the mission records it; where it says a position, a mark on the map
on("mission_step", (step) => missionStep(step));

function missionStep(step) {
  if (step.step === 0) mission.steps = [];
  mission.steps.push(step);
  renderSteps(mission.steps);
  const r = step.result || {};
  if (typeof r.x === "number" && typeof r.y === "number") {
    const size = Math.max(0.06, state.view.w / 150);
    const g = layer("trajectory");
    const dot = svg("circle", { class: "estimate", cx: r.x, cy: -r.y, r: size,
      "data-step": step.step });
    dot.append(svg("title", {}, `${step.step}: ${step.what}`));
    g.append(dot);
  }
}

function trajectoryLine(rid, kind) {
  const g = layer("trajectory");
  let line = g.querySelector(`polyline[data-run="${CSS.escape(rid)}"]`);
  if (!line) {
    line = svg("polyline", { class: "traj", "data-run": rid, "data-kind": kind, points: "",
      "stroke-width": 2, "vector-effect": "non-scaling-stroke" });
    g.append(line);
  }
  return line;
}

// a SLAM or localization run's pose as its scans are processed
function livePose(kind) {
  return (d) => {
    if (!d.pose) return;
    const line = trajectoryLine(d.run, kind);
    line.setAttribute("points", `${line.getAttribute("points")} ${d.pose.x},${-d.pose.y}`.trim());
    line.dataset.scans = d.scans;
    $("#live-run").textContent = `${kind} run ${d.run}: ${d.scans} scans, pose ` +
      `(${d.pose.x.toFixed(2)}, ${d.pose.y.toFixed(2)}, ${d.pose.theta.toFixed(2)})`;
    if (kind !== "SLAM") return;
    const b = document.querySelector(`#slam-runs button[data-run="${CSS.escape(d.run)}"]`);
    if (!b) loadRuns(state.world); // a run started since the list was read
    else b.textContent = b.textContent.replace(/· [\d?]+ scans$/, `· ${d.scans} scans`);
    if (d.run === runs.shown) scheduleRunRefresh();
  };
}
on("slam_pose", livePose("SLAM"));
on("localization_pose", livePose("localization"));
on("artifact", (a) => {
  const summary = state.summaries[state.world];
  if (summary) summary.artifacts = [...new Set([...summary.artifacts, a.kind, ...a.with])];
  if (["saved_map", "eigenspace", "slam_facts"].includes(a.kind)) drawMap(false);
});
on("world_deleted", () => { status(`world ${state.world} was deleted`); loadWorlds(); });

// -- jobs: the list once, then kept current by the service-wide job events --------------
const jobs = { rows: new Map(), source: null };

function jobRow(j) {
  const cancel = el("button", { type: "button", class: "secondary", text: "Cancel",
    "aria-label": `Cancel job ${j.id}` });
  cancel.disabled = !["queued", "running"].includes(j.status);
  cancel.addEventListener("click", async () => {
    try { await api("DELETE", `/jobs/${enc(j.id)}`); } catch (e) { showProblem($("#status"), e); }
  });
  return el("tr", { "data-job": j.id, "data-status": j.status },
    el("td", { text: j.id.slice(0, 8) }), el("td", { text: j.world }),
    el("td", { text: j.kind }), el("td", { text: j.status }), el("td", { text: j.stage }),
    el("td", {}, el("progress", { max: 1, value: j.progress,
      "aria-label": `progress of job ${j.id}` })), el("td", {}, cancel));
}

function showJob(j) {
  const row = jobRow(j);
  const old = jobs.rows.get(j.id);
  if (old) old.replaceWith(row); else $("#jobs-table tbody").append(row);
  jobs.rows.set(j.id, row);
}

async function loadJobs() {
  // listen first, then list: a change between the two arrives as an event
  followJobs();
  const list = await api("GET", "/jobs");
  jobs.rows.clear();
  $("#jobs-table tbody").replaceChildren();
  for (const j of list) showJob(j);
}

function followJobs() {
  if (jobs.source) return;
  jobs.source = new EventSource("/jobs/events");
  jobs.source.addEventListener("job", (ev) => showJob(JSON.parse(ev.data)));
  jobs.source.addEventListener("open", () => { $("#jobs-table").dataset.live = "true"; });
}

function unfollowJobs() {
  if (jobs.source) jobs.source.close();
  jobs.source = null;
  delete $("#jobs-table").dataset.live;
}

// -- query --------------------------------------------------------------------------------
$("#query-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const out = $("#query-result");
  out.replaceChildren(el("p", { text: "running…" }));
  try {
    const r = await api("POST", worldPath(state.world, "/query"), { goal: $("#goal").value });
    out.replaceChildren();
    if (!r.solutions.length) { out.append(el("p", { text: "false (no solutions)" })); return; }
    const cols = [...new Set(r.solutions.flatMap((s) => Object.keys(s)))];
    const table = el("table", { id: "solutions" });
    table.append(el("thead", {}, el("tr", {}, ...cols.map((c) => el("th", { scope: "col", text: c })))));
    const tbody = el("tbody");
    for (const s of r.solutions) {
      tbody.append(el("tr", {}, ...cols.map((c) => el("td", {
        text: typeof s[c] === "object" ? JSON.stringify(s[c]) : String(s[c] ?? "") }))));
    }
    table.append(tbody);
    out.append(el("p", { text: `${r.solutions.length} solution(s)${r.truncated ? " (truncated)" : ""}` }), table);
  } catch (e) { showProblem(out, e); }
});

// -- routing --------------------------------------------------------------------------------
async function route() {
  const name = (location.hash.replace(/^#\//, "") || "map").split("/")[0];
  for (const v of document.querySelectorAll(".view")) {
    v.classList.toggle("active", v.id === `view-${name}`);
  }
  for (const a of document.querySelectorAll("header nav a[data-view]")) {
    if (a.dataset.view === name) a.setAttribute("aria-current", "page");
    else a.removeAttribute("aria-current");
  }
  if (name !== "jobs") unfollowJobs();
  try {
    if (name === "worlds") await loadWorlds();
    if (name === "jobs") await loadJobs();
  } catch (e) { showProblem($("#status"), e); }
}

window.addEventListener("hashchange", route);

(async () => {
  try {
    const templates = loadTemplates(); // the create form's list: the map need not wait
    await loadWorlds();
    // #/map/<world> opens that world
    const wanted = decodeURIComponent(location.hash.split("/")[2] || "");
    if (state.summaries[wanted]) state.world = wanted;
    if (state.world) await selectWorld(state.world);
    await Promise.all([route(), templates]);
    document.body.dataset.ready = "true";
  } catch (e) { showProblem($("#status"), e); }
})();
