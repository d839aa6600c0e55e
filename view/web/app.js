// flyover view: the page of `flyover view` (thesis V.D): two OST fly-over views side by side,
// playback with a speed dial, Right/Left travel, roll, bookmarks, screenshots, the overview,
// CT slices correlated with the 3D views, measuring and the missed regions.
//
// Every request carries the token of the printed URL (header X-Flyover-Token). World
// coordinates are LPS millimetres throughout; slice pixels are mapped to mm only through the
// X-Flyover-Slice header the server sends with each slice.
//
// Rendering keeps one /api/pair request in flight: a new one goes out only when the last image
// has arrived, always for the state at that moment, so intermediate states are dropped and
// playback never queues up behind the renderer.
//
// A study that `flyover run` is still computing ("live study"): the page polls /api/status
// (every 1 s) until the server serves a study, then starts; afterwards it polls every 2 s and,
// when the server has swapped in a new revision (coverage landed, a re-run replaced the
// surface), fetches /api/study again and applies it in place (applyStudy), without a reload.

'use strict';

import { findingsPanel } from './findings.js';

const $ = (sel) => document.querySelector(sel);

// ---------------------------------------------------------------- token and requests

const token = (() => {
  const fromUrl = new URLSearchParams(location.search).get('token');
  if (fromUrl) {
    try { sessionStorage.setItem('flyover_token', fromUrl); } catch (_) { /* storage off */ }
    return fromUrl;
  }
  try { return sessionStorage.getItem('flyover_token') || ''; } catch (_) { return ''; }
})();

class ApiError extends Error {
  constructor(status, message) { super(message); this.status = status; }
}

/** fetch() of an API path with the token; throws ApiError with the server's one-line error. */
async function api(path, params = {}, init = {}) {
  const url = new URL(path, location.origin);
  for (const [k, v] of Object.entries(params)) url.searchParams.set(k, String(v));
  const headers = Object.assign({ 'X-Flyover-Token': token }, init.headers || {});
  const res = await fetch(url, Object.assign({}, init, { headers, cache: 'no-store' }));
  if (!res.ok) {
    let msg = `${res.status} ${res.statusText}`;
    try {
      const j = await res.json();
      if (j && j.error) msg = j.error;
    } catch (_) { /* not JSON */ }
    throw new ApiError(res.status, `${path}: ${msg}`);
  }
  return res;
}

async function apiJson(path, params, init) {
  return (await api(path, params, init)).json();
}

/** The URL of a download link: same origin, token in the query (the cookie also works). */
function tokenUrl(path) {
  const url = new URL(path, location.origin);
  if (token && !url.searchParams.has('token')) url.searchParams.set('token', token);
  return url.pathname + url.search;
}

// ---------------------------------------------------------------- small helpers

const fmt = (v, d = 2) => Number(v.toFixed(d));
const clamp = (v, lo, hi) => Math.min(hi, Math.max(lo, v));
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const scale = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const norm = (a) => Math.hypot(a[0], a[1], a[2]);
const fmtPoint = (p) => p.map((v) => v.toFixed(1)).join(', ');
const normRoll = (r) => { let x = ((r + 180) % 360 + 360) % 360 - 180; if (x === -180) x = 180; return fmt(x, 1); };

function parsePoint(text) {
  const parts = String(text).split(/[\s,;]+/).filter((s) => s.length).map(Number);
  if (parts.length !== 3 || parts.some((v) => !Number.isFinite(v))) return null;
  return parts;
}

function setStatus(text, state = 'ready') {
  const el = $('#status');
  el.textContent = text;
  el.dataset.state = state;
  el.title = text;
}

function reportError(e) {
  console.warn(e);
  setStatus(e && e.message ? e.message : String(e), 'error');
}

// ---------------------------------------------------------------- state

const S = {
  study: null,
  arc: 0,
  roll: 0,
  direction: 'right', // right = travel rectum -> cecum (arc increases when moving forward)
  mode: 'flyover',
  clip: 0.5,
  px: 512,
  speed: 20, // mm/s, negative = backward
  playing: false,
  measuring: false,
  shown: null, // {key, params, pose, gen} of the frame on screen
  gen: 0, // +1 each time a study document is applied: a frame of an older one is stale
  marker: null, // {key, view, x, y, px}: a located point, drawn when its pose is on screen
  picks: [], // [{key, view, x, y, px, point}] picked points (measure) on the views
  cursor: null, // CT cursor, LPS mm
  window: 1500,
  level: -500,
  frames: 0,
};

const stepMm = () => (S.study ? Math.max(S.study.step_mm || 1, 1) * 5 : 5);
const travelSign = () => (S.direction === 'right' ? 1 : -1);
const arcMax = () => (S.study ? S.study.arc_max_mm : 0);

/** Parameters of /api/pair for the current state. */
function pairParams() {
  return {
    arc_mm: snapArc(S.arc), roll_deg: fmt(S.roll, 1), direction: S.direction, mode: S.mode,
    clip_offset_fraction: S.clip, px: S.px, format: 'jpeg',
  };
}
/** The centerline point an arc length falls on: the server renders at centerline points only. */
function snapArc(a) {
  const st = (S.study && S.study.step_mm) || 1;
  return fmt(clamp(Math.round(a / st) * st, 0, arcMax()), 3);
}
const poseKey = (p) => [p.arc_mm, p.roll_deg, p.direction, p.mode, p.clip_offset_fraction, p.px].join('|');

/** The pose as bookmarks and screenshots store it. */
function poseBody() {
  return {
    arc_mm: snapArc(S.arc), roll_deg: fmt(S.roll, 1), direction: S.direction, mode: S.mode,
    clip_offset_fraction: S.clip,
  };
}

// ---------------------------------------------------------------- the fly-over pair

const pairCanvas = $('#pair');
const pairCtx = pairCanvas.getContext('2d');
const overlay = $('#pair-overlay');
const overlayCtx = overlay.getContext('2d');
const views = $('#views');

let pairInFlight = false;
let fpsTimes = [];

