// Browser test of the `flyover view` page on a study that is still being computed ("live study"):
// Debian's chromium driven by playwright-core, like view_browser_test.mjs.
//
//   node view_live_browser_test.mjs --flyover BIN --study DIR [--chromium PATH] [--keep-open]
//
// DIR is a complete study (make_study.sh); it is only read. The test makes an empty study folder
// T, holds T's study lock as a `flyover run` does (util-linux `flock T/.flyover/lock sleep 600`),
// starts `flyover view --study T --port 0` and opens the page, which must say that the study is
// being computed. It then lands DIR's files in T as a run writes them (a temporary name in the
// same folder, then a rename): first manifest.json, ct.vdb, centerline.json and surface.ply (the
// page must start by itself, no reload, with no missed regions), then coverage/ (the page must
// pick up the new revision and list DIR's missed regions, still without a reload); last it ends
// the "run" (kills the flock) and the page must drop its "run in progress" mark. Every check says
// what it expected and what it saw.
//
// Exit codes: 0 pass, 1 fail, 77 skipped (no chromium, or no util-linux flock; CTest's
// SKIP_RETURN_CODE).

import { spawn, spawnSync } from 'node:child_process';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';

import {
  apiOf, check, CheckFailed, chromiumOrSkip, finish, launchBrowser, loadPlaywrightChromium, log, parseArgs, SKIP,
  Viewer, waitFor,
} from './harness.mjs';

const args = parseArgs(process.argv.slice(2),
  { name: 'view_live_browser_test', values: ['flyover', 'study'], required: ['flyover', 'study'] });
const chromiumPath = chromiumOrSkip(args.chromium);
if (spawnSync('flock', ['--version'], { stdio: 'ignore' }).error) {
  console.log('SKIPPED: no util-linux `flock` (it holds the study lock as a flyover run does); install util-linux');
  process.exit(SKIP);
}
const chromium = await loadPlaywrightChromium('view_live_browser_test');

// ---------------------------------------------------------------- the study folder and its "run"

const src = path.resolve(args.study);
let T = null; // the live study folder
let runner = null; // flock holding T/.flyover/lock (its own process group: flock and its sleep)
let runnerExit = null;

for (const f of ['manifest.json', 'centerline.json', 'surface.ply', path.join('coverage', 'coverage.json')]) {
  if (!fs.existsSync(path.join(src, f))) {
    console.error(`view_live_browser_test: ${path.join(src, f)} is missing: --study must be a complete study (make_study.sh)`);
    process.exit(2);
  }
}

/** Whether some process holds T's study lock (flock -n fails when it is held). */
function lockHeld() {
  const r = spawnSync('flock', ['-n', path.join(T, '.flyover', 'lock'), 'true'], { stdio: 'ignore' });
  return r.status !== 0;
}

async function holdLock() {
  runner = spawn('flock', [path.join(T, '.flyover', 'lock'), 'sleep', '600'], { stdio: 'ignore', detached: true });
  runner.on('exit', (code, signal) => { runnerExit = { code, signal }; });
  const r = await waitFor(async () => lockHeld(), (v) => v || runnerExit !== null, 10000, 50);
  check(r.ok && !runnerExit, 'study lock held by `flock T/.flyover/lock sleep 600`', 'held within 10 s',
    runnerExit ? `flock exited ${JSON.stringify(runnerExit)}` : 'not held');
  // As a run does: its pid in the lock file (the viewer needs it where /proc/locks names another
  // device than stat(), on an overlay file system).
  fs.writeFileSync(path.join(T, '.flyover', 'lock'), String(runner.pid));
}

/** Ends the "run": flock and its sleep (the sleep inherits the locked file descriptor). */
async function releaseLock() {
  if (!runner || runnerExit) return;
  try { process.kill(-runner.pid, 'SIGTERM'); } catch (_) { /* gone */ }
  await waitFor(async () => runnerExit, (v) => v !== null, 5000, 50);
}

/** Copies a file of the complete study into T as a run writes it: a temporary name, then a rename. */
function landFile(rel) {
  const to = path.join(T, rel);
  const tmp = path.join(path.dirname(to), `.${path.basename(rel)}.part${process.pid}`);
  fs.copyFileSync(path.join(src, rel), tmp);
  fs.renameSync(tmp, to);
}

// ---------------------------------------------------------------- the test

let viewer = null;
let browser = null;
let srv = null;
let failure = null;
const pageErrors = [];
let apiGet = null; // GET with the token (apiOf): {status, json, text, ...}
let apiJson = null; // the same, 200 with JSON expected

const status = () => apiJson('/api/status');
const brief = (st) => JSON.stringify(st);

