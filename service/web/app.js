// MAGNET web page: upload a mesh, run a job, follow it live (server-sent events), look at the
// result (2D SVG, picture, box plots, files; a hierarchy's levels one over the other), list,
// cancel, delete and compare jobs.
// Plain JavaScript, no library: everything goes through the same HTTP API as the other clients.
"use strict";

const $ = (sel, root = document) => root.querySelector(sel);
const FINAL = ["succeeded", "failed", "cancelled"];
const NUMBER_FIELDS = ["k", "nref", "target_size", "mult_factor"];
const OPTION_FIELDS = ["seed", "absorb_fraction", "hole_policy", "method", "physical_tag", "boundary_tag", "weld", "allow_extra", "fill"];
const NUMBER_OPTIONS = ["seed", "absorb_fraction", "boundary_tag", "weld"];
const CHECK_OPTIONS = ["allow_extra", "fill"]; // checkboxes: sent as true when ticked, left out otherwise
const HIERARCHY_FIELDS = ["ratio", "coarsest", "finest", "boxfit"];
const SCHEDULED = ["aggregation", "quality", "nested"]; // finest levels that take the default schedule (no ratio)
const FIELDS = ["model", "mode", ...NUMBER_FIELDS, "subset", "refiner", "hierarchy", ...HIERARCHY_FIELDS, ...OPTION_FIELDS];
const MODE_FIELDS = {
  kway: ["k"], nref: ["nref"], "target-size": ["target_size"], "mult-factor": ["mult_factor"],
  segregated: ["mult_factor"], coarsen: ["subset", "k", "nref", "target_size", "mult_factor"],
};
const state = {
  mesh: null, models: [], jobs: [], meshes: new Map(), selected: new Set(), follow: null, timer: null, fine: new Map(),
};

// --- HTTP --------------------------------------------------------------------------------------

class ApiError extends Error {
  constructor(status, body) {
    super(errorText(body));
    this.status = status;
    this.body = body;
  }
}

function errorText(body) {
  const d = body && body.detail;
  if (typeof d === "string") return d;
  if (Array.isArray(d)) return d.map((e) => `${fieldOf(e.loc) || "request"}: ${e.msg}`).join("; ");
  return JSON.stringify(body);
}

const token = () => localStorage.getItem("magnet.token") || "";

async function api(path, options = {}) {
  const headers = { ...(options.headers || {}) };
  if (token()) headers.Authorization = `Bearer ${token()}`;
  const response = await fetch(path, { ...options, headers });
  if (response.status === 401) notice("This server needs an API key: enter yours in the API key field above.");
  if (!response.ok) {
    const body = await response.json().catch(() => ({ detail: response.statusText }));
    throw new ApiError(response.status, body);
  }
  return response;
}

const getJSON = async (path) => (await api(path)).json();
const blobURL = async (path) => URL.createObjectURL(await (await api(path)).blob());
const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

function notice(text) {
  const p = $("#notice");
  p.textContent = text || "";
  p.hidden = !text;
}

