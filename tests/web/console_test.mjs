// The web console in Debian's Chromium (playwright-core), against a server with a small
// simulated map and two versions (tests/web/console_test.sh sets it up): the page loads
// with no console errors, renders landmark features (asked of the map, not the DOM),
// toggles layers, shows the diff between the two versions as the server computes it, draws
// the stored HD-map comparison (matched and unmatched features, summary), shows a
// landmark's first/last seen and version history in its popup, lists
// the fleet with an operator key that never reaches the URL or the server's log, is served
// with the security headers a console needs, and works on a phone-sized viewport.
// Screenshots go to $POLMAP_ARTIFACTS.
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import { createRequire } from 'node:module';

const require = createRequire(path.resolve('web/console/package.json'));
const { chromium } = require('playwright-core');

const URL = process.env.POLMAP_URL;
const KEY = process.env.POLMAP_KEY;
const ART = process.env.POLMAP_ARTIFACTS;
const LOG = process.env.POLMAP_SERVER_LOG;
assert.ok(URL && KEY && ART && LOG, 'POLMAP_URL, POLMAP_KEY, POLMAP_ARTIFACTS, POLMAP_SERVER_LOG');

let failures = 0;
async function check(name, fn) {
  try {
    await fn();
    console.log('ok   ' + name);
  } catch (e) {
    failures++;
    console.log('FAIL ' + name + '\n     ' + String(e.stack || e).split('\n').slice(0, 12).join('\n     '));
  }
}

// ---------------------------------------------------------------- headers (no browser)
await check('the page is served with a strict CSP and the usual headers', async () => {
  const res = await fetch(URL + '/');
  assert.equal(res.status, 200);
  assert.match(res.headers.get('content-type'), /^text\/html/);
  const csp = res.headers.get('content-security-policy') || '';
  assert.match(csp, /worker-src blob:/);
  assert.match(csp, /script-src 'self'/);
  assert.match(csp, /frame-ancestors 'none'/);
  assert.doesNotMatch(csp, /unsafe-inline|unsafe-eval/);
  assert.equal(res.headers.get('x-content-type-options'), 'nosniff');
  assert.equal(res.headers.get('referrer-policy'), 'no-referrer');
  const html = await res.text();
  assert.doesNotMatch(html, /<script>|<script [^>]*>[^<]+<\/script>|\son[a-z]+=/i, 'no inline script or handler');
  const js = await fetch(URL + '/console/maplibre-gl.js');
  assert.equal(js.status, 200);
  assert.ok((await js.arrayBuffer()).byteLength > 100000, 'MapLibre GL JS comes from this server');
  assert.equal((await fetch(URL + '/console/nope.js')).status, 404);
});

const browser = await chromium.launch({
  executablePath: process.env.POLMAP_CHROMIUM || '/usr/bin/chromium',
  headless: true,
  // CI runs as root (no sandbox there); WebGL on the CPU (SwiftShader), no GPU.
  args: ['--no-sandbox', '--disable-dev-shm-usage', '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist'],
});
// Playwright's waitForFunction evaluates its predicate with eval in the page, which the
// console's CSP forbids (as it should); page.evaluate goes through the debugger protocol.
async function waitFor(page, fn, arg, timeoutMs = 60000) {
  const end = Date.now() + timeoutMs;
  for (;;) {
    if (await page.evaluate(fn, arg)) return;
    if (Date.now() > end) throw new Error('timed out waiting for ' + fn.toString().slice(0, 80));
    await new Promise((r) => setTimeout(r, 100));
  }
}
const errors = [];
const externalRequests = [];
async function openConsole(viewport) {
  const page = await browser.newPage({ viewport });
  // Playwright's own waits (waitForSelector, click) default to 30 s; software WebGL on a
  // loaded 2-core machine can take longer to render a popup, so they get waitFor's 60 s
  // (a margin for a loaded machine; the one failure traced so far was a race in
  // console.js's build status, fixed there).
  page.setDefaultTimeout(60000);
  page.on('console', (m) => { if (m.type() === 'error') errors.push(m.text()); });
  page.on('pageerror', (e) => errors.push('pageerror: ' + e.message));
  page.on('response', (r) => { if (r.status() >= 400) errors.push(r.status() + ' ' + r.url()); });
  page.on('request', (r) => {
    const u = r.url();
    if (!u.startsWith(URL) && !u.startsWith('blob:') && !u.startsWith('data:')) externalRequests.push(u);
  });
  await page.goto(URL + '/', { waitUntil: 'load' });
  await waitFor(page, () => window.polmapConsole && window.polmapConsole.ready === true);
  return page;
}

