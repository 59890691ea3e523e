// End-to-end tests of `blueshift view` in headless Chromium (Debian's /usr/bin/chromium,
// driven by playwright-core; no browser is downloaded), against the real server on a
// loopback port. Usage: node e2e.mjs PATH/TO/blueshift
//
// Each scenario starts its own `blueshift view ... --port 0 --save-dir TMP` and reads the
// URL from its first stdout line. Every check prints `ok NAME` or `FAIL NAME: why`; the
// script ends with a summary and exits non-zero when any check failed. It also prints the
// frame rate the page saw while refining a larger render (`note fps ...`).

import { spawn, spawnSync } from 'node:child_process';
import fs from 'node:fs';
import http from 'node:http';
import os from 'node:os';
import path from 'node:path';
import readline from 'node:readline';
import { chromium } from 'playwright-core';

const CHROMIUM = process.env.BLUESHIFT_CHROMIUM || '/usr/bin/chromium';
const BIN = process.argv[2] ? path.resolve(process.argv[2]) : null;
if (!BIN || !fs.existsSync(BIN)) {
  console.error('usage: node e2e.mjs PATH/TO/blueshift');
  process.exit(2);
}

const T0 = Date.now();
const results = [];
const cleanups = [];
const tmpRoot = fs.mkdtempSync(path.join(os.tmpdir(), 'blueshift-e2e-'));

// ---- reporting ----

async function check(name, fn) {
  const t = Date.now();
  try {
    await fn();
    results.push({ name, ok: true });
    console.log(`ok ${name} (${Date.now() - t} ms)`);
  } catch (e) {
    const why = String(e && e.message ? e.message : e).replace(/\s+/g, ' ').slice(0, 600);
    results.push({ name, ok: false, why });
    console.log(`FAIL ${name}: ${why}`);
  }
}

function assert(cond, msg) {
  if (!cond) throw new Error(msg);
}

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

/** Polls fn() until it returns a truthy value; throws `what` after timeoutMs. */
async function until(fn, what, timeoutMs = 15000, everyMs = 25) {
  const t0 = Date.now();
  for (;;) {
    const v = await fn();
    if (v) return v;
    if (Date.now() - t0 > timeoutMs)
      throw new Error(`timed out after ${timeoutMs} ms: ${typeof what === 'function' ? what() : what}`);
    await sleep(everyMs);
  }
}

// ---- the server ----

/** Starts `blueshift view ARGS --port 0 --save-dir DIR/saved`; resolves once it printed its URL. */
async function startViewer(label, args) {
  const dir = fs.mkdtempSync(path.join(tmpRoot, `${label}-`));
  const saveDir = path.join(dir, 'saved');
  const child = spawn(BIN, ['view', ...args, '--port', '0', '--save-dir', saveDir], {
    cwd: dir,
    stdio: ['ignore', 'pipe', 'pipe'],
  });
  let stderr = '';
  child.stderr.on('data', (d) => {
    stderr = (stderr + d).slice(-4000);
  });
  const v = {
    child,
    dir,
    saveDir,
    stderr: () => stderr,
    stop() {
      if (child.exitCode === null && child.signalCode === null) child.kill('SIGKILL');
    },
  };
  cleanups.push(() => v.stop());
  const line = await new Promise((resolve, reject) => {
    const rl = readline.createInterface({ input: child.stdout });
    const timer = setTimeout(() => reject(new Error(`no URL within 30 s; stderr: ${stderr}`)), 30000);
    rl.once('line', (l) => {
      clearTimeout(timer);
      resolve(l);
    });
    child.once('exit', (code) => {
      clearTimeout(timer);
      reject(new Error(`blueshift view exited (${code}) before printing its URL; stderr: ${stderr}`));
    });
  });
  const m = /^blueshift view: (http:\/\/([^/]+)\/([0-9a-f]{32})\/)$/.exec(line.trim());
  if (!m) throw new Error(`unexpected first line: ${JSON.stringify(line)}`);
  v.url = m[1];
  v.authority = m[2];
  v.token = m[3];
  v.port = Number(m[2].split(':').pop());
  return v;
}

/** GET with an explicit Host header; resolves {status, body}. */
function rawGet(v, pathName, host) {
  return new Promise((resolve, reject) => {
    const req = http.request(
      { host: '127.0.0.1', port: v.port, path: pathName, method: 'GET', headers: { Host: host }, agent: false },
      (res) => {
        let body = '';
        res.setEncoding('utf8');
        res.on('data', (d) => (body += d));
        res.on('end', () => resolve({ status: res.statusCode, body }));
      },
    );
    req.on('error', reject);
    req.setTimeout(10000, () => req.destroy(new Error('timeout')));
    req.end();
  });
}