/** Sends the next /api/pair request if none is in flight and the state differs from the screen. */
async function pumpPair() {
  if (pairInFlight || !S.study) return;
  const params = pairParams();
  const key = poseKey(params);
  if (S.shown && S.shown.key === key && S.shown.gen === S.gen) return;
  const gen = S.gen;
  const revision = S.study.revision;
  pairInFlight = true;
  views.dataset.loading = 'true';
  try {
    const res = await api('/api/pair', params);
    let pose = null;
    try { pose = JSON.parse(res.headers.get('X-Flyover-Pose') || 'null'); } catch (_) { pose = null; }
    const bmp = await createImageBitmap(await res.blob());
    if (pairCanvas.width !== bmp.width || pairCanvas.height !== bmp.height) {
      pairCanvas.width = overlay.width = bmp.width;
      pairCanvas.height = overlay.height = bmp.height;
      views.style.aspectRatio = `${bmp.width} / ${bmp.height}`;
    }
    pairCtx.drawImage(bmp, 0, 0);
    bmp.close();
    S.shown = { key, params, pose, gen };
    S.frames += 1;
    const d = views.dataset;
    d.arcMm = String(params.arc_mm);
    d.rollDeg = String(params.roll_deg);
    d.direction = params.direction;
    d.mode = params.mode;
    d.px = String(params.px);
    d.frames = String(S.frames);
    d.key = key;
    d.pose = pose ? JSON.stringify(pose) : '';
    d.revision = String(revision);
    const now = performance.now();
    fpsTimes.push(now);
    fpsTimes = fpsTimes.filter((t) => now - t < 2000);
    $('#fps').textContent = fpsTimes.length > 1 ? `${(fpsTimes.length / 2).toFixed(1)} frames/s` : '';
    drawOverlay();
    if ($('#status').dataset.state === 'loading') $('#status').dataset.state = 'ready';
    maybeOverview();
  } catch (e) {
    // Do not retry the same state in a loop: remember it as shown (with no image).
    S.shown = { key, params, pose: null, failed: true, gen };
    if (S.playing) setPlaying(false);
    reportError(e);
  } finally {
    pairInFlight = false;
    views.dataset.loading = 'false';
  }
  pumpPair();
}

/** Width of the separator between the two views in the pair image (canvas pixels). */
function viewGap() {
  return Math.max(0, pairCanvas.width - 2 * pairCanvas.height);
}

function drawOverlay() {
  const ctx = overlayCtx;
  ctx.clearRect(0, 0, overlay.width, overlay.height);
  if (!S.shown) return;
  const h = overlay.height;
  const at = (m) => {
    const s = h / m.px;
    return [m.view * (h + viewGap()) + m.x * s, m.y * s];
  };
  const r = Math.max(6, h / 40);
  if (S.marker && S.marker.key === S.shown.key) {
    const [x, y] = at(S.marker);
    ctx.lineWidth = Math.max(2, h / 256);
    ctx.strokeStyle = '#ffd24a';
    ctx.beginPath(); ctx.arc(x, y, r * 1.6, 0, 2 * Math.PI); ctx.stroke();
    ctx.beginPath();
    ctx.moveTo(x - r * 2.6, y); ctx.lineTo(x - r * 0.8, y);
    ctx.moveTo(x + r * 0.8, y); ctx.lineTo(x + r * 2.6, y);
    ctx.moveTo(x, y - r * 2.6); ctx.lineTo(x, y - r * 0.8);
    ctx.moveTo(x, y + r * 0.8); ctx.lineTo(x, y + r * 2.6);
    ctx.stroke();
  }
  const onScreen = S.picks.filter((p) => p.key === S.shown.key);
  ctx.lineWidth = Math.max(2, h / 300);
  for (const p of onScreen) {
    const [x, y] = at(p);
    ctx.strokeStyle = p.point ? '#6bd68b' : '#ff6b6b';
    ctx.beginPath(); ctx.arc(x, y, r * 0.7, 0, 2 * Math.PI); ctx.stroke();
  }
  if (onScreen.length === 2 && onScreen[0].view === onScreen[1].view) {
    const [x0, y0] = at(onScreen[0]);
    const [x1, y1] = at(onScreen[1]);
    ctx.setLineDash([6, 4]);
    ctx.strokeStyle = '#6bd68b';
    ctx.beginPath(); ctx.moveTo(x0, y0); ctx.lineTo(x1, y1); ctx.stroke();
    ctx.setLineDash([]);
  }
  findings.draw(ctx, h, viewGap(), S.shown);
}

/** The view and pixel (in a view of the shown px) under a mouse event, or null. */
function viewPixel(ev) {
  if (!S.shown || S.shown.failed) return null;
  const rect = pairCanvas.getBoundingClientRect();
  const px = S.shown.params.px;
  // canvas pixels: view 0 | separator | view 1; a view of px pixels is pairCanvas.height high
  const k = pairCanvas.height / px;
  const u = ((ev.clientX - rect.left) / rect.width) * pairCanvas.width / k;
  const v = ((ev.clientY - rect.top) / rect.height) * px;
  const gap = viewGap() / k;
  if (u < 0 || v < 0 || v >= px) return null;
  let view;
  let x;
  if (u < px) { view = 0; x = u; } else if (u >= px + gap && u < 2 * px + gap) { view = 1; x = u - px - gap; } else return null;
  return { view, x: fmt(x, 1), y: fmt(v, 1), px };
}

async function pickAt(vp) {
  const p = S.shown.params;
  const res = await apiJson('/api/pick', {
    arc_mm: p.arc_mm, roll_deg: p.roll_deg, direction: p.direction, mode: p.mode,
    clip_offset_fraction: p.clip_offset_fraction, px: p.px, view: vp.view, x: vp.x, y: vp.y,
  });
  return res;
}