const page = await openConsole({ width: 1280, height: 800 });
const renderedCount = (layer) => page.evaluate((l) => window.polmapConsole.map.queryRenderedFeatures({ layers: [l] }).length, layer);
const idle = () => page.evaluate(() => new Promise((r) => {
  const m = window.polmapConsole.map;
  if (m.loaded() && !m.isMoving()) { m.once('idle', r); m.triggerRepaint(); } else { m.once('idle', r); }
}));

await check('the map renders point and line landmarks of the current version', async () => {
  assert.ok((await page.evaluate(() => document.documentElement.scrollHeight)) <= 800, 'the page itself does not scroll');
  const label = await page.textContent('#version-label');
  const list = await (await fetch(URL + '/v1/maps')).json();
  assert.equal(label, 'map version ' + list.current);
  // The whole map in view.
  await page.evaluate(async () => {
    const tj = await (await fetch('/v1/tilejson.json')).json();
    const b = tj.bounds;
    window.polmapConsole.map.fitBounds([[b[0], b[1]], [b[2], b[3]]], { animate: false, padding: 20 });
  });
  await idle();
  const points = await renderedCount('points');
  const lines = await renderedCount('lines');
  assert.ok(points > 0, 'point features rendered: ' + points);
  assert.ok(lines > 0, 'line features rendered: ' + lines);
  const classes = await page.evaluate(() => [...new Set(window.polmapConsole.map.queryRenderedFeatures({ layers: ['points'] }).map((f) => f.properties.class))]);
  assert.ok(classes.every((c) => ['odd', 'even', 'mixed', 'unknown'].includes(c)), 'classes ' + classes);
  await page.screenshot({ path: path.join(ART, 'console-1280x800.png') });
});

await check('layers toggle (points, gridmap rendering)', async () => {
  await page.click('#layer-points');
  assert.equal(await page.evaluate(() => window.polmapConsole.map.getLayoutProperty('points', 'visibility')), 'none');
  await idle();
  assert.equal(await renderedCount('points'), 0);
  await page.click('#layer-points');
  await idle();
  assert.ok((await renderedCount('points')) > 0);
  await page.check('input[name="gridmap-style"][value="mechanism"]');
  const vis = await page.evaluate(() => [window.polmapConsole.map.getLayoutProperty('gridmap', 'visibility'),
    window.polmapConsole.map.getLayoutProperty('gridmap-mechanism', 'visibility')]);
  assert.deepEqual(vis, ['none', 'visible']);
  await idle();
  await page.screenshot({ path: path.join(ART, 'console-mechanism.png') });
  await page.check('input[name="gridmap-style"][value="amplitude"]');
});

await check('the diff between the two versions is drawn as the server computes it', async () => {
  const rows = await page.$$eval('#versions tbody tr', (trs) => trs.length);
  assert.equal(rows, 2);
  assert.equal(await page.inputValue('#diff-from'), '1');
  assert.equal(await page.inputValue('#diff-to'), '2');
  await page.click('#diff-show');
  await waitFor(page, () => window.polmapConsole.diff !== undefined);
  const expected = await (await fetch(URL + '/v1/maps/2/diff?from=1')).json();
  const s = expected.counts;
  assert.ok(s.added + s.moved + s.retired > 0, 'the third drive changed the map');
  assert.equal(await page.textContent('#diff-summary'), `v1 → v2: ${s.added} added, ${s.moved} moved, ${s.retired} retired`);
  const shown = await page.evaluate(() => window.polmapConsole.diff.features.length);
  assert.equal(shown, s.added + s.moved + s.retired);
  await idle();
  const drawn = await page.evaluate(() => window.polmapConsole.map.queryRenderedFeatures({ layers: ['diff-points', 'diff-lines'] }).length);
  assert.ok(drawn > 0, 'diff features drawn: ' + drawn);
  await page.screenshot({ path: path.join(ART, 'console-diff.png') });
});