/** Splits a printed (POSIX-shell-quoted) command line into words. */
function shellWords(cmd) {
  const words = [];
  let cur = null;
  for (let i = 0; i < cmd.length; i++) {
    const c = cmd[i];
    if (c === "'") {
      const j = cmd.indexOf("'", i + 1);
      if (j < 0) throw new Error(`unbalanced quote in ${cmd}`);
      cur = (cur ?? '') + cmd.slice(i + 1, j);
      i = j;
    } else if (c === '"') {
      let s = '';
      for (i++; i < cmd.length && cmd[i] !== '"'; i++) s += cmd[i] === '\\' ? cmd[++i] : cmd[i];
      cur = (cur ?? '') + s;
    } else if (c === '\\') {
      cur = (cur ?? '') + cmd[++i];
    } else if (/\s/.test(c)) {
      if (cur !== null) words.push(cur);
      cur = null;
    } else cur = (cur ?? '') + c;
  }
  if (cur !== null) words.push(cur);
  return words;
}

/** Runs a printed `blueshift ...` command with the binary under test. */
function runCommand(cmd, extra, cwd) {
  const words = shellWords(cmd);
  assert(words[0] === 'blueshift', `the printed command does not start with blueshift: ${cmd}`);
  const out = spawnSync(BIN, [...words.slice(1), ...extra], { cwd, encoding: 'utf8', timeout: 60000 });
  assert(out.status === 0, `${cmd} ${extra.join(' ')} failed (${out.status}): ${out.stderr}`);
  return out;
}

/** Flux-weighted centroid of CSV points over [a, b] by exact trapezoid moments (as view.rs). */
function csvCentroid(csv, a, b) {
  const pts = csv
    .trim()
    .split('\n')
    .slice(1)
    .map((l) => l.split(',').map(Number));
  let m0 = 0;
  let m1 = 0;
  for (let i = 0; i + 1 < pts.length; i++) {
    const [x0, y0] = pts[i];
    const [x1, y1] = pts[i + 1];
    const l0 = Math.max(x0, a);
    const l1 = Math.min(x1, b);
    if (l1 <= l0 || x1 <= x0) continue;
    const at = (x) => y0 + ((y1 - y0) * (x - x0)) / (x1 - x0);
    const f0 = at(l0);
    const f1 = at(l1);
    const d = l1 - l0;
    m0 += 0.5 * (f0 + f1) * d;
    m1 += (d * (f0 * (2 * l0 + l1) + f1 * (l0 + 2 * l1))) / 6;
  }
  return m1 / m0;
}

/**
 * HDR VolVis Eq. 2 for one focus region (centre c, width w, magnification M, transition
 * tr) lying inside [0, 1]: the context magnification and the integral of the profile.
 */
function fisheyeClosedForm(c, w, M, tr) {
  const mMin = (1 - M * (w + tr)) / (1 - w - tr);
  const a = c - w / 2 - tr;
  const b = c - w / 2;
  const d = c + w / 2;
  const e = c + w / 2 + tr;
  const k = (M - mMin) / tr; // slope of the transitions
  const Fa = mMin * a;
  const Fb = Fa + 0.5 * (mMin + M) * tr;
  const Fd = Fb + M * w;
  const Fe = Fd + 0.5 * (M + mMin) * tr;
  const forward = (t) => {
    if (t <= a) return mMin * t;
    if (t <= b) return Fa + mMin * (t - a) + 0.5 * k * (t - a) ** 2;
    if (t <= d) return Fb + M * (t - b);
    if (t <= e) return Fd + M * (t - d) - 0.5 * k * (t - d) ** 2;
    return Fe + mMin * (t - e);
  };
  return { mMin, forward, knots: [a, b, c, d, e] };
}

// ---- the page ----

let context;

async function openPage(v) {
  const page = await context.newPage();
  const errors = [];
  page.on('pageerror', (e) => errors.push(String(e)));
  page.on('console', (m) => {
    if (m.type() === 'error') errors.push(m.text());
  });
  page.errors = errors;
  const res = await page.goto(v.url, { waitUntil: 'load', timeout: 15000 });
  assert(res && res.status() === 200, `GET ${v.url}: status ${res && res.status()}`);
  await page.waitForFunction(() => window.blueshift && window.blueshift.info, null, { timeout: 10000 });
  return page;
}

