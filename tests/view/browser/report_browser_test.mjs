// Browser test of report.html (`flyover report`): a hand-written study (coverage.json,
// candidates.json with images, no findings yet: a draft) is reported, and the page is opened
// from the file in Debian's chromium through playwright-core, offline. It must load without a
// console error, make no request but for its own file and data: URIs, show the draft banner on
// screen and in print, and print on A4.
//
//   node report_browser_test.mjs --flyover BIN [--chromium PATH] [--keep-open]
//
// Exit codes: 0 pass, 1 fail, 77 skipped (no chromium).

import { execFileSync } from 'node:child_process';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';

import { check, CheckFailed, chromiumOrSkip, launchBrowser, loadPlaywrightChromium, log, parseArgs } from './harness.mjs';

const args = parseArgs(process.argv.slice(2), { name: 'report_browser_test', values: ['flyover'], required: ['flyover'] });
const chromiumPath = chromiumOrSkip(args.chromium);
const chromium = await loadPlaywrightChromium('report_browser_test');

const PNG = Buffer.from('iVBORw0KGgoAAAANSUhEUgAAAAQAAAAECAIAAAAmkwkpAAAAEElEQVR4nGM4kWIERwzEcQBCchXhIRsTawAAAABJRU5ErkJggg==', 'base64');
const SEGMENTS = ['rectum', 'sigmoid', 'descending', 'splenic_flexure', 'transverse', 'hepatic_flexure', 'ascending', 'cecum'];

/** A study folder with what `flyover report` reads. */
function makeStudy(dir) {
  fs.mkdirSync(path.join(dir, 'coverage'), { recursive: true });
  fs.mkdirSync(path.join(dir, 'polyps'), { recursive: true });
  const method = { fraction: 0.93, seen_area_mm2: 1, missed_regions: [] };
  fs.writeFileSync(path.join(dir, 'coverage', 'coverage.json'), JSON.stringify({
    schema: 'flyover.coverage/1', world_frame: 'LPS', flyover: { both_cameras: method },
    flyover_with_review: { fraction: 0.96, target: 0.99 }, review_views: 3,
    segments: SEGMENTS.map((s) => ({ segment: s, area_mm2: 10000, flyover: 0.93, flyover_with_review: 0.96 })),
  }));
  fs.writeFileSync(path.join(dir, 'polyps', 'c1_pair.png'), PNG);
  fs.writeFileSync(path.join(dir, 'polyps', 'c1_axial.png'), PNG);
  const cand = (id, size, segment, arc, images) => ({
    id, centroid_mm: [10, -20, 30 + arc / 10], size_mm: size, height_mm: size / 2, volume_mm3: size ** 3 / 3,
    morphology: 'sessile', arc_mm: arc, segment, score: 0.9 - arc / 10000, pose: null, images,
  });
  fs.writeFileSync(path.join(dir, 'polyps', 'candidates.json'), JSON.stringify({
    schema: 'flyover.polyps/1', world_frame: 'LPS',
    candidates: [cand('c1', 12.4, 'sigmoid', 300, { pair: 'c1_pair.png', axial: 'c1_axial.png', sagittal: 'missing.png' }),
      cand('c2', 7.0, 'transverse', 900, {}), cand('c3', 3.0, 'cecum', 1300)],
  }));
}

let browser = null;
let failure = null;
const dir = fs.mkdtempSync(path.join(os.tmpdir(), 'flyover-report-browser-'));

async function run() {
  makeStudy(dir);
  execFileSync(args.flyover, ['--quiet', 'report', '--study', dir], { stdio: ['ignore', 'inherit', 'inherit'] });
  const file = path.join(dir, 'report', 'report.html');
  const report = JSON.parse(fs.readFileSync(path.join(dir, 'report', 'report.json'), 'utf8'));
  check(report.draft === true && report.c_rads === 'C3', 'report.json of an unreviewed study', 'a C3 draft',
    `${report.c_rads}, draft ${report.draft}`);
  browser = await launchBrowser(chromium, chromiumPath);
  log(`chromium ${browser.version()}`);
  const context = await browser.newContext({ viewport: { width: 1000, height: 1200 }, offline: true });
  const page = await context.newPage();
  const problems = [];
  const requests = [];
  page.on('pageerror', (e) => problems.push(`page error: ${e.message}`));
  page.on('console', (m) => { if (m.type() === 'error' || m.type() === 'warning') problems.push(`console ${m.type()}: ${m.text()}`); });
  page.on('request', (r) => requests.push(r.url()));
  page.on('requestfailed', (r) => problems.push(`request failed: ${r.url().slice(0, 80)}`));
  const url = `file://${file}`;
  await page.goto(url, { waitUntil: 'load' });
  const foreign = requests.filter((u) => u !== url && !u.startsWith('data:'));
  check(foreign.length === 0, 'requests of report.html besides its own file and data: URIs', 'none', foreign.join(' '));
  check(problems.length === 0, 'console errors and failed requests', 'none', problems.join(' | '));
  check((await page.textContent('#c-rads')).trim() === 'C3', 'C-RADS category shown', 'C3', await page.textContent('#c-rads'));
  const images = await page.$$eval('img', (imgs) => imgs.map((i) => ({ ok: i.complete && i.naturalWidth > 0, src: i.src.slice(0, 22) })));
  check(images.length === 2 && images.every((i) => i.ok && i.src.startsWith('data:image/png')), 'embedded images decoded',
    '2 data: PNGs', JSON.stringify(images));
  check(await page.isVisible('#draft-banner'), 'draft banner on screen', 'visible', 'hidden');
  check((await page.textContent('body')).includes('to be filled by the reader'), 'E category', 'left to the reader', 'missing');
  await page.emulateMedia({ media: 'print' });
  const printed = await page.$eval('#draft-banner', (b) => ({ pos: getComputedStyle(b).position, shown: b.getBoundingClientRect().height > 0 }));
  check(printed.pos === 'fixed' && printed.shown, 'draft banner in print (fixed: on every page)', 'fixed and shown', JSON.stringify(printed));
  const pdf = await page.pdf({ preferCSSPageSize: true, printBackground: true });
  const mediaBox = /\/MediaBox\s*\[\s*0 0 ([\d.]+) ([\d.]+)\s*\]/.exec(pdf.toString('latin1'));
  check(mediaBox && Math.abs(Number(mediaBox[1]) - 595.9) < 2 && Math.abs(Number(mediaBox[2]) - 842.9) < 2,
    'printed page size', 'A4 (595 x 842 pt)', mediaBox ? `${mediaBox[1]} x ${mediaBox[2]}` : 'no MediaBox');
  log(`report.html: ${fs.statSync(file).size} bytes, ${images.length} images, PDF ${pdf.length} bytes`);
}

try {
  await run();
} catch (e) {
  failure = e;
}
if (browser && !args.keepOpen) await browser.close().catch(() => {});
fs.rmSync(dir, { recursive: true, force: true });
if (failure) {
  console.error(`FAIL: ${failure instanceof CheckFailed ? '' : 'error: '}${failure.message}`);
  process.exit(1);
}
log('PASS');
process.exit(0);
