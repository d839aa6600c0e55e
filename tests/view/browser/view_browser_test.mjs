// Browser test of the `flyover view` page: Debian's chromium driven by playwright-core.
//
//   node view_browser_test.mjs --flyover BIN --study DIR --truth TRUTH.json [--screenshot OUT.png]
//                              [--chromium PATH] [--keep-open]
//
// Starts `flyover view --study DIR --port 0`, opens the printed URL and uses the page as a
// person would: plays, flips Left/Right, rolls (buttons, keys, drag), steps, switches to the
// fly-through, saves a bookmark and finds it after a reload, takes a screenshot, clicks a truth
// polyp in a fly-over view and checks where the CT crosshair lands, clicks a polyp centre in a
// CT slice and checks that the fly-over shows it, measures, jumps from the overview and to the
// next missed region, walks the polyp candidates (accept with an edited size, reject), adds a
// finding by hand at a picked point and finds them all after a reload, and shows the CT slices
// as large as the views. Every check says what it expected and what it saw.
//
// Exit codes: 0 pass, 1 fail, 77 skipped (no chromium; CTest's SKIP_RETURN_CODE).

import fs from 'node:fs';
import path from 'node:path';

import {
  apiOf, check, CheckFailed, chromiumOrSkip, finish, launchBrowser, loadPlaywrightChromium, log, parseArgs, sleep,
  Viewer,
} from './harness.mjs';

const args = parseArgs(process.argv.slice(2),
  { name: 'view_browser_test', values: ['flyover', 'study', 'truth', 'screenshot'], required: ['flyover', 'study', 'truth'] });
const chromiumPath = chromiumOrSkip(args.chromium);
const chromium = await loadPlaywrightChromium('view_browser_test');

// ---------------------------------------------------------------- checks

const dist = (a, b) => Math.hypot(a[0] - b[0], a[1] - b[1], a[2] - b[2]);
const fmtP = (p) => `(${p.map((v) => Number(v).toFixed(2)).join(', ')})`;

// Slice mapping as the server states it in X-Flyover-Slice ("rule"): the centre of pixel (c, r) is
// origin_mm + c * pixel_mm * col_dir + r * pixel_mm * row_dir (written here independently of the page).
function pixelMm(m) { return Array.isArray(m.pixel_mm) ? m.pixel_mm : [m.pixel_mm, m.pixel_mm]; }
function sliceToWorld(m, col, row) {
  const [pc, pr] = pixelMm(m);
  return [0, 1, 2].map((i) => m.origin_mm[i] + col * pc * m.col_dir[i] + row * pr * m.row_dir[i]);
}
function worldToSlice(m, p) {
  const [pc, pr] = pixelMm(m);
  const d = [0, 1, 2].map((i) => p[i] - m.origin_mm[i]);
  return [(d[0] * m.col_dir[0] + d[1] * m.col_dir[1] + d[2] * m.col_dir[2]) / pc,
    (d[0] * m.row_dir[0] + d[1] * m.row_dir[1] + d[2] * m.row_dir[2]) / pr];
}

// ---------------------------------------------------------------- the server

const truth = JSON.parse(fs.readFileSync(args.truth, 'utf8'));
const viewer = new Viewer(args.flyover, args.study);

// The candidates the page lists: the polyps stage's when the study has them, else the truth's
// largest polyps written as polyps/candidates.json (flyover.polyps/1). findings.json starts empty.
const candFile = path.join(args.study, 'polyps', 'candidates.json');
const findingsFile = path.join(args.study, 'findings.json');
function candidatesFixture() {
  if (fs.existsSync(candFile)) return;
  const cl = JSON.parse(fs.readFileSync(path.join(args.study, 'centerline.json'), 'utf8'));
  const seg = (arc) => (cl.segment || [])[Math.max(0, Math.min(cl.point_count - 1, Math.round(arc / cl.step_mm)))] || 'sigmoid';
  const list = (truth.polyps || []).filter((p) => p.arc_mm > 30).sort((a, b) => b.radius_mm - a.radius_mm).slice(0, 3)
    .map((p, i) => ({
      id: `c${i + 1}`, centroid_mm: p.center_mm, size_mm: Number((2 * p.radius_mm).toFixed(1)), height_mm: p.radius_mm,
      volume_mm3: 2.1 * p.radius_mm ** 3, morphology: 'sessile', arc_mm: p.arc_mm, segment: seg(p.arc_mm),
      score: Number((0.9 - 0.1 * i).toFixed(2)), pose: null,
    }));
  fs.mkdirSync(path.dirname(candFile), { recursive: true });
  fs.writeFileSync(candFile, JSON.stringify({ schema: 'flyover.polyps/1', world_frame: 'LPS', candidates: list }, null, 1));
}
candidatesFixture();
fs.rmSync(findingsFile, { force: true });

// ---------------------------------------------------------------- the test

let browser = null;
let srv = null;
let failure = null;
const pageErrors = [];
let apiJson = null; // GET of a JSON endpoint, 200 expected (apiOf)

