// The treesim jobs page (GET /): every process the service offers, its settings as a form
// built from the process description (GET /v1/processes/{id}), uploads to reuse, jobs with
// their progress, dismissal, results, reports and 3D views. Plain JavaScript, no build step,
// nothing loaded from elsewhere (the page's Content-Security-Policy allows this origin only).
"use strict";

// The token lives only in this variable (for uploads, runs and dismissals): it is exchanged
// once for the server's session cookie (HttpOnly: no script reads it), which opens reading
// requests (the lists, the descriptions, reports). A reload forgets the token; the session
// stays.
let token = "";

const state = {
  processes: [],      // GET /v1/processes
  desc: null,         // the chosen process's description
  uploads: [],        // GET /v1/uploads
  jobs: [],           // the job list as last drawn
  jobsKey: "",        // its JSON, to redraw only on change
  files: new Map(),   // job id → its result files (a successful job's files do not change)
  open: new Set(),    // job ids whose results are unfolded
};

// -- small helpers --------------------------------------------------------------------------
const $ = (id) => document.getElementById(id);

function el(tag, attrs, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (v == null || v === false) continue;
    if (k === "dataset") Object.assign(e.dataset, v);
    else if (k in e && k !== "list") e[k] = v;
    else e.setAttribute(k, v === true ? "" : String(v));
  }
  for (const c of children) {
    if (c == null) continue;
    e.appendChild(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return e;
}

function say(text, isError) {
  const m = $("message");
  m.textContent = text;
  m.className = isError ? "error" : "";
}

function when(iso) {
  if (!iso) return "";
  const d = new Date(iso);
  return isNaN(d) ? iso : d.toLocaleString();
}

function bytes(n) {
  if (n == null) return "";
  if (n < 1e3) return `${n} B`;
  if (n < 1e6) return `${(n / 1e3).toFixed(1)} kB`;
  if (n < 1e9) return `${(n / 1e6).toFixed(1)} MB`;
  return `${(n / 1e9).toFixed(2)} GB`;
}

// -- the API: every error is application/problem+json (RFC 9457) --------------------------
function problemError(status, body) {
  const p = body && typeof body === "object" ? body : {};
  const title = p.title || `HTTP ${status}`;
  const detail = typeof p.detail === "string" ? p.detail : p.detail ? JSON.stringify(p.detail) : "";
  const err = new Error(detail && detail !== title ? `${title}: ${detail}` : title);
  err.status = status;
  err.problem = p;
  return err;
}

async function api(path, options) {
  const opts = Object.assign({}, options || {});
  opts.headers = Object.assign({}, opts.headers || {});
  if (token) opts.headers["Authorization"] = "Bearer " + token;
  const res = await fetch(path, opts);
  let body = null;
  const type = res.headers.get("content-type") || "";
  if (type.includes("json")) body = await res.json();
  if (!res.ok) throw problemError(res.status, body);
  return body;
}

function showError(e, prefix) {
  say((prefix || "") + e.message, true);
  const field = e.problem && typeof e.problem.field === "string" ? e.problem.field : "";
  const path = field.replace(/^(inputs|parameters)\./, "");
  for (const f of document.querySelectorAll("#process-form [data-path]")) {
    if (path && (f.dataset.path === path || path.startsWith(f.dataset.path + "."))) {
      f.classList.add("invalid");
    }
  }
}

// -- signing in -----------------------------------------------------------------------------
async function setToken(value) {
  token = value;
  const stateEl = $("token-state");
  const who = $("who");
  if (!value) { await fetch("/session", {method: "DELETE"}); who.textContent = ""; return; }
  const res = await fetch("/session", {method: "POST", headers: {"Content-Type": "application/json"},
                                        body: JSON.stringify({token: value})});
  if (!res.ok) { token = ""; stateEl.textContent = "wrong token"; return; }
  const me = await res.json();
  stateEl.textContent = "";
  who.textContent = me.user ? `signed in as ${me.user}` : "";
}

async function showSession() {
  const res = await fetch("/session");
  if (res.ok) {
    const who = await res.json();
    if (who.user) $("who").textContent = `signed in as ${who.user}`;
  }
}

// -- files: which uploads and results fit an input ----------------------------------------
// An input's kinds, from the media types its schema names (KIND_MEDIA_TYPES on the server);
// application/octet-stream is every binary format and tells nothing.
function fileMedia(schema) {
  const alts = schema && schema.anyOf ? schema.anyOf : [schema || {}];
  const media = alts.filter((a) => a && a.contentMediaType).map((a) => a.contentMediaType);
  return media.length ? media : null;
}

function kindsOf(media) {
  const kinds = new Set();
  for (const m of media) {
    if (m.startsWith("application/vnd.las")) kinds.add("cloud");
    else if (m.startsWith("model/")) kinds.add("mesh");
    else if (m === "application/zip") kinds.add("plot");
    else if (m === "text/csv") { kinds.add("cylinders"); kinds.add("table"); }
  }
  return kinds;
}

// A job result's kinds as an input, by its suffix (as the service's kind_of_result).
const SUFFIX_KINDS = {
  las: ["cloud"], laz: ["cloud"], e57: ["cloud"], xyz: ["cloud"], txt: ["cloud"], pts: ["cloud"],
  ply: ["cloud", "mesh"], obj: ["mesh"], stl: ["mesh"], off: ["mesh"], glb: ["mesh"],
  zip: ["plot"], csv: ["table"],
};

const KIND_ACCEPT = {
  cloud: ".las,.laz,.ply,.xyz,.txt,.csv,.asc,.pts,.e57",
  mesh: ".ply,.obj,.stl,.off,.glb",
  plot: ".zip",
  cylinders: ".csv,.txt",
  table: ".csv",
};

function resultKinds(name) {
  const dot = name.lastIndexOf(".");
  return dot < 0 ? [] : SUFFIX_KINDS[name.slice(dot + 1).toLowerCase()] || [];
}

function uploadLabel(u) {
  const size = u.n_trees != null ? `${u.n_trees} trees`
    : u.n_triangles != null ? `${u.n_triangles.toLocaleString()} triangles`
    : u.n_points != null ? `${u.n_points.toLocaleString()} points` : bytes(u.size_bytes);
  return `${u.filename} (${u.kind}, ${size})`;
}

// the options of one file input's chooser, keeping its choice where it still exists
function fillFileSelect(select) {
  const kinds = new Set(select.dataset.kinds.split(","));
  const keep = select.options.length ? select.value : null;  // null: a new chooser
  const required = select.required;
  select.replaceChildren(el("option", {value: ""}, required ? "— choose —" : "— none —"));
  const ups = state.uploads.filter((u) => kinds.has(u.kind));
  if (ups.length) {
    const g = el("optgroup", {label: "your uploads"});
    for (const u of ups) g.appendChild(el("option", {value: "upload:" + u.id}, uploadLabel(u)));
    select.appendChild(g);
  }
  const g = el("optgroup", {label: "results of finished jobs"});
  for (const j of state.jobs.filter((x) => x.status === "successful")) {
    for (const r of state.files.get(j.jobID) || []) {
      if (!resultKinds(r.name).some((k) => kinds.has(k))) continue;
      g.appendChild(el("option", {value: `result:${j.jobID}:${r.name}`},
                       `${r.name} of ${j.processID} ${j.jobID.slice(0, 8)}`));
    }
  }
  if (g.children.length) select.appendChild(g);
  select.appendChild(el("option", {value: "new"}, "a new upload…"));
  if (select.dataset.byValue) select.appendChild(el("option", {value: "value"}, "by value (JSON)…"));
  const values = Array.from(select.options, (o) => o.value);
  select.value = values.includes(keep) ? keep : (required ? "new" : "");
  syncNewFile(select);
}

function syncNewFile(select) {
  const picker = select.parentElement.querySelector("input[type=file]");
  if (picker) picker.hidden = select.value !== "new";
  const text = select.parentElement.querySelector("input.json");
  if (text) text.hidden = select.value !== "value";
}

function refillFileSelects() {
  for (const s of document.querySelectorAll("#process-form select[data-file]")) fillFileSelect(s);
}

// -- the process form, built from the process description ---------------------------------
// an input's description as help text, less what the form itself says: how a file is
// referenced in a request, and that a setting may also go in the parameters object
function help(text) {
  return el("small", {className: "help"}, (text || "")
    .replace(/ \(a setting; also accepted in the parameters object\)$/, "")
    .replace(/, by reference: \{"href": URL\}.*?\{"job": JOB_ID, "result": NAME\}/, ""));
}

function changed(control) {
  control.dataset.changed = "1";
  control.closest(".field").classList.add("changed");
}

function fileField(name, spec, media) {
  // the service names the kinds (x-treesim-kinds); the media types are the fallback
  const kinds = spec["x-treesim-kinds"] ? new Set(spec["x-treesim-kinds"]) : kindsOf(media);
  const required = (spec.minOccurs ?? 1) > 0;
  const select = el("select", {id: "in-" + name, required,
                               dataset: {file: name, kinds: Array.from(kinds).join(",")}});
  const accept = Array.from(new Set(Array.from(kinds, (k) => KIND_ACCEPT[k] || "")
                                      .join(",").split(",").filter(Boolean))).join(",");
  const picker = el("input", {type: "file", id: "new-" + name, accept, hidden: true});
  // an input that is a file or a value (plot-scan's stations: a CSV or a list)
  const byValue = (spec.schema.anyOf || []).find((a) => !a.contentMediaType);
  const text = byValue ? el("input", {type: "text", id: "value-" + name, className: "json",
                                      placeholder: "JSON", hidden: true}) : null;
  if (byValue) select.dataset.byValue = "1";
  const field = el("div", {className: "field file", dataset: {path: name}},
                   el("label", {htmlFor: "in-" + name}, name, required ? " *" : ""),
                   select, picker, text, help(spec.description));
  select.addEventListener("change", () => syncNewFile(select));
  fillFileSelect(select);
  return field;
}

// a schema without its null alternative (OpenAPI 3.0's nullable, or JSON Schema's anyOf)
function plain(schema) {
  let s = schema || {};
  let nullable = !!s.nullable;
  if (s.anyOf) {
    const alts = s.anyOf.filter((a) => a.type !== "null");
    if (alts.length < s.anyOf.length) nullable = true;
    if (alts.length === 1) s = Object.assign({}, alts[0], {description: s.description,
                                                           default: s.default});
  }
  return {s, nullable};
}

function numberControl(id, s, nullable) {
  const lo = typeof s.exclusiveMinimum === "number" ? s.exclusiveMinimum : s.minimum;
  const hi = typeof s.exclusiveMaximum === "number" ? s.exclusiveMaximum : s.maximum;
  return el("input", {
    type: "number", id, dataset: {type: s.type, nullable: nullable ? "1" : ""},
    step: s.type === "integer" ? "1" : "any",
    min: lo != null && Math.abs(lo) < 1e15 ? lo : null,
    max: hi != null && Math.abs(hi) < 1e15 ? hi : null,
    value: typeof s.default === "number" ? String(s.default) : "",
    placeholder: nullable ? "empty: null" : "not set",
  });
}

function settingControl(id, s, nullable) {
  if (Array.isArray(s.enum)) {
    const select = el("select", {id, dataset: {type: "enum"}});
    if (s.default === undefined || nullable) select.appendChild(el("option", {value: ""}, "not set"));
    for (const v of s.enum) {
      select.appendChild(el("option", {value: JSON.stringify(v), selected: v === s.default},
                            String(v)));
    }
    return select;
  }
  if (s.type === "boolean" && typeof s.default === "boolean") {
    return el("input", {type: "checkbox", id, checked: s.default, dataset: {type: "boolean"}});
  }
  if (s.type === "boolean") {
    return el("select", {id, dataset: {type: "enum"}}, el("option", {value: ""}, "not set"),
              el("option", {value: "true"}, "true"), el("option", {value: "false"}, "false"));
  }
  if (s.type === "number" || s.type === "integer") return numberControl(id, s, nullable);
  if (s.type === "string") {
    return el("input", {type: "text", id, value: s.default ?? "", dataset: {type: "string"}});
  }
  return el("input", {type: "text", id, className: "json", placeholder: "JSON",
                      value: s.default != null ? JSON.stringify(s.default) : "",
                      dataset: {type: "json", nullable: nullable ? "1" : ""}});
}

function settingField(path, schema, label) {
  const {s, nullable} = plain(schema);
  const id = "set-" + path.replace(/\./g, "-");
  if (s.type === "object" && s.properties) {
    const box = el("details", {className: "group", dataset: {path}},
                   el("summary", {}, label, " ", el("span", {className: "muted"},
                                                     s.description || "")));
    for (const [k, sub] of Object.entries(s.properties)) {
      box.appendChild(settingField(`${path}.${k}`, sub, k));
    }
    return box;
  }
  const control = settingControl(id, s, nullable);
  control.dataset.setting = path;
  control.addEventListener("input", () => changed(control));
  control.addEventListener("change", () => changed(control));
  const lbl = el("label", {htmlFor: id}, label);
  const field = el("div", {className: "field", dataset: {path}});
  if (control.type === "checkbox") field.append(control, lbl);
  else field.append(lbl, control);
  field.append(help(schema.description || s.description));
  return field;
}

function buildForm(desc) {
  const files = $("process-files");
  const settings = $("process-settings");
  files.replaceChildren();
  settings.replaceChildren();
  let nSettings = 0;
  for (const [name, spec] of Object.entries(desc.inputs || {})) {
    const media = fileMedia(spec.schema);
    if (media) files.appendChild(fileField(name, spec, media));
    else { settings.appendChild(settingField(name, spec.schema, name)); nSettings += 1; }
  }
  $("settings-count").textContent = `(${nSettings}; only those you change are sent)`;
  $("process-help").textContent = desc.description || "";
  $("submit").textContent = `Run ${desc.id}`;
}

async function chooseProcess(id) {
  try {
    state.desc = await api(`/v1/processes/${encodeURIComponent(id)}`);
    buildForm(state.desc);
  } catch (e) {
    if (e.status !== 401) showError(e, "could not load the process: ");
  }
}

async function loadProcesses() {
  const sel = $("process");
  try {
    const data = await api("/v1/processes?limit=1000");
    state.processes = data.processes;
    const keep = sel.value || "run";
    sel.replaceChildren(...data.processes.map((p) => el("option", {value: p.id},
                                                         `${p.id}: ${p.title}`)));
    const ids = data.processes.map((p) => p.id);
    sel.value = ids.includes(keep) ? keep : ids[0];
    await chooseProcess(sel.value);
  } catch (e) {
    if (e.status !== 401) showError(e, "could not load the processes: ");
  }
}

// -- reading the form -----------------------------------------------------------------------
function settingValue(c) {
  const t = c.dataset.type;
  if (t === "boolean") return c.checked;
  if (t === "enum") return c.value === "" ? undefined : JSON.parse(c.value);
  if (t === "number" || t === "integer") {
    if (c.value.trim() === "") return c.dataset.nullable ? null : undefined;
    const v = Number(c.value);
    if (!Number.isFinite(v)) throw new Error(`${c.dataset.setting}: ${c.value} is no number`);
    return v;
  }
  if (t === "json") {
    if (c.value.trim() === "") return c.dataset.nullable ? null : undefined;
    try { return JSON.parse(c.value); } catch (_) {
      throw new Error(`${c.dataset.setting}: ${c.value} is not JSON (a list is [0.01, 0.02])`);
    }
  }
  return c.value === "" ? undefined : c.value;
}

// the settings the user changed, nested as the schema nests them
function collectSettings() {
  const out = {};
  for (const c of document.querySelectorAll("#process-form [data-setting]")) {
    if (!c.dataset.changed) continue;
    const v = settingValue(c);
    if (v === undefined) continue;
    const keys = c.dataset.setting.split(".");
    let o = out;
    for (const k of keys.slice(0, -1)) o = o[k] = o[k] || {};
    o[keys[keys.length - 1]] = v;
  }
  return out;
}

function uploadFile(file) {
  return new Promise((resolve, reject) => {
    const bar = $("upload-progress");
    const xhr = new XMLHttpRequest();
    xhr.open("POST", `/v1/uploads?filename=${encodeURIComponent(file.name)}`);
    if (token) xhr.setRequestHeader("Authorization", "Bearer " + token);
    xhr.setRequestHeader("Content-Type", "application/octet-stream");
    xhr.responseType = "json";
    bar.value = 0;
    bar.hidden = false;
    xhr.upload.onprogress = (e) => { if (e.lengthComputable) bar.value = (100 * e.loaded) / e.total; };
    xhr.onload = () => {
      bar.hidden = true;
      if (xhr.status >= 200 && xhr.status < 300) resolve(xhr.response);
      else reject(problemError(xhr.status, xhr.response));
    };
    xhr.onerror = () => { bar.hidden = true; reject(new Error(`${file.name}: the upload failed`)); };
    say(`uploading ${file.name} (${bytes(file.size)})…`);
    xhr.send(file);
  });
}

function uploadHref(u) {
  const self = (u.links || []).find((l) => l.rel === "self");
  return self ? self.href : `${location.origin}/v1/uploads/${encodeURIComponent(u.id)}`;
}

function resultHref(job, name) {
  return `${location.origin}/v1/jobs/${encodeURIComponent(job)}/results/` +
    name.split("/").map(encodeURIComponent).join("/");
}

// each file input as OGC's {"href": URL}: an upload (new ones sent first) or a job's result
async function collectFiles() {
  const inputs = {};
  const sent = [];
  for (const s of document.querySelectorAll("#process-form select[data-file]")) {
    const name = s.dataset.file;
    if (s.value === "") continue;
    if (s.value === "value") {
      const text = s.parentElement.querySelector("input.json").value.trim();
      try { inputs[name] = JSON.parse(text); } catch (_) {
        throw new Error(`${name}: ${text || "nothing"} is not JSON (a list is [[0, 5], [5, 0]])`);
      }
    } else if (s.value === "new") {
      const file = s.parentElement.querySelector("input[type=file]").files[0];
      if (!file) {
        if (s.required) throw new Error(`${name}: choose a file to upload`);
        continue;
      }
      const up = await uploadFile(file);
      sent.push(up);
      inputs[name] = {href: uploadHref(up)};
    } else if (s.value.startsWith("upload:")) {
      const up = state.uploads.find((u) => u.id === s.value.slice(7));
      inputs[name] = {href: up ? uploadHref(up) : `${location.origin}/v1/uploads/${s.value.slice(7)}`};
    } else {
      const [, job, ...rest] = s.value.split(":");
      inputs[name] = {href: resultHref(job, rest.join(":"))};
    }
  }
  return {inputs, sent};
}

async function submitProcess(ev) {
  ev.preventDefault();
  const desc = state.desc;
  if (!desc) return;
  for (const f of document.querySelectorAll("#process-form .invalid")) f.classList.remove("invalid");
  const button = $("submit");
  button.disabled = true;
  try {
    const settings = collectSettings();
    const {inputs, sent} = await collectFiles();
    if (sent.length) await loadUploads();
    const job = await api(`/v1/processes/${encodeURIComponent(desc.id)}/execution`, {
      method: "POST",
      headers: {"Content-Type": "application/json", "Prefer": "respond-async"},
      body: JSON.stringify({inputs: Object.assign(inputs, settings)}),
    });
    const what = sent.map((u) => `${uploadLabel(u)} uploaded; `).join("");
    const names = Object.keys(settings);
    say(`${what}job ${job.jobID.slice(0, 8)} of ${desc.id} accepted` +
        (names.length ? ` with ${names.join(", ")} set` : ""));
    refreshJobs();
  } catch (e) {
    showError(e);
  } finally {
    button.disabled = false;
  }
}

// -- uploads ------------------------------------------------------------------------------
async function loadUploads() {
  try {
    const data = await api("/v1/uploads?limit=200");
    state.uploads = data.uploads;
    renderUploads();
    refillFileSelects();
  } catch (e) {
    if (e.status !== 401) showError(e, "could not list the uploads: ");
  }
}

function renderUploads() {
  const body = document.querySelector("#uploads tbody");
  body.replaceChildren();
  for (const u of state.uploads) {
    const del = el("button", {type: "button", className: "small"}, "delete");
    del.addEventListener("click", async () => {
      try {
        await api(`/v1/uploads/${encodeURIComponent(u.id)}`, {method: "DELETE"});
        say(`${u.filename} deleted`);
        loadUploads();
      } catch (e) { showError(e, `${u.filename}: `); }
    });
    const size = u.n_trees != null ? `${u.n_trees} trees`
      : u.n_triangles != null ? `${u.n_triangles.toLocaleString()} triangles`
      : u.n_points != null ? `${u.n_points.toLocaleString()} points` : "";
    body.appendChild(el("tr", {dataset: {upload: u.id}},
      el("td", {}, u.filename), el("td", {}, u.kind), el("td", {}, u.format),
      el("td", {}, size), el("td", {}, bytes(u.size_bytes)),
      el("td", {}, el("code", {title: u.sha256}, u.sha256.slice(0, 12))),
      el("td", {}, when(u.created)), el("td", {}, del)));
  }
  $("upload-count").textContent = `(${state.uploads.length})`;
}

// -- jobs ---------------------------------------------------------------------------------
function jobInputs(j) {
  return Object.entries(j.inputs || {})
    .map(([k, i]) => `${k}: ${i.filename || (i.result ? `${i.result} of ${String(i.job).slice(0, 8)}` : "")}`)
    .join(", ");
}

function showView(href, title) {
  const frame = $("view-frame");
  frame.src = href + "#viewer";
  $("view-title").textContent = title;
  $("view-open").href = href;
  $("view").hidden = false;
  $("view").scrollIntoView({block: "start"});
}

function resultsRow(j, span) {
  const files = state.files.get(j.jobID);
  const cellEl = el("td", {colSpan: span});
  if (!files) { cellEl.textContent = "loading the results…"; return el("tr", {className: "results"}, cellEl); }
  const list = el("ul", {className: "files"});
  for (const r of files) {
    const item = el("li", {}, el("a", {href: r.href, download: r.name.split("/").pop()}, r.name),
                    " ", el("span", {className: "muted"}, `${bytes(r.size_bytes)}, ${r.media_type}`));
    if (r.media_type === "text/html") {
      item.append(" ", el("a", {href: r.href, className: "open"}, "open"), " ");
      const view = el("button", {type: "button", className: "small view3d"}, "3D view");
      view.addEventListener("click", () => showView(r.href, `${r.name} of job ${j.jobID.slice(0, 8)}`));
      item.appendChild(view);
    }
    list.appendChild(item);
  }
  cellEl.appendChild(list);
  return el("tr", {className: "results", dataset: {resultsOf: j.jobID}}, cellEl);
}

async function loadFiles(jobID) {
  if (state.files.has(jobID)) return false;
  try {
    const data = await api(`/v1/jobs/${encodeURIComponent(jobID)}/files`);
    state.files.set(jobID, data.results);
    return true;
  } catch (e) {
    return false;
  }
}

async function dismiss(j) {
  const what = j.status === "successful" ? "its results are deleted"
    : j.status === "failed" ? "its record is kept as dismissed" : "it is stopped";
  if (!confirm(`Dismiss job ${j.jobID.slice(0, 8)} (${j.processID})? ${what}.`)) return;
  try {
    await api(`/v1/jobs/${encodeURIComponent(j.jobID)}`, {method: "DELETE"});
    state.files.delete(j.jobID);
    state.open.delete(j.jobID);
    say(`job ${j.jobID.slice(0, 8)} dismissed`);
    refreshJobs();
  } catch (e) { showError(e, `job ${j.jobID.slice(0, 8)}: `); }
}

function actions(j) {
  const td = el("td", {className: "actions"});
  if (j.status === "successful") {
    const report = (j.links || []).find((l) => l.title === "report");
    if (report) td.append(el("a", {href: report.href}, "report"), " ");
    const open = state.open.has(j.jobID);
    const b = el("button", {type: "button", className: "small results-toggle"},
                 open ? "hide results" : "results");
    b.addEventListener("click", async () => {
      if (state.open.has(j.jobID)) state.open.delete(j.jobID);
      else { state.open.add(j.jobID); await loadFiles(j.jobID); }
      renderJobs(state.jobs);
    });
    td.append(b, " ");
  }
  if (j.status !== "dismissed") {
    const b = el("button", {type: "button", className: "small dismiss"}, "dismiss");
    b.addEventListener("click", () => dismiss(j));
    td.appendChild(b);
  }
  return td;
}

function renderJobs(jobs) {
  const body = document.querySelector("#jobs tbody");
  const span = document.querySelectorAll("#jobs thead th").length;
  body.replaceChildren();
  for (const j of jobs) {
    const bar = el("progress", {max: 100, value: j.progress, title: j.progress + " %"});
    const params = JSON.stringify(j.parameters || {});
    const msg = j.error ? `${j.error.title || ""}: ${j.error.detail || ""}`
      : [j.stage, j.message].filter(Boolean).join(": ");
    body.appendChild(el("tr", {dataset: {job: j.jobID, status: j.status}},
      el("td", {}, el("a", {href: `/v1/jobs/${encodeURIComponent(j.jobID)}`}, j.jobID.slice(0, 8))),
      el("td", {}, j.processID),
      el("td", {}, jobInputs(j)),
      el("td", {className: "params", title: params}, params === "{}" ? "" : params),
      el("td", {className: "status-" + j.status},
         j.status + (j.attempt > 1 ? ` (attempt ${j.attempt})` : "")),
      el("td", {}, bar),
      el("td", {}, msg),
      el("td", {}, when(j.created)),
      actions(j)));
    if (state.open.has(j.jobID)) body.appendChild(resultsRow(j, span));
  }
  $("count").textContent = `(${jobs.length} newest)`;
}

let timer = null;
async function refreshJobs() {
  clearTimeout(timer);
  try {
    const statuses = $("show-dismissed").checked ? "" : "&status=accepted,running,successful,failed";
    const data = await api(`/v1/jobs?limit=50${statuses}`);
    $("token-state").textContent = "";
    const got = await Promise.all(data.jobs.filter((j) => j.status === "successful")
                                          .map((j) => loadFiles(j.jobID)));
    const more = got.some(Boolean);
    const key = JSON.stringify(data.jobs);
    state.jobs = data.jobs;
    if (key !== state.jobsKey) { state.jobsKey = key; renderJobs(data.jobs); }
    if (more) refillFileSelects();
  } catch (e) {
    $("token-state").textContent = e.status === 401 ? "this service needs a token" : e.message;
  }
  clearTimeout(timer);  // one poll pending, however many refreshes overlapped
  timer = setTimeout(refreshJobs, 2000);
}

async function loadAll() {
  await Promise.all([loadUploads(), loadProcesses()]);
  await refreshJobs();
}

// -- wiring ---------------------------------------------------------------------------------
$("token-save").addEventListener("click", async () => {
  await setToken($("token").value.trim());
  $("token").value = "";
  loadAll();
});
$("process").addEventListener("change", (ev) => chooseProcess(ev.target.value));
$("process-form").addEventListener("submit", submitProcess);
$("show-dismissed").addEventListener("change", () => { state.jobsKey = ""; refreshJobs(); });
$("view-close").addEventListener("click", () => {
  $("view").hidden = true;
  $("view-frame").src = "about:blank";
});

showSession();
loadAll();