await check('the HD-map overlay draws the stored comparison, matched and unmatched', async () => {
  const list = await (await fetch(URL + '/v1/maps/current/hdmap-comparison')).json();
  assert.equal(list.comparisons.length, 1);
  const name = list.comparisons[0].name;
  assert.equal(await page.isDisabled('#layer-hdmap'), false, 'the toggle is enabled');
  const summary = await page.textContent('#hdmap-summary');
  for (const k of ['point precision', 'point recall', 'median point offset', 'line coverage', 'median lateral line offset']) {
    assert.ok(summary.includes(k), k + ' in the summary: ' + summary);
  }
  const s = list.comparisons[0].summary;
  assert.ok(summary.includes((100 * s.line_coverage).toFixed(1) + ' %'), 'coverage as the server has it');
  const g = await (await fetch(URL + '/v1/maps/current/hdmap-comparison/' + name)).json();
  assert.equal(await page.evaluate(() => window.polmapConsole.hdmap.features.length), g.features.length);
  await page.click('#layer-diff');  // off: only the overlay on top of the landmarks
  await page.click('#layer-hdmap');
  await idle();
  const drawn = await page.evaluate(() => {
    const m = window.polmapConsole.map;
    const out = {};
    for (const f of m.queryRenderedFeatures({ layers: ['hdmap-hd-points', 'hdmap-map-points', 'hdmap-map-lines', 'hdmap-hd-lines'] })) {
      const p = f.properties;
      const k = f.layer.id + ':' + (!p.in_area || p.judged === false ? 'grey' : p.matched ? 'matched' : 'unmatched');
      out[k] = (out[k] || 0) + 1;
    }
    return out;
  });
  const n = (prefix) => Object.entries(drawn).filter(([k]) => k.startsWith(prefix)).reduce((a, [, v]) => a + v, 0);
  assert.ok(n('hdmap-hd-lines') > 0, 'HD lines drawn: ' + JSON.stringify(drawn));
  assert.ok(n('hdmap-map-') > 0, 'landmarks of the comparison drawn: ' + JSON.stringify(drawn));
  assert.ok(n('hdmap-hd-lines:matched') + n('hdmap-map-lines:matched') > 0, 'matched features: ' + JSON.stringify(drawn));
  assert.ok(Object.keys(drawn).some((k) => k.endsWith(':unmatched')), 'unmatched features: ' + JSON.stringify(drawn));
  await page.screenshot({ path: path.join(ART, 'console-hdmap.png') });
  // A click on an HD line tells what it is.
  const pt = await page.evaluate(() => {
    const m = window.polmapConsole.map;
    const f = m.queryRenderedFeatures({ layers: ['hdmap-hd-lines'] })[0];
    const c = f.geometry.type === 'LineString' ? f.geometry.coordinates : f.geometry.coordinates[0];
    const a = m.project(c[0]), b = m.project(c[1]);
    const r = m.getContainer().getBoundingClientRect();
    return { x: r.left + (a.x + b.x) / 2, y: r.top + (a.y + b.y) / 2 };
  });
  await page.mouse.click(pt.x, pt.y);
  await page.waitForSelector('.maplibregl-popup .popup');
  assert.match(await page.textContent('.maplibregl-popup'), /HD-map feature|HD comparison/);
  await page.click('#layer-hdmap');
  assert.equal(await page.evaluate(() => window.polmapConsole.map.getLayoutProperty('hdmap-hd-lines', 'visibility')), 'none');
});