async function run() {
  srv = await viewer.start();
  apiJson = apiOf(srv).getJson;
  log(`server: ${srv.url.replace(srv.token, '…')}`);
  browser = await launchBrowser(chromium, chromiumPath);
  log(`chromium ${browser.version()}`);
  const context = await browser.newContext({ viewport: { width: 1600, height: 1000 }, acceptDownloads: true });
  const page = await context.newPage();
  page.on('pageerror', (e) => pageErrors.push(`page error: ${e.message}`));
  page.on('console', (m) => { if (m.type() === 'error') pageErrors.push(`console error: ${m.text()}`); });

  // One /api/pair in flight at a time, counted from the network.
  let pairInFlight = 0;
  let pairMaxInFlight = 0;
  let pairRequests = 0;
  const isPair = (r) => new URL(r.url()).pathname === '/api/pair';
  page.on('request', (r) => { if (isPair(r)) { pairRequests += 1; pairInFlight += 1; pairMaxInFlight = Math.max(pairMaxInFlight, pairInFlight); } });
  const pairDone = (r) => { if (isPair(r)) pairInFlight -= 1; };
  page.on('requestfinished', pairDone);
  page.on('requestfailed', pairDone);

  const study = await apiJson('/api/study');
  check(study.world_frame === 'LPS', '/api/study world_frame', '"LPS"', JSON.stringify(study.world_frame));
  check(study.arc_max_mm > 100, '/api/study arc_max_mm', '> 100 mm', study.arc_max_mm);

  // ---- load
  const ready = async () => {
    await page.waitForSelector('body[data-ready="true"]', { timeout: 30000 });
    await page.waitForFunction(() => Number(document.querySelector('#views').dataset.frames || 0) >= 1, null, { timeout: 60000 });
  };
  await page.goto(srv.url);
  await ready();
  check(await page.title() === 'flyover view', 'page title', '"flyover view"', await page.title());
  const status0 = await page.getAttribute('#status', 'data-state');
  check(status0 !== 'error', 'status after loading', 'no error', `${status0}: ${await page.textContent('#status')}`);
  log('page loaded, first frame shown');

  const viewsData = () => page.$eval('#views', (v) => ({ ...v.dataset }));
  // Waits until the frame on screen satisfies pred(dataset).
  const waitFrame = async (what, pred, timeout = 30000) => {
    const deadline = Date.now() + timeout;
    for (;;) {
      const d = await viewsData();
      if (pred(d)) return d;
      if (Date.now() > deadline) throw new CheckFailed(`${what}: the frame on screen never matched; last ${JSON.stringify(d)}`);
      await sleep(50);
    }
  };
  const near = (a, b, tol = 0.05) => Math.abs(Number(a) - Number(b)) <= tol;
  const nearAngle = (a, b, tol = 0.06) => Math.abs(((Number(a) - Number(b)) % 360 + 540) % 360 - 180) <= tol;

  // ---- play forward, pause
  await page.keyboard.press('0');
  for (let i = 0; i < 6; i++) await page.keyboard.press('ArrowUp'); // 30 mm/s
  check(await page.textContent('#speed-value') === '30 mm/s', 'speed dial after 0 and six ↑', '30 mm/s', await page.textContent('#speed-value'));
  const before = await viewsData();
  await page.click('#play');
  check(await page.getAttribute('#play', 'data-playing') === 'true', 'play button state', 'playing', 'paused');
  await sleep(2500);
  await page.click('#play');
  await sleep(300);
  await page.waitForFunction(() => document.querySelector('#views').dataset.loading === 'false');
  const played = await viewsData();
  const playedFrames = Number(played.frames) - Number(before.frames);
  check(Number(played.arcMm) > Number(before.arcMm) + 5, 'arc after playing 2.5 s forward at 30 mm/s',
    `> ${Number(before.arcMm) + 5} mm`, `${played.arcMm} mm`);
  check(playedFrames >= 3, 'frames shown while playing 2.5 s', '>= 3', playedFrames);
  check(pairMaxInFlight === 1, '/api/pair requests in flight at once', '1', pairMaxInFlight);
  const pose = JSON.parse(played.pose || 'null');
  check(pose && near(pose.arc_mm, played.arcMm, 0.01), 'X-Flyover-Pose arc_mm of the last frame', played.arcMm, pose && pose.arc_mm);
  // Paused at the frame on screen: the arc readout is that frame's arc, not playback's
  // unrounded one (from which a step forward and back could land on the next frame).
  check(near(await page.inputValue('#arc-input'), played.arcMm, 1e-9), 'arc readout after pausing (the frame on screen)',
    played.arcMm, await page.inputValue('#arc-input'));
  log(`played: arc ${before.arcMm} -> ${played.arcMm} mm, ${playedFrames} frames, at most ${pairMaxInFlight} /api/pair in flight`);

  // ---- Left: forward now runs towards the rectum
  await page.click('#direction');
  check(await page.textContent('#direction') === 'Left', 'direction button after a click', 'Left', await page.textContent('#direction'));
  const left = await waitFrame('direction left', (d) => d.direction === 'left');
  check(JSON.parse(left.pose).direction === 'left', 'X-Flyover-Pose direction', 'left', JSON.parse(left.pose).direction);
  await page.click('#play');
  await sleep(1500);
  await page.click('#play');
  await page.waitForFunction(() => document.querySelector('#views').dataset.loading === 'false');
  const leftPlayed = await viewsData();
  check(Number(leftPlayed.arcMm) < Number(left.arcMm) - 3, 'arc after playing 1.5 s with Left', `< ${Number(left.arcMm) - 3} mm`, `${leftPlayed.arcMm} mm`);
  check(near(await page.inputValue('#arc-input'), leftPlayed.arcMm, 1e-9), 'arc readout after pausing with Left',
    leftPlayed.arcMm, await page.inputValue('#arc-input'));
  await page.keyboard.press('d');
  await waitFrame('direction right (key D)', (d) => d.direction === 'right');
  log(`Left: arc ${left.arcMm} -> ${leftPlayed.arcMm} mm; back to Right with D`);

  // ---- step and keys
  const s0 = Number((await viewsData()).arcMm);
  await page.keyboard.press('ArrowRight');
  const s1 = await waitFrame('step forward (→)', (d) => Number(d.arcMm) > s0 + 0.5);
  await page.click('#step-back');
  await waitFrame('step back (button)', (d) => near(d.arcMm, s0, 0.01));
  log(`step: ${s0} -> ${s1.arcMm} -> ${s0} mm`);

  // ---- roll: buttons, keys, drag
  await page.click('#roll-right');
  await waitFrame('roll +15 (button)', (d) => near(d.rollDeg, 15));
  await page.keyboard.press('e');
  await waitFrame('roll +30 (key E)', (d) => near(d.rollDeg, 30));
  await page.keyboard.press('q');
  await waitFrame('roll +15 (key Q)', (d) => near(d.rollDeg, 15));
  const box = await page.locator('#pair').boundingBox();
  const pickBefore = await page.getAttribute('#pick-info', 'data-point-mm');
  await page.mouse.move(box.x + box.width * 0.25, box.y + box.height * 0.5);
  await page.mouse.down();
  for (let i = 1; i <= 10; i++) await page.mouse.move(box.x + box.width * 0.25 + i * 12, box.y + box.height * 0.5);
  await page.mouse.up();
  const dragged = await waitFrame('roll by dragging', (d) => !near(d.rollDeg, 15, 1) && d.loading === 'false');
  check(await page.getAttribute('#pick-info', 'data-point-mm') === pickBefore, 'a drag does not pick', 'no pick', 'a pick');
  await page.keyboard.press('r');
  await waitFrame('roll reset (key R)', (d) => near(d.rollDeg, 0));
  log(`roll: 15, 30, 15, drag -> ${dragged.rollDeg}, reset 0`);

  // ---- fly-through and back
  await page.keyboard.press('f');
  await waitFrame('fly-through (key F)', (d) => d.mode === 'flythrough');
  await page.click('#mode');
  await waitFrame('fly-over (checkbox)', (d) => d.mode === 'flyover');
  log('fly-through and back');

  // ---- the truth polyps, most visible first (largest radius, away from the ends)
  const polyps = (truth.polyps || [])
    .filter((p) => p.arc_mm > 30 && p.arc_mm < study.arc_max_mm - 30)
    .sort((a, b) => b.radius_mm - a.radius_mm);
  check(polyps.length >= 2, 'truth polyps away from the ends', '>= 2', polyps.length);

  // The pose that shows polyp A, taken to through the page's own controls.
  const A = polyps[0];
  const locA = await apiJson('/api/locate', { x_mm: A.center_mm[0], y_mm: A.center_mm[1], z_mm: A.center_mm[2] });
  const curDir = await page.getAttribute('#direction', 'data-direction');
  if (curDir !== locA.direction) await page.click('#direction');
  await page.fill('#roll', String(Number(locA.roll_deg).toFixed(1)));
  await page.press('#roll', 'Enter');
  await page.fill('#arc-input', String(Number(locA.arc_mm).toFixed(2)));
  await page.press('#arc-input', 'Enter');
  await page.locator('#pair').focus().catch(() => {});
  const atA = await waitFrame('pose of polyp A', (d) => near(d.arcMm, locA.arc_mm, 0.01) && nearAngle(d.rollDeg, locA.roll_deg)
    && d.direction === locA.direction && d.loading === 'false');
  const pxShown = Number(atA.px);
  const k = pxShown / Number(locA.px);
  // The pair image is view 0 | separator | view 1, each view px x px (the server puts a few
  // pixels between them, as in frames/pair_NNNN.png); the canvas shows it scaled to its box.
  const pairBox = await page.locator('#pair').boundingBox();
  const [pairW, pairH] = await page.$eval('#pair', (c) => [c.width, c.height]);
  check(pairH === pxShown && pairW >= 2 * pxShown && pairW <= 2 * pxShown + 16, 'pair image size',
    `${2 * pxShown} (+ separator) x ${pxShown}`, `${pairW} x ${pairH}`);
  const gap = pairW - 2 * pxShown;
  const toScreen = (view, x, y) => [pairBox.x + ((view * (pxShown + gap) + x * k) / pairW) * pairBox.width,
    pairBox.y + ((y * k) / pairH) * pairBox.height];

  // ---- click polyp A in the fly-over view -> the CT crosshair lands on it
  const cursorBefore = await page.getAttribute('#ct', 'data-cursor-mm');
  const [cx, cy] = toScreen(Number(locA.view), Number(locA.x), Number(locA.y));
  await page.mouse.click(cx, cy);
  await page.waitForFunction((prev) => document.querySelector('#ct').dataset.cursorMm !== prev, cursorBefore, { timeout: 20000 });
  const picked = JSON.parse(await page.getAttribute('#pick-info', 'data-point-mm'));
  check(dist(picked, A.center_mm) <= A.radius_mm + 1.0, 'picked point on polyp A (distance to the true centre)',
    `<= ${(A.radius_mm + 1).toFixed(1)} mm (radius + 1 mm surface tolerance)`, `${dist(picked, A.center_mm).toFixed(2)} mm`);
  if (study.has_ct) {
    const cross = await waitCrosshairs(page, picked);
    for (const [plane, p] of Object.entries(cross)) {
      const d = dist(p, A.center_mm);
      check(d <= A.radius_mm + 1.0, `${plane} crosshair on polyp A (distance of its LPS point to the true centre)`,
        `<= ${(A.radius_mm + 1).toFixed(1)} mm`, `${d.toFixed(2)} mm at ${fmtP(p)}`);
      check(Math.abs(d - A.radius_mm) <= 1.5, `${plane} crosshair on polyp A's surface: | |p - centre| - radius |`,
        '<= 1.5 mm', `${Math.abs(d - A.radius_mm).toFixed(2)} mm`);
      check(dist(p, picked) <= 0.05, `${plane} crosshair at the picked point`, fmtP(picked), fmtP(p));
    }
    log(`polyp A (r ${A.radius_mm} mm): picked ${dist(picked, A.center_mm).toFixed(2)} mm from the centre; crosshairs `
      + Object.entries(cross).map(([pl, p]) => `${pl} ${dist(p, A.center_mm).toFixed(2)} mm`).join(', '));
  }

  // ---- measure: two clicks on the same view
  await page.keyboard.press('m');
  check(await page.getAttribute('#measure', 'data-active') === 'true', 'measure mode (key M)', 'on', 'off');
  const m0 = [Number(locA.x), Number(locA.y)];
  const m1 = [clampPx(Number(locA.x) + 25 / k, locA.px), clampPx(Number(locA.y) + 10 / k, locA.px)];
  const pickApi = async (x, y) => apiJson('/api/pick', {
    arc_mm: atA.arcMm, roll_deg: atA.rollDeg, direction: atA.direction, mode: atA.mode, px: pxShown, view: locA.view,
    x: (x * k).toFixed(1), y: (y * k).toFixed(1),
  });
  const e0 = await pickApi(...m0);
  const e1 = await pickApi(...m1);
  if (e0.hit && e1.hit) {
    await page.mouse.click(...toScreen(Number(locA.view), ...m0));
    await page.waitForFunction(() => /second/.test(document.querySelector('#measure-result').textContent));
    await page.mouse.click(...toScreen(Number(locA.view), ...m1));
    await page.waitForFunction(() => document.querySelector('#measure-result').dataset.distanceMm !== '');
    const measured = Number(await page.getAttribute('#measure-result', 'data-distance-mm'));
    const expected = dist(e0.point_mm, e1.point_mm);
    check(Math.abs(measured - expected) < 0.5, 'measured distance against /api/pick of the same two pixels',
      `${expected.toFixed(2)} mm`, `${measured.toFixed(2)} mm`);
    const sizeField = Number(await page.inputValue('#finding-size'));
    check(Math.abs(sizeField - measured) <= 0.051, 'finding size field after measuring', `${measured.toFixed(1)} mm`, sizeField);
    log(`measure: ${measured.toFixed(2)} mm (API ${expected.toFixed(2)} mm)`);
  } else {
    log('measure: skipped (a measuring pixel missed the surface)');
  }
  await page.keyboard.press('m');

  // ---- click polyp B's centre in the axial CT slice -> the fly-over shows it, marked
  if (study.has_ct) {
    const B = polyps[1];
    await page.fill('#ct-point', B.center_mm.join(', '));
    await page.press('#ct-point', 'Enter');
    await waitCrosshairs(page, B.center_mm);
    const ax = await sliceInfo(page, 'axial');
    const [col, row] = worldToSlice(ax.map, B.center_mm);
    const inPlane = sliceToWorld(ax.map, col, row);
    check(dist(inPlane, B.center_mm) < 1.5, 'axial slice through polyp B (distance of the centre to the slice plane)',
      '< 1.5 mm', `${dist(inPlane, B.center_mm).toFixed(2)} mm`);
    const sx = ax.box.x + ax.r.x + (col + 0.5) * ax.r.k;
    const sy = ax.box.y + ax.r.y + (row + 0.5) * ax.r.k;
    const markBefore = (await viewsData()).markerKey || '';
    await page.mouse.click(sx, sy);
    const marked = await waitFrame('fly-over at the pose of the slice click', (d) => d.markerKey && d.markerKey !== markBefore
      && d.key === d.markerKey && d.loading === 'false');
    const loc = JSON.parse(marked.locate);
    const hit = await apiJson('/api/pick', {
      arc_mm: marked.arcMm, roll_deg: marked.rollDeg, direction: marked.direction, mode: marked.mode, px: loc.px,
      view: marked.markerView, x: marked.markerX, y: marked.markerY,
    });
    check(hit.hit === true, '/api/pick at the marked pixel', 'a hit', JSON.stringify(hit));
    const off = Math.abs(dist(hit.point_mm, B.center_mm) - B.radius_mm);
    check(off <= 1.0, 'marked pixel on polyp B: | |hit - centre| - radius |', '<= 1.0 mm (surface of the polyp)',
      `${off.toFixed(2)} mm (hit ${fmtP(hit.point_mm)}, radius ${B.radius_mm} mm)`);
    // the marker is drawn: the overlay has yellow pixels at the marked spot
    const drawn = await page.$eval('#pair-overlay', (c, m) => {
      const s = c.height / Number(m.px);
      const x = Math.round(Number(m.view) * (c.width - c.height) + Number(m.x) * s);
      const y = Math.round(Number(m.y) * s);
      const r = Math.ceil(Math.max(6, c.height / 40) * 3);
      const img = c.getContext('2d').getImageData(Math.max(0, x - r), Math.max(0, y - r), 2 * r, 2 * r).data;
      let n = 0;
      for (let i = 0; i < img.length; i += 4) if (img[i + 3] > 0) n += 1;
      return n;
    }, { view: marked.markerView, x: marked.markerX, y: marked.markerY, px: loc.px });
    check(drawn > 20, 'marker drawn on the overlay around the marked pixel', '> 20 painted pixels', drawn);
    log(`polyp B (r ${B.radius_mm} mm): axial click -> arc ${marked.arcMm} mm, view ${marked.markerView}; `
      + `pick at the marker ${dist(hit.point_mm, B.center_mm).toFixed(2)} mm from the centre`);
  }

  // ---- bookmark: save, reload, find, load, delete
  const note = `browser test ${process.pid} ${Date.now()}`;
  await page.keyboard.press('Escape');
  await page.fill('#arc-input', '123');
  await page.press('#arc-input', 'Enter');
  await page.click('#roll-right');
  const bmPose = await waitFrame('pose to bookmark', (d) => near(d.arcMm, 123, 0.01) && d.loading === 'false');
  await page.fill('#bookmark-note', note);
  await page.click('#bookmark-save');
  const liSel = `#bookmark-list li:has(.note:text-is("${note}"))`;
  await page.waitForSelector(liSel, { timeout: 10000 });
  const bmFile = path.join(args.study, 'bookmarks.json');
  check(fs.existsSync(bmFile) && fs.readFileSync(bmFile, 'utf8').includes(note), 'bookmarks.json in the study holds the note',
    'the note', fs.existsSync(bmFile) ? fs.readFileSync(bmFile, 'utf8').slice(0, 300) : 'no file');
  await page.reload();
  await ready();
  check(await page.locator(liSel).count() === 1, 'bookmark listed after a reload', '1 entry', await page.locator(liSel).count());
  await page.locator(`${liSel} button.load`).click();
  const loaded = await waitFrame('pose of the loaded bookmark', (d) => near(d.arcMm, 123, 0.01) && d.loading === 'false');
  check(near(loaded.rollDeg, bmPose.rollDeg, 0.05), 'roll of the loaded bookmark', bmPose.rollDeg, loaded.rollDeg);
  await page.locator(`${liSel} button.delete`).click();
  await page.waitForSelector(liSel, { state: 'detached', timeout: 10000 });
  check(!fs.readFileSync(bmFile, 'utf8').includes(note), 'bookmarks.json after deleting the bookmark', 'no note', 'the note');
  log('bookmark saved, found after a reload, loaded, deleted');

  // ---- screenshot
  await page.click('#screenshot');
  await page.waitForSelector('#screenshot-link:not([hidden])', { timeout: 30000 });
  const file = await page.getAttribute('#screenshot-link', 'data-file');
  const poseFile = await page.getAttribute('#screenshot-link', 'data-pose-file');
  const shot = path.join(args.study, file);
  check(fs.existsSync(shot), 'screenshot file in the study', shot, 'no file');
  check(fs.readFileSync(shot).subarray(1, 4).toString() === 'PNG', 'screenshot file format', 'PNG', fs.readFileSync(shot).subarray(0, 8).toString('hex'));
  const poseCandidates = [path.join(args.study, poseFile), path.join(path.dirname(shot), path.basename(poseFile))];
  const poseAt = poseCandidates.find((p) => fs.existsSync(p));
  check(!!poseAt, 'screenshot pose file', poseCandidates.join(' or '), 'no file');
  const shotPose = JSON.parse(fs.readFileSync(poseAt, 'utf8'));
  check(near(shotPose.arc_mm, 123, 0.01), 'arc_mm in the screenshot pose file', 123, shotPose.arc_mm);
  const href = await page.getAttribute('#screenshot-link', 'href');
  const dl = await page.evaluate(async (h) => {
    const r = await fetch(h);
    const b = new Uint8Array(await r.arrayBuffer());
    return { status: r.status, cd: r.headers.get('Content-Disposition'), magic: String.fromCharCode(...b.slice(1, 4)), n: b.length };
  }, href);
  check(dl.status === 200 && dl.magic === 'PNG', 'download link of the screenshot', '200 PNG', `${dl.status} ${dl.magic}`);
  check(/attachment/i.test(dl.cd || ''), 'Content-Disposition of the download', 'attachment', dl.cd);
  log(`screenshot ${file} (${dl.n} bytes), pose ${path.relative(args.study, poseAt)}`);

  // ---- overview: a click jumps to the nearest centerline point of the clicked colon pixel
  const ovPx = await page.$eval('#overview', (i) => i.naturalWidth);
  let target = null;
  for (let gy = 0.3; gy <= 0.7 && !target; gy += 0.05) {
    for (let gx = 0.2; gx <= 0.8 && !target; gx += 0.05) {
      const x = Math.floor(gx * ovPx);
      const y = Math.floor(gy * ovPx);
      const r = await apiJson('/api/overview/pick', { x, y, px: ovPx });
      if (r.hit && Math.abs(r.arc_mm - 123) > 20) target = { x, y, r };
    }
  }
  if (target) {
    // the panels below the overview (candidates, bookmarks) may have scrolled it out of sight
    await page.locator('#overview').scrollIntoViewIfNeeded();
    const ob = await page.locator('#overview').boundingBox();
    await page.mouse.click(ob.x + ((target.x + 0.5) / ovPx) * ob.width, ob.y + ((target.y + 0.5) / ovPx) * ob.height);
    const jumped = await waitFrame('jump from the overview', (d) => !near(d.arcMm, 123, 0.5) && d.loading === 'false');
    check(Math.abs(Number(jumped.arcMm) - target.r.arc_mm) <= 2, 'arc after clicking the overview',
      `${target.r.arc_mm} mm (±2)`, `${jumped.arcMm} mm`);
    await page.waitForFunction((a) => Math.abs(Number(document.querySelector('#overview').dataset.markerMm) - a) < 1,
      Number(jumped.arcMm), { timeout: 20000 });
    log(`overview click -> arc ${jumped.arcMm} mm (overview marker follows)`);
  } else {
    throw new CheckFailed('overview: expected a colon pixel in the middle of the overview, found none');
  }

  // ---- next missed region
  if ((study.missed_regions || []).length) {
    await page.fill('#arc-input', '0');
    await page.press('#arc-input', 'Enter');
    await waitFrame('start', (d) => near(d.arcMm, 0) && d.loading === 'false');
    await page.keyboard.press('n');
    const first = study.missed_regions.slice().sort((a, b) => a.arc_mm - b.arc_mm).find((r) => r.arc_mm > 1) || study.missed_regions[0];
    const want = await apiJson('/api/locate', {
      x_mm: first.centroid_mm[0], y_mm: first.centroid_mm[1], z_mm: first.centroid_mm[2], direction: 'right',
    });
    const at = await waitFrame('next missed region (key N)', (d) => near(d.arcMm, want.arc_mm, 0.01) && d.key === d.markerKey);
    log(`next missed region ${first.id}: arc ${at.arcMm} mm`);
  } else {
    log('next missed region: the study has none (button disabled)');
    check(await page.isDisabled('#next-missed'), 'next missed region button with no regions', 'disabled', 'enabled');
  }

  await findingsSteps(page, waitFrame, study);

  // ---- shortcuts listed on the page
  const shortcuts = await page.textContent('#shortcuts');
  for (const k of ['Space', 'play', 'roll', 'measure', 'missed', 'bookmark', 'screenshot']) {
    check(shortcuts.toLowerCase().includes(k.toLowerCase()), 'shortcut list', `mentions "${k}"`, shortcuts.slice(0, 200));
  }

  // ---- a picture of the page for the README
  if (args.screenshot) {
    await page.fill('#arc-input', String(Number(locA.arc_mm).toFixed(2)));
    await page.press('#arc-input', 'Enter');
    await page.fill('#goto', A.center_mm.map((v) => v.toFixed(1)).join(', '));
    await page.press('#goto', 'Enter');
    await page.waitForFunction(() => {
      const d = document.querySelector('#views').dataset;
      return d.markerKey && d.key === d.markerKey && d.loading === 'false';
    }, null, { timeout: 30000 });
    await page.setViewportSize({ width: 1440, height: 880 });
    await sleep(1500);
    const png = /\.png$/i.test(args.screenshot);
    await page.screenshot({ path: args.screenshot, type: png ? 'png' : 'jpeg', ...(png ? {} : { quality: 82 }) });
    log(`page picture: ${args.screenshot} (${fs.statSync(args.screenshot).size} bytes)`);
  }

  check(pairMaxInFlight === 1, '/api/pair requests in flight at once over the whole test', '1', pairMaxInFlight);
  log(`${pairRequests} /api/pair requests, never more than ${pairMaxInFlight} in flight`);
  const errs = pageErrors.filter((e) => !/favicon/.test(e));
  check(errs.length === 0, 'errors in the page console', 'none', errs.join(' | '));
}