const hook = (page, expr) => page.evaluate(expr);

/** The status line's samples so far and target (`pass P · S/T spp · ...`). */
function parseStatus(text) {
  const m = /(\d+)\/(\d+) spp/.exec(text);
  return { spp: m ? Number(m[1]) : NaN, target: m ? Number(m[2]) : NaN, full: / full/.test(text), done: / done/.test(text) };
}

/**
 * Waits until the page shows a finished full-resolution frame newer than `afterSeq` (the
 * status line says `full · done` at the target spp) and no new frame arrived for `quietMs`
 * (the last edit's render is complete).
 */
async function settled(page, afterSeq = -1, timeoutMs = 30000, quietMs = 350) {
  let last = null;
  let since = Date.now();
  await until(
    async () => {
      const s = await page.evaluate(() => ({
        frames: window.blueshift.frames,
        f: window.blueshift.lastFrame,
        status: document.getElementById('status').textContent,
      }));
      if (!last || s.frames !== last.frames || s.status !== last.status) {
        last = s;
        since = Date.now();
        return false;
      }
      const st = parseStatus(s.status);
      return s.f && s.f.seq > afterSeq && !s.f.preview && st.full && st.done && st.spp >= st.target &&
        Date.now() - since >= quietMs;
    },
    () => `a finished frame after seq ${afterSeq} (last status: ${last && last.status})`,
    timeoutMs,
  );
  return page.evaluate(() => window.blueshift.lastFrame);
}

/** Page coordinates -> viewport coordinates for page.mouse (the page may be scrolled). */
async function toViewport(page, p) {
  const s = await page.evaluate(() => [window.scrollX, window.scrollY]);
  return { x: p.x - s[0], y: p.y - s[1] };
}

/** Waits for the next download the page offers and returns its text. */
async function downloadText(page, click) {
  const [dl] = await Promise.all([page.waitForEvent('download', { timeout: 10000 }), click()]);
  const file = await dl.path();
  return fs.readFileSync(file, 'utf8');
}

const close = (a, b, tol) => Math.abs(a - b) <= tol;

// ---- scenarios ----

