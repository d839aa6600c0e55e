// flyover view: the candidates of the polyps stage and the reader's findings (findings.json).
//
// The list shows each candidate's size, segment and score, best score first; previous / next
// walk it and fly to each one; Accept and Reject review the current candidate with the size in
// the size field (filled from the candidate, or by the two-click measure). A finding is added by
// hand at the last picked wall point. Candidates and findings are marked in the fly-over views
// where their point projects into a view's cameras (from the pose the server sends with the
// pair) and on the overview (drawn by the server, /api/overview?findings=1), coloured by status.
// Everything goes through /api/findings (docs/viewer.md).

'use strict';

const $ = (sel) => document.querySelector(sel);
const COLOURS = { unreviewed: '#4ad1ff', accepted: '#6bd68b', rejected: '#9a9a9a', hand: '#ff9f43' };
const MARK_MAX_DEPTH_MM = 90; // farther points are not marked (they would be hidden by the wall anyway)

/** Where a world point falls in a camera's px x px image, or null (behind it, out of frame, too far). */
function project(cam, p, px) {
  const d = [p[0] - cam.position_mm[0], p[1] - cam.position_mm[1], p[2] - cam.position_mm[2]];
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const z = dot(d, cam.forward);
  if (!(z > 1) || z > MARK_MAX_DEPTH_MM) return null;
  const t = Math.tan((cam.fov_deg * Math.PI) / 360);
  const x = ((dot(d, cam.right) / (z * t) + 1) / 2) * px;
  const y = ((1 - dot(d, cam.up) / (z * t)) / 2) * px;
  if (x < 0 || y < 0 || x > px || y > px) return null;
  return [x, y];
}

/** The panel. `app` gives what it needs of the page: apiJson, flyToPoint, setStatus, reportError,
 *  redraw (the views' overlay). */