/** Pixels of the overview image within 14 of `rgb` on every channel (the server draws findings' rings). */
async function overviewColour(page, rgb) {
  return page.$eval('#overview', (img, c) => {
    if (!img.naturalWidth) return 0;
    const cv = document.createElement('canvas');
    cv.width = img.naturalWidth; cv.height = img.naturalHeight;
    const ctx = cv.getContext('2d');
    ctx.drawImage(img, 0, 0);
    const d = ctx.getImageData(0, 0, cv.width, cv.height).data;
    let n = 0;
    for (let i = 0; i < d.length; i += 4) {
      if (Math.abs(d[i] - c[0]) <= 14 && Math.abs(d[i + 1] - c[1]) <= 14 && Math.abs(d[i + 2] - c[2]) <= 14) n += 1;
    }
    return n;
  }, rgb);
}

/** Waits until `pred(count)` holds for the overview's pixels of `rgb`; @return the last count. */
async function waitOverviewColour(page, rgb, pred, what) {
  let n = -1;
  for (let t = 0; t < 100; t += 1) {
    n = await overviewColour(page, rgb);
    if (pred(n)) return n;
    await page.waitForTimeout(200);
  }
  throw new CheckFailed(`${what}: overview pixels of rgb(${rgb}) gave ${n} after 20 s`);
}