async function trackingScenario() {
  let v;
  await check('tracking: the server starts and prints its URL', async () => {
    v = await startViewer('tracking', [
      '--synth', 'three-cubes', '--res', '32', '--width', '128', '--height', '128', '--spp', '8',
    ]);
  });
  if (!v) return;
  let page;

  await check('page loads with the token and shows a non-blank frame', async () => {
    const t = Date.now();
    page = await openPage(v);
    await until(
      () => page.evaluate(() => window.blueshift.frames > 0 && window.blueshift.meanLuminance() > 0),
      'a drawn frame with mean luminance > 0',
      5000,
    );
    const mode = await page.textContent('#mode');
    assert(mode === 'tracking', `#mode shows ${mode}`);
    const lum = await hook(page, () => window.blueshift.meanLuminance());
    console.log(`  first frame after ${Date.now() - t} ms, mean luminance ${lum.toFixed(4)}`);
  });
  if (!page) return;

  await check('a wrong token and the bare root are refused (404, no page)', async () => {
    const p = await context.newPage();
    try {
      const wrong = '0'.repeat(32);
      for (const u of [`http://${v.authority}/${wrong}/`, `http://${v.authority}/`, `http://${v.authority}/app.js`]) {
        const res = await p.goto(u, { waitUntil: 'load', timeout: 10000 });
        assert(res && res.status() === 404, `${u}: status ${res && res.status()} (want 404)`);
        await sleep(150);
        const has = await p.evaluate(() => typeof window.blueshift !== 'undefined' || !!document.getElementById('view'));
        assert(!has, `${u}: the page (or window.blueshift) is there`);
      }
      // The WebSocket under a wrong token does not open either.
      const opened = await p.evaluate(
        (u) =>
          new Promise((resolve) => {
            const ws = new WebSocket(u);
            ws.onopen = () => resolve(true);
            ws.onerror = () => resolve(false);
            setTimeout(() => resolve(false), 3000);
          }),
        `ws://${v.authority}/${wrong}/ws`,
      );
      assert(!opened, 'a WebSocket under a wrong token opened');
    } finally {
      await p.close();
    }
  });

  await check('a foreign Host header is refused (403)', async () => {
    const ok = await rawGet(v, `/${v.token}/`, v.authority);
    assert(ok.status === 200, `own Host: status ${ok.status}`);
    const bad = await rawGet(v, `/${v.token}/`, `evil.example:${v.port}`);
    assert(bad.status === 403, `Host evil.example:${v.port}: status ${bad.status} (want 403)`);
    assert(!bad.body.includes('app.js'), 'the refused reply carries the page');
  });

  await check('dragging an opacity knot up brightens the frame', async () => {
    const f0 = await settled(page);
    const before = await hook(page, () => window.blueshift.meanLuminance());
    const tf = await page.evaluate(() => window.blueshift.info.channels[window.blueshift.tf.channel].tf);
    // The knot with the lowest opacity (an inner one when tied): dragged to the top.
    let best = 0;
    tf.opacity.forEach((k, i) => {
      if (k.alpha < tf.opacity[best].alpha - 1e-12) best = i;
    });
    await page.locator('#tf-canvas').scrollIntoViewIfNeeded();
    const p = await toViewport(page, await page.evaluate((i) => window.blueshift.tf.knotScreenPos('opacity', i), best));
    const box = await page.locator('#tf-canvas').boundingBox();
    await page.mouse.move(p.x, p.y);
    await page.mouse.down();
    await page.mouse.move(p.x, box.y + 2, { steps: 10 });
    await page.mouse.up();
    const moved = await toViewport(page, await page.evaluate((i) => window.blueshift.tf.knotScreenPos('opacity', i), best));
    assert(moved.y < p.y - 10, `knot ${best} did not move up (y ${p.y} -> ${moved.y})`);
    await settled(page, f0.seq);
    const after = await hook(page, () => window.blueshift.meanLuminance());
    console.log(`  knot ${best} alpha ${tf.opacity[best].alpha} -> top: mean luminance ${before.toFixed(4)} -> ${after.toFixed(4)}`);
    assert(after > before, `mean luminance did not rise: ${before} -> ${after}`);
  });

  const ts = [0, 0.05, 0.2, 0.3, 0.34, 0.37, 0.4, 0.43, 0.46, 0.5, 0.52, 0.6, 0.8, 0.95, 1];
  const compareFisheye = (got, c, w, M, tr) => {
    const cf = fisheyeClosedForm(c, w, M, tr);
    assert(close(got.mMin, cf.mMin, 1e-12), `M_min ${got.mMin}, Eq. 2 gives ${cf.mMin}`);
    const all = [...ts, ...cf.knots];
    all.forEach((t, i) => {
      const want = cf.forward(t);
      assert(close(got.fw[i], want, 1e-9), `forward(${t}) = ${got.fw[i]}, closed form ${want}`);
    });
    assert(Math.abs(got.fw[all.indexOf(c)] - c) > 1e-6 || c === 0.5, 'the focus does not move the axis');
    return all;
  };

  await check('fisheye focus (hook addFocus) maps the axis as Eq. 2', async () => {
    const [c, w, M, tr] = [0.4, 0.1, 4, 0.05];
    const cf = fisheyeClosedForm(c, w, M, tr);
    const all = [...ts, ...cf.knots];
    const got = await page.evaluate(
      ({ c, w, M, tr, all }) => {
        const bs = window.blueshift.tf;
        const before = bs.knotScreenPos('opacity', 0).x;
        bs.addFocus(c, w, M, tr);
        const fe = bs.fisheye;
        return {
          mMin: fe.mMin,
          fw: all.map((t) => fe.forward(t)),
          inv: all.map((t) => fe.inverse(fe.forward(t))),
          regions: fe.regions,
          mminText: document.getElementById('tf-mmin').textContent,
          before,
        };
      },
      { c, w, M, tr, all },
    );
    assert(got.regions.length === 1, `${got.regions.length} regions`);
    compareFisheye(got, c, w, M, tr);
    all.forEach((t, i) => assert(close(got.inv[i], t, 1e-9), `inverse(forward(${t})) = ${got.inv[i]}`));
    assert(got.mminText === cf.mMin.toFixed(3), `#tf-mmin shows ${got.mminText}, want ${cf.mMin.toFixed(3)}`);
  });

  await check('fisheye focus (the "+ focus" button, another channel) maps the axis as Eq. 2', async () => {
    const tabs = page.locator('#tf-tabs button');
    assert((await tabs.count()) >= 2, 'fewer than two channel tabs');
    await tabs.nth(1).click();
    assert((await hook(page, () => window.blueshift.tf.channel)) === 1, 'the second tab is not selected');
    const lin = await page.evaluate(() => window.blueshift.tf.fisheye.forward(0.3));
    assert(close(lin, 0.3, 1e-12), `channel 1 starts with a non-identity axis: forward(0.3) = ${lin}`);
    await page.click('#tf-add-focus');
    const regions = await page.evaluate(() => window.blueshift.tf.fisheye.regions);
    assert(regions.length === 1, `${regions.length} regions after the button`);
    const r = regions[0];
    const cf = fisheyeClosedForm(r.center, r.width, r.magnification, r.transition);
    const all = [...ts, ...cf.knots];
    const got = await page.evaluate((all) => {
      const fe = window.blueshift.tf.fisheye;
      return { mMin: fe.mMin, fw: all.map((t) => fe.forward(t)) };
    }, all);
    compareFisheye(got, r.center, r.width, r.magnification, r.transition);
    console.log(
      `  region c=${r.center} w=${r.width} M=${r.magnification} tr=${r.transition}: M_min ${got.mMin.toFixed(6)}`,
    );
    await tabs.nth(0).click();
  });

  await check('a malformed WebSocket message gets an error and the next frame still arrives', async () => {
    // Raw text on a second socket of the page (window.blueshift.send only sends JSON).
    const r = await page.evaluate(
      () =>
        new Promise((resolve) => {
          const url = new URL('ws', location.href);
          url.protocol = 'ws:';
          const ws = new WebSocket(url);
          ws.binaryType = 'arraybuffer';
          let phase = 'info';
          let error = null;
          const done = (v) => {
            ws.close();
            resolve(v);
          };
          const timer = setTimeout(() => done({ error, phase, timeout: true }), 20000);
          ws.onmessage = (ev) => {
            if (typeof ev.data !== 'string') {
              if (phase === 'frame') {
                const n = new DataView(ev.data).getUint32(0, true);
                const h = JSON.parse(new TextDecoder().decode(new Uint8Array(ev.data, 4, n)));
                clearTimeout(timer);
                done({ error, header: h });
              }
              return;
            }
            const m = JSON.parse(ev.data);
            if (phase === 'info' && m.type === 'info') {
              phase = 'error';
              ws.send('garbage');
            } else if (phase === 'error' && m.type === 'error') {
              error = m;
              phase = 'frame';
              ws.send(JSON.stringify({ type: 'view', name: 'iso' }));
            }
          };
          ws.onerror = () => done({ error, phase, wsError: true });
        }),
    );
    assert(r.error, `no error reply to 'garbage' (${JSON.stringify(r)})`);
    assert(typeof r.error.message === 'string' && r.error.message.length > 0 && !r.error.message.includes('\n'),
      `bad error message ${JSON.stringify(r.error)}`);
    assert(r.header && r.header.kind === 'frame', `no frame after the edit (${JSON.stringify(r)})`);
    // And on the page's own socket: a bad (JSON) message shows an error, the page still draws.
    const f0 = await settled(page);
    await page.evaluate(() => {
      window.blueshift.lastError = null;
      window.blueshift.send({ type: 'settings', spp: 0 });
    });
    const err = await until(() => page.evaluate(() => window.blueshift.lastError), 'an error reply on the page', 5000);
    assert(err.request === 'settings', `error ${JSON.stringify(err)}`);
    const msg = await page.textContent('#message');
    assert(/error/.test(msg), `#message shows ${JSON.stringify(msg)}`);
    await page.locator('#presets button', { hasText: /^x$/ }).click();
    await until(
      () => page.evaluate((s) => window.blueshift.lastFrame.seq > s, f0.seq),
      'a frame after the preset click',
      10000,
    );
    await settled(page, f0.seq);
  });

  await check('save writes the EXR its printed command writes (byte for byte)', async () => {
    await settled(page);
    await page.evaluate(() => (window.blueshift.lastSaved = null));
    await page.fill('#save-name', 'e2e-tracking');
    await page.click('#save');
    const saved = await until(() => page.evaluate(() => window.blueshift.lastSaved), 'a saved reply', 20000);
    const shown = await page.textContent('#command');
    assert(shown === saved.command, `#command shows ${shown}`);
    assert(saved.command.startsWith('blueshift render '), saved.command);
    const exr = saved.files.find((f) => f.endsWith('.exr'));
    assert(exr && fs.existsSync(exr), `no EXR among ${saved.files}`);
    const aside = exr.replace(/\.exr$/, '.viewer.exr');
    fs.renameSync(exr, aside);
    runCommand(saved.command, [], v.dir);
    const a = fs.readFileSync(aside);
    const b = fs.readFileSync(exr);
    assert(a.equals(b), `${saved.command}: its EXR (${b.length} bytes) differs from the viewer's (${a.length} bytes)`);
  });

  await check('TF export as ParaView preset round-trips through tf_load', async () => {
    const norm = (t) => JSON.parse(t);
    await page.selectOption('#tf-format', 'blueshift');
    const a = norm(await downloadText(page, () => page.click('#tf-export')));
    await page.selectOption('#tf-format', 'paraview');
    const pvText = await downloadText(page, () => page.click('#tf-export'));
    const pv = norm(pvText);
    assert(!pv.format || pv.format !== 'blueshift-transfer-function', 'the ParaView export is blueshift JSON');
    // Put a different TF on the channel first, so that the load visibly restores it.
    const f0 = await settled(page);
    await page.evaluate(
      (a) => {
        const t = structuredClone(a);
        t.opacity = [
          { x: t.domain[0], alpha: 0 },
          { x: t.domain[1], alpha: 0.01 },
        ];
        window.blueshift.send({ type: 'tf', channel: window.blueshift.tf.channel, tf: t });
      },
      a,
    );
    await settled(page, f0.seq);
    // Load the preset through the page's file input.
    const file = path.join(v.dir, 'exported.paraview.json');
    fs.writeFileSync(file, pvText);
    const f1 = await hook(page, () => window.blueshift.lastFrame);
    await page.setInputFiles('#tf-file', file);
    await settled(page, f1.seq);
    const err = await hook(page, () => window.blueshift.lastError);
    assert(!err || err.request !== 'tf_load', `tf_load refused: ${JSON.stringify(err)}`);
    await page.selectOption('#tf-format', 'blueshift');
    const b = norm(await downloadText(page, () => page.click('#tf-export')));
    const diffs = [];
    const cmp = (what, x, y, tol = 1e-6) => {
      if (!close(x, y, tol * Math.max(1, Math.abs(x)))) diffs.push(`${what}: ${x} vs ${y}`);
    };
    cmp('domain lo', a.domain[0], b.domain[0]);
    cmp('domain hi', a.domain[1], b.domain[1]);
    if (a.opacity.length !== b.opacity.length) diffs.push(`opacity knots ${a.opacity.length} vs ${b.opacity.length}`);
    else
      a.opacity.forEach((k, i) => {
        cmp(`opacity[${i}].x`, k.x, b.opacity[i].x);
        cmp(`opacity[${i}].alpha`, k.alpha, b.opacity[i].alpha);
      });
    if (a.color.length !== b.color.length) diffs.push(`colour knots ${a.color.length} vs ${b.color.length}`);
    else
      a.color.forEach((k, i) => {
        cmp(`color[${i}].x`, k.x, b.color[i].x);
        k.rgb.forEach((c, j) => cmp(`color[${i}].rgb[${j}]`, c, b.color[i].rgb[j]));
      });
    if (a.color_space !== b.color_space) diffs.push(`color_space ${a.color_space} vs ${b.color_space}`);
    assert(diffs.length === 0, `the round trip changed the TF: ${diffs.slice(0, 6).join('; ')}`);
  });

  await check('tracking: no page errors', async () => {
    assert(page.errors.length === 0, page.errors.slice(0, 3).join(' | '));
  });
  await page.close();
  v.stop();
}