await check('the operator key shows the fleet and never reaches the URL or the log', async () => {
  assert.match(await page.textContent('#fleet-status'), /operator key/);
  await page.fill('#api-key', KEY);
  await page.click('#key-form button[type="submit"]');
  await waitFor(page, () => /^[0-9]+ drives$/.test(document.getElementById('fleet-status').textContent));
  assert.equal(await page.textContent('#fleet-status'), '3 drives');
  assert.equal(await page.$$eval('#drives tbody tr', (t) => t.length), 3);
  // Status, positioning and date columns: the simulated drives are RTK-grade, their clock
  // is relative (the upload day is shown), and each is used by the current version or newer.
  const rows = await page.$$eval('#drives tbody tr', (t) => t.map((r) => [...r.cells].map((c) => c.textContent)));
  for (const r of rows) {
    assert.match(r[1], /^(in v[0-9]+|new \(next build\)|excluded from v[0-9]+)$/, 'status ' + r[1]);
    assert.match(r[4], /^survey [0-9]+ cm$/, 'positioning ' + r[4]);
    assert.match(r[5], /^[0-9]{4}-[0-9]{2}-[0-9]{2} \(upload\)$/, 'date ' + r[5]);
  }
  assert.ok(rows.some((r) => /^in v[0-9]+$/.test(r[1])), 'some drive is in the current version');
  assert.equal(await page.inputValue('#api-key'), '', 'the field is cleared');
  await page.click('#layer-coverage');
  await idle();
  assert.ok((await renderedCount('coverage')) > 0, 'drive coverage drawn with the key');
  assert.ok(!page.url().includes(KEY));
  assert.match(page.url(), /#[0-9.]+\/-?[0-9.]+\/-?[0-9.]+/, 'the view is kept in the URL (#z/lat/lon)');
  assert.ok(!fs.readFileSync(LOG, 'utf8').includes(KEY), 'the key is not in the server log');
  const stored = await page.evaluate(() => JSON.stringify(Object.assign({}, localStorage, sessionStorage)) + document.cookie);
  assert.ok(!stored.includes(KEY), 'nor in storage or cookies');
});

await check('the reported localization run is drawn coloured by error, with its plot and the fleet layer', async () => {
  // tests/web/console_test.sh localized the held-out drive with --report and --truth.
  const runs = await (await fetch(URL + '/v1/runs', { headers: { Authorization: 'Bearer ' + KEY } })).json();
  assert.equal(runs.count, 1);
  const s = runs.runs[0].summary;
  assert.ok(s.evaluated > 20, 'the run carries errors: ' + JSON.stringify(s));
  assert.ok(s.lat_rmse_m < 0.3, 'lateral RMSE ' + s.lat_rmse_m);
  await waitFor(page, () => window.polmapConsole.run !== undefined);
  assert.equal(await page.$$eval('#runs tbody tr', (t) => t.length), 1);
  assert.match(await page.textContent('#run-summary'), /lateral RMSE 0\.[0-9]{3} m/);
  assert.ok(await page.isChecked('input[name="run-colour"][value="error"]'), 'coloured by error');
  const segments = await page.evaluate(() => window.polmapConsole.run.features.length);
  assert.equal(segments, runs.runs[0].samples - 1);
  await page.click('#runs tbody tr:first-child button');  // fits the map to the run
  await idle();
  assert.ok((await renderedCount('run')) > 0, 'run segments drawn');
  const curve = await page.getAttribute('#run-plot path.curve', 'd');
  assert.ok(curve && curve.split('L').length > 20, 'the error-vs-distance plot has a curve');
  await page.screenshot({ path: path.join(ART, 'console-run.png') });
  await page.check('input[name="run-colour"][value="status"]');
  const colour = await page.evaluate(() => window.polmapConsole.map.getPaintProperty('run', 'line-color'));
  assert.equal(colour[0], 'match', 'coloured by status');
  await page.click('#layer-quality');
  await idle();
  assert.ok((await renderedCount('quality')) > 0, 'fleet quality cells drawn');
  assert.equal(await page.evaluate(() => window.polmapConsole.quality.properties.runs), 'newest_map');
  // (page.waitForFunction evaluates a string, which the page's CSP refuses: poll instead.)
  const qualityRuns = async (want) => {
    for (let i = 0; i < 100; ++i) {
      if (await page.evaluate(() => window.polmapConsole.quality.properties.runs) === want) return true;
      await new Promise((r) => setTimeout(r, 50));
    }
    return false;
  };
  await page.click('#quality-all-runs');  // every stored run, older map versions too
  assert.ok(await qualityRuns('all'), 'the layer reloads with every run');
  await page.click('#quality-all-runs');
  assert.ok(await qualityRuns('newest_map'), 'and back to the newest map version per cell');
  await page.screenshot({ path: path.join(ART, 'console-run-status.png') });
  await page.click('#layer-quality');
  await page.check('input[name="run-colour"][value="error"]');
});

await check('an operator starts a build and sees its progress, then deletes a drive', async () => {
  await page.click('#build-start');
  await waitFor(page, () => /^version [0-9]+: published/.test(document.getElementById('build-status').textContent));
  const list = await (await fetch(URL + '/v1/maps')).json();
  assert.equal(list.current, 3);
  assert.equal(list.versions.find((v) => v.version === 3).parameters.notes, 'started from the console');
  assert.equal(await page.textContent('#version-label'), 'map version 3');
  // The map reloads its tiles for the new current version and shows its landmarks again.
  await waitFor(page, () => window.polmapConsole.map.queryRenderedFeatures({ layers: ['points'] }).length > 0);
  assert.equal(await page.$$eval('#versions tbody tr', (t) => t.length), 3);
  page.once('dialog', (d) => d.accept());
  await page.click('#drives tbody tr:first-child button');
  await waitFor(page, () => document.querySelectorAll('#drives tbody tr').length === 2);
  const drives = await (await fetch(URL + '/v1/drives', { headers: { Authorization: 'Bearer ' + KEY } })).json();
  assert.equal(drives.count, 2);
  assert.ok(!fs.readFileSync(LOG, 'utf8').includes(KEY), 'the key is not in the server log');
});

await check('a landmark click shows its attributes', async () => {
  await waitFor(page, () => window.polmapConsole.map.loaded() &&
    window.polmapConsole.map.queryRenderedFeatures({ layers: ['points'] }).length > 0);
  const pt = await page.evaluate(() => {
    const m = window.polmapConsole.map;
    const f = m.queryRenderedFeatures({ layers: ['points'] })[0];
    const p = m.project(f.geometry.coordinates);
    const r = m.getContainer().getBoundingClientRect();  // project() is relative to the map
    return { x: r.left + p.x, y: r.top + p.y };
  });
  await page.mouse.click(pt.x, pt.y);
  await page.waitForSelector('.maplibregl-popup .popup');
  const text = await page.textContent('.maplibregl-popup .popup');
  assert.match(text, /support \(drives\)/);
  assert.match(text, /spread/);
  // Support times and version history, from GET /v1/maps/{v}/landmarks/{key}.
  await waitFor(page, () => /history/.test((document.querySelector('.maplibregl-popup .popup') || {}).textContent || ''));
  const full = await page.textContent('.maplibregl-popup .popup');
  assert.match(full, /first seen\s*\d{4}-\d\d-\d\d/);
  assert.match(full, /last seen\s*\d{4}-\d\d-\d\d/);
  // The details of the first popup's landmark (a point on a line opens two popups).
  const key = await page.getAttribute('.maplibregl-popup .popup', 'data-key');
  await waitFor(page, (k) => (window.polmapConsole.landmarks || {})[k] !== undefined, key);
  const d = await page.evaluate((k) => window.polmapConsole.landmarks[k], key);
  assert.ok(d.history.length > 0, 'a history: ' + JSON.stringify(d));
  const h = d.history[d.history.length - 1];
  assert.ok(full.includes('v' + h.version + ' ' + h.change), 'the oldest entry shown: ' + full);
  const again = await (await fetch(URL + '/v1/maps/' + d.version + '/landmarks/' + d.key)).json();
  assert.deepEqual(again.history, d.history);
  assert.equal(again.supporting_drives, d.supporting_drives);
  assert.ok(Array.isArray(d.drives), 'the drives with the operator key');
  await page.screenshot({ path: path.join(ART, 'console-landmark-popup.png') });
});

await check('the view is kept in the URL and restored on load', async () => {
  const u = page.url();
  const again = await openConsole({ width: 1280, height: 800 });
  await again.goto(u, { waitUntil: 'load' });
  await waitFor(again, () => window.polmapConsole && window.polmapConsole.ready === true);
  const z = await again.evaluate(() => window.polmapConsole.map.getZoom());
  const want = Number(u.split('#')[1].split('/')[0]);
  assert.ok(Math.abs(z - want) < 0.01, `zoom ${z} vs ${want}`);
  await again.close();
});

await check('works on a phone-sized viewport', async () => {
  const phone = await openConsole({ width: 390, height: 844 });
  const box = await phone.evaluate(() => {
    const r = document.getElementById('map').getBoundingClientRect();
    return { w: r.width, h: r.height, scroll: document.documentElement.scrollWidth };
  });
  assert.ok(box.w >= 380 && box.h > 200, JSON.stringify(box));
  assert.ok(box.scroll <= 390, 'no horizontal scrolling: ' + box.scroll);
  const tall = await phone.evaluate(() => document.documentElement.scrollHeight);
  assert.ok(tall <= 844, 'the page itself does not scroll (the panel does): ' + tall);
  await phone.screenshot({ path: path.join(ART, 'console-phone.png') });
  await phone.close();
});

await check('no console errors and nothing fetched from elsewhere', async () => {
  assert.equal(errors.length, 0, 'console errors:\n' + errors.join('\n'));
  assert.deepEqual(externalRequests, []);
});

await browser.close();
if (failures > 0) {
  console.log(failures + ' console check(s) failed');
  process.exit(1);
}
console.log('console: all checks passed; screenshots in ' + ART);