async function run() {
  // ---- a. an empty study folder whose "run" holds the lock
  T = fs.mkdtempSync(path.join(os.tmpdir(), 'flyover-live-'));
  fs.mkdirSync(path.join(T, '.flyover'));
  await holdLock();
  log(`study folder ${T}, lock held by flock (pid ${runner.pid})`);

  // ---- b. the viewer starts on it and says that the study is being computed
  viewer = new Viewer(args.flyover, T);
  srv = await viewer.start(30000, 'flyover view on a study whose run holds the lock (no surface.ply, no centerline.json): '
    + 'expected it to start and print its URL, saw it exit');
  ({ get: apiGet, getJson: apiJson } = apiOf(srv));
  log(`server: ${srv.url.replace(srv.token, '…')}`);
  browser = await launchBrowser(chromium, chromiumPath);
  log(`chromium ${browser.version()}`);
  const context = await browser.newContext({ viewport: { width: 1600, height: 1000 } });
  const page = await context.newPage();
  page.on('pageerror', (e) => pageErrors.push(`page error: ${e.message}`));
  page.on('console', (m) => { if (m.type() === 'error') pageErrors.push(`console error: ${m.text()}`); });
  let navigations = 0;
  page.on('framenavigated', (f) => { if (f === page.mainFrame()) navigations += 1; });

  const st0 = await status();
  check(st0.ready === false, '/api/status ready before surface.ply and centerline.json exist', 'false', brief(st0));
  check(st0.computing === true, '/api/status computing while flock holds the lock', 'true', brief(st0));
  const wf = st0.waiting_for || [];
  check(wf.includes('surface.ply') && wf.includes('centerline.json'), '/api/status waiting_for',
    'surface.ply and centerline.json', JSON.stringify(st0.waiting_for));
  check(st0.revision === 0, '/api/status revision with nothing served', '0', brief(st0));
  const study503 = await apiGet('/api/study');
  check(study503.status === 503, 'GET /api/study while nothing is served', '503', `${study503.status} ${study503.text}`);
  check(!!(study503.json && /surface\.ply/.test(study503.json.error || '')), 'error of the 503 /api/study',
    '{"error": "… waiting for surface.ply, …"}', study503.text);

  await page.goto(srv.url);
  check(await page.title() === 'flyover view', 'page title', '"flyover view"', await page.title());
  const bodyText = () => page.evaluate(() => document.body.innerText);
  const computingShown = await waitFor(bodyText, (t) => /being computed/i.test(t) && /surface\.ply/.test(t), 15000);
  check(computingShown.ok, 'visible text of the page while the study is being computed',
    'mentions "being computed" and "surface.ply"', JSON.stringify(computingShown.value.slice(0, 300)));
  check(await page.isVisible('#notice'), 'notice over the views while the study is being computed', 'visible', 'hidden');
  const notice = await page.textContent('#notice');
  check(/being computed/i.test(notice) && /surface\.ply/.test(notice) && /centerline\.json/.test(notice),
    'notice over the views', 'being computed … waiting for surface.ply, centerline.json', JSON.stringify(notice));
  const statusState = await page.getAttribute('#status', 'data-state');
  check(statusState === 'computing', 'status line state while computing', 'computing',
    `${statusState}: ${await page.textContent('#status')}`);
  const runMark = await waitFor(async () => page.isVisible('#run-state'), (v) => v, 5000);
  check(runMark.ok && /run in progress/i.test(await page.textContent('#run-state')), '"run in progress" mark while computing',
    'visible, "run in progress …"', `${runMark.value ? 'visible' : 'hidden'}: ${JSON.stringify(await page.textContent('#run-state'))}`);
  check(await page.getAttribute('body', 'data-ready') !== 'true', 'page ready before the study exists', 'not ready', 'ready');
  log(`computing state shown: ${JSON.stringify(notice)}`);

  // A variable of this page: it survives only if the page is never reloaded.
  const stamp = `live-${process.pid}-${Date.now()}`;
  await page.evaluate((s) => { window.__flyoverLiveStamp = s; }, stamp);
  const sameDocument = async (what) => {
    const seen = await page.evaluate(() => window.__flyoverLiveStamp || null);
    check(seen === stamp && navigations === 1, `${what}: the same document (no reload)`,
      `window.__flyoverLiveStamp = ${stamp}, 1 navigation`, `${seen}, ${navigations} navigation(s)`);
  };

  // ---- c. the run lands the surface and the centerline (no coverage yet): the page starts by itself
  const first = ['manifest.json'];
  if (fs.existsSync(path.join(src, 'ct.vdb'))) first.push('ct.vdb');
  first.push('centerline.json', 'surface.ply');
  const landed = Date.now();
  for (const f of first) landFile(f);
  log(`landed ${first.join(', ')}`);
  const frames = () => page.evaluate(() => Number(document.querySelector('#views').dataset.frames || 0));
  const started = await waitFor(async () => ({
    ready: await page.getAttribute('body', 'data-ready'), frames: await frames(),
  }), (v) => v.ready === 'true' && v.frames >= 1, 30000);
  check(started.ok, 'page after surface.ply and centerline.json landed (no reload)', 'ready with a frame drawn within 30 s',
    `${JSON.stringify(started.value)} after ${started.ms} ms; status line ${JSON.stringify(await page.textContent('#status'))}`);
  log(`page ready by itself ${((Date.now() - landed) / 1000).toFixed(1)} s after the files landed`);
  await sameDocument('page once ready');
  const painted = await page.$eval('#pair', (c) => {
    const img = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    let lit = 0;
    let lo = 255;
    let hi = 0;
    for (let i = 0; i < img.length; i += 4) {
      const y = (img[i] + img[i + 1] + img[i + 2]) / 3;
      if (img[i + 3] > 0 && y > 12) lit += 1;
      lo = Math.min(lo, y); hi = Math.max(hi, y);
    }
    return { lit: lit / (img.length / 4), lo, hi, w: c.width, h: c.height };
  });
  check(painted.lit > 0.05 && painted.hi - painted.lo > 30, 'pair image drawn on the canvas',
    '> 5 % lit pixels and some contrast', JSON.stringify(painted));
  check(!(await page.isVisible('#notice')), 'notice over the views once the study is shown', 'hidden', 'visible');
  const st1 = await status();
  check(st1.ready === true && st1.revision >= 1, '/api/status once the study is served', 'ready true, revision >= 1', brief(st1));
  check(st1.computing === true, '/api/status computing (the run still holds the lock)', 'true', brief(st1));
  // The server may swap in more than one revision while the files land: wait until it is
  // settled and the page shows the last one.
  const settled = await waitFor(async () => {
    const st = await status();
    return { st, page: await page.getAttribute('body', 'data-revision') };
  }, (v) => v.st.ready && !v.st.loading && v.page === String(v.st.revision), 20000, 700);
  check(settled.ok, 'page revision once the server is settled (loading false)', `the server's revision`,
    `page ${settled.value.page}, server ${brief(settled.value.st)}`);
  const rev1 = settled.value.st.revision;
  const study1 = await apiJson('/api/study');
  check(study1.revision === rev1, '/api/study revision', rev1, study1.revision);
  check((study1.missed_regions || []).length === 0, '/api/study missed regions without coverage/', 'none',
    JSON.stringify(study1.missed_regions));
  const missed1 = await page.locator('#missed-list li').count();
  check(missed1 === 0, 'missed regions listed without coverage/', '0', missed1);
  check(await page.isDisabled('#next-missed'), 'next missed region button without coverage/', 'disabled', 'enabled');
  const arcMax = Number(await page.getAttribute('#arc', 'max'));
  check(Math.abs(arcMax - study1.arc_max_mm) < 1e-6, 'arc slider max', study1.arc_max_mm, arcMax);
  if (study1.has_ct) {
    const ctShown = await waitFor(async () => page.evaluate(() => {
      const f = document.querySelector('.slice[data-plane="axial"]');
      return { visible: !document.querySelector('#slices').hidden, mapping: !!f.dataset.mapping };
    }), (v) => v.visible && v.mapping, 20000);
    check(ctShown.ok, 'CT slices shown (the study has ct.vdb)', 'visible with a slice', JSON.stringify(ctShown.value));
  }
  log(`revision ${rev1}: ${study1.arc_max_mm.toFixed(0)} mm of path, ${painted.w}x${painted.h} pair drawn `
    + `(${(painted.lit * 100).toFixed(0)} % lit), no missed regions`);

  // ---- d. the run lands coverage/: a new revision, its missed regions listed, no reload
  const framesBefore = await frames();
  fs.cpSync(path.join(src, 'coverage'), path.join(T, 'coverage.tmp'), { recursive: true });
  fs.renameSync(path.join(T, 'coverage.tmp'), path.join(T, 'coverage'));
  const covLanded = Date.now();
  const cov = JSON.parse(fs.readFileSync(path.join(src, 'coverage', 'coverage.json'), 'utf8'));
  const covRegions = ((((cov.flyover || {}).both_cameras || {}).missed_regions) || []).length;
  log(`landed coverage/ (${covRegions} fly-over missed region(s) in coverage.json)`);
  const bumped = await waitFor(status, (st) => st.revision > rev1 && !st.loading, 15000, 250);
  check(bumped.ok, '/api/status revision after coverage/ landed', `> ${rev1} within 15 s`, brief(bumped.value));
  const rev2 = bumped.value.revision;
  const study2 = await apiJson('/api/study');
  const want = (study2.missed_regions || []).length;
  check(want === covRegions, '/api/study missed regions after coverage/ landed', `${covRegions} (coverage.json)`, want);
  check(want > 0, 'missed regions of the complete study', '> 0 (else this step checks little)', want);
  const listed = await waitFor(async () => ({
    n: await page.locator('#missed-list li').count(), rev: await page.getAttribute('body', 'data-revision'),
  }), (v) => v.n === want && v.rev === String(rev2), Math.max(1000, 15000 - (Date.now() - covLanded)));
  check(listed.ok, 'missed regions listed by the page after coverage/ landed', `${want}, revision ${rev2}, within 15 s`,
    `${JSON.stringify(listed.value)} ${((Date.now() - covLanded) / 1000).toFixed(1)} s after`);
  log(`page at revision ${rev2} ${((Date.now() - covLanded) / 1000).toFixed(1)} s after coverage/ landed, ${want} missed region(s)`);
  await sameDocument('page after the new revision');
  const statusLine = await page.textContent('#status');
  check(new RegExp(`revision ${rev2}\\b`).test(statusLine) && /updated/i.test(statusLine), 'status line after the new revision',
    `"Study updated: revision ${rev2} …"`, JSON.stringify(statusLine));
  const redrawn = await waitFor(async () => page.$eval('#views', (v) => ({ ...v.dataset })),
    (d) => d.revision === String(rev2) && d.loading === 'false', 15000);
  check(redrawn.ok && Number(redrawn.value.frames) > framesBefore, 'current pair asked for again at the new revision',
    `a new frame of revision ${rev2}`, `revision ${redrawn.value.revision}, frames ${framesBefore} -> ${redrawn.value.frames}`);
  const arcs = await page.$$eval('#missed-list li', (lis) => lis.map((li) => Number(li.dataset.arcMm)));
  const wantArcs = study2.missed_regions.map((r) => Number(r.arc_mm));
  check(JSON.stringify(arcs) === JSON.stringify(wantArcs), 'arcs of the listed missed regions', JSON.stringify(wantArcs),
    JSON.stringify(arcs));
  check(!(await page.isDisabled('#next-missed')), 'next missed region button with missed regions', 'enabled', 'disabled');

  // ---- e. the run ends: computing false, the "run in progress" mark goes
  await releaseLock();
  check(runnerExit !== null && !lockHeld(), 'study lock after killing flock', 'released', runnerExit ? 'held' : 'flock still running');
  const ended = await waitFor(status, (st) => st.computing === false, 10000, 250);
  check(ended.ok, '/api/status computing after the run ended', 'false within 10 s', brief(ended.value));
  check(ended.value.ready === true && ended.value.revision >= rev2, '/api/status after the run ended',
    `ready true, revision >= ${rev2}`, brief(ended.value));
  const markGone = await waitFor(async () => ({
    visible: await page.isVisible('#run-state'), computing: await page.getAttribute('body', 'data-computing'),
  }), (v) => !v.visible && v.computing === 'false', 10000);
  check(markGone.ok, '"run in progress" mark after the run ended', 'hidden within 10 s', JSON.stringify(markGone.value));
  const stateEnd = await page.getAttribute('#status', 'data-state');
  check(stateEnd !== 'error', 'status line after the run ended', 'no error', `${stateEnd}: ${await page.textContent('#status')}`);
  await sameDocument('page after the run ended');
  log('run ended: computing false, the mark is gone');

  const errs = pageErrors.filter((e) => !/favicon/.test(e));
  check(errs.length === 0, 'errors in the page console', 'none', errs.join(' | '));
}

// ---------------------------------------------------------------- main

async function cleanup() {
  if (browser && !args.keepOpen) await browser.close().catch(() => {});
  const stopped = viewer ? await viewer.stop() : null;
  await releaseLock();
  if (T && !args.keepOpen) fs.rmSync(T, { recursive: true, force: true });
  return stopped;
}

const guard = setTimeout(async () => {
  console.error('FAIL: the live browser test ran past 280 s');
  if (viewer) viewer.kill();
  if (runner && !runnerExit) { try { process.kill(-runner.pid, 'SIGKILL'); } catch (_) { /* gone */ } }
  if (T) fs.rmSync(T, { recursive: true, force: true });
  process.exit(1);
}, 280000);

try {
  await run();
} catch (e) {
  failure = e;
}
const stopped = await cleanup();
clearTimeout(guard);

if (!failure && T && !args.keepOpen && fs.existsSync(T)) failure = new CheckFailed(`study folder removed: expected no ${T}, saw it`);
finish(failure, stopped, viewer);