async function dopplerScenario() {
  let v;
  await check('doppler: the server starts and prints its URL', async () => {
    v = await startViewer('doppler', ['--synth', 'galaxy', '--doppler', '--res', '24', '--width', '64', '--height', '64']);
  });
  if (!v) return;
  let page;
  await check('doppler: the page loads and shows a frame', async () => {
    page = await openPage(v);
    assert((await page.textContent('#mode')) === 'doppler', 'not in doppler mode');
    const f0 = await settled(page, -1, 30000);
    // A moved camera (the iso preset), so the printed command must carry it.
    await page.locator('#presets button', { hasText: /^iso$/ }).click();
    await settled(page, f0.seq, 30000);
  });
  if (!page) return;

  await check('doppler: a click on a pixel plots the spectrum with the centroids of `doppler --pick`', async () => {
    // The brightest pixel of the drawn frame (so that its lines carry flux).
    const px = await page.evaluate(() => {
      const cv = document.getElementById('view');
      const { data } = cv.getContext('2d').getImageData(0, 0, cv.width, cv.height);
      let best = 0;
      let bi = 0;
      for (let i = 0; i < data.length; i += 4) {
        const l = 0.2126 * data[i] + 0.7152 * data[i + 1] + 0.0722 * data[i + 2];
        if (l > best) [best, bi] = [l, i / 4];
      }
      return { x: bi % cv.width, y: Math.floor(bi / cv.width), w: cv.width, h: cv.height };
    });
    const box = await page.locator('#view').boundingBox();
    const cx = box.x + ((px.x + 0.5) / px.w) * box.width;
    const cy = box.y + ((px.y + 0.5) / px.h) * box.height;
    await page.evaluate(() => (window.blueshift.lastSpectrum = null));
    await page.mouse.click(cx, cy);
    const sp = await until(() => page.evaluate(() => window.blueshift.lastSpectrum), 'a spectrum after the click', 20000);
    assert(sp.x === px.x && sp.y === px.y, `clicked pixel (${px.x}, ${px.y}), the page picked (${sp.x}, ${sp.y})`);
    // The plot is drawn (not blank).
    await sleep(100);
    const ink = await page.evaluate(() => {
      const cv = document.getElementById('spectrum-canvas');
      if (!cv.width || !cv.height) return { n: 0, w: cv.width, h: cv.height };
      const { data } = cv.getContext('2d').getImageData(0, 0, cv.width, cv.height);
      const first = data.slice(0, 4).join();
      let n = 0;
      for (let i = 0; i < data.length; i += 4) if (data.slice(i, i + 4).join() !== first) n++;
      return { n, w: cv.width, h: cv.height };
    });
    assert(ink.n > 50, `#spectrum-canvas (${ink.w}x${ink.h}) is blank (${ink.n} pixels differ from the corner)`);
    // The printed command of a save, with --pick X,Y.
    await page.evaluate(() => (window.blueshift.lastSaved = null));
    await page.click('#save');
    const saved = await until(() => page.evaluate(() => window.blueshift.lastSaved), 'a saved reply', 20000);
    const { x, y } = sp;
    runCommand(saved.command, ['--pick', `${x},${y}`], v.dir);
    const words = shellWords(saved.command);
    const out = words[words.indexOf('--out') + 1];
    assert(out, `no --out in ${saved.command}`);
    const csvPath = path.join(path.dirname(out), `${path.basename(out).replace(/\.[^.]+$/, '')}_pick_${x}_${y}.csv`);
    assert(fs.existsSync(csvPath), `the CLI wrote no ${csvPath}`);
    const csv = fs.readFileSync(csvPath, 'utf8');
    let checked = 0;
    const report = [];
    for (const line of sp.lines) {
      if (line.centroid_nm === null || line.centroid_nm === undefined) continue;
      assert(Array.isArray(line.window_nm), `line ${line.name} has no window_nm`);
      const cli = csvCentroid(csv, line.window_nm[0], line.window_nm[1]);
      assert(
        Math.abs(cli - line.centroid_nm) <= 1e-6,
        `${line.name}: page ${line.centroid_nm} nm, CLI pick ${cli} nm (differ by ${Math.abs(cli - line.centroid_nm)})`,
      );
      report.push(`${line.name} ${line.centroid_nm.toFixed(4)}`);
      checked++;
    }
    assert(checked >= 1, `no line carries flux at (${x}, ${y})`);
    console.log(`  pixel (${x}, ${y}): ${report.join(', ')} nm`);
  });

  await check('doppler: the velocity panel button shows a velocity frame', async () => {
    await page.locator('#panel-doppler button', { hasText: 'velocity panel' }).click();
    await until(() => page.evaluate(() => !document.getElementById('panel-velocity').hidden), '#panel-velocity shown', 20000);
    const r = await until(
      () =>
        page.evaluate(() => {
          const cv = document.getElementById('velocity');
          if (!cv.width || !cv.height) return null;
          const { data } = cv.getContext('2d').getImageData(0, 0, cv.width, cv.height);
          let lit = 0;
          for (let i = 0; i < data.length; i += 4) if (data[i] + data[i + 1] + data[i + 2] > 0) lit++;
          return lit > 0 ? { w: cv.width, h: cv.height, lit } : null;
        }),
      'a non-blank velocity panel',
      20000,
    );
    console.log(`  velocity panel ${r.w}x${r.h}, ${r.lit} lit pixels`);
  });

  await check('doppler: the observer beta slider re-renders, and its save command writes the same EXR', async () => {
    const before = await settled(page);
    await page.evaluate(() => {
      const s = document.getElementById('observer-beta');
      s.value = '0.4';
      s.dispatchEvent(new Event('input'));
      s.dispatchEvent(new Event('change'));
    });
    await settled(page, before.seq, 30000);
    await page.evaluate(() => (window.blueshift.lastSaved = null));
    await page.click('#save');
    const saved = await until(() => page.evaluate(() => window.blueshift.lastSaved), 'a saved reply', 20000);
    assert(/ --beta 0\.4( |$)/.test(saved.command), `no --beta 0.4 in ${saved.command}`);
    const exr = saved.files.find((f) => f.endsWith('.exr'));
    assert(exr && fs.existsSync(exr), `no EXR among ${saved.files}`);
    const aside = exr.replace(/\.exr$/, '.viewer.exr');
    fs.renameSync(exr, aside);
    runCommand(saved.command, [], v.dir);
    assert(
      fs.readFileSync(aside).equals(fs.readFileSync(exr)),
      `${saved.command}: its EXR differs from the viewer's`,
    );
  });

  await check('doppler: no page errors', async () => {
    assert(page.errors.length === 0, page.errors.slice(0, 3).join(' | '));
  });
  await page.close();
  v.stop();
}

