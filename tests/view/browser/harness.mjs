// What the page's browser tests share: arguments, finding Debian's chromium and playwright-core,
// checks that say what they expected and saw, `flyover view` as a child process, the HTTP API
// with the session's token, and the end of a test (exit codes: 0 pass, 1 fail, 77 skipped).

import { spawn } from 'node:child_process';
import fs from 'node:fs';
import readline from 'node:readline';

export const SKIP = 77;

const t0 = Date.now();
export const log = (...a) => console.log(`[${((Date.now() - t0) / 1000).toFixed(1)} s]`, ...a);
export const sleep = (ms) => new Promise((ok) => setTimeout(ok, ms));

/** `--name value` options (`values`), `--flag` switches (`flags`), `required` among the values;
 *  `--chromium PATH` and `--keep-open` always. Exits 2 with a one-line message on a bad one. */
export function parseArgs(argv, { name, values, required, flags = [] }) {
  const out = { chromium: process.env.FLYOVER_CHROMIUM || '', keepOpen: false };
  const valueNames = new Set([...values, 'chromium']);
  const flagNames = new Set([...flags, 'keep-open']);
  const camel = (k) => k.replace(/-([a-z])/g, (_, c) => c.toUpperCase());
  try {
    for (let i = 0; i < argv.length; i++) {
      const a = argv[i];
      const k = a.startsWith('--') ? a.slice(2) : '';
      if (valueNames.has(k)) {
        if (i + 1 >= argv.length) throw new Error(`${a} needs a value`);
        out[camel(k)] = argv[++i];
      } else if (flagNames.has(k)) {
        out[camel(k)] = true;
      } else {
        throw new Error(`unknown argument ${a}`);
      }
    }
    for (const k of required) if (!out[camel(k)]) throw new Error(`--${k} is required`);
  } catch (e) {
    console.error(`${name}: ${e.message}`);
    process.exit(2);
  }
  return out;
}

/** The chromium to drive (--chromium, $FLYOVER_CHROMIUM, Debian's), or a skip (exit 77). */
export function chromiumOrSkip(given) {
  const candidates = [given, '/usr/bin/chromium', '/usr/bin/chromium-browser'].filter(Boolean);
  for (const c of candidates) {
    try { fs.accessSync(c, fs.constants.X_OK); return c; } catch (_) { /* next */ }
  }
  console.log('SKIPPED: no chromium found (looked at $FLYOVER_CHROMIUM, /usr/bin/chromium, /usr/bin/chromium-browser); '
    + 'install it with `apt-get install chromium` (scripts/setup.sh does)');
  process.exit(SKIP);
}

/** playwright-core's chromium (installed by `npm ci` here), or exit 1 saying so. */
export async function loadPlaywrightChromium(name) {
  try {
    return (await import('playwright-core')).chromium;
  } catch (e) {
    console.error(`${name}: cannot load playwright-core (${e.message}); run \`npm ci\` in tests/view/browser`);
    process.exit(1);
  }
}

/** Headless chromium as root on a machine without a GPU or network; launch() gives it a fresh
 *  temporary profile (its --user-data-dir), removed when the browser closes. */
export function launchBrowser(chromium, executablePath) {
  return chromium.launch({
    executablePath,
    headless: true,
    args: ['--no-sandbox', '--no-first-run', '--disable-background-networking', '--disable-component-update',
      '--disable-sync'],
  });
}

// ---------------------------------------------------------------- checks

export class CheckFailed extends Error {}
let checkCount = 0;
export const checks = () => checkCount;
export function check(cond, what, expected, seen) {
  checkCount += 1;
  if (!cond) throw new CheckFailed(`${what}: expected ${expected}, saw ${seen}`);
}

/** Polls fn() every `every` ms until pred(value) holds; returns {ok, value, ms}. */
export async function waitFor(fn, pred, timeoutMs, every = 200) {
  const start = Date.now();
  let value;
  for (;;) {
    value = await fn();
    if (pred(value)) return { ok: true, value, ms: Date.now() - start };
    if (Date.now() - start > timeoutMs) return { ok: false, value, ms: Date.now() - start };
    await sleep(every);
  }
}

// ---------------------------------------------------------------- flyover view