async function onViewClick(ev) {
  const vp = viewPixel(ev);
  if (!vp) return;
  const key = S.shown.key;
  try {
    const res = await pickAt(vp);
    const info = $('#pick-info');
    info.dataset.hit = String(!!res.hit);
    if (!res.hit) {
      info.dataset.pointMm = '';
      info.textContent = 'no surface under that pixel';
      if (S.measuring) { S.picks = [{ key, ...vp, point: null }]; drawOverlay(); }
      return;
    }
    const point = res.point_mm;
    info.dataset.pointMm = JSON.stringify(point);
    info.textContent = `picked (${fmtPoint(point)}) LPS mm, ${Number(res.distance_mm).toFixed(1)} mm from the camera`;
    const mark = { key, ...vp, point };
    if (S.measuring) {
      if (S.picks.length >= 2 || (S.picks.length === 1 && !S.picks[0].point)) S.picks = [];
      S.picks.push(mark);
      const out = $('#measure-result');
      if (S.picks.length === 2) {
        const d = norm(sub(S.picks[1].point, S.picks[0].point));
        out.dataset.distanceMm = String(fmt(d, 3));
        out.textContent = `distance ${d.toFixed(1)} mm`;
        findings.measured(d);
      } else {
        out.dataset.distanceMm = '';
        out.textContent = 'first point picked: click the second one';
      }
    } else {
      S.picks = [mark];
    }
    findings.picked(point);
    drawOverlay();
    setCursor(point);
  } catch (e) { reportError(e); }
}

// Mouse on the views: a click picks; a horizontal drag rolls both cameras.
(() => {
  let drag = null;
  views.addEventListener('pointerdown', (ev) => {
    if (ev.button !== 0) return;
    drag = { x0: ev.clientX, y0: ev.clientY, roll0: S.roll, moved: false, id: ev.pointerId };
    views.setPointerCapture(ev.pointerId);
  });
  views.addEventListener('pointermove', (ev) => {
    if (!drag) return;
    const dx = ev.clientX - drag.x0;
    if (!drag.moved && Math.abs(dx) + Math.abs(ev.clientY - drag.y0) > 5) {
      drag.moved = true;
      views.classList.add('dragging');
    }
    if (drag.moved) {
      const rect = pairCanvas.getBoundingClientRect();
      setRoll(drag.roll0 + (dx / (rect.width / 2)) * 180);
    }
  });
  const end = (ev) => {
    if (!drag) return;
    const moved = drag.moved;
    drag = null;
    views.classList.remove('dragging');
    if (ev.type === 'pointerup' && !moved) onViewClick(ev);
  };
  views.addEventListener('pointerup', end);
  views.addEventListener('pointercancel', end);
})();

// ---------------------------------------------------------------- navigation

function updateReadout() {
  $('#arc').value = String(S.arc);
  const ai = $('#arc-input');
  if (document.activeElement !== ai) ai.value = S.arc.toFixed(1);
  $('#roll-value').textContent = `${S.roll.toFixed(0)}°`;
  const ri = $('#roll');
  if (document.activeElement !== ri) ri.value = String(S.roll);
  const dirBtn = $('#direction');
  dirBtn.textContent = S.direction === 'right' ? 'Right' : 'Left';
  dirBtn.dataset.direction = S.direction;
  $('#mode').checked = S.mode === 'flythrough';
  if (S.study && S.study.centerline && S.study.centerline.length) {
    const cl = S.study.centerline;
    const i = clamp(Math.round(S.arc / (S.study.step_mm || 1)), 0, cl.length - 1);
    $('#point').textContent = `#${i} (${fmtPoint(cl[i])})`;
    $('#point').dataset.index = String(i);
    $('#bridged-flag').hidden = !(S.study.bridged && S.study.bridged[i]);
  }
  updateMissedHighlight();
}

/** Moves to a new pose (any field), then asks for its frame. */
function setPose(p, { keepMarker = false } = {}) {
  if (p.arc_mm !== undefined) S.arc = fmt(clamp(Number(p.arc_mm), 0, arcMax()));
  if (p.roll_deg !== undefined) S.roll = normRoll(Number(p.roll_deg));
  if (p.direction === 'right' || p.direction === 'left') S.direction = p.direction;
  if (p.mode === 'flyover' || p.mode === 'flythrough') S.mode = p.mode;
  if (p.clip_offset_fraction !== undefined && Number.isFinite(Number(p.clip_offset_fraction))) {
    S.clip = Number(p.clip_offset_fraction);
    $('#clip').value = String(S.clip);
  }
  if (!keepMarker) S.marker = null;
  updateReadout();
  pumpPair();
}

const setArc = (a) => setPose({ arc_mm: a });
const setRoll = (r) => setPose({ roll_deg: r });
const step = (n) => setArc(S.arc + n * stepMm() * travelSign());

function setPlaying(on) {
  S.playing = on;
  const b = $('#play');
  b.dataset.playing = String(on);
  b.textContent = on ? '❚❚ Pause' : '▶ Play';
  if (on) {
    lastTick = performance.now();
    requestAnimationFrame(tick);
  } else {
    // Paused where the frame on screen is: the unrounded arc of playback could otherwise round
    // the other way once a step is added (29.496 shows 29; +5 and -5 gave 29.5, shown as 30).
    S.arc = snapArc(S.arc);
    updateReadout();
  }
}

let lastTick = 0;
function tick(now) {
  if (!S.playing) return;
  // rAF's time stamp is the frame's start and may precede the press of Play: never negative
  const dt = clamp((now - lastTick) / 1000, 0, 0.25);
  lastTick = Math.max(lastTick, now);
  const v = S.speed * travelSign();
  const next = S.arc + v * dt;
  const max = arcMax();
  if ((v < 0 && next <= 0) || (v > 0 && next >= max)) {
    S.arc = clamp(next, 0, max);
    setPlaying(false);
    setStatus(next <= 0 ? 'Reached the start of the colon' : 'Reached the end of the colon');
  } else {
    S.arc = next; // unrounded while playing: small speeds still advance
  }
  S.marker = null;
  updateReadout();
  pumpPair();
  if (S.playing) requestAnimationFrame(tick);
}