async function frameRateScenario() {
  let v;
  await check('frame rate: the server starts', async () => {
    v = await startViewer('fps', ['--synth', 'three-cubes', '--res', '64', '--width', '256', '--height', '256', '--spp', '64']);
  });
  if (!v) return;
  await check('frame rate while refining (256x256, 64 spp)', async () => {
    const page = await openPage(v);
    try {
      await settled(page, -1, 60000);
      // Count the frames drawn over one refinement after an edit (a view preset).
      const r = await page.evaluate(
        () =>
          new Promise((resolve) => {
            const bs = window.blueshift;
            const seq0 = bs.lastFrame.seq;
            const frames0 = bs.frames;
            const t0 = performance.now();
            let tFirst = null;
            let fFirst = 0;
            bs.send({ type: 'view', name: 'iso' });
            const poll = () => {
              const f = bs.lastFrame;
              const status = document.getElementById('status').textContent;
              if (f.seq > seq0 && tFirst === null) {
                tFirst = performance.now();
                fFirst = bs.frames;
              }
              if (f.seq > seq0 && !f.preview && / full · done/.test(status) && /(\d+)\/\1 spp/.test(status)) {
                const t1 = performance.now();
                resolve({ frames: bs.frames - frames0, ms: t1 - t0, refineFrames: bs.frames - fFirst, refineMs: t1 - tFirst, status });
              } else if (performance.now() - t0 > 45000) resolve({ timeout: true, frames: bs.frames - frames0, status });
              else setTimeout(poll, 10);
            };
            poll();
          }),
      );
      assert(!r.timeout, `the refinement did not finish in 45 s (${r.frames} frames; ${r.status})`);
      const fps = (r.frames / r.ms) * 1000;
      console.log(
        `note fps: ${fps.toFixed(1)} frames/s seen by the page over one refinement of 256x256 to 64 spp ` +
          `(${r.frames} frames in ${(r.ms / 1000).toFixed(2)} s; status: ${r.status})`,
      );
      assert(r.frames >= 2, `only ${r.frames} frames over the refinement`);
    } finally {
      await page.close();
    }
  });
  v.stop();
}