function esc(value) {
  return String(value).replace(/[&<>"']/g, (c) => `&#${c.charCodeAt(0)};`);
}

const fmt = (v) => (typeof v === "number" && !Number.isInteger(v) ? v.toPrecision(4) : String(v));
// the server's advice names job options: on this page they are form fields, said by their labels
const OPTION_WORDS = [
  [/(?:set )?options\.fill(?: = true)?/g, "tick “Fill the closed surface with tetrahedra”"],
  [/options\.allow_extra/g, "“Allow extra elements” under Options"],
  [/options\.weld/g, "“Weld points closer than” under Options"],
];
const pageWords = (text) => OPTION_WORDS.reduce((t, [re, words]) => t.replace(re, words), String(text ?? ""));
// a hierarchy's ratio (one number, or one per level): at most 3 significant digits each
const fmtRatio = (r) => [].concat(r).map((v) => (typeof v === "number" ? String(+v.toPrecision(3)) : String(v))).join(", ");

// --- upload and mesh summary -------------------------------------------------------------------

async function upload(file) {
  const box = $("#mesh");
  box.hidden = false;
  box.innerHTML = `<p>uploading ${esc(file.name)} (${(file.size / 1e6).toFixed(2)} MB)…</p>`;
  $("#form").hidden = true;
  try {
    const response = await api(`v1/meshes?filename=${encodeURIComponent(file.name)}`, {
      method: "POST", headers: { "Content-Type": "application/octet-stream" }, body: file,
    });
    state.mesh = await response.json();
    state.meshes.set(state.mesh.id, state.mesh);
  } catch (e) {
    box.innerHTML = `<p class="error">${esc(file.name)}: ${esc(e.message)}</p>`;
    return;
  }
  showMesh(state.mesh);
  buildForm();
}

function showMesh(mesh) {
  const types = Object.entries(mesh.cell_types).map(([t, n]) => `${n} ${t}`).join(", ");
  const bbox = mesh.bbox[0].slice(0, mesh.dim).map((lo, i) => `[${fmt(lo)}, ${fmt(mesh.bbox[1][i])}]`).join(" × ");
  const rows = [
    ["file", mesh.filename], ["cells", mesh.cells], ["points", mesh.points], ["dimension", mesh.dim],
    ["cell types", types], ["physical groups", mesh.physical_groups.join(", ") || "none"], ["bounding box", bbox],
  ];
  if (mesh.boundary_groups && mesh.boundary_groups.length) rows.push(["boundary groups", mesh.boundary_groups.join(", ")]);
  let html = `<h3>Mesh</h3><table class="kv" id="mesh-summary">${rows.map(([k, v]) => `<tr><th>${k}</th><td>${esc(v)}</td></tr>`).join("")}</table>`;
  if (mesh.check != null) html += `<h3>Check</h3><div id="mesh-check">${checkReport(mesh.check)}</div>`;
  if (mesh.boundary != null) html += `<details><summary>Boundary</summary>${report(mesh.boundary)}</details>`;
  $("#mesh").innerHTML = html;
}

function checkReport(check) {
  // `magnet check`'s report: the verdict and each issue in words; the counts folded away
  if (!check || !Array.isArray(check.issues)) return report(check);
  const issues = check.issues.map((i) => `<li class="${esc(i.severity)}"><b>${esc(i.severity)}</b> ${esc(i.message || i.kind)}</li>`);
  const shown = ["file", "verdict", "issues", "dim", "cells", "points", "cell_types", "physical_groups", "boundary", "boundary_notes"];
  const rest = Object.entries(check).filter(([k]) => !shown.includes(k));
  return `<p>verdict <span class="verdict ${esc(check.verdict)}">${esc(check.verdict)}</span></p>`
    + (issues.length ? `<ul class="issues">${issues.join("")}</ul>` : `<p class="hint">no issues</p>`)
    + (rest.length ? `<details><summary>counts</summary>${report(Object.fromEntries(rest))}</details>` : "");
}

function report(value) {
  // the upload's check report, whatever its shape: nested objects as tables, lists as lists
  if (Array.isArray(value)) return value.length ? `<ul>${value.map((v) => `<li>${report(v)}</li>`).join("")}</ul>` : "none";
  if (value && typeof value === "object") {
    return `<table class="kv">${Object.entries(value).map(([k, v]) => `<tr><th>${esc(k)}</th><td>${report(v)}</td></tr>`).join("")}</table>`;
  }
  return esc(fmt(value));
}

// --- the job form, built from GET /v1/models ----------------------------------------------------

const form = () => $("#form");
const field = (name) => form().querySelector(`.field[data-field="${name}"]`);
const input = (name) => form().elements[name];

function fillSelect(select, values, keep) {
  const old = keep ? select.value : null;
  select.innerHTML = values.map((v) => `<option>${esc(v)}</option>`).join("");
  if (old && values.includes(old)) select.value = old;
}

function buildForm() {
  const dim = state.mesh.dim;
  const usable = state.models.filter((m) => m.dimension == null || [].concat(m.dimension).map(Number).includes(dim));
  fillSelect(input("model"), usable.map((m) => m.name), true);
  const cells = state.mesh.cells;
  const extent = Math.max(...state.mesh.bbox[1].map((hi, i) => hi - state.mesh.bbox[0][i]));
  if (!input("k").value) input("k").value = Math.min(64, cells);
  if (!input("nref").value) input("nref").value = Math.min(6, Math.floor(Math.log2(cells)));
  if (!input("mult_factor").value) input("mult_factor").value = 0.1;
  input("target_size").value = +(extent / 10).toPrecision(3);
  // a closed surface (STL, OBJ, PLY, OFF): its job fills it with tetrahedra first (options.fill)
  const surface = Boolean(state.mesh.surface);
  field("fill").hidden = !surface;
  input("fill").checked = surface;
  $("#fill-hint").hidden = !surface;
  onModel();
  form().hidden = false;
}

function onModel() {
  const model = state.models.find((m) => m.name === input("model").value) || { modes: [] };
  $("#model-description").textContent = model.description || "";
  fillSelect(input("mode"), model.modes, true);
  const refiners = model.refiners || [];
  field("refiner").hidden = refiners.length === 0;
  fillSelect(input("refiner"), ["none", ...refiners], true);
  field("method").hidden = model.name !== "metis";
  onMode();
}

function onMode() {
  const wanted = MODE_FIELDS[input("mode").value] || [];
  for (const name of [...NUMBER_FIELDS, "subset"]) field(name).hidden = !wanted.includes(name);
  onHierarchy();
}

function onHierarchy() {
  // a hierarchy: nested levels of their own at this ratio (any model), or the levels a recursive mode records
  const on = input("hierarchy").checked;
  for (const name of HIERARCHY_FIELDS) field(name).hidden = !on;
  if (on && SCHEDULED.includes(input("finest").value)) field("ratio").hidden = true;
  $("#hierarchy-hint").hidden = !on;
  $("#submit").textContent = on ? "Build hierarchy" : "Agglomerate";
  clearErrors();
}

function clearErrors() {
  form().querySelectorAll(".error").forEach((e) => { e.textContent = ""; });
  form().querySelectorAll(".invalid").forEach((e) => e.classList.remove("invalid"));
}

function fieldOf(loc) {
  // pydantic's loc: ["body", "k"] or ["body", "options", "seed"]
  const names = (loc || []).filter((p) => typeof p === "string" && p !== "body" && p !== "options");
  return names.length ? names[names.length - 1] : null;
}

function guessField(message) {
  // the library's messages start with the parameter: "k = 9000 is larger ...", "options.seed must ..."
  const m = /^(?:options\.)?([a-z_]+)/.exec(message || "");
  return m && FIELDS.includes(m[1]) ? m[1] : null;
}

function showErrors(error) {
  const items = [];
  const detail = error.body && error.body.detail;
  // a malformed request lists each problem in `errors` (loc + msg); the library names one `field`
  const listed = Array.isArray(detail) ? detail : error.body && error.body.errors;
  if (error.status === 422 && Array.isArray(listed)) {
    for (const e of listed) items.push([fieldOf(e.loc), e.msg]);
  } else if (error.status === 422) {
    items.push([(error.body && error.body.field) || guessField(detail), error.message]);
  } else {
    items.push([null, error.message]);
  }
  for (const [name, said] of items) {
    const box = name && field(name);
    const text = pageWords(said);
    if (box && !box.hidden) {
      box.querySelector(".error").textContent = text;
      box.classList.add("invalid");
      if (box.closest("details")) box.closest("details").open = true;
    } else {
      $("#form-error").textContent = (name ? `${name}: ` : "") + text;
    }
  }
}

function jobBody() {
  const body = { mesh_id: state.mesh.id, model: input("model").value, mode: input("mode").value };
  for (const name of NUMBER_FIELDS) {
    const raw = input(name).value.trim();
    if (!field(name).hidden && raw !== "") body[name] = Number(raw);
  }
  const subset = input("subset").value.trim();
  if (!field("subset").hidden && subset) {
    body.subset = subset.startsWith("[") ? JSON.parse(subset) : subset.split(/[\s,]+/).filter(Boolean).map(Number);
  }
  if (!field("refiner").hidden && input("refiner").value !== "none") body.refiner = input("refiner").value;
  const options = {};
  for (const name of OPTION_FIELDS) {
    if (field(name).hidden) continue;
    if (CHECK_OPTIONS.includes(name)) {
      if (input(name).checked) options[name] = true;
      continue;
    }
    const raw = input(name).value.trim();
    if (raw === "") continue;
    options[name] = NUMBER_OPTIONS.includes(name) ? Number(raw) : raw;
  }
  if (input("hierarchy").checked) {
    options.hierarchy = true;
    const ratio = input("ratio").value.trim();
    const coarsest = input("coarsest").value.trim();
    const finest = input("finest").value;
    const scheduled = SCHEDULED.includes(finest);
    if (ratio !== "" && !scheduled) options.ratio = Number(ratio);
    if ((ratio !== "" || finest !== "") && coarsest !== "") options.coarsest = Number(coarsest);
    if (finest !== "") options.finest = finest;
    if (input("boxfit").checked) options.boxfit = true;
  }
  body.options = options;
  return body;
}

async function submit(event) {
  event.preventDefault();
  clearErrors();
  let body;
  try {
    body = jobBody();
  } catch (e) {
    showErrors({ status: 422, body: { detail: "subset: not a JSON list", field: "subset" }, message: "not a JSON list" });
    return;
  }
  try {
    const job = await (await api("v1/jobs", {
      method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body),
    })).json();
    refreshJobs();
    follow(job);
  } catch (e) {
    showErrors(e);
  }
}

// --- live progress: GET /v1/jobs/{id}/events read with fetch (EventSource cannot send the key) ----

function showProgress(job) {
  const pct = Math.round(100 * (job.progress || 0));
  $("#progress").hidden = false;
  $("#progress-job").textContent = job.id.slice(0, 8);
  $("#bar-fill").style.width = `${pct}%`;
  $("#bar-fill").className = job.status;
  $("#progress-pct").textContent = `${pct}%`;
  $("#progress-stage").textContent = job.stage || job.status;
  $("#progress-status").textContent = job.status + (job.error ? `: ${pageWords(job.error)}` : "");
}

async function* jobEvents(id, signal) {
  const response = await api(`v1/jobs/${id}/events`, { signal });
  const reader = response.body.pipeThrough(new TextDecoderStream()).getReader();
  let buffer = "";
  for (;;) {
    const { value, done } = await reader.read();
    if (done) return;
    buffer += value;
    let cut;
    while ((cut = buffer.indexOf("\n\n")) >= 0) {
      const block = buffer.slice(0, cut);
      buffer = buffer.slice(cut + 2);
      const data = block.split("\n").filter((l) => l.startsWith("data:")).map((l) => l.slice(5).trim()).join("\n");
      if (data) yield JSON.parse(data);
    }
  }
}

async function follow(job) {
  if (state.follow) state.follow.abort();
  const control = new AbortController();
  state.follow = control;
  showProgress(job);
  while (!FINAL.includes(job.status) && !control.signal.aborted) {
    try {
      for await (const record of jobEvents(job.id, control.signal)) {
        if (!record.status) return; // the job was deleted
        job = record;
        showProgress(job);
      }
    } catch (e) {
      if (control.signal.aborted || (e instanceof ApiError && e.status < 500)) return;
    }
    if (!FINAL.includes(job.status)) await sleep(1000); // the stream closed early: reconnect
  }
  if (control.signal.aborted) return;
  refreshJobs();
  if (job.status === "succeeded") showResult(job.id);
}

// --- result view -------------------------------------------------------------------------------

const RESULT_FILES = [
  ["mesh", "mesh.vtu"], ["metrics", "metrics.json"], ["labels", "labels.json"], ["preview.png", "preview.png"],
  ["lymph?format=json", "lymph.json", 2], ["lymph?format=mat", "lymph.mat", 2],
];

function paramText(params) {
  const p = params || {};
  const value = { kway: `k=${p.k}`, nref: p.nref, "target-size": p.target_size, "mult-factor": p.mult_factor,
    segregated: `f=${p.mult_factor}`, coarsen: `of ${(p.subset || []).length} cells` }[p.mode];
  const o = p.options || {};
  const levels = o.hierarchy ? ` · hierarchy${o.ratio ? ` ratio ${fmtRatio(o.ratio)}` : ""}${o.finest ? ` · finest ${o.finest}` : ""}` : "";
  return `${p.mode || ""} ${value ?? ""}`.trim() + levels;
}

const jobLabel = (job) => `${job.params.model} ${paramText(job.params)} · ${job.id.slice(0, 6)}`;

async function showResult(id) {
  $("#compare").hidden = true;
  const [job, metrics] = await Promise.all([getJSON(`v1/jobs/${id}`), getJSON(`v1/jobs/${id}/metrics`)]);
  const section = $("#result");
  section.hidden = false;
  section.dataset.job = id;
  $("#result-title").textContent = jobLabel(job);
  const run = metrics.run || {};
  const part = metrics.partition || {};
  const rows = [
    ["elements", metrics.elements], ["requested", run.requested], ["from cells", run.cells],
    ["parts split", run.parts_split], ["fragments absorbed", run.fragments_absorbed], ["holed elements split", run.holes_split],
    ["edge cut", part.cut], ["normalized cut", part.normalized_cut], ["volume imbalance", part.volume_imbalance],
    ["connected", part.connected], ["compute time", job.result && job.result.timings.total != null ? `${fmt(job.result.timings.total)} s` : ""],
  ].filter(([, v]) => v !== undefined && v !== null && v !== "");
  $("#partition").innerHTML = rows.map(([k, v]) => `<tr><th>${k}</th><td>${esc(fmt(v))}</td></tr>`).join("");
  $("#downloads").innerHTML = RESULT_FILES.filter(([, , dim]) => !dim || dim === metrics.dim)
    .map(([path, name]) => `<li><a href="v1/jobs/${id}/${path}" data-download="${id}-${name}">${name}</a></li>`).join("");
  $("#boxplots").innerHTML = boxPlot(Object.entries(metrics.summary).map(([name, stats]) => ({ label: name, stats })));
  $("#preview").src = await blobURL(`v1/jobs/${id}/preview.png`);
  $("#drawing").hidden = metrics.dim !== 2;
  const hierarchy = job.params.options && job.params.options.hierarchy;
  if (!hierarchy) $("#hierarchy").hidden = true;
  if (metrics.dim === 2) drawMesh(await getJSON(`v1/jobs/${id}/polygons`));
  if (hierarchy) await showHierarchy(job);
}

// --- a hierarchy: every level one over the other (coarsest on top), drawn over the fine mesh ------

async function finePolygons(mesh) {
  // the uploaded cells, drawn thin under every level (fetched once per mesh; none when too many)
  if (mesh.dim !== 2 || mesh.cells > 200000) return null;
  if (!state.fine.has(mesh.id)) state.fine.set(mesh.id, getJSON(`v1/meshes/${mesh.id}/polygons`).catch(() => null));
  return state.fine.get(mesh.id);
}

function loops(poly) {
  // one "M...Z" per element (or cell), y flipped for SVG
  const { points, connectivity, offsets } = poly;
  const out = [];
  for (let e = 0; e + 1 < offsets.length; e++) {
    out.push(`M${connectivity.slice(offsets[e], offsets[e + 1]).map((j) => `${points[j][0]},${-points[j][1]}`).join("L")}Z`);
  }
  return out;
}

const MEDIANS = [["circle_ratio", "circle ratio"], ["box_ratio", "box ratio"], ["uniformity_factor", "uniformity"],
  ["volume_difference", "volume difference"], ["area_perimeter_ratio", "area/perimeter"]];

function levelTable(level) {
  const s = level.summary || {};
  const p = level.partition || {};
  const rows = [["elements", level.elements]];
  for (const [name, label] of MEDIANS) if (s[name]) rows.push([`${label} (median)`, s[name].median]);
  rows.push(["coverage", level.coverage], ["normalized cut", level.normalized_cut], ["connected", p.connected]);
  return `<table class="kv">${rows.filter(([, v]) => v != null)
    .map(([k, v]) => `<tr><th>${esc(k)}</th><td data-metric="${esc(k)}">${esc(fmt(v))}</td></tr>`).join("")}</table>`;
}

async function showHierarchy(job) {
  const section = $("#hierarchy");
  section.hidden = false;
  section.dataset.job = job.id;
  const info = await getJSON(`v1/jobs/${job.id}/hierarchy/levels`);
  const n = info.levels.length;
  $("#hierarchy-title").textContent = `${info.model || job.params.model}${info.ratio ? ` · ratio ${fmtRatio(info.ratio)}` : ""}`
    + ` · ${n} levels · ${info.nested ? "nested" : "not nested"} · ${info.cells} cells`;
  $("#hierarchy-download").innerHTML = `<a href="v1/jobs/${job.id}/hierarchy" data-download="${job.id}-hierarchy.zip">hierarchy.zip</a>`;
  const host = $("#levels");
  host.innerHTML = info.levels.map((lv) => `<div class="level" data-level="${lv.level}" data-elements="${lv.elements}">`
    + `<h3>Level ${lv.level} · <span class="count">${lv.elements}</span> elements${lv.level === n - 1 ? " (finest)" : lv.level === 0 ? " (coarsest)" : ""}</h3>`
    + `<div class="level-row"><div class="level-view">${info.dim === 2 ? "" : `<img alt="level ${lv.level}">`}</div>`
    + `${levelTable(lv)}</div></div>`).join("");
  if (info.dim !== 2) {
    // 3D: each level's picture, as a 3D job's preview.png (the exploded view), drawn by the server
    await Promise.all(info.levels.map(async (lv) => {
      const img = $(`#levels .level[data-level="${lv.level}"] img`);
      try {
        img.src = await blobURL(`v1/jobs/${job.id}/hierarchy/levels/${lv.level}/preview.png`);
      } catch (e) {
        img.replaceWith(Object.assign(document.createElement("p"), { className: "error", textContent: e.message }));
      }
    }));
    return;
  }
  const [fine, ...polys] = await Promise.all([
    meshOf(job.mesh_id).then(finePolygons),
    ...info.levels.map((lv) => getJSON(`v1/jobs/${job.id}/hierarchy/levels/${lv.level}`)),
  ]);
  if ($("#hierarchy").dataset.job !== job.id) return; // another result was opened meanwhile
  drawLevels(polys, fine);
}

function drawLevels(polys, fine) {
  const pts = polys[0].points;
  const xs = pts.map((p) => p[0]);
  const ys = pts.map((p) => p[1]);
  const [x0, x1, y0, y1] = [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)];
  const pad = 0.02 * Math.max(x1 - x0, y1 - y0);
  const home = [x0 - pad, -y1 - pad, x1 - x0 + 2 * pad, y1 - y0 + 2 * pad];
  const finePath = fine ? `<path class="fine" d="${loops(fine).join("")}"/>` : "";
  const shapes = polys.map(loops);
  const svgs = polys.map((poly, L) => {
    const fills = shapes[L].map((d, e) => `<path data-e="${e}" d="${d}"/>`);
    const coarser = L > 0 ? `<path class="coarser" d="${shapes[L - 1].join("")}"/>` : "";
    const svg = `<svg class="level-svg" viewBox="${home.join(" ")}" preserveAspectRatio="xMidYMid meet">`
      + `<g class="fills">${fills.join("")}</g>${finePath}<path class="outline" d="${shapes[L].join("")}"/>${coarser}</svg>`;
    const view = $(`#levels .level[data-level="${poly.level}"] .level-view`);
    view.innerHTML = svg;
    const el = view.querySelector("svg");
    // colour after the level-0 ancestor (its hue), siblings in lighter and darker shades
    el.querySelectorAll(".fills path").forEach((p, e) => {
      p.style.fill = `hsl(${((poly.root[e] * 137.508) % 360).toFixed(1)}, 55%, ${58 + ((e * 7) % 4) * 8}%)`;
    });
    el.dataset.elements = poly.offsets.length - 1;
    hoverTip(el, (e) => `<b>level ${poly.level}, element ${e}</b>${poly.parent ? ` · in ${poly.parent[e]} of level ${poly.level - 1}` : ""}`, poly.cell_data);
    return el;
  });
  panZoom(svgs, home); // one view for all levels: zoom one, every level follows
}