/** Candidates: the list, next, accept with an edited size, reject; a finding by hand at a
 *  pick; all of it in findings.json and after a reload; the CT slices as large as the views. */
async function findingsSteps(page, waitFrame, study) {
  const cands = JSON.parse(fs.readFileSync(candFile, 'utf8')).candidates.slice().sort((a, b) => b.score - a.score);
  check(cands.length >= 2, 'candidates in polyps/candidates.json', '>= 2', cands.length);
  await page.waitForFunction((n) => document.querySelectorAll('#candidate-list li').length === n, cands.length, { timeout: 10000 })
    .catch(() => {});
  const rows = await page.$$eval('#candidate-list li', (lis) => lis.map((li) => ({ id: li.dataset.id, text: li.textContent })));
  check(rows.length === cands.length, 'candidate list entries', cands.length, rows.length);
  const c1 = cands[0];
  const c2 = cands[1];
  check(rows[0].id === c1.id && rows[0].text.includes(Number(c1.size_mm).toFixed(1)) && rows[0].text.includes(Number(c1.score).toFixed(2))
    && rows[0].text.includes(c1.segment.replace(/_/g, ' ')), 'first candidate row (best score: id, size, segment, score)',
  `${c1.id} ${c1.size_mm} mm ${c1.segment} ${c1.score}`, rows[0].text);
  // the overview marks the candidates (cyan rings, drawn by the server)
  const CYAN = [74, 209, 255], GREEN = [107, 214, 139], ORANGE = [255, 159, 67];
  const cyanBefore = await waitOverviewColour(page, CYAN, (n) => n > 20, 'candidates ringed on the overview');
  const greenBefore = await overviewColour(page, GREEN);
  const markBefore = (await page.$eval('#views', (v) => v.dataset.markerKey)) || '';
  await page.click('#candidate-next');
  await waitFrame(`fly to candidate ${c1.id}`, (d) => d.markerKey && d.markerKey !== markBefore && d.key === d.markerKey && d.loading === 'false');
  check(await page.getAttribute('#candidate-current', 'data-id') === c1.id, 'current candidate after Next', c1.id,
    await page.getAttribute('#candidate-current', 'data-id'));
  check(Number(await page.inputValue('#finding-size')) === Number(Number(c1.size_mm).toFixed(1)), 'size field of the candidate',
    c1.size_mm, await page.inputValue('#finding-size'));
  const ringPixels = await page.$eval('#pair-overlay', (c) => {
    const img = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    let n = 0;
    for (let i = 0; i < img.length; i += 4) if (img[i + 3] > 200 && img[i] < 120 && img[i + 1] > 170 && img[i + 2] > 220) n += 1;
    return n;
  });
  check(ringPixels > 20, `candidate ${c1.id} marked in the views (cyan ring)`, '> 20 pixels', ringPixels);

  await page.fill('#finding-size', '11.5');
  await page.click('#candidate-accept');
  await page.waitForSelector(`#candidate-list li[data-id="${c1.id}"][data-status="accepted"]`, { timeout: 10000 });
  const green = await waitOverviewColour(page, GREEN, (n) => n > greenBefore + 10, `accepted ${c1.id} ringed green on the overview`);
  const cyanAccepted = await overviewColour(page, CYAN);
  check(cyanAccepted < cyanBefore, `cyan rings on the overview after accepting ${c1.id}`, `< ${cyanBefore}`, cyanAccepted);
  await page.click('#candidate-next');
  await waitFrame(`fly to candidate ${c2.id}`, (d) => JSON.parse(d.locate || '{}') && d.key === d.markerKey && d.loading === 'false');
  await page.click('#candidate-reject');
  await page.waitForSelector(`#candidate-list li[data-id="${c2.id}"][data-status="rejected"]`, { timeout: 10000 });
  const cyanRejected = await waitOverviewColour(page, CYAN, (n) => n < cyanAccepted, `rejected ${c2.id} no longer ringed on the overview`);
  log(`overview: candidate rings ${cyanBefore} cyan px; accepted ${green} green px, cyan ${cyanAccepted}; after a reject cyan ${cyanRejected}`);
  let saved = JSON.parse(fs.readFileSync(findingsFile, 'utf8'));
  const f1 = saved.findings.find((f) => f.candidate_id === c1.id);
  const f2 = saved.findings.find((f) => f.candidate_id === c2.id);
  check(saved.schema === 'flyover.findings/1' && f1 && f1.status === 'accepted' && f1.size_mm === 11.5,
    `findings.json: ${c1.id} accepted with the edited size`, 'accepted, 11.5 mm', JSON.stringify(f1));
  // The size field shows the candidate's size to 0.1 mm, and the review takes the field's size.
  const c2Shown = Number(Number(c2.size_mm).toFixed(1));
  check(f2 && f2.status === 'rejected' && f2.size_mm === c2Shown, `findings.json: ${c2.id} rejected`, `rejected, ${c2Shown} mm`,
    JSON.stringify(f2));

  // a finding by hand at a wall point picked on the left view
  const box = await page.locator('#pair').boundingBox();
  let point = null;
  for (const [fx, fy] of [[0.25, 0.5], [0.2, 0.35], [0.3, 0.65], [0.15, 0.5], [0.35, 0.4]]) {
    const before = await page.getAttribute('#pick-info', 'data-point-mm');
    await page.mouse.click(box.x + box.width * fx, box.y + box.height * fy);
    await page.waitForFunction((b) => document.querySelector('#pick-info').dataset.pointMm !== b
      || document.querySelector('#pick-info').dataset.hit === 'false', before, { timeout: 10000 }).catch(() => {});
    const p = await page.getAttribute('#pick-info', 'data-point-mm');
    if (p) { point = JSON.parse(p); break; }
  }
  check(!!point, 'a wall point picked on the left view', 'a hit', 'no hit at five pixels');
  check(!(await page.isDisabled('#finding-add')), 'add-by-hand button after a pick', 'enabled', 'disabled');
  const orangeBefore = await overviewColour(page, ORANGE);
  await page.fill('#finding-size', '7');
  await page.selectOption('#finding-morphology', 'flat');
  await page.click('#finding-add');
  await page.waitForSelector('#finding-list li[data-source="hand"]', { timeout: 10000 });
  await waitOverviewColour(page, ORANGE, (n) => n > orangeBefore + 10, 'the hand finding ringed orange on the overview');
  saved = JSON.parse(fs.readFileSync(findingsFile, 'utf8'));
  const hand = saved.findings.find((f) => f.source === 'hand');
  check(hand && hand.status === 'accepted' && hand.size_mm === 7 && hand.morphology === 'flat'
    && dist(hand.position_mm, point) < 1e-6 && typeof hand.segment === 'string' && hand.arc_mm >= 0,
  'findings.json: the hand finding at the picked point', `accepted 7 mm flat at ${fmtP(point)}`, JSON.stringify(hand));

  // all of it after a reload
  await page.reload();
  await page.waitForSelector('body[data-ready="true"]', { timeout: 30000 });
  await page.waitForFunction(() => document.querySelectorAll('#finding-list li').length === 3, null, { timeout: 10000 }).catch(() => {});
  check(await page.locator('#finding-list li').count() === 3, 'findings listed after a reload', 3, await page.locator('#finding-list li').count());
  check(await page.getAttribute(`#candidate-list li[data-id="${c1.id}"]`, 'data-status') === 'accepted',
    `candidate ${c1.id} after a reload`, 'accepted', await page.getAttribute(`#candidate-list li[data-id="${c1.id}"]`, 'data-status'));
  log(`candidates: ${cands.length} listed; ${c1.id} accepted at 11.5 mm, ${c2.id} rejected, a 7 mm finding by hand at ${fmtP(point)}`);

  // the CT slices as large as the fly-over views
  if (study.has_ct) {
    await page.waitForFunction(() => Number(document.querySelector('#views').dataset.frames || 0) >= 1, null, { timeout: 60000 });
    await page.click('#ct-large');
    const pair = await page.locator('#pair').boundingBox();
    const slice = await page.locator('.slice[data-plane="axial"] .slice-box').boundingBox();
    check(Math.abs(slice.width - pair.width / 2) < pair.width * 0.05, 'axial slice width with CT large', `about ${(pair.width / 2).toFixed(0)} px (a view)`,
      slice.width.toFixed(0));
    await page.click('#ct-large');
  }
}