// ---- main ----

async function main() {
  const profile = fs.mkdtempSync(path.join(tmpRoot, 'profile-'));
  await check('chromium starts', async () => {
    context = await chromium.launchPersistentContext(profile, {
      executablePath: CHROMIUM,
      headless: true,
      args: [
        '--headless',
        '--no-sandbox',
        '--disable-gpu',
        '--disable-background-networking',
        '--disable-component-update',
        '--no-first-run',
      ],
      viewport: { width: 1280, height: 1100 },
      acceptDownloads: true,
      timeout: 30000,
    });
  });
  if (context) {
    await trackingScenario();
    await dopplerScenario();
    await frameRateScenario();
    await context.close();
  }
}

let code = 0;
try {
  await main();
} catch (e) {
  console.log(`FAIL harness: ${e && e.stack ? e.stack : e}`);
  results.push({ name: 'harness', ok: false });
} finally {
  for (const c of cleanups) {
    try {
      c();
    } catch {
      // already gone
    }
  }
  const failed = results.filter((r) => !r.ok);
  console.log(
    `${failed.length ? 'FAILED' : 'passed'}: ${results.length - failed.length} ok, ${failed.length} failed ` +
      `(${((Date.now() - T0) / 1000).toFixed(1)} s)`,
  );
  for (const f of failed) console.log(`  failed: ${f.name}`);
  code = failed.length || results.length === 0 ? 1 : 0;
  try {
    fs.rmSync(tmpRoot, { recursive: true, force: true });
  } catch {
    // leave it
  }
}
process.exit(code);