async function download(event) {
  const link = event.target.closest("a[data-download]");
  if (!link) return;
  event.preventDefault(); // a plain link cannot send the API key: fetch, then save the blob
  try {
    const url = await blobURL(link.getAttribute("href"));
    const a = Object.assign(document.createElement("a"), { href: url, download: link.dataset.download });
    document.body.append(a);
    a.click();
    a.remove();
    setTimeout(() => URL.revokeObjectURL(url), 60000);
  } catch (e) {
    notice(`download failed: ${e.message}`);
  }
}

// --- 2D drawing: one SVG path per element, zoom, pan, hover, colour by any metric ---------------

const VIRIDIS = [[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]];

function viridis(t) {
  const x = Math.min(Math.max(t, 0), 1) * (VIRIDIS.length - 1);
  const i = Math.min(Math.floor(x), VIRIDIS.length - 2);
  const c = VIRIDIS[i].map((a, j) => Math.round(a + (VIRIDIS[i + 1][j] - a) * (x - i)));
  return `rgb(${c.join(",")})`;
}

function drawMesh(poly) {
  const { points, connectivity, offsets, cell_data: data } = poly;
  const xs = points.map((p) => p[0]);
  const ys = points.map((p) => p[1]);
  const [x0, x1, y0, y1] = [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)];
  const pad = 0.02 * Math.max(x1 - x0, y1 - y0);
  const home = [x0 - pad, -y1 - pad, x1 - x0 + 2 * pad, y1 - y0 + 2 * pad];
  const paths = [];
  for (let e = 0; e + 1 < offsets.length; e++) {
    const loop = connectivity.slice(offsets[e], offsets[e + 1]).map((j) => `${points[j][0]},${-points[j][1]}`);
    paths.push(`<path data-e="${e}" d="M${loop.join("L")}Z"/>`);
  }
  const host = $("#svg-host");
  host.innerHTML = `<svg id="mesh-svg" viewBox="${home.join(" ")}" preserveAspectRatio="xMidYMid meet">${paths.join("")}</svg>`;
  const svg = $("#mesh-svg");
  svg.dataset.elements = offsets.length - 1;
  const names = Object.keys(data).filter((n) => n !== "element_id");
  const select = $("#color-by");
  fillSelect(select, ["element", ...names], true);
  const paint = () => {
    const by = select.value;
    const values = data[by];
    let legend = "";
    if (!values) {
      svg.querySelectorAll("path").forEach((p, e) => { p.style.fill = `hsl(${(e * 137.508) % 360}, 55%, 68%)`; });
    } else {
      const lo = Math.min(...values);
      const hi = Math.max(...values);
      svg.querySelectorAll("path").forEach((p, e) => { p.style.fill = viridis(hi > lo ? (values[e] - lo) / (hi - lo) : 0.5); });
      legend = `${fmt(lo)} <span class="ramp"></span> ${fmt(hi)}`;
    }
    $("#legend").innerHTML = legend;
  };
  select.onchange = paint;
  paint();

  hoverTip(svg, (e) => `<b>element ${e}</b>`, data);
  $("#reset-view").onclick = panZoom([svg], home);
}