function clampPx(v, px) { return Math.min(Number(px) - 1, Math.max(0, v)); }

/** Slice element geometry and mapping, from the page. */
async function sliceInfo(page, plane) {
  const fig = page.locator(`.slice[data-plane="${plane}"]`);
  const d = await fig.evaluate((f) => ({ ...f.dataset }));
  const box = await fig.locator('.slice-box').boundingBox();
  const map = JSON.parse(d.mapping);
  const iw = Number(d.width);
  const ih = Number(d.height);
  const kk = Math.min(box.width / iw, box.height / ih);
  return { d, map, box, r: { x: (box.width - iw * kk) / 2, y: (box.height - ih * kk) / 2, k: kk, iw, ih } };
}

/** Waits until all three slices show the point p, then returns each crosshair's LPS point. */
async function waitCrosshairs(page, p) {
  const deadline = Date.now() + 30000;
  let last = null;
  for (;;) {
    const out = {};
    let ok = true;
    for (const plane of ['axial', 'coronal', 'sagittal']) {
      const d = await page.locator(`.slice[data-plane="${plane}"]`).evaluate((f) => ({ ...f.dataset }));
      if (!d.mapping || d.crossCol === undefined) { ok = false; break; }
      const map = JSON.parse(d.mapping);
      const col = Number(d.crossCol);
      const row = Number(d.crossRow);
      const inside = col >= -0.5 && row >= -0.5 && col <= Number(d.width) - 0.5 && row <= Number(d.height) - 0.5;
      const w = sliceToWorld(map, col, row);
      out[plane] = w;
      last = { plane, col, row, w, inside };
      // the slice went through p (within a voxel) and the crosshair is inside the image
      if (!inside || dist(w, p) > 2.5) { ok = false; break; }
    }
    if (ok) return out;
    if (Date.now() > deadline) {
      throw new CheckFailed(`crosshairs at ${fmtP(p)}: expected every slice through the point with its crosshair inside the image; last ${JSON.stringify(last)}`);
    }
    await sleep(100);
  }
}

// ---------------------------------------------------------------- main

const guard = setTimeout(() => {
  console.error('FAIL: the browser test ran past 300 s');
  viewer.kill();
  process.exit(1);
}, 300000);

try {
  await run();
} catch (e) {
  failure = e;
}
if (browser && !args.keepOpen) await browser.close().catch(() => {});
const stopped = srv ? await viewer.stop() : null;
clearTimeout(guard);
finish(failure, stopped, viewer);