function setSpeed(v) {
  S.speed = clamp(Math.round(v), Number($('#speed').min), Number($('#speed').max));
  $('#speed').value = String(S.speed);
  $('#speed-value').textContent = `${S.speed} mm/s`;
}

function toggleDirection() { setPose({ direction: S.direction === 'right' ? 'left' : 'right' }); }
function toggleMode() { setPose({ mode: S.mode === 'flyover' ? 'flythrough' : 'flyover' }); }

function setMeasuring(on) {
  S.measuring = on;
  $('#measure').dataset.active = String(on);
  S.picks = [];
  const out = $('#measure-result');
  out.dataset.distanceMm = '';
  out.textContent = on ? 'measure: click two points on a view' : 'click a view to pick a point';
  drawOverlay();
}

/** Flies to the pose that shows a world point best (/api/locate) and marks it. */
async function flyToPoint(point, what = 'point') {
  const r = await apiJson('/api/locate', {
    x_mm: fmt(point[0], 3), y_mm: fmt(point[1], 3), z_mm: fmt(point[2], 3), px: S.px, direction: S.direction,
  });
  if (S.playing) setPlaying(false);
  setPose({ arc_mm: r.arc_mm, roll_deg: r.roll_deg, direction: r.direction, mode: r.mode || 'flyover' });
  const key = poseKey(pairParams());
  S.marker = { key, view: Number(r.view), x: Number(r.x), y: Number(r.y), px: Number(r.px) };
  const d = views.dataset;
  d.markerView = String(r.view);
  d.markerX = String(r.x);
  d.markerY = String(r.y);
  d.markerPx = String(r.px);
  d.markerKey = key;
  d.locate = JSON.stringify(r);
  setStatus(`${what} (${fmtPoint(point)}) shown in view ${r.view} at arc ${Number(r.arc_mm).toFixed(1)} mm`);
  drawOverlay();
  return r;
}

// ---------------------------------------------------------------- overview

const overviewImg = $('#overview');
let overviewInFlight = false;
let overviewShownArc = null;
let overviewAt = 0;
let overviewUrl = null;
let overviewPx = 512;
let overviewForced = false; // a forced refresh (new study revision) waits for the one in flight

async function maybeOverview(force = false) {
  if (force) overviewForced = true;
  if (overviewInFlight || !S.study) return;
  force = overviewForced;
  const arc = fmt(S.arc, 1);
  if (!force && overviewShownArc !== null && Math.abs(arc - overviewShownArc) < 0.5) return;
  const now = performance.now();
  if (!force && now - overviewAt < 500) {
    setTimeout(() => maybeOverview(), 520 - (now - overviewAt));
    return;
  }
  overviewInFlight = true;
  overviewForced = false;
  overviewAt = now;
  try {
    const res = await api('/api/overview', { marker_mm: arc, px: overviewPx, findings: 1 });
    const url = URL.createObjectURL(await res.blob());
    await new Promise((ok) => { overviewImg.onload = ok; overviewImg.onerror = ok; overviewImg.src = url; });
    if (overviewUrl) URL.revokeObjectURL(overviewUrl);
    overviewUrl = url;
    overviewShownArc = arc;
    overviewImg.dataset.markerMm = String(arc);
  } catch (e) { reportError(e); }
  finally { overviewInFlight = false; }
  if (overviewForced || Math.abs(fmt(S.arc, 1) - overviewShownArc) >= 0.5) maybeOverview();
}

overviewImg.addEventListener('click', async (ev) => {
  if (!overviewImg.naturalWidth) return;
  const rect = overviewImg.getBoundingClientRect();
  const x = Math.floor(((ev.clientX - rect.left) / rect.width) * overviewPx);
  const y = Math.floor(((ev.clientY - rect.top) / rect.height) * overviewPx);
  try {
    const r = await apiJson('/api/overview/pick', { x: clamp(x, 0, overviewPx - 1), y: clamp(y, 0, overviewPx - 1), px: overviewPx });
    if (!r.hit) { setStatus('No colon under that point of the overview'); return; }
    if (S.playing) setPlaying(false);
    setArc(r.arc_mm);
    setStatus(`Jumped to arc ${Number(r.arc_mm).toFixed(1)} mm (overview point ${fmtPoint(r.point_mm)})`);
  } catch (e) { reportError(e); }
});

// ---------------------------------------------------------------- CT slices

const PLANES = ['axial', 'coronal', 'sagittal'];
const slices = {};
for (const plane of PLANES) {
  const fig = document.querySelector(`.slice[data-plane="${plane}"]`);
  slices[plane] = {
    fig, box: fig.querySelector('.slice-box'), img: fig.querySelector('img'), canvas: fig.querySelector('canvas'),
    map: null, shownKey: null, inFlight: false, url: null,
  };
}

const pixelMm = (m) => (Array.isArray(m.pixel_mm) ? m.pixel_mm : [m.pixel_mm, m.pixel_mm]);

/** World point of slice pixel (col, row) (pixel centres at integers), by the server's mapping:
 *  centre of pixel (c, r) = origin_mm + c * pixel_mm * col_dir + r * pixel_mm * row_dir. */
function sliceToWorld(m, col, row) {
  const [pc, pr] = pixelMm(m);
  return add(m.origin_mm, add(scale(m.col_dir, col * pc), scale(m.row_dir, row * pr)));
}

/** Slice pixel (col, row) of a world point, projected onto the slice plane. */
function worldToSlice(m, p) {
  const [pc, pr] = pixelMm(m);
  const d = sub(p, m.origin_mm);
  return [dot(d, m.col_dir) / pc, dot(d, m.row_dir) / pr];
}

/** The image's drawn rectangle inside its box (object-fit: contain), in CSS pixels. */
function drawnRect(s) {
  const bw = s.box.clientWidth;
  const bh = s.box.clientHeight;
  const iw = s.img.naturalWidth;
  const ih = s.img.naturalHeight;
  const k = Math.min(bw / iw, bh / ih);
  return { x: (bw - iw * k) / 2, y: (bh - ih * k) / 2, k, iw, ih, bw, bh };
}