function hoverTip(svg, title, data) {
  // hover an element (path[data-e]): outline it, show its cell data in the tip
  const names = Object.keys(data).filter((n) => n !== "element_id");
  const tip = $("#tip");
  svg.onmousemove = (event) => {
    const path = event.target.closest("path[data-e]");
    if (!path) { tip.hidden = true; return; }
    const e = +path.dataset.e;
    svg.querySelectorAll("path.hover").forEach((p) => p.classList.remove("hover"));
    path.classList.add("hover");
    tip.innerHTML = `${title(e)}<table>${names.map((n) => `<tr><th>${esc(n)}</th><td>${fmt(data[n][e])}</td></tr>`).join("")}</table>`;
    tip.style.left = `${event.clientX + 14}px`;
    tip.style.top = `${event.clientY + 14}px`;
    tip.hidden = false;
  };
  svg.onmouseleave = () => { tip.hidden = true; };
}

function panZoom(svgs, home) {
  // wheel: zoom about the pointer, drag: pan; every SVG of `svgs` shows the same view. Returns a reset.
  let view = [...home];
  const setView = (v) => { view = v; for (const svg of svgs) svg.setAttribute("viewBox", v.join(" ")); };
  for (const svg of svgs) {
    const toWorld = (event) => {
      const r = svg.getBoundingClientRect();
      const s = Math.max(view[2] / r.width, view[3] / r.height); // meet: the larger scale applies
      return [view[0] + view[2] / 2 + (event.clientX - r.left - r.width / 2) * s,
        view[1] + view[3] / 2 + (event.clientY - r.top - r.height / 2) * s, s];
    };
    svg.onwheel = (event) => {
      event.preventDefault();
      const [wx, wy] = toWorld(event);
      const f = Math.exp(event.deltaY * 0.0015);
      setView([wx - (wx - view[0]) * f, wy - (wy - view[1]) * f, view[2] * f, view[3] * f]);
    };
    let drag = null;
    svg.onpointerdown = (event) => { drag = [event.clientX, event.clientY, toWorld(event)[2], [...view]]; svg.setPointerCapture(event.pointerId); };
    svg.onpointermove = (event) => {
      if (!drag) return;
      const [cx, cy, s, v] = drag;
      setView([v[0] - (event.clientX - cx) * s, v[1] - (event.clientY - cy) * s, v[2], v[3]]);
    };
    svg.onpointerup = () => { drag = null; };
  }
  return () => setView([...home]);
}

