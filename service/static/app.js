// Eigenscope web page: upload a clip, queue an analysis, follow the jobs, show a result.
// Plain JavaScript, no framework, no build step; every request goes to this origin with relative URLs.
"use strict";

(() => {
  const KEY_STORAGE = "eigenscope.apiKey";
  const POLL_ACTIVE_MS = 800;
  const POLL_IDLE_MS = 5000;
  const TERMINAL = new Set(["succeeded", "failed", "cancelled"]);
  const IMAGE_EXT = /\.(png|jpe?g|gif|webp|svg)$/i;

  // Known result images: display order and alt text (what each figure shows, as the API's Artifacts
  // schema describes it). Unknown names are shown too, after these.
  const IMAGE_INFO = {
    "overlay.png": "Overlay: a frame of the clip with each object outlined in its colour and labelled with its id, frequency, stiffness and mass",
    "frequency_map.png": "Frequency map: the dominant frequency of each pixel, with a colour bar in hertz; pixels below the noise floor are muted",
    "spectrum.png": "Spectrum: summed motion power against frequency on a log scale, with the eigenfrequencies, harmonics, noise floor and rejected peaks marked",
    "displacement.png": "Displacement: each object's motion against time, with the fitted damped oscillation and the release instant",
    "ringdown.png": "Ring-down spectrogram: each object's motion power by frequency over time as its oscillation decays",
    "modes.png": "Mode shapes: for each object, one panel per mode showing its part of the frame dimmed, with the mode's shape drawn as arrows and a deformed outline in the object's colour, magnified, and labelled with the mode's frequency and damping ratio",
    "modes.gif": "Mode animation: the mode shapes' panels, each object's pixels moving back and forth in the mode's magnified shape",
    "mask.png": "Segmentation mask: each object's pixels in its own colour (the file stores object ids)",
  };

  // Form fields sent as analysis parameters, with their checks.
  const PARAMS = {
    fps: { kind: "positive", max: 100000 },
    method: { kind: "choice" },
    flow: { kind: "choice" },
    frames: { kind: "int", min: 8, max: 100000 },
    start_frame: { kind: "int", min: 0 },
    min_frequency_hz: { kind: "nonneg" },
    max_frequency_hz: { kind: "positive" },
    depth_m: { kind: "positive" },
    depth_scale: { kind: "positive" },
    fx: { kind: "positive" },
    fy: { kind: "positive" },
    cx: { kind: "number" },
    cy: { kind: "number" },
    color_topic: { kind: "text" },
    depth_topic: { kind: "text" },
  };
  const EXCITATION_FIELDS = {
    step_release: { value: "force_n", uncertainty: "force_uncertainty_n" },
    impulse: { value: "impulse_ns", uncertainty: "impulse_uncertainty_ns" },
  };

  const $ = (id) => document.getElementById(id);

  const state = {
    jobs: [],
    selectedId: null,
    shownKey: null, // "<job id>:<status>" of what the result view shows
    objectUrls: [],
    pollTimer: null,
    polling: false,
    pollAgain: false,
    statuses: new Map(), // job id -> last status seen (for announcements)
    clipNames: new Map(), // clip id -> file name (null when unknown)
    lastUpload: null, // { file, clipId } so a re-run with other options does not upload again
    deepLink: false, // the page was opened at a job's URL: keep its headline in view until the lists fill
    shownJob: null, // the job the result view shows
    xhr: null,
    busy: false,
  };

  // ---------------------------------------------------------------- helpers

  function el(tag, attrs, ...children) {
    const node = document.createElement(tag);
    for (const [name, value] of Object.entries(attrs || {})) {
      if (value === null || value === undefined || value === false) continue;
      if (name === "class") node.className = value;
      else if (name === "text") node.textContent = value;
      else if (name.startsWith("on")) node.addEventListener(name.slice(2), value);
      else node.setAttribute(name, value === true ? "" : String(value));
    }
    for (const child of children.flat()) {
      if (child === null || child === undefined || child === false) continue;
      node.append(child instanceof Node ? child : document.createTextNode(String(child)));
    }
    return node;
  }

  function announce(message) {
    const live = $("live");
    live.textContent = "";
    // A fresh text node after a tick makes screen readers announce repeated messages too.
    window.setTimeout(() => { live.textContent = message; }, 50);
  }

  function shortId(id) { return id ? id.slice(0, 8) : ""; }

  function isFiniteNumber(x) { return typeof x === "number" && Number.isFinite(x); }

  // Round `value` to the precision its uncertainty supports (two significant digits of the uncertainty).
  function formatMeasured(value, uncertainty, scale = 1) {
    if (!isFiniteNumber(value)) return { value: "—", unc: "" };
    const v = value * scale;
    if (isFiniteNumber(uncertainty) && uncertainty > 0) {
      const u = uncertainty * scale;
      const decimals = Math.max(0, Math.min(10, 1 - Math.floor(Math.log10(u))));
      return { value: v.toFixed(decimals), unc: u.toFixed(decimals) };
    }
    return { value: formatNumber(v), unc: "" };
  }

  function formatNumber(v, digits = 4) {
    if (!isFiniteNumber(v)) return "—";
    if (v === 0) return "0";
    const abs = Math.abs(v);
    if (abs >= 1e6 || abs < 1e-4) return v.toExponential(digits - 1);
    const decimals = Math.max(0, digits - 1 - Math.floor(Math.log10(abs)));
    return v.toFixed(Math.min(decimals, 10));
  }

  function formatTime(iso) {
    if (!iso) return "";
    const d = new Date(iso);
    if (Number.isNaN(d.getTime())) return iso;
    const sameDay = d.toDateString() === new Date().toDateString();
    return sameDay ? d.toLocaleTimeString() : d.toLocaleString();
  }

  function statusLabel(status) {
    return { queued: "Queued", running: "Running", succeeded: "Succeeded", failed: "Failed", cancelled: "Cancelled" }[status] || status;
  }

  // ---------------------------------------------------------------- HTTP

  class ApiError extends Error {
    constructor(status, problem, retryAfterS = null) {
      super((problem && (problem.detail || problem.title)) || `HTTP ${status}`);
      this.status = status;
      this.problem = problem || {};
      this.retryAfterS = retryAfterS;
    }
  }

  function retryAfter(value) {
    const seconds = Number(value);
    return Number.isFinite(seconds) && seconds > 0 ? Math.min(seconds, 300) : null;
  }

  function apiKey() {
    try { return window.sessionStorage.getItem(KEY_STORAGE) || ""; } catch { return ""; }
  }

  function withAuth(headers) {
    const key = apiKey();
    if (key) headers.Authorization = `Bearer ${key}`;
    return headers;
  }

  function problemFromText(status, statusText, text, contentType) {
    if (text && /json/i.test(contentType || "")) {
      try {
        const doc = JSON.parse(text);
        if (doc && typeof doc === "object") return doc;
      } catch { /* fall through */ }
    }
    return {
      title: statusText || `HTTP ${status}`,
      status,
      detail: text ? text.slice(0, 300) : null,
    };
  }

  async function api(path, { method = "GET", body } = {}) {
    const init = { method, cache: "no-store", headers: withAuth({ Accept: "application/json, application/problem+json" }) };
    if (body !== undefined) {
      init.body = JSON.stringify(body);
      init.headers["Content-Type"] = "application/json";
    }
    let response;
    try {
      response = await fetch(path, init);
    } catch {
      throw new ApiError(0, { title: "Network error", detail: "The server could not be reached. Is it still running?" });
    }
    if (!response.ok) {
      const text = await response.text().catch(() => "");
      throw new ApiError(response.status, problemFromText(response.status, response.statusText, text, response.headers.get("Content-Type")),
        retryAfter(response.headers.get("Retry-After")));
    }
    if (response.status === 204) return null;
    return response.json();
  }

  // Fetch a file with the API key and hand back an object URL (img tags cannot send headers).
  async function fetchBlobUrl(url) {
    let response;
    try {
      response = await fetch(url, { headers: withAuth({}), cache: "no-store" });
    } catch {
      throw new ApiError(0, { title: "Network error", detail: `could not load ${url}` });
    }
    if (!response.ok) {
      const text = await response.text().catch(() => "");
      throw new ApiError(response.status, problemFromText(response.status, response.statusText, text, response.headers.get("Content-Type")));
    }
    const objectUrl = URL.createObjectURL(await response.blob());
    state.objectUrls.push(objectUrl);
    return objectUrl;
  }

  function uploadClip(file, onProgress) {
    return new Promise((resolve, reject) => {
      const xhr = new XMLHttpRequest();
      state.xhr = xhr;
      xhr.open("POST", "v1/clips");
      xhr.setRequestHeader("Accept", "application/json, application/problem+json");
      const key = apiKey();
      if (key) xhr.setRequestHeader("Authorization", `Bearer ${key}`);
      xhr.upload.addEventListener("progress", (event) => {
        onProgress(event.lengthComputable ? event.loaded / event.total : null, false);
      });
      xhr.upload.addEventListener("load", () => onProgress(1, true));
      xhr.addEventListener("load", () => {
        state.xhr = null;
        const problem = problemFromText(xhr.status, xhr.statusText, xhr.responseText, xhr.getResponseHeader("Content-Type"));
        if (xhr.status === 201) resolve(problem);
        else reject(new ApiError(xhr.status, problem));
      });
      xhr.addEventListener("error", () => {
        state.xhr = null;
        reject(new ApiError(0, {
          title: "Upload failed",
          detail: "The connection was closed during the upload. The server may be down, or the file larger than it accepts.",
        }));
      });
      xhr.addEventListener("abort", () => {
        state.xhr = null;
        reject(new ApiError(-1, { title: "Upload cancelled", detail: "The upload was cancelled." }));
      });
      const form = new FormData();
      form.append("file", file, file.name);
      xhr.send(form);
    });
  }

  // ---------------------------------------------------------------- problems

  function problemNode(target, err, { fieldErrors = true } = {}) {
    const problem = err instanceof ApiError ? err.problem : { title: "Error", detail: String(err && err.message ? err.message : err) };
    const status = err instanceof ApiError ? err.status : null;
    target.replaceChildren();
    const title = problem.title || "Request refused";
    target.append(el("strong", {}, status > 0 ? `${title} (HTTP ${status})` : title));
    if (problem.detail) target.append(el("p", { class: "problem-detail" }, problem.detail));
    if (status === 401) {
      target.append(el("p", {}, "This server needs an API key: enter it in the API key field at the top of the page."));
    } else if (status === 403) {
      target.append(el("p", {}, "The API key was refused. Check the key in the field at the top of the page."));
    }
    const errors = Array.isArray(problem.errors) ? problem.errors : [];
    if (fieldErrors && errors.length) {
      target.append(el("ul", { class: "problem-errors" },
        errors.map((e) => el("li", {},
          el("code", {}, Array.isArray(e.loc) ? e.loc.filter((x) => x !== "body").join(".") : String(e.loc || "")),
          ": ", String(e.msg || e.message || JSON.stringify(e))))));
    }
    target.hidden = false;
    return problem;
  }

  // ---------------------------------------------------------------- API key

  function initKey() {
    const input = $("api-key");
    input.value = apiKey();
    $("key-form").addEventListener("submit", (event) => {
      event.preventDefault();
      const value = input.value.trim();
      try {
        if (value) window.sessionStorage.setItem(KEY_STORAGE, value);
        else window.sessionStorage.removeItem(KEY_STORAGE);
      } catch { /* storage disabled: the key lasts until reload */ }
      announce(value ? "API key set for this tab." : "API key cleared.");
      state.shownKey = null;
      refreshJobs();
    });
    $("key-clear").addEventListener("click", () => {
      input.value = "";
      try { window.sessionStorage.removeItem(KEY_STORAGE); } catch { /* ignore */ }
      announce("API key forgotten.");
    });
  }

  // ---------------------------------------------------------------- form

  function fieldInput(name) { return document.getElementById(name); }

  function setFieldError(name, message) {
    const errorNode = $(`${name}-error`);
    if (name === "clip-file") $("dropzone").classList.toggle("invalid", Boolean(message));
    const input = fieldInput(name);
    if (input && name !== "clip-file") {
      if (message) input.setAttribute("aria-invalid", "true");
      else input.removeAttribute("aria-invalid");
    }
    if (errorNode) {
      errorNode.textContent = message || "";
      errorNode.hidden = !message;
    }
  }

  function clearErrors() {
    for (const node of document.querySelectorAll("#upload-form .error-text")) {
      node.textContent = "";
      node.hidden = true;
    }
    for (const node of document.querySelectorAll("#upload-form [aria-invalid]")) node.removeAttribute("aria-invalid");
    $("dropzone").classList.remove("invalid");
    $("form-problem").hidden = true;
  }

  function excitationType() {
    const checked = document.querySelector('input[name="excitation"]:checked');
    return checked ? checked.value : "none";
  }

  function syncExcitationFields() {
    const type = excitationType();
    for (const node of document.querySelectorAll("[data-excitation]")) {
      node.hidden = node.dataset.excitation !== type;
    }
  }

  // Read one numeric input: { value } or { error } ("" means empty).
  function readNumber(name, { kind, min, max }) {
    const input = fieldInput(name);
    if (input.validity && input.validity.badInput) return { error: "Enter a number." };
    const raw = input.value.trim();
    if (raw === "") return { value: null };
    const value = Number(raw);
    if (!Number.isFinite(value)) return { error: "Enter a number." };
    if (kind === "positive" && !(value > 0)) return { error: "Must be greater than 0." };
    if (kind === "nonneg" && value < 0) return { error: "Must not be negative." };
    if (kind === "int" && !Number.isInteger(value)) return { error: "Enter a whole number." };
    if (min !== undefined && value < min) return { error: `Must be at least ${min}.` };
    if (max !== undefined && value > max) return { error: `Must be at most ${max}.` };
    return { value };
  }

  // Check the form; returns { ok, body, file } with the job request body (without clip_id).
  function validate() {
    const errors = [];
    const file = $("clip-file").files[0] || null;
    if (!file) errors.push(["clip-file", "Choose a clip file to analyse."]);
    else if (file.size === 0) errors.push(["clip-file", "This file is empty."]);

    let excitation = null;
    const type = excitationType();
    if (type in EXCITATION_FIELDS) {
      const names = EXCITATION_FIELDS[type];
      const value = readNumber(names.value, { kind: "positive" });
      const unc = readNumber(names.uncertainty, { kind: "nonneg" });
      if (value.error) errors.push([names.value, value.error]);
      else if (value.value === null) {
        errors.push([names.value, type === "impulse"
          ? "Enter the impulse, or choose “Unknown” as the excitation."
          : "Enter the holding force, or choose “Unknown” as the excitation."]);
      }
      if (unc.error) errors.push([names.uncertainty, unc.error]);
      if (!value.error && value.value !== null) {
        excitation = { type, [names.value]: value.value };
        if (!unc.error && unc.value !== null) excitation[names.uncertainty] = unc.value;
      }
    }

    const parameters = {};
    for (const [name, rule] of Object.entries(PARAMS)) {
      const input = fieldInput(name);
      if (rule.kind === "choice" || rule.kind === "text") {
        const value = input.value.trim();
        if (value !== "" && !(name === "method" && value === "default")) parameters[name] = value;
        continue;
      }
      const result = readNumber(name, rule);
      if (result.error) errors.push([name, result.error]);
      else if (result.value !== null) parameters[name] = result.value;
    }
    if (isFiniteNumber(parameters.min_frequency_hz) && isFiniteNumber(parameters.max_frequency_hz)
        && parameters.min_frequency_hz >= parameters.max_frequency_hz) {
      errors.push(["max_frequency_hz", "Must be above the lowest frequency."]);
    }
    return { ok: errors.length === 0, errors, file, body: { excitation, parameters } };
  }

  // Map the API's field errors (loc like ["body", "parameters", "fps"]) onto the form's inputs.
  function showApiFieldErrors(problem) {
    const errors = Array.isArray(problem.errors) ? problem.errors : [];
    let first = null;
    for (const error of errors) {
      const loc = Array.isArray(error.loc) ? error.loc.map(String) : [];
      const name = [...loc].reverse().find((part) => fieldInput(part) && part !== "file");
      const target = name || (loc.includes("file") ? "clip-file" : null);
      if (!target) continue;
      setFieldError(target, String(error.msg || "Not accepted by the server."));
      first = first || target;
    }
    return first;
  }

  function focusField(name) {
    if (name === "clip-file") { $("dropzone").focus(); return; }
    const input = fieldInput(name);
    if (!input) return;
    const details = input.closest("details");
    if (details) details.open = true;
    input.focus();
  }

  function showChosenFile(file) {
    const chosen = $("file-chosen");
    if (file) {
      const mb = file.size / (1024 * 1024);
      chosen.textContent = `${file.name} · ${mb >= 1 ? mb.toFixed(1) + " MB" : Math.max(1, Math.round(file.size / 1024)) + " kB"}`;
      chosen.hidden = false;
      $("dropzone").classList.add("has-file");
      setFieldError("clip-file", null);
    } else {
      chosen.textContent = "";
      chosen.hidden = true;
      $("dropzone").classList.remove("has-file");
    }
  }

  function initDropzone() {
    const zone = $("dropzone");
    const input = $("clip-file");
    const open = () => { if (!state.busy) input.click(); };
    zone.addEventListener("click", open);
    zone.addEventListener("keydown", (event) => {
      if (event.key === "Enter" || event.key === " ") {
        event.preventDefault();
        open();
      }
    });
    input.addEventListener("change", () => showChosenFile(input.files[0] || null));
    for (const type of ["dragenter", "dragover"]) {
      zone.addEventListener(type, (event) => {
        event.preventDefault();
        if (event.dataTransfer) event.dataTransfer.dropEffect = "copy";
        zone.classList.add("dragover");
      });
    }
    for (const type of ["dragleave", "dragend"]) {
      zone.addEventListener(type, (event) => {
        if (event.type === "dragleave" && zone.contains(event.relatedTarget)) return;
        zone.classList.remove("dragover");
      });
    }
    zone.addEventListener("drop", (event) => {
      event.preventDefault();
      zone.classList.remove("dragover");
      const files = event.dataTransfer ? event.dataTransfer.files : null;
      if (!files || files.length === 0) return;
      if (files.length > 1) {
        setFieldError("clip-file", "Drop one clip at a time.");
        return;
      }
      const transfer = new DataTransfer();
      transfer.items.add(files[0]);
      input.files = transfer.files;
      showChosenFile(files[0]);
      announce(`Chosen ${files[0].name}.`);
    });
    // A file dropped next to the zone should not navigate away from the page.
    window.addEventListener("dragover", (event) => event.preventDefault());
    window.addEventListener("drop", (event) => event.preventDefault());
  }

  function setBusy(busy) {
    state.busy = busy;
    const submit = $("submit");
    submit.disabled = busy;
    submit.textContent = busy ? "Working…" : "Upload and analyse";
    $("reset").textContent = busy ? "Cancel upload" : "Clear";
    $("dropzone").setAttribute("aria-disabled", busy ? "true" : "false");
  }

  function showUploadProgress(fraction, label) {
    const box = $("upload-progress");
    const bar = $("upload-bar");
    box.hidden = false;
    box.classList.remove("done");
    if (fraction === null) bar.removeAttribute("value");
    else bar.value = Math.round(fraction * 100);
    $("upload-label").textContent = label;
  }

  async function onSubmit(event) {
    event.preventDefault();
    if (state.busy) return;
    clearErrors();
    const check = validate();
    if (!check.ok) {
      for (const [name, message] of check.errors) setFieldError(name, message);
      focusField(check.errors[0][0]);
      announce(`Please fix ${check.errors.length === 1 ? "1 field" : `${check.errors.length} fields`} before uploading.`);
      return;
    }
    setBusy(true);
    const file = check.file;
    try {
      let clipId;
      if (state.lastUpload && state.lastUpload.file === file) {
        clipId = state.lastUpload.clipId;
        showUploadProgress(1, `Already uploaded ${file.name}; queuing the analysis…`);
      } else {
        showUploadProgress(0, `Uploading ${file.name}…`);
        let lastAnnounced = -1;
        const clip = await uploadClip(file, (fraction, done) => {
          if (done) {
            showUploadProgress(1, "Upload complete; the server is checking the clip…");
            return;
          }
          const pct = fraction === null ? null : Math.round(fraction * 100);
          showUploadProgress(fraction, pct === null ? `Uploading ${file.name}…` : `Uploading ${file.name}: ${pct}%`);
          if (pct !== null && pct >= lastAnnounced + 25) {
            lastAnnounced = pct - (pct % 25);
            announce(`Upload ${lastAnnounced}%`);
          }
        });
        clipId = clip.id;
        state.lastUpload = { file, clipId };
        state.clipNames.set(clipId, clip.filename || file.name);
        showUploadProgress(1, `Uploaded ${file.name}: ${clip.frames} frames, ${clip.width}×${clip.height}` +
          `${isFiniteNumber(clip.fps) ? ` at ${formatNumber(clip.fps, 4)} fps` : ""}. Queuing the analysis…`);
      }
      const job = await api("v1/jobs", { method: "POST", body: { clip_id: clipId, ...check.body } });
      $("upload-label").textContent = `Job ${shortId(job.id)} queued for ${file.name}.`;
      $("upload-progress").classList.add("done");
      announce(`Analysis queued as job ${shortId(job.id)}.`);
      upsertJob(job);
      selectJob(job.id, { focus: false });
      schedulePoll(POLL_ACTIVE_MS);
    } catch (err) {
      $("upload-progress").hidden = true;
      if (err instanceof ApiError && err.status === -1) {
        announce("Upload cancelled.");
        return;
      }
      if (err instanceof ApiError && [404, 410].includes(err.status) && state.lastUpload && state.lastUpload.file === file) {
        state.lastUpload = null; // the clip is gone; the next attempt uploads it again
      }
      const problem = problemNode($("form-problem"), err);
      $("form-problem").scrollIntoView({ block: "nearest" });
      const first = err instanceof ApiError ? showApiFieldErrors(problem) : null;
      if (err instanceof ApiError && [413, 415, 422].includes(err.status) && !first && !state.lastUpload) {
        setFieldError("clip-file", problem.detail || problem.title);
      }
      if (err instanceof ApiError && err.status === 401) $("api-key").focus();
      announce(`Refused: ${problem.title || "error"}. ${problem.detail || ""}`);
    } finally {
      setBusy(false);
    }
  }

  function initForm() {
    const form = $("upload-form");
    form.addEventListener("submit", onSubmit);
    form.addEventListener("reset", (event) => {
      if (state.busy) {
        event.preventDefault();
        if (state.xhr) state.xhr.abort();
        return;
      }
      window.setTimeout(() => {
        clearErrors();
        showChosenFile(null);
        syncExcitationFields();
        $("upload-progress").hidden = true;
      }, 0);
    });
    for (const radio of document.querySelectorAll('input[name="excitation"]')) {
      radio.addEventListener("change", syncExcitationFields);
    }
    // Clear a field's error as soon as it is edited.
    form.addEventListener("input", (event) => {
      const target = event.target;
      if (target && target.id && $(`${target.id}-error`)) setFieldError(target.id, null);
    });
    syncExcitationFields();
  }

  // ---------------------------------------------------------------- jobs list

  function upsertJob(job) {
    const index = state.jobs.findIndex((j) => j.id === job.id);
    if (index >= 0) state.jobs[index] = job;
    else state.jobs.unshift(job);
    renderJobs();
  }

  function clipName(clipId) {
    if (state.clipNames.has(clipId)) return state.clipNames.get(clipId);
    state.clipNames.set(clipId, null);
    api(`v1/clips/${encodeURIComponent(clipId)}`)
      .then((clip) => {
        state.clipNames.set(clipId, clip.filename || null);
        renderJobs();
        showClipName(clipId);
      })
      .catch(() => { /* deleted clip or no access: keep the id */ });
    return null;
  }

  // The result view names the clip as soon as its name is known.
  function showClipName(clipId) {
    const job = state.shownJob;
    if (!job || job.id !== state.selectedId || job.clip_id !== clipId) return;
    setText($("result-title"), `Job ${shortId(job.id)} · ${jobTitle(job)}`);
    const dd = document.querySelector("#result-body [data-clip-name]");
    if (dd) setText(dd, jobTitle(job));
  }

  function jobTitle(job) {
    return clipName(job.clip_id) || `Clip ${shortId(job.clip_id)}`;
  }

  // The main frequency of a job: lists carry a summary of each result, a job of its own the whole result.
  function jobFrequency(job) {
    const f = job.summary ? job.summary.eigenfrequency_hz : job.result ? job.result.eigenfrequency_hz : null;
    return isFiniteNumber(f) ? f : null;
  }

  function progressPercent(job) {
    return Math.round(Math.max(0, Math.min(1, Number(job.progress) || 0)) * 100);
  }

  function jobNode(job) {
    const button = el("button", { type: "button", class: "job", "data-job-id": job.id },
      el("span", { class: "job-top" },
        el("span", { class: "job-name" }),
        el("span", { class: "badge" })),
      el("progress", { max: "100" }),
      el("span", { class: "job-meta" },
        el("span", { class: "stage" }),
        el("span", { class: "freq" }),
        el("span", { class: "mono id" }),
        el("span", { class: "time" })));
    button.addEventListener("click", () => selectJob(job.id, { focus: true }));
    return el("li", { "data-job-id": job.id }, button);
  }

  function setText(node, text) { if (node.textContent !== text) node.textContent = text; }

  function updateJobNode(li, job) {
    const button = li.firstElementChild;
    const pct = progressPercent(job);
    // A long name is elided; the whole of it shows on hover (title) and, wrapped, on hover or focus (CSS).
    setText(button.querySelector(".job-name"), jobTitle(job));
    button.querySelector(".job-name").title = jobTitle(job);
    const badge = button.querySelector(".badge");
    setText(badge, statusLabel(job.status));
    badge.className = `badge badge-${job.status}`;
    const bar = button.querySelector("progress");
    bar.value = job.status === "succeeded" ? 100 : pct;
    bar.className = job.status;
    bar.setAttribute("aria-label", `Progress ${pct}%`);
    const stage = job.status === "running" ? `${job.stage || "running"} · ${pct}%`
      : job.status === "queued" ? "waiting for a worker" : (job.status === "failed" && job.error ? job.error.title : "");
    setText(button.querySelector(".stage"), stage);
    const f = jobFrequency(job) !== null ? `f = ${formatNumber(jobFrequency(job), 4)} Hz` : "";
    setText(button.querySelector(".freq"), f);
    setText(button.querySelector(".id"), `job ${shortId(job.id)}`);
    setText(button.querySelector(".time"), formatTime(job.created_at));
    if (job.id === state.selectedId) button.setAttribute("aria-current", "true");
    else button.removeAttribute("aria-current");
  }

  function renderJobs() {
    const list = $("jobs");
    const existing = new Map([...list.children].map((li) => [li.dataset.jobId, li]));
    const wanted = new Set(state.jobs.map((j) => j.id));
    for (const [id, li] of existing) if (!wanted.has(id)) li.remove();
    state.jobs.forEach((job, index) => {
      let li = existing.get(job.id);
      if (!li) li = jobNode(job);
      updateJobNode(li, job);
      // Only move nodes that are out of place, so a focused job keeps its focus.
      const current = list.children[index];
      if (current !== li) list.insertBefore(li, current || null);
    });
    $("jobs-empty").hidden = state.jobs.length > 0;
  }

  function noteStatusChanges() {
    for (const job of state.jobs) {
      const before = state.statuses.get(job.id);
      if (before && before !== job.status) {
        const f = jobFrequency(job) !== null ? `, ${formatNumber(jobFrequency(job), 4)} Hz` : "";
        announce(`Job ${shortId(job.id)} (${jobTitle(job)}): ${statusLabel(job.status).toLowerCase()}${f}.`);
      }
      state.statuses.set(job.id, job.status);
    }
  }

  function streamLine(stream) {
    const e = stream.last_estimate;
    const head = `Stream ${shortId(stream.id)}: ${stream.frames_received} frames`;
    if (!e) return `${head}, waiting for motion`;
    let text = `${head}, f = ${formatNumber(e.eigenfrequency_hz, 5)} ± ${formatNumber(e.eigenfrequency_uncertainty_hz, 2)} Hz ` +
      `(${formatNumber(e.relative_uncertainty * 100, 2)} %)`;
    if (isFiniteNumber(e.damping_ratio)) text += `, ζ = ${formatNumber(e.damping_ratio, 3)}`;
    if (isFiniteNumber(e.stiffness_n_per_m)) text += `, k = ${formatNumber(e.stiffness_n_per_m, 4)} N/m`;
    if (isFiniteNumber(e.mass_kg)) text += `, m = ${formatNumber(e.mass_kg, 4)} kg`;
    return text + (stream.converged ? " — converged" : "");
  }

  async function refreshStreams() {
    const page = await api("v1/streams?active=true&limit=10");
    const list = $("streams");
    list.replaceChildren(...page.items.map((stream) => {
      const li = document.createElement("li");
      li.className = "job stream";
      li.dataset.streamId = stream.id;
      li.textContent = streamLine(stream);
      return li;
    }));
    $("streams-empty").hidden = page.items.length > 0;
    return page.items.length > 0;
  }

  async function refreshJobs() {
    window.clearTimeout(state.pollTimer);
    if (state.polling) {
      // A poll is in flight (perhaps with a key that was just replaced): poll again as soon as it ends.
      state.pollAgain = true;
      return;
    }
    state.polling = true;
    state.pollAgain = false;
    const keyAtStart = apiKey();
    let delay = POLL_IDLE_MS;
    try {
      const streaming = await refreshStreams();
      const page = await api("v1/jobs?limit=30");
      const selected = state.selectedId ? state.jobs.find((j) => j.id === state.selectedId) : null;
      state.jobs = page.items;
      // Keep a selected job that fell off the first page.
      if (selected && !state.jobs.some((j) => j.id === selected.id)) state.jobs.push(selected);
      $("jobs-problem").hidden = true;
      noteStatusChanges();
      renderJobs();
      if (state.selectedId) await renderSelected();
      if (state.deepLink) {
        showHeadline();
        state.deepLink = false; // from now on the reader scrolls
      }
      if (streaming || state.jobs.some((j) => !TERMINAL.has(j.status))) delay = POLL_ACTIVE_MS;
    } catch (err) {
      if (apiKey() !== keyAtStart) {
        state.pollAgain = true; // refused with the previous key: not news any more
      } else {
        problemNode($("jobs-problem"), err);
        // Busy or over a quota: come back when the server says so.
        if (err instanceof ApiError && err.retryAfterS) delay = Math.max(delay, err.retryAfterS * 1000);
      }
    } finally {
      state.polling = false;
      if (state.pollAgain) delay = 0;
      schedulePoll(document.hidden && !state.pollAgain ? POLL_IDLE_MS * 2 : delay);
    }
  }

  function schedulePoll(ms) {
    window.clearTimeout(state.pollTimer);
    state.pollTimer = window.setTimeout(refreshJobs, ms);
  }

  // ---------------------------------------------------------------- result view

  // Every job has its own URL, jobs/<id> (relative: the service may live under a path prefix).
  function jobUrl(id) {
    return new URL(`jobs/${encodeURIComponent(id)}`, document.baseURI).href;
  }

  function jobIdInUrl() {
    const match = window.location.pathname.match(/\/jobs\/([^/]+)\/?$/);
    return match ? decodeURIComponent(match[1]) : null;
  }

  function selectJob(id, { focus, history = "push", deepLink = false }) {
    state.selectedId = id;
    state.shownKey = null;
    state.deepLink = deepLink;
    const url = jobUrl(id);
    if (history === "push" && window.location.href !== url) window.history.pushState({ job: id }, "", url);
    else if (history === "replace") window.history.replaceState({ job: id }, "", url);
    document.title = `Job ${shortId(id)} · Eigenscope`;
    renderJobs();
    const section = $("result");
    section.hidden = false;
    renderSelected().then(() => {
      if (focus) section.focus({ preventScroll: true });
      showHeadline();
    });
  }

  // A job's own URL opens on its headline (title and summary cards), also after the lists above it fill.
  function showHeadline() {
    if (!state.deepLink) return;
    const section = $("result");
    if (!section.hidden) section.scrollIntoView({ block: "start" });
  }

  async function renderSelected() {
    const id = state.selectedId;
    let job = state.jobs.find((j) => j.id === id);
    if (!job || (TERMINAL.has(job.status) && state.shownKey !== `${id}:${job.status}`)) {
      try {
        job = await api(`v1/jobs/${encodeURIComponent(id)}`);
      } catch (err) {
        if (id !== state.selectedId) return;
        state.shownKey = null;
        const box = el("div", { class: "problem", role: "alert" });
        problemNode(box, err);
        $("result-body").replaceChildren(box);
        $("result-actions").replaceChildren();
        return;
      }
      if (id !== state.selectedId) return; // another job was selected meanwhile
    }
    const key = `${job.id}:${job.status}`;
    if (TERMINAL.has(job.status)) {
      if (state.shownKey === key) return;
      state.shownKey = key;
      renderFinished(job);
    } else {
      renderRunning(job, state.shownKey === key);
      state.shownKey = key;
    }
  }

  function resultActions(job) {
    const actions = [];
    if (!TERMINAL.has(job.status)) {
      actions.push(el("button", {
        type: "button", class: "btn btn-small", onclick: async (event) => {
          event.currentTarget.disabled = true;
          try {
            upsertJob(await api(`v1/jobs/${encodeURIComponent(job.id)}/cancel`, { method: "POST" }));
            announce(`Job ${shortId(job.id)} cancelled.`);
          } catch (err) {
            const box = el("div", { class: "problem", role: "alert" });
            problemNode(box, err);
            $("result-body").prepend(box);
          }
          refreshJobs();
        },
      }, "Cancel job"));
    }
    actions.push(el("a", { href: jobUrl(job.id), class: "btn btn-small btn-ghost", "data-permalink": "" }, "Link to this job"));
    actions.push(authLink(`v1/jobs/${encodeURIComponent(job.id)}`, "Job JSON", { class: "btn btn-small btn-ghost" }));
    actions.push(el("a", { href: "docs", class: "btn btn-small btn-ghost" }, "API docs"));
    $("result-actions").replaceChildren(...actions);
  }

  // A link to an API URL. With an API key set, a click fetches it with the key and opens the blob instead.
  function authLink(url, text, attrs = {}) {
    const link = el("a", { href: url, target: "_blank", rel: "noopener", ...attrs }, text);
    link.addEventListener("click", async (event) => {
      if (!apiKey()) return;
      event.preventDefault();
      const win = window.open("", "_blank");
      try {
        const objectUrl = await fetchBlobUrl(url);
        if (win) win.location.href = objectUrl;
        else window.location.href = objectUrl;
      } catch (err) {
        if (win) win.close();
        announce(`Could not open ${text}: ${err.message}`);
      }
    });
    return link;
  }

  function renderRunning(job, inPlace) {
    const pct = progressPercent(job);
    const stageText = job.status === "queued" ? "Waiting for a worker…" : `Stage: ${job.stage || "starting"} · ${pct}%`;
    if (inPlace) {
      const bar = document.querySelector("#result-body .running-view progress");
      if (bar) {
        bar.value = pct;
        bar.setAttribute("aria-valuetext", `${pct}%`);
        setText(document.querySelector("#result-body .running-view .stage"), stageText);
        setText(document.querySelector("#result-body .running-view .badge"), statusLabel(job.status));
        document.querySelector("#result-body .running-view .badge").className = `badge badge-${job.status}`;
        return;
      }
    }
    revokeObjectUrls();
    state.shownJob = job;
    $("result-title").textContent = `Job ${shortId(job.id)} · ${jobTitle(job)}`;
    resultActions(job);
    $("result-body").replaceChildren(
      el("div", { class: "running-view" },
        el("p", {}, el("span", { class: `badge badge-${job.status}` }, statusLabel(job.status))),
        el("label", { for: "job-progress" }, "Analysis progress"),
        el("progress", { id: "job-progress", max: "100", value: String(pct) }),
        el("p", { class: "stage" }, stageText),
        el("p", { class: "hint" }, "The result appears here when the job finishes.")));
  }

  function revokeObjectUrls() {
    for (const url of state.objectUrls) URL.revokeObjectURL(url);
    state.objectUrls = [];
  }

  function excitationText(excitation) {
    if (!excitation) return "unknown (no stiffness or mass)";
    if (excitation.type === "step_release") {
      const u = excitation.force_uncertainty_n ? ` ± ${formatNumber(excitation.force_uncertainty_n)}` : "";
      return `held by ${formatNumber(excitation.force_n)}${u} N, released`;
    }
    if (excitation.type === "impulse") {
      const u = excitation.impulse_uncertainty_ns ? ` ± ${formatNumber(excitation.impulse_uncertainty_ns)}` : "";
      return `struck with ${formatNumber(excitation.impulse_ns)}${u} N·s`;
    }
    return excitation.type;
  }

  // The excitation an object's k and m were measured with (the result's ExcitationUsed), and its source.
  function usedExcitationText(used) {
    const pm = used.uncertainty ? ` ± ${formatNumber(used.uncertainty)}` : "";
    const what = {
      step_release: `held force ${formatNumber(used.value)}${pm} N`,
      impulse: `impulse ${formatNumber(used.value)}${pm} N·s`,
      forced: `a force that kept acting, RMS ${formatNumber(used.value)}${pm} N`,
    }[used.type] || used.type;
    const verb = used.type === "impulse" ? "struck" : "released";
    const when = isFiniteNumber(used.release_time_s) ? `, ${verb} at ${formatNumber(used.release_time_s, 4)} s` : "";
    return `${what}${when}, from ${used.source}`;
  }

  function usedExcitation(obj) {
    const used = obj.excitation;
    if (!used) return null;
    const notes = Array.isArray(used.notes) ? used.notes : [];
    return el("div", { class: "excitation-used", "data-excitation-source": used.source },
      el("p", {}, el("strong", {}, "Excitation: "), usedExcitationText(used)),
      notes.length ? el("ul", { class: "nulls", "aria-label": "About the excitation" },
        notes.map((n) => el("li", {}, n))) : null);
  }

  function stat(label, value, unc, unit, quantity) {
    if (value === "—") {
      return el("div", { class: "stat", "data-quantity": quantity },
        el("div", { class: "stat-label" }, label),
        el("div", { class: "stat-value na" }, "not measured"));
    }
    return el("div", { class: "stat", "data-quantity": quantity },
      el("div", { class: "stat-label" }, label),
      el("div", { class: "stat-value" },
        el("span", { class: "num" }, value),
        unc ? el("span", { class: "pm" }, ` ±\u00a0${unc}`) : null,
        unit ? el("span", { class: "unit" }, ` ${unit}`) : null));
  }

  function objectTable(obj) {
    const rows = [
      ["Eigenfrequency (damped)", "eigenfrequency_hz", obj.eigenfrequency_hz, obj.eigenfrequency_uncertainty_hz, 1, "Hz"],
      ["Natural frequency", "natural_frequency_hz", obj.natural_frequency_hz, null, 1, "Hz"],
      ["Angular frequency ω", "angular_frequency_rad_s", obj.angular_frequency_rad_s, null, 1, "rad/s"],
      ["Damping ratio ζ", "damping_ratio", obj.damping_ratio, obj.damping_ratio_uncertainty, 1, ""],
      ["Amplitude", "amplitude_m", obj.amplitude_m, obj.amplitude_uncertainty_m, 1000, "mm"],
      ["Amplitude in the image", "amplitude_px", obj.amplitude_px, null, 1, "px"],
      ["Stiffness k", "stiffness_n_per_m", obj.stiffness_n_per_m, obj.stiffness_uncertainty_n_per_m, 1, "N/m"],
      ["Mass m", "mass_kg", obj.mass_kg, obj.mass_uncertainty_kg, 1, "kg"],
      ["Distance from camera", "depth_m", obj.depth_m, null, 1, "m"],
      ["Signal to noise", "snr_db", obj.snr_db, null, 1, "dB"],
      ["Pixel count", "pixel_count", obj.pixel_count, null, 1, "px"],
    ];
    const body = rows.map(([label, quantity, value, unc, scale, unit]) => {
      const shown = quantity === "pixel_count" && isFiniteNumber(value)
        ? { value: value.toLocaleString("en-US"), unc: "" }
        : formatMeasured(value, unc, scale);
      const missing = !isFiniteNumber(value);
      return el("tr", { "data-quantity": quantity },
        el("th", { scope: "row" }, label),
        el("td", { class: missing ? "value na" : "value", "data-value": missing ? null : String(value) }, missing ? "not measured" : shown.value),
        el("td", { class: "unc" }, shown.unc ? `±\u00a0${shown.unc}` : ""),
        el("td", { class: "unit-cell" }, missing ? "" : unit));
    });
    return el("table", { class: "quantities" },
      el("caption", { class: "visually-hidden" }, `Measurements of object ${obj.id}`),
      el("thead", {}, el("tr", {},
        el("th", { scope: "col" }, "Quantity"),
        el("th", { scope: "col" }, "Value"),
        el("th", { scope: "col", class: "unc-head" }, el("span", { "aria-hidden": "true" }, "± unc."),
          el("span", { class: "visually-hidden" }, "Uncertainty")),
        el("th", { scope: "col" }, el("span", { class: "visually-hidden" }, "Unit")))),
      el("tbody", {}, body));
  }

  function flagList(flags) {
    return el("ul", { class: "flags", "aria-label": "Quality warnings" },
      flags.map((flag) => {
        const severity = ["info", "warning", "error"].includes(flag.severity) ? flag.severity : "warning";
        return el("li", { class: `flag flag-${severity}`, "data-code": flag.code },
          el("span", { class: "flag-label" }, severity),
          el("span", {}, flag.message, " ", el("code", {}, flag.code)));
      }));
  }

  function artifactEntries(artifacts) {
    const entries = Object.entries(artifacts || {})
      .filter(([, url]) => typeof url === "string" && url)
      .map(([key, url]) => ({ key, url, name: decodeURIComponent(url.split("?")[0].split("/").pop() || key) }));
    const order = Object.keys(IMAGE_INFO);
    const rank = (name) => (order.includes(name) ? order.indexOf(name) : order.length);
    entries.sort((a, b) => rank(a.name) - rank(b.name) || a.name.localeCompare(b.name));
    return entries;
  }

  // Colour a label image (pixel value = object id) so that the objects are visible.
  function imageFigure(entry, job) {
    const alt = IMAGE_INFO[entry.name] || `Result image ${entry.name} of job ${shortId(job.id)}`;
    const img = el("img", { alt, "data-artifact": entry.name, decoding: "async" });
    const wrap = el("div", { class: "img-wrap" }, img);
    const figure = el("figure", { class: "figure", "data-artifact": entry.name },
      wrap,
      el("figcaption", {},
        el("span", { class: "name" }, entry.name),
        authLink(entry.url, "Open full size", { "aria-label": `Open ${entry.name} full size` })));
    fetchBlobUrl(entry.url)
      .then((objectUrl) => new Promise((resolve, reject) => {
        img.addEventListener("load", resolve, { once: true });
        img.addEventListener("error", () => reject(new Error("not a readable image")), { once: true });
        img.src = objectUrl;
      }))
      .then(() => {
        // mask.png is a palette image: the browser shows each object in its colour; keep its pixels sharp.
        if (entry.name === "mask.png") img.classList.add("pixelated");
        img.dataset.loaded = "true";
      })
      .catch((err) => {
        img.dataset.loaded = "error";
        wrap.append(el("p", { class: "img-error" }, `Could not load ${entry.name}: ${err.message}`));
      });
    return figure;
  }

  function renderFinished(job) {
    state.shownJob = job;
    revokeObjectUrls();
    $("result-title").textContent = `Job ${shortId(job.id)} · ${jobTitle(job)}`;
    resultActions(job);
    const body = [];
    body.push(el("p", {}, el("span", { class: `badge badge-${job.status}` }, statusLabel(job.status)),
      job.finished_at ? el("span", { class: "hint" }, `  finished ${formatTime(job.finished_at)}`) : null));

    if (job.status === "failed") {
      const box = el("div", { class: "problem", role: "alert" });
      problemNode(box, new ApiError(job.error && job.error.status ? job.error.status : 0, job.error || { title: "The analysis failed" }));
      body.push(box);
    }
    if (job.status === "cancelled") body.push(el("p", {}, "This job was cancelled before it finished."));

    const result = job.result;
    if (job.status === "succeeded" && result) {
      const objects = Array.isArray(result.objects) ? result.objects : [];
      const main = objects.find((o) => o.eigenfrequency_hz === result.eigenfrequency_hz) || objects[0] || null;
      if (main) {
        const f = formatMeasured(main.eigenfrequency_hz, main.eigenfrequency_uncertainty_hz);
        const z = formatMeasured(main.damping_ratio, main.damping_ratio_uncertainty);
        const k = formatMeasured(main.stiffness_n_per_m, main.stiffness_uncertainty_n_per_m);
        const m = formatMeasured(main.mass_kg, main.mass_uncertainty_kg);
        body.push(el("div", { class: "summary", "aria-label": "Main object" },
          stat("Eigenfrequency", f.value, f.unc, "Hz", "eigenfrequency_hz"),
          stat("Damping ratio", z.value, z.unc, "", "damping_ratio"),
          stat("Stiffness", k.value, k.unc, isFiniteNumber(main.stiffness_n_per_m) ? "N/m" : "", "stiffness_n_per_m"),
          stat("Mass", m.value, m.unc, isFiniteNumber(main.mass_kg) ? "kg" : "", "mass_kg")));
      } else {
        body.push(el("p", {}, "No oscillating object was found in this clip."));
      }

      const timings = result.timings_s ? Object.values(result.timings_s).filter(isFiniteNumber) : [];
      const total = timings.reduce((a, b) => a + b, 0);
      const frames = Array.isArray(result.frames_used) && result.frames_used.length === 2
        ? `${result.frames_used[0]}–${result.frames_used[1]}` : "";
      const size = Array.isArray(result.frame_size_px) && result.frame_size_px.length === 2
        ? `${result.frame_size_px[0]} × ${result.frame_size_px[1]} px` : "";
      const meta = [
        ["Clip", jobTitle(job)],
        ["Excitation", !job.excitation && objects.some((o) => o.excitation)
          ? "recorded with the clip (see each object)" : excitationText(job.excitation)],
        ["Method", result.method],
        ["Frame rate", isFiniteNumber(result.fps) ? `${formatNumber(result.fps, 5)} fps (${result.fps_source})` : ""],
        ["Frames", frames],
        ["Frame size", size],
        ["Analysis time", total > 0 ? `${total.toFixed(2)} s` : ""],
        ["Version", result.version],
      ].filter(([, v]) => v);
      body.push(el("dl", { class: "meta" }, meta.map(([k, v]) => el("div", {}, el("dt", {}, `${k}:`),
        el("dd", k === "Clip" ? { "data-clip-name": "" } : {}, v)))));

      const quality = Array.isArray(result.quality) ? result.quality : [];
      body.push(el("h3", { class: "section-title" }, "Quality"));
      if (quality.length) body.push(flagList(quality));
      else body.push(el("p", { class: "hint" }, "No quality warnings."));

      if (objects.length) {
        body.push(el("h3", { class: "section-title" }, objects.length === 1 ? "Object" : `Objects (${objects.length})`));
        body.push(el("div", { class: "objects" }, objects.map((obj) => {
          const reasons = Array.isArray(obj.null_reasons) ? obj.null_reasons : [];
          return el("section", { class: "object", "data-object-id": String(obj.id), "aria-label": `Object ${obj.id}` },
            el("h3", {}, el("span", {}, `Object ${obj.id}`),
              obj.regime ? el("span", { class: "regime", "data-regime": obj.regime }, obj.regime.replace("_", "-")) : null,
              obj.amplitude_source ? el("span", { class: "unit" }, `amplitude from ${obj.amplitude_source}`) : null),
            el("div", { class: "table-wrap" }, objectTable(obj)),
            usedExcitation(obj),
            reasons.length ? el("ul", { class: "nulls", "aria-label": "Why some values are missing" },
              reasons.map((r) => el("li", {}, r))) : null);
        })));
      }
    }

    const entries = result ? artifactEntries(result.artifacts) : [];
    const images = entries.filter((e) => IMAGE_EXT.test(e.name));
    const files = entries.filter((e) => !IMAGE_EXT.test(e.name));
    if (images.length) {
      body.push(el("h3", { class: "section-title" }, "Images"));
      body.push(el("div", { class: "gallery" }, images.map((entry) => imageFigure(entry, job))));
    }
    const links = [
      ...files.map((e) => el("li", {}, authLink(e.url, e.name))),
      el("li", {}, authLink(`v1/jobs/${encodeURIComponent(job.id)}`, "Job record (JSON)")),
      el("li", {}, el("a", { href: "docs" }, "API documentation (/docs)")),
    ];
    body.push(el("ul", { class: "links", "aria-label": "Files and links" }, links));
    $("result-body").replaceChildren(...body);
    if (job.status === "succeeded") announce(`Result of job ${shortId(job.id)} shown.`);
  }

  // ---------------------------------------------------------------- start

  function init() {
    initKey();
    initDropzone();
    initForm();
    $("jobs-refresh").addEventListener("click", () => refreshJobs());
    document.addEventListener("visibilitychange", () => { if (!document.hidden) refreshJobs(); });
    window.addEventListener("popstate", () => {
      const id = jobIdInUrl();
      if (id) {
        selectJob(id, { focus: false, history: "none" });
      } else {
        state.selectedId = null;
        state.shownKey = null;
        document.title = "Eigenscope";
        $("result").hidden = true;
        renderJobs();
      }
    });
    const linked = jobIdInUrl();
    if (linked) selectJob(linked, { focus: true, history: "replace", deepLink: true });
    refreshJobs();
  }

  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", init);
  else init();
})();