/** `flyover view --study STUDY --port 0` as a child process. */
export class Viewer {
  constructor(flyover, study) {
    this.flyover = flyover;
    this.study = study;
    this.proc = null;
    this.exit = null; // {code, signal} once it exited
    this.output = '';
  }

  /** Starts it; resolves to {url, port, token} from its URL line. `exitedWhy` words the
   *  failure when it exits before printing one. */
  start(timeoutMs = 90000, exitedWhy = 'flyover view exited before printing its URL') {
    return new Promise((resolve, reject) => {
      this.proc = spawn(this.flyover, ['view', '--study', this.study, '--port', '0'], { stdio: ['ignore', 'pipe', 'pipe'] });
      const timer = setTimeout(() => reject(new Error(`flyover view printed no URL within ${timeoutMs / 1000} s; output:\n${this.output}`)), timeoutMs);
      readline.createInterface({ input: this.proc.stdout }).on('line', (line) => {
        this.output += `${line}\n`;
        const m = /^flyover: view: (http:\/\/127\.0\.0\.1:(\d+)\/\?token=([A-Za-z0-9_-]+))\s*$/.exec(line);
        if (m) { clearTimeout(timer); resolve({ url: m[1], port: Number(m[2]), token: m[3] }); }
      });
      readline.createInterface({ input: this.proc.stderr }).on('line', (l) => { this.output += `${l}\n`; });
      this.proc.on('exit', (code, signal) => {
        this.exit = { code, signal };
        clearTimeout(timer);
        reject(new CheckFailed(`${exitedWhy} (code ${code}, signal ${signal}):\n${this.output}`));
      });
    });
  }

  /** SIGTERM, then SIGKILL after 15 s; resolves to how it ended. */
  async stop() {
    if (!this.proc || this.exit) return this.exit;
    const done = new Promise((ok) => this.proc.once('exit', (code, signal) => ok({ code, signal })));
    this.proc.kill('SIGTERM');
    const r = await Promise.race([done, sleep(15000).then(() => null)]);
    if (!r) { this.proc.kill('SIGKILL'); return { code: null, signal: 'timeout' }; }
    return r;
  }

  kill() { if (this.proc && !this.exit) this.proc.kill('SIGKILL'); }
}

/** The HTTP API of a started viewer ({port, token}) from the test itself (not the page). */
export function apiOf(srv) {
  const get = async (p, params = {}) => {
    const url = new URL(p, `http://127.0.0.1:${srv.port}`);
    for (const [k, v] of Object.entries(params)) url.searchParams.set(k, String(v));
    const res = await fetch(url, { headers: { 'X-Flyover-Token': srv.token } });
    const body = Buffer.from(await res.arrayBuffer());
    let json = null;
    try { json = JSON.parse(body.toString('utf8')); } catch (_) { json = null; }
    return { status: res.status, headers: res.headers, body, json, text: body.toString('utf8').slice(0, 300) };
  };
  const getJson = async (p, params) => {
    const r = await get(p, params);
    if (r.status !== 200 || !r.json) {
      throw new CheckFailed(`GET ${p} ${JSON.stringify(params || {})}: expected 200 with JSON, saw ${r.status} ${r.text}`);
    }
    return r.json;
  };
  return { get, getJson };
}

/** The end of a test: a viewer stopped by SIGTERM must have exited cleanly; prints PASS with
 *  the number of checks, or FAIL with the failure and the viewer's last lines; exits. */
export function finish(failure, stopped, viewer) {
  if (!failure && stopped && !(stopped.code === 0 || stopped.signal === 'SIGTERM')) {
    failure = new CheckFailed(`flyover view after SIGTERM: expected exit code 0, saw code ${stopped.code} signal ${stopped.signal}`);
  }
  if (failure) {
    console.error(`FAIL: ${failure instanceof CheckFailed ? '' : 'error: '}${failure.message}`);
    if (!(failure instanceof CheckFailed)) console.error(failure.stack);
    if (viewer && viewer.output) console.error(`flyover view output:\n${viewer.output.split('\n').slice(-20).join('\n')}`);
    process.exit(1);
  }
  log(`PASS: ${checks()} checks; flyover view stopped cleanly (code ${stopped && stopped.code})`);
  process.exit(0);
}