// --- box plots in SVG, from the metrics summary (min, q1, median, q3, max, mean) ----------------

function boxPlot(groups, title = "") {
  const W = Math.max(320, 120 * groups.length + 60);
  const H = 230;
  const [left, top, bottom] = [48, title ? 26 : 10, 44];
  let lo = Math.min(...groups.map((g) => g.stats.min));
  let hi = Math.max(...groups.map((g) => g.stats.max));
  if (lo >= 0 && hi <= 1) [lo, hi] = [0, 1];
  if (hi === lo) hi = lo + 1;
  const y = (v) => top + (H - top - bottom) * (1 - (v - lo) / (hi - lo));
  const col = (W - left - 10) / groups.length;
  let svg = `<svg class="boxplot" viewBox="0 0 ${W} ${H}" width="${W}" height="${H}">`;
  if (title) svg += `<text x="${W / 2}" y="16" class="title">${esc(title)}</text>`;
  for (let i = 0; i <= 4; i++) {
    const v = lo + ((hi - lo) * i) / 4;
    svg += `<line x1="${left}" x2="${W - 10}" y1="${y(v)}" y2="${y(v)}" class="grid"/><text x="${left - 6}" y="${y(v) + 4}" class="tick">${+v.toPrecision(3)}</text>`;
  }
  groups.forEach((g, i) => {
    const s = g.stats;
    const cx = left + col * (i + 0.5);
    const w = Math.min(50, col * 0.5);
    svg += `<g class="box" data-label="${esc(g.label)}">`
      + `<line x1="${cx}" x2="${cx}" y1="${y(s.max)}" y2="${y(s.q3)}"/><line x1="${cx}" x2="${cx}" y1="${y(s.q1)}" y2="${y(s.min)}"/>`
      + `<line x1="${cx - w / 4}" x2="${cx + w / 4}" y1="${y(s.max)}" y2="${y(s.max)}"/><line x1="${cx - w / 4}" x2="${cx + w / 4}" y1="${y(s.min)}" y2="${y(s.min)}"/>`
      + `<rect x="${cx - w / 2}" y="${y(s.q3)}" width="${w}" height="${Math.max(1, y(s.q1) - y(s.q3))}"/>`
      + `<line x1="${cx - w / 2}" x2="${cx + w / 2}" y1="${y(s.median)}" y2="${y(s.median)}" class="median"/>`
      + (s.mean != null ? `<circle cx="${cx}" cy="${y(s.mean)}" r="2.5"/>` : "")
      + `<title>${esc(g.label)}: min ${fmt(s.min)}, q1 ${fmt(s.q1)}, median ${fmt(s.median)}, q3 ${fmt(s.q3)}, max ${fmt(s.max)}</title></g>`
      + `<text x="${cx}" y="${H - bottom + 16}" class="label">${esc(g.label)}</text>`;
  });
  return `${svg}</svg>`;
}