function sliceParams(plane) {
  return {
    plane, x_mm: fmt(S.cursor[0], 3), y_mm: fmt(S.cursor[1], 3), z_mm: fmt(S.cursor[2], 3),
    window: S.window, level: S.level,
  };
}

async function pumpSlice(plane) {
  const s = slices[plane];
  if (s.inFlight || !S.cursor || !S.study || !S.study.has_ct) return;
  const params = sliceParams(plane);
  const key = JSON.stringify(params);
  if (key === s.shownKey) { drawCrosshair(plane); return; }
  s.inFlight = true;
  try {
    const res = await api('/api/slice', params);
    const map = JSON.parse(res.headers.get('X-Flyover-Slice') || 'null');
    if (!map || !map.origin_mm || !map.row_dir || !map.col_dir || map.pixel_mm === undefined) {
      throw new Error('/api/slice: the response has no usable X-Flyover-Slice header');
    }
    const url = URL.createObjectURL(await res.blob());
    await new Promise((ok, fail) => {
      s.img.onload = ok;
      s.img.onerror = () => fail(new Error(`/api/slice: the ${plane} image did not decode`));
      s.img.src = url;
    });
    if (s.url) URL.revokeObjectURL(s.url);
    s.url = url;
    s.map = map;
    s.shownKey = key;
    s.fig.dataset.mapping = JSON.stringify(map);
    s.fig.dataset.width = String(s.img.naturalWidth);
    s.fig.dataset.height = String(s.img.naturalHeight);
  } catch (e) {
    s.shownKey = key;
    reportError(e);
  } finally {
    s.inFlight = false;
  }
  drawCrosshair(plane);
  pumpSlice(plane);
}

function drawCrosshair(plane) {
  const s = slices[plane];
  const c = s.canvas;
  const dpr = window.devicePixelRatio || 1;
  const w = Math.round(s.box.clientWidth * dpr);
  const h = Math.round(s.box.clientHeight * dpr);
  if (c.width !== w || c.height !== h) { c.width = w; c.height = h; }
  const ctx = c.getContext('2d');
  ctx.clearRect(0, 0, w, h);
  if (!s.map || !S.cursor || !s.img.naturalWidth) return;
  const [col, row] = worldToSlice(s.map, S.cursor);
  s.fig.dataset.crossCol = String(fmt(col, 3));
  s.fig.dataset.crossRow = String(fmt(row, 3));
  const r = drawnRect(s);
  const x = (r.x + (col + 0.5) * r.k) * dpr;
  const y = (r.y + (row + 0.5) * r.k) * dpr;
  const gap = 6 * dpr;
  ctx.strokeStyle = '#4fb3ff';
  ctx.lineWidth = Math.max(1, dpr);
  ctx.beginPath();
  ctx.moveTo(r.x * dpr, y); ctx.lineTo(x - gap, y);
  ctx.moveTo(x + gap, y); ctx.lineTo((r.x + r.iw * r.k) * dpr, y);
  ctx.moveTo(x, r.y * dpr); ctx.lineTo(x, y - gap);
  ctx.moveTo(x, y + gap); ctx.lineTo(x, (r.y + r.ih * r.k) * dpr);
  ctx.stroke();
}

/** Moves the CT cursor (LPS mm) and reloads the slices through it. */
function setCursor(p) {
  S.cursor = p.slice(0, 3).map(Number);
  $('#ct').dataset.cursorMm = JSON.stringify(S.cursor);
  const ci = $('#ct-point');
  if (document.activeElement !== ci) ci.value = fmtPoint(S.cursor);
  for (const plane of PLANES) pumpSlice(plane);
}

function reloadSlices() { for (const plane of PLANES) pumpSlice(plane); }

for (const plane of PLANES) {
  const s = slices[plane];
  s.box.addEventListener('click', async (ev) => {
    if (!s.map || !s.img.naturalWidth) return;
    const r = drawnRect(s);
    const bx = s.box.getBoundingClientRect();
    const col = (ev.clientX - bx.left - r.x) / r.k - 0.5;
    const row = (ev.clientY - bx.top - r.y) / r.k - 0.5;
    if (col < -0.5 || row < -0.5 || col > r.iw - 0.5 || row > r.ih - 0.5) return;
    const p = sliceToWorld(s.map, col, row);
    setCursor(p);
    try { await flyToPoint(p, `${plane} slice point`); } catch (e) { reportError(e); }
  });
  s.box.addEventListener('wheel', (ev) => {
    if (!s.map || !S.cursor) return;
    ev.preventDefault();
    const n = cross(s.map.col_dir, s.map.row_dir);
    const len = norm(n) || 1;
    const stepLen = (S.study.ct && S.study.ct.spacing_mm) ? Math.min(...[].concat(S.study.ct.spacing_mm)) : 1;
    const k = (ev.deltaY > 0 ? -1 : 1) * stepLen / len;
    setCursor(add(S.cursor, scale(n, k)));
  }, { passive: false });
}

function setWindowLevel(w, l) {
  if (Number.isFinite(w) && w > 0) S.window = w;
  if (Number.isFinite(l)) S.level = l;
  $('#window').value = String(S.window);
  $('#level').value = String(S.level);
  reloadSlices();
}

// ---------------------------------------------------------------- missed regions

let currentMissed = null;

function renderMissed() {
  const list = $('#missed-list');
  list.textContent = '';
  const regions = (S.study && S.study.missed_regions) || [];
  $('#missed-count').textContent = regions.length ? `${regions.length} (fly-over, ≥ 10 mm²)` : 'none';
  $('#next-missed').disabled = regions.length === 0;
  for (const r of regions) {
    const li = document.createElement('li');
    li.dataset.id = String(r.id);
    li.dataset.arcMm = String(r.arc_mm);
    const b = document.createElement('button');
    b.textContent = `${Number(r.area_mm2).toFixed(0)} mm² at ${Number(r.arc_mm).toFixed(0)} mm`;
    b.title = `centroid (${fmtPoint(r.centroid_mm)}) LPS mm`;
    b.addEventListener('click', () => flyToMissed(r));
    li.appendChild(b);
    list.appendChild(li);
  }
}