export function findingsPanel(app) {
  const F = { candidates: [], findings: [], current: -1, picked: null, error: '' };

  const sizeInput = $('#finding-size');
  const sizeValue = () => {
    const v = Number(sizeInput.value);
    return sizeInput.value !== '' && Number.isFinite(v) && v > 0 ? v : null;
  };
  const post = (path, body) => app.apiJson(path, {}, {
    method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(body),
  });

  function render() {
    const list = $('#candidate-list');
    list.textContent = '';
    const n = F.candidates.length;
    const reviewed = F.candidates.filter((c) => c.status !== 'unreviewed').length;
    $('#candidate-count').textContent = n ? `${reviewed} of ${n} reviewed` : 'none';
    const err = $('#findings-error');
    err.hidden = !F.error;
    err.textContent = F.error;
    F.candidates.forEach((c, i) => {
      const li = document.createElement('li');
      li.dataset.id = c.id;
      li.dataset.status = c.status;
      li.classList.toggle('current', i === F.current);
      const b = document.createElement('button');
      b.className = 'go';
      b.textContent = `${c.id}: ${Number(c.size_mm).toFixed(1)} mm, ${c.segment.replace(/_/g, ' ') || '?'}, score ${Number(c.score).toFixed(2)}`;
      b.title = `${c.morphology}, arc ${Number(c.arc_mm).toFixed(0)} mm`;
      b.addEventListener('click', () => select(i));
      const st = document.createElement('span');
      st.className = 'status';
      st.textContent = c.status;
      li.append(b, st);
      list.appendChild(li);
    });
    $('#candidate-prev').disabled = n === 0;
    $('#candidate-next').disabled = n === 0;
    $('#candidate-accept').disabled = F.current < 0;
    $('#candidate-reject').disabled = F.current < 0;
    const cur = F.candidates[F.current];
    $('#candidate-current').textContent = cur ? `${cur.id} (${cur.status})` : '';
    $('#candidate-current').dataset.id = cur ? cur.id : '';
    renderFindings();
    app.redraw();
  }

  function renderFindings() {
    const list = $('#finding-list');
    list.textContent = '';
    for (const f of F.findings) {
      const li = document.createElement('li');
      li.dataset.id = f.id;
      li.dataset.source = f.source;
      li.dataset.status = f.status;
      li.dataset.sizeMm = String(f.size_mm);
      const go = document.createElement('button');
      go.className = 'go';
      go.textContent = `${f.id} ${f.source === 'hand' ? 'by hand' : f.candidate_id}: ${Number(f.size_mm).toFixed(1)} mm, `
        + `${(f.segment || '?').replace(/_/g, ' ')}, ${f.status}`;
      go.addEventListener('click', () => app.flyToPoint(f.position_mm, `finding ${f.id}`).catch(app.reportError));
      const del = document.createElement('button');
      del.className = 'delete';
      del.textContent = '✕';
      del.title = 'delete this finding (a candidate is then unreviewed again)';
      del.addEventListener('click', () => remove(f.id));
      li.append(go, del);
      list.appendChild(li);
    }
    $('#finding-add').disabled = !F.picked;
  }

  async function load() {
    try {
      const r = await app.apiJson('/api/findings');
      const curId = F.candidates[F.current] ? F.candidates[F.current].id : null;
      F.candidates = r.candidates || [];
      F.findings = r.findings || [];
      F.error = r.error || '';
      F.current = curId ? F.candidates.findIndex((c) => c.id === curId) : -1;
      render();
      // The overview marks them too (server-drawn): ask for a new one when what it marks changed.
      const marks = JSON.stringify([F.candidates.map((c) => [c.id, c.status]), F.findings.map((f) => [f.id, f.status, f.size_mm])]);
      if (marks !== F.marks) { F.marks = marks; if (app.marksChanged) app.marksChanged(); }
    } catch (e) { app.reportError(e); }
  }

  async function select(i) {
    if (!F.candidates.length) return;
    F.current = ((i % F.candidates.length) + F.candidates.length) % F.candidates.length;
    const c = F.candidates[F.current];
    const f = F.findings.find((x) => x.source === 'candidate' && x.candidate_id === c.id);
    sizeInput.value = String(Number((f ? f.size_mm : c.size_mm).toFixed(1)));
    render();
    try { await app.flyToPoint(c.centroid_mm, `candidate ${c.id}`); } catch (e) { app.reportError(e); }
  }

  async function review(status) {
    const c = F.candidates[F.current];
    if (!c) { app.setStatus('choose a candidate first (previous / next)', 'error'); return; }
    const body = { candidate_id: c.id, status };
    if (sizeValue() !== null) body.size_mm = sizeValue();
    try {
      const r = await post('/api/findings/review', body);
      app.setStatus(`candidate ${c.id} ${status} as ${r.finding.id}, ${Number(r.finding.size_mm).toFixed(1)} mm`);
      await load();
    } catch (e) { app.reportError(e); }
  }

  async function addByHand() {
    if (!F.picked) { app.setStatus('pick a wall point on a view first', 'error'); return; }
    const size = sizeValue();
    if (size === null) { app.setStatus('size: measure the finding (two clicks) or type its size in mm', 'error'); return; }
    try {
      const r = await post('/api/findings/hand', {
        position_mm: F.picked, size_mm: size, morphology: $('#finding-morphology').value,
      });
      app.setStatus(`finding ${r.finding.id} added by hand: ${size.toFixed(1)} mm, ${r.finding.segment || 'no segment'}`);
      await load();
    } catch (e) { app.reportError(e); }
  }

  async function remove(id) {
    try {
      await app.apiJson('/api/findings', { id }, { method: 'DELETE' });
      await load();
    } catch (e) { app.reportError(e); }
  }

  /** Marks the candidates and findings that project into the views of the frame on screen. */
  function draw(ctx, h, gap, shown) {
    if (!shown || !shown.pose || !Array.isArray(shown.pose.cameras)) return;
    const px = shown.params.px;
    const s = h / px;
    const points = F.candidates.map((c, i) => ({ p: c.centroid_mm, label: c.id, colour: COLOURS[c.status] || COLOURS.unreviewed, current: i === F.current }));
    for (const f of F.findings) {
      if (f.source === 'hand') points.push({ p: f.position_mm, label: f.id, colour: COLOURS.hand, current: false });
    }
    ctx.save();
    ctx.font = `${Math.max(11, Math.round(h / 40))}px sans-serif`;
    ctx.lineWidth = Math.max(2, h / 300);
    shown.pose.cameras.forEach((cam, view) => {
      for (const m of points) {
        const at = project(cam, m.p, px);
        if (!at) continue;
        const x = view * (h + gap) + at[0] * s;
        const y = at[1] * s;
        const r = Math.max(8, h / 28) * (m.current ? 1.4 : 1);
        ctx.strokeStyle = m.colour;
        ctx.fillStyle = m.colour;
        ctx.setLineDash(m.current ? [] : [5, 3]);
        ctx.beginPath(); ctx.arc(x, y, r, 0, 2 * Math.PI); ctx.stroke();
        ctx.fillText(m.label, x + r + 2, y - r);
      }
    });
    ctx.restore();
  }

  $('#candidate-prev').addEventListener('click', () => select(F.current < 0 ? F.candidates.length - 1 : F.current - 1));
  $('#candidate-next').addEventListener('click', () => select(F.current + 1));
  $('#candidate-accept').addEventListener('click', () => review('accepted'));
  $('#candidate-reject').addEventListener('click', () => review('rejected'));
  $('#finding-add').addEventListener('click', addByHand);
  sizeInput.addEventListener('keydown', (e) => { if (e.key === 'Enter') e.target.blur(); });

  return {
    load,
    draw,
    next: () => select(F.current + 1),
    previous: () => select(F.current < 0 ? F.candidates.length - 1 : F.current - 1),
    accept: () => review('accepted'),
    reject: () => review('rejected'),
    /** A wall point picked on a view: where a finding by hand goes. */
    picked(point) { F.picked = point; $('#finding-add').disabled = false; $('#finding-add').dataset.pointMm = JSON.stringify(point); },
    /** A two-click measure: the size of the finding being reviewed. */
    measured(mm) { sizeInput.value = String(Number(mm.toFixed(1))); },
  };
}