// --- jobs list, cancel, delete, compare ---------------------------------------------------------

async function meshOf(id) {
  if (!state.meshes.has(id)) state.meshes.set(id, await getJSON(`v1/meshes/${id}`).catch(() => ({ filename: id.slice(0, 8) })));
  return state.meshes.get(id);
}

function seconds(job) {
  if (!job.started_at) return "";
  const end = job.finished_at ? Date.parse(job.finished_at) : Date.now();
  return `${((end - Date.parse(job.started_at)) / 1000).toFixed(1)} s`;
}

async function refreshJobs() {
  let list;
  try {
    list = await getJSON("v1/jobs?limit=100");
  } catch (e) {
    $("#job-rows").innerHTML = `<tr><td colspan="9" class="error">${esc(e.message)}</td></tr>`;
    return;
  }
  if (token() || list) notice("");
  state.jobs = list.items;
  const meshes = await Promise.all(state.jobs.map((j) => meshOf(j.mesh_id)));
  $("#job-rows").innerHTML = state.jobs.map((job, i) => {
    const active = !FINAL.includes(job.status);
    const mesh = meshes[i];
    const actions = [
      job.status === "succeeded" ? `<button data-act="view">view</button>` : "",
      active ? `<button data-act="cancel">cancel</button>` : "",
      `<button data-act="delete">delete</button>`,
    ].join("");
    return `<tr data-job="${job.id}" class="${job.status}">`
      + `<td><input type="checkbox" ${state.selected.has(job.id) ? "checked" : ""} ${job.status === "succeeded" ? "" : "disabled"}></td>`
      + `<td>${esc(new Date(job.created_at).toLocaleString())}</td><td class="status" title="${esc(pageWords(job.error || ""))}">${job.status}${active ? ` ${Math.round(100 * job.progress)}%` : ""}</td>`
      + `<td>${esc(job.params.model)}</td><td>${esc(paramText(job.params))}</td>`
      + `<td>${esc(mesh.filename || "")}${mesh.cells ? ` <small>(${mesh.cells} cells)</small>` : ""}</td>`
      + `<td>${job.result && job.result.elements != null ? job.result.elements : ""}</td><td>${seconds(job)}</td><td>${actions}</td></tr>`;
  }).join("") || `<tr><td colspan="9" class="hint">no jobs yet</td></tr>`;
  for (const id of [...state.selected]) if (!state.jobs.some((j) => j.id === id)) state.selected.delete(id);
  $("#compare-button").disabled = state.selected.size < 2;
  clearTimeout(state.timer);
  if (state.jobs.some((j) => !FINAL.includes(j.status))) state.timer = setTimeout(refreshJobs, 3000);
}