function updateMissedHighlight() {
  for (const li of document.querySelectorAll('#missed-list li')) {
    li.classList.toggle('current', currentMissed !== null && li.dataset.id === String(currentMissed));
  }
}

async function flyToMissed(r) {
  currentMissed = r.id;
  $('#missed-list').dataset.currentId = String(r.id);
  try {
    await flyToPoint(r.centroid_mm, `missed region ${r.id}`);
  } catch (e) {
    setArc(r.arc_mm); // the region's nearest centerline point, if locate fails
    reportError(e);
  }
  updateMissedHighlight();
}

function nextMissed() {
  const regions = ((S.study && S.study.missed_regions) || []).slice();
  if (!regions.length) { setStatus('No missed regions in this study'); return; }
  const sgn = travelSign();
  regions.sort((a, b) => sgn * (a.arc_mm - b.arc_mm));
  const ahead = regions.find((r) => sgn * (r.arc_mm - S.arc) > 1 && r.id !== currentMissed);
  flyToMissed(ahead || regions[0]);
}

// ---------------------------------------------------------------- candidates and findings

const findings = findingsPanel({ apiJson, flyToPoint, setStatus, reportError, redraw: () => drawOverlay(), marksChanged: () => maybeOverview(true) });

/** The CT slices as large as the fly-over views: under them, two a row. */
function setCtLarge(on) {
  const ct = $('#ct');
  ct.classList.toggle('large', on);
  if (on) $('#left').insertBefore(ct, $('#transport'));
  else $('#right').insertBefore(ct, $('#missed-panel'));
  $('#ct-large').dataset.active = String(on);
  $('#ct-large').textContent = on ? 'CT small' : 'CT large';
  for (const plane of PLANES) drawCrosshair(plane);
}

// ---------------------------------------------------------------- bookmarks

async function loadBookmarks() {
  try {
    const j = await apiJson('/api/bookmarks');
    renderBookmarks(Array.isArray(j) ? j : (j.bookmarks || []));
  } catch (e) { reportError(e); }
}

function renderBookmarks(list) {
  const ul = $('#bookmark-list');
  ul.textContent = '';
  ul.dataset.count = String(list.length);
  for (const b of list) {
    const li = document.createElement('li');
    li.dataset.id = String(b.id);
    const note = document.createElement('span');
    note.className = 'note';
    note.textContent = b.note || '(no note)';
    note.title = `${b.note || ''}\n${b.created || ''}`;
    const meta = document.createElement('span');
    meta.className = 'meta';
    meta.textContent = `${Number(b.arc_mm).toFixed(0)} mm${Number(b.roll_deg) ? `, ${Number(b.roll_deg).toFixed(0)}°` : ''}, ${b.direction === 'left' ? 'L' : 'R'}${b.mode === 'flythrough' ? ', FT' : ''}`;
    const load = document.createElement('button');
    load.className = 'load';
    load.textContent = 'load';
    load.addEventListener('click', () => {
      if (S.playing) setPlaying(false);
      setPose(b);
      setStatus(`Loaded bookmark “${b.note || b.id}”`);
    });
    const del = document.createElement('button');
    del.className = 'delete';
    del.textContent = '✕';
    del.title = 'delete';
    del.addEventListener('click', async () => {
      try {
        await api('/api/bookmarks', { id: b.id }, { method: 'DELETE' });
        setStatus(`Deleted bookmark “${b.note || b.id}”`);
      } catch (e) { reportError(e); }
      loadBookmarks();
    });
    li.append(note, meta, load, del);
    ul.appendChild(li);
  }
}

async function saveBookmark() {
  const noteEl = $('#bookmark-note');
  const body = Object.assign({ note: noteEl.value.trim() }, poseBody());
  try {
    const b = await apiJson('/api/bookmarks', {}, {
      method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(body),
    });
    noteEl.value = '';
    setStatus(`Saved bookmark “${b.note || b.id}” at arc ${Number(b.arc_mm).toFixed(1)} mm`);
  } catch (e) { reportError(e); }
  loadBookmarks();
}

// ---------------------------------------------------------------- screenshot

async function screenshot() {
  const body = Object.assign(poseBody(), { px: S.px });
  try {
    const r = await apiJson('/api/screenshot', {}, {
      method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(body),
    });
    const a = $('#screenshot-link');
    a.href = tokenUrl(r.url);
    const name = String(r.file).split('/').pop();
    a.setAttribute('download', name);
    a.textContent = `download ${name}`;
    a.dataset.file = r.file;
    a.dataset.poseFile = r.pose_file || '';
    a.hidden = false;
    setStatus(`Saved ${r.file} (pose in ${r.pose_file})`);
  } catch (e) { reportError(e); }
}

// ---------------------------------------------------------------- controls and keys

function bind() {
  $('#play').addEventListener('click', () => setPlaying(!S.playing));
  $('#start').addEventListener('click', () => setArc(0));
  $('#end').addEventListener('click', () => setArc(arcMax()));
  $('#step-back').addEventListener('click', () => step(-1));
  $('#step-fwd').addEventListener('click', () => step(1));
  $('#speed').addEventListener('input', (e) => setSpeed(Number(e.target.value)));
  $('#direction').addEventListener('click', toggleDirection);
  $('#roll-left').addEventListener('click', () => setRoll(S.roll - 15));
  $('#roll-right').addEventListener('click', () => setRoll(S.roll + 15));
  $('#roll').addEventListener('change', (e) => {
    const v = Number(e.target.value);
    if (Number.isFinite(v)) setRoll(v); else e.target.value = String(S.roll);
  });
  $('#mode').addEventListener('change', (e) => setPose({ mode: e.target.checked ? 'flythrough' : 'flyover' }));
  $('#clip').addEventListener('change', (e) => {
    const v = Number(e.target.value);
    if (Number.isFinite(v) && v >= 0 && v <= 1) setPose({ clip_offset_fraction: v });
    else { e.target.value = String(S.clip); setStatus('clip offset fraction: a number in 0..1', 'error'); }
  });
  $('#px').addEventListener('change', (e) => { S.px = Number(e.target.value); S.marker = null; pumpPair(); });
  $('#arc').addEventListener('input', (e) => setArc(Number(e.target.value)));
  $('#arc-input').addEventListener('change', (e) => {
    const v = Number(e.target.value);
    if (Number.isFinite(v)) setArc(v);
    e.target.value = S.arc.toFixed(1);
  });
  $('#measure').addEventListener('click', () => setMeasuring(!S.measuring));
  $('#screenshot').addEventListener('click', screenshot);
  $('#bookmark-form').addEventListener('submit', (e) => { e.preventDefault(); saveBookmark(); });
  $('#next-missed').addEventListener('click', nextMissed);
  $('#ct-large').addEventListener('click', () => setCtLarge(!$('#ct').classList.contains('large')));
  $('#window').addEventListener('change', (e) => setWindowLevel(Number(e.target.value), S.level));
  $('#level').addEventListener('change', (e) => setWindowLevel(S.window, Number(e.target.value)));
  $('#wl-preset').addEventListener('change', (e) => {
    if (!e.target.value) return;
    const [w, l] = e.target.value.split(',').map(Number);
    setWindowLevel(w, l);
    e.target.value = '';
  });
  $('#ct-point').addEventListener('change', (e) => {
    const p = parsePoint(e.target.value);
    if (p) setCursor(p);
    else setStatus('cursor: three numbers x, y, z (LPS mm)', 'error');
  });
  $('#goto').addEventListener('change', async (e) => {
    const p = parsePoint(e.target.value);
    if (!p) { setStatus('go to: three numbers x, y, z (LPS mm)', 'error'); return; }
    setCursor(p);
    try { await flyToPoint(p); } catch (err) { reportError(err); }
  });
  // Enter in a value field applies it and hands the keys back to the shortcuts.
  for (const id of ['#arc-input', '#roll', '#clip', '#goto', '#ct-point', '#window', '#level', '#finding-size']) {
    $(id).addEventListener('keydown', (e) => { if (e.key === 'Enter') e.target.blur(); });
  }
  window.addEventListener('resize', () => { for (const plane of PLANES) drawCrosshair(plane); });

  document.addEventListener('keydown', (ev) => {
    const t = ev.target;
    if (t && (t.tagName === 'INPUT' || t.tagName === 'SELECT' || t.tagName === 'TEXTAREA')) {
      if (ev.key === 'Escape') t.blur();
      return;
    }
    if (ev.ctrlKey || ev.metaKey || ev.altKey) return;
    const k = ev.key;
    let handled = true;
    if (k === ' ') setPlaying(!S.playing);
    else if (k === 'ArrowRight') step(ev.shiftKey ? 10 : 1);
    else if (k === 'ArrowLeft') step(ev.shiftKey ? -10 : -1);
    else if (k === 'ArrowUp') setSpeed(S.speed + 5);
    else if (k === 'ArrowDown') setSpeed(S.speed - 5);
    else if (k === '0') setSpeed(0);
    else if (k === 'Home') setArc(0);
    else if (k === 'End') setArc(arcMax());
    else if (k === 'd' || k === 'D') toggleDirection();
    else if (k === 'q' || k === 'Q') setRoll(S.roll - (ev.shiftKey ? 5 : 15));
    else if (k === 'e' || k === 'E') setRoll(S.roll + (ev.shiftKey ? 5 : 15));
    else if (k === 'r' || k === 'R') setRoll(0);
    else if (k === 'f' || k === 'F') toggleMode();
    else if (k === 'm' || k === 'M') setMeasuring(!S.measuring);
    else if (k === 'n' || k === 'N') nextMissed();
    else if (k === 'b' || k === 'B') saveBookmark();
    else if (k === 's' || k === 'S') screenshot();
    else if (k === '.') findings.next();
    else if (k === ',') findings.previous();
    else if (k === 'a' || k === 'A') findings.accept();
    else if (k === 'x' || k === 'X') findings.reject();
    else if (k === 'Escape') { S.marker = null; S.picks = []; drawOverlay(); }
    else handled = false;
    if (handled) ev.preventDefault();
  });
}

// ---------------------------------------------------------------- the study document

/** The CT slices and their controls, or the note that the study has no CT. */
function showCt(on) {
  $('#ct-missing').hidden = on;
  $('#slices').hidden = !on;
  $('#ct-controls').hidden = !on;
}

/** Fills the view size menu (up to the study's max_px, with its default); returns the sizes. */
function fillPxSizes(study) {
  const maxPx = study.max_px || study.default_px || 512;
  const sizes = [...new Set([256, 384, 512, 640, 768, 1024, study.default_px].filter((v) => v && v <= maxPx))].sort((a, b) => a - b);
  const sel = $('#px');
  if (sel.dataset.sizes !== sizes.join(',')) {
    sel.textContent = '';
    for (const v of sizes) {
      const o = document.createElement('option');
      o.value = String(v); o.textContent = String(v);
      sel.appendChild(o);
    }
    sel.dataset.sizes = sizes.join(',');
  }
  return sizes;
}

/** Applies a study document (/api/study): at start (first) and again at each new revision the
 *  server swaps in. The pose is kept (the arc clamped to the new path) and its pair, the slices
 *  and the overview are asked for again. */