async function onJobRow(event) {
  const row = event.target.closest("tr[data-job]");
  if (!row) return;
  const id = row.dataset.job;
  if (event.target.type === "checkbox") {
    if (event.target.checked) state.selected.add(id); else state.selected.delete(id);
    $("#compare-button").disabled = state.selected.size < 2;
    return;
  }
  const act = event.target.dataset.act;
  try {
    if (act === "view") await showResult(id);
    if (act === "cancel") await api(`v1/jobs/${id}`, { method: "DELETE" });
    if (act === "delete") {
      await api(`v1/jobs/${id}?purge=true`, { method: "DELETE" });
      state.selected.delete(id);
      if ($("#result").dataset.job === id) $("#result").hidden = true;
      if ($("#hierarchy").dataset.job === id) $("#hierarchy").hidden = true;
    }
  } catch (e) {
    notice(e.message);
  }
  if (act === "cancel" || act === "delete") refreshJobs();
}

async function compare() {
  const jobs = state.jobs.filter((j) => state.selected.has(j.id));
  if (jobs.some((j) => j.status !== "succeeded")) return notice("compare finished jobs only");
  if (new Set(jobs.map((j) => j.mesh_id)).size > 1) return notice("compare jobs of the same mesh only");
  notice("");
  const metrics = await Promise.all(jobs.map((j) => getJSON(`v1/jobs/${j.id}/metrics`)));
  const pictures = await Promise.all(jobs.map((j) => blobURL(`v1/jobs/${j.id}/preview.png`)));
  $("#result").hidden = true;
  $("#hierarchy").hidden = true;
  $("#compare").hidden = false;
  const mesh = await meshOf(jobs[0].mesh_id);
  $("#compare-title").textContent = `${jobs.length} jobs of ${mesh.filename || jobs[0].mesh_id.slice(0, 8)}`;
  $("#compare-pictures").innerHTML = jobs.map((j, i) => `<figure><img src="${pictures[i]}" alt="job ${j.id}">`
    + `<figcaption>${esc(jobLabel(j))} · ${metrics[i].elements} elements</figcaption></figure>`).join("");
  const names = [...new Set(metrics.flatMap((m) => Object.keys(m.summary)))];
  $("#compare-plots").innerHTML = names.map((name) => boxPlot(
    jobs.map((j, i) => ({ label: `${j.params.model} ${paramText(j.params)}`, stats: metrics[i].summary[name] })).filter((g) => g.stats),
    name,
  )).join("");
}