function applyStudy(study, first) {
  const prev = S.study;
  S.study = study;
  S.gen += 1; // the frame on screen is of the old document: pumpPair asks for it again
  document.body.dataset.revision = String(study.revision);
  if (first) {
    S.clip = Number.isFinite(study.clip_offset_fraction) ? study.clip_offset_fraction : 0.5;
    $('#clip').value = String(S.clip);
    overviewPx = Math.min(768, Math.max(256, Math.round(370 * (window.devicePixelRatio || 1))));
  }
  const arc = $('#arc');
  arc.max = String(study.arc_max_mm);
  arc.step = String(study.step_mm || 1);
  $('#arc-max').textContent = Number(study.arc_max_mm).toFixed(0);
  $('#arc-input').max = String(study.arc_max_mm);
  const sizes = fillPxSizes(study);
  if (first || !sizes.includes(S.px)) S.px = study.default_px || sizes[sizes.length - 1];
  $('#px').value = String(S.px);

  const hadCt = !!(prev && prev.has_ct && prev.ct);
  const hasCt = !!(study.has_ct && study.ct);
  showCt(hasCt);
  if (hasCt && !hadCt) {
    setWindowLevel(Number(study.ct.default_window) || S.window, Number.isFinite(study.ct.default_level) ? study.ct.default_level : S.level);
  }
  for (const plane of PLANES) slices[plane].shownKey = null; // the CT may be another one now

  if (prev && JSON.stringify(prev.missed_regions || []) !== JSON.stringify(study.missed_regions || [])) {
    currentMissed = null; // region ids are positions in the list: they name other regions now
    $('#missed-list').dataset.currentId = '';
  }
  renderMissed();

  if (first) setPose({ arc_mm: 0 });
  else setPose({ arc_mm: S.arc }, { keepMarker: true });
  const cl = study.centerline || [];
  if (hasCt && S.cursor) reloadSlices();
  else if (hasCt && cl.length) setCursor(cl[clamp(Math.round(S.arc / (study.step_mm || 1)), 0, cl.length - 1)]);
  maybeOverview(true);
}

const studySummary = (study) => `${Number(study.length_mm).toFixed(0)} mm of centerline, ${(study.missed_regions || []).length} missed region(s)`;

// ---------------------------------------------------------------- live study

const WAIT_POLL_MS = 1000; // /api/status while no study is served yet
const LIVE_POLL_MS = 2000; // /api/status once the page shows a study
const sleep = (ms) => new Promise((ok) => setTimeout(ok, ms));
let lastReloadError = '';

const stagesDone = (st) => ((st.stages || []).length ? `stages done: ${st.stages.join(', ')}` : 'no stage done yet');

/** The header's unobtrusive mark while a flyover run holds the study's lock. */
function showRunState(st) {
  const on = !!(st && st.computing);
  const el = $('#run-state');
  el.hidden = !on;
  el.textContent = on ? `run in progress: ${stagesDone(st)}` : '';
  el.title = on ? 'flyover run is still working on this study; the page picks up what it writes' : '';
  document.body.dataset.computing = String(on);
}

/** The notice over the views while no study is served ('' hides it). */
function showNotice(text, state = 'computing') {
  const n = $('#notice');
  n.hidden = !text;
  n.textContent = text;
  n.dataset.state = text ? state : '';
}

/** Says why no study is served yet (status with ready false). */
function showNotReady(st) {
  const waiting = st.waiting_for || [];
  let text;
  let state;
  if (st.loading) {
    text = 'Loading the study…';
    state = 'loading';
  } else if (st.computing) {
    text = `The study is being computed by flyover run: waiting for ${waiting.length ? waiting.join(', ') : 'its files'} — ${stagesDone(st)}`;
    state = 'computing';
  } else {
    text = st.error ? `The study cannot be shown: ${st.error}`
      : `The run ended without making ${waiting.length ? waiting.join(', ') : 'what the viewer needs'}`;
    state = 'error';
  }
  document.body.dataset.state = state;
  setStatus(text, state);
  showNotice(text, state);
}

/** Polls /api/status until the server serves a study (a complete study is served at once:
 *  its requests wait for its load); returns the status, or null when the token is refused. */
async function waitUntilReady() {
  for (;;) {
    try {
      const st = await apiJson('/api/status');
      showRunState(st);
      if (st.ready) return st;
      showNotReady(st);
    } catch (e) {
      reportError(e);
      if (e instanceof ApiError && (e.status === 401 || e.status === 403)) return null;
    }
    await sleep(WAIT_POLL_MS);
  }
}

/** Once a study is shown: follows the run's state and swaps in each new revision. */
async function pollLive() {
  try {
    const st = await apiJson('/api/status');
    showRunState(st);
    const err = st.error || '';
    if (err && err !== lastReloadError) {
      setStatus(`Reloading the study failed: ${err} (still showing revision ${S.study.revision})`, 'error');
    }
    lastReloadError = err;
    if (st.ready && st.revision !== S.study.revision) {
      const study = await apiJson('/api/study');
      if (study.revision !== S.study.revision) {
        applyStudy(study, false);
        setStatus(`Study updated: revision ${study.revision} (${studySummary(study)})`, 'loading');
      }
    }
  } catch (e) { reportError(e); }
  setTimeout(pollLive, LIVE_POLL_MS);
}

// ---------------------------------------------------------------- start

async function start() {
  bind();
  setSpeed(S.speed);
  if (!token) {
    setStatus('No token: open the exact URL that `flyover view` printed (…/?token=…)', 'error');
    return;
  }
  let study = null;
  while (!study) {
    if (!(await waitUntilReady())) return;
    try {
      study = await apiJson('/api/study');
    } catch (e) {
      // 503: no study served after all (the status changed in between): wait again
      if (!(e instanceof ApiError) || e.status !== 503) { reportError(e); return; }
      await sleep(WAIT_POLL_MS);
    }
  }
  showNotice('');
  applyStudy(study, true);
  document.body.dataset.state = 'ready';
  document.body.dataset.ready = 'true';
  setStatus(`Study: ${studySummary(study)}`, 'loading');
  loadBookmarks();
  findings.load();
  setTimeout(pollLive, LIVE_POLL_MS);
}

// Read-only view of the state for debugging from the console.
window.flyover = { get state() { return JSON.parse(JSON.stringify({ ...S, study: undefined })); } };

start();