// --- start ---------------------------------------------------------------------------------------

async function loadModels() {
  try {
    state.models = await getJSON("v1/models");
  } catch (e) {
    notice(`cannot load the models: ${e.message}`);
  }
}

function init() {
  const tokenInput = $("#token");
  tokenInput.value = token();
  tokenInput.addEventListener("change", () => {
    localStorage.setItem("magnet.token", tokenInput.value.trim());
    notice("");
    state.meshes.clear();
    loadModels();
    refreshJobs();
  });
  const drop = $("#drop");
  drop.addEventListener("dragover", (e) => { e.preventDefault(); drop.classList.add("over"); });
  drop.addEventListener("dragleave", () => drop.classList.remove("over"));
  drop.addEventListener("drop", (e) => {
    e.preventDefault();
    drop.classList.remove("over");
    if (e.dataTransfer.files.length) upload(e.dataTransfer.files[0]);
  });
  $("#file").addEventListener("change", (e) => { if (e.target.files.length) upload(e.target.files[0]); });
  input("model").addEventListener("change", onModel);
  input("mode").addEventListener("change", onMode);
  form().addEventListener("submit", submit);
  form().addEventListener("input", (e) => {
    const box = e.target.closest(".field");
    if (box) { box.classList.remove("invalid"); box.querySelector(".error").textContent = ""; }
  });
  $("#downloads").addEventListener("click", download);
  $("#hierarchy").addEventListener("click", download);
  input("hierarchy").addEventListener("change", onHierarchy);
  input("finest").addEventListener("change", onHierarchy);
  $("#job-rows").addEventListener("click", onJobRow);
  $("#compare-button").addEventListener("click", compare);
  $("#refresh").addEventListener("click", refreshJobs);
  loadModels();
  refreshJobs();
}

init();
