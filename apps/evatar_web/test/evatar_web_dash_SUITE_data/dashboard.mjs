// Run by evatar_web_dash_SUITE: opens the dashboard in Debian's chromium
// (headless, through playwright-core) and checks what a person would see,
// with axe-core (from npm) run on every view.
// Usage: node dashboard.mjs URL PAIRING HOME_PAIRING LONG_PAIRING LONG_ENTITY SCREENSHOT_DIR
// Prints one line per step. After "ready" it waits for the suite to send a
// request and for that request to appear in the live tail; after "robots"
// it waits for the suite's robots story and the names its VAs anchored.
// Exits 0 when every check passed; otherwise prints "FAIL ..." and exits 1.
import { chromium } from 'playwright-core';
import { createRequire } from 'node:module';

const require = createRequire(import.meta.url);
const AXE = require.resolve('axe-core/axe.min.js');
const [url, pairing, home, longPairing, longEntity, shots] = process.argv.slice(2);
const executablePath = process.env.CHROMIUM || '/usr/bin/chromium';
const say = s => console.log(s);
const T = { timeout: 30000 };

// Polls `fn' in the page (it may be async) until it returns a truthy
// value, which is returned; `what' names the wait in the failure, with
// the last value seen.
async function until(page, what, fn, arg, ms = 30000) {
  const end = Date.now() + ms;
  let last;
  for (;;) {
    last = await page.evaluate(fn, arg);
    if (last && last.ok !== false) return last;
    if (Date.now() > end) throw new Error(`${what}: ${JSON.stringify(last)}`);
    await page.waitForTimeout(200);
  }
}

// axe-core on the page as it is: no serious or critical finding, and a
// visible heading level one.
async function audit(page, what) {
  if (!(await page.evaluate(() => typeof window.axe === 'object'))) await page.addScriptTag({ path: AXE });
  const found = await page.evaluate(async () => (await window.axe.run(document, { resultTypes: ['violations'] }))
    .violations.map(v => ({ id: v.id, impact: v.impact, nodes: v.nodes.length,
      first: v.nodes.slice(0, 3).map(n => `${n.target.join(' ')}: ${n.failureSummary || ''}`.slice(0, 300)) })));
  const bad = found.filter(v => v.impact === 'serious' || v.impact === 'critical');
  say(`axe ${what}: ${found.length} rules broken, ${bad.length} serious or critical` +
    (found.length ? ` (${found.map(v => `${v.id} ${v.impact} x${v.nodes}`).join(', ')})` : ''));
  if (bad.length) throw new Error(`axe-core on ${what}: ${JSON.stringify(bad)}`);
  const h1 = await page.evaluate(() => [...document.querySelectorAll('h1')].filter(e => e.getClientRects().length).length);
  if (h1 < 1) throw new Error(`${what} has no visible heading level one`);
}

const graphOf = id => `/api/pairings/${encodeURIComponent(id)}/graph`;

// A check of what a periodic redraw shows fires the redraw (app.js:
// window.evatarDashboard) instead of waiting for its 1, 3 or 5 s period.
const redrawGraph = page => page.evaluate(() => window.evatarDashboard.graph());

const browser = await chromium.launch({ executablePath, headless: true, args: ['--no-sandbox'] });
let code = 0;
try {
  const page = await browser.newPage({ viewport: { width: 1280, height: 1000 } });
  page.on('console', m => { if (m.type() === 'error') say(`console error: ${m.text()}`); });
  page.on('pageerror', e => say(`page error: ${e.message}`));
  await page.goto(url);
  await page.waitForSelector(`#pairings tr[data-pairing="${pairing}"]`, T);
  const rows = await until(page, 'the cluster lists 200 pairings more',
    () => document.querySelectorAll('#pairings tbody tr').length > 200 && document.querySelectorAll('#pairings tbody tr').length);
  say(`cluster view shows the pairing among ${rows}`);
  await audit(page, 'the cluster view');

  // Opening a pairing from a long table brings its view into the window.
  await page.click(`#pairings tr[data-pairing="${pairing}"] a`);
  await page.waitForSelector('#entities li[data-entity]', T);
  const top = await until(page, "the pairing's view is in the window", () => {
    const r = document.querySelector('#pairing-view').getBoundingClientRect();
    return { ok: r.top >= 0 && r.top < window.innerHeight, top: Math.round(r.top), height: window.innerHeight,
      focus: document.activeElement && document.activeElement.id };
  }, null, 5000);
  say(`pairing view top at ${top.top} px of ${top.height}, focus on #${top.focus}`);
  const entities = await page.$$eval('#entities li', ls => ls.map(l => l.textContent));
  say(`entities: ${JSON.stringify(entities)}`);
  await page.waitForSelector('#graph g.bound', T);
  const edges = await page.$$eval('#graph g.bound .edge-label', ls => ls.map(l => l.textContent));
  say(`bound edges: ${JSON.stringify(edges)}`);
  await page.waitForSelector('#unbound li[data-reason] .reason', T);
  const unbound = await page.$$eval('#unbound > li', ls => ls.map(l => l.textContent));
  say(`unbound: ${JSON.stringify(unbound)}`);
  await page.waitForFunction(() => /live on/.test(document.querySelector('#tail-status').textContent), null, T);
  say('ready');
  // The suite sends 20 requests now; they must appear live, and their edge flash.
  await page.waitForSelector('#tail li[data-kind="request"]', T);
  const row = await page.$eval('#tail li[data-kind="request"]', l => l.textContent);
  say(`live request: ${row}`);
  await page.waitForSelector('#graph g.bound[data-traffic]', T);
  // The element is marked: the graph's periodic redraw replaces it.
  const flashed = await page.$eval('#graph g.bound[data-traffic]',
    g => { g.dataset.drawnBefore = ''; return Number(g.dataset.traffic); });
  say(`edge flashed (${flashed} signals on it)`);
  // The suite sent 20 requests, answered: the tail scrolls, and a region
  // that scrolls must be reachable from the keyboard.
  const tail = await until(page, 'the live tail scrolls', () => {
    const t = document.querySelector('#tail');
    return { ok: t.scrollHeight > t.clientHeight, rows: t.children.length };
  });
  say(`the live tail scrolls (${tail.rows} rows)`);
  await audit(page, 'the pairing view');
  // The graph is redrawn every 5 s (fired here); the edge's count of
  // signals outlives the redraw (a redraw once wiped it, and with it the
  // check above when the redraw came between the flash and the check).
  await redrawGraph(page);
  if (!(await page.$('#graph g.bound:not([data-drawn-before])'))) throw new Error('the graph was not redrawn');
  const kept = await page.$eval('#graph g.bound[data-traffic]', g => Number(g.dataset.traffic || 0));
  say(`after a redraw the edge counts ${kept} signals`);
  if (kept < flashed) throw new Error(`the redraw lost the edge's traffic: ${kept} < ${flashed}`);

  // The simulated home's Body Mapping Registry: one edge per bound entry
  // (several entries bind the same two components), no label under a box
  // or over another label.
  await page.evaluate(id => { location.hash = `#/pairing/${encodeURIComponent(id)}`; }, home);
  const bmr = await until(page, 'one edge per bound entry of the home', async src => {
    const g = await (await fetch(src)).json();
    const drawn = document.querySelectorAll('#graph g.bound').length;
    const pairs = new Set(g.bound.map(b => [b.consumer.component, b.provider.component].sort().join(' '))).size;
    return { ok: g.bound.length > pairs && drawn === g.bound.length && document.querySelector('#pairing-id').textContent === g.pairing,
      bound: g.bound.length, pairs, drawn };
  }, graphOf(home));
  say(`home: ${bmr.drawn} edges for ${bmr.bound} bound entries between ${bmr.pairs} pairs of components`);
  const overlaps = await page.evaluate(() => {
    const hit = (a, b) => a.left < b.right - 0.5 && b.left < a.right - 0.5 && a.top < b.bottom - 0.5 && b.top < a.bottom - 0.5;
    const boxes = [...document.querySelectorAll('#graph g.node rect')].map(r => r.getBoundingClientRect());
    const labels = [...document.querySelectorAll('#graph text.edge-label, #graph text.unbound-label')]
      .map(l => ({ text: l.textContent, r: l.getBoundingClientRect() }));
    return { labels: labels.length,
      underBox: labels.filter(l => boxes.some(b => hit(l.r, b))).map(l => l.text),
      overLabel: labels.filter((l, i) => labels.some((m, j) => i !== j && hit(l.r, m.r))).map(l => l.text) };
  });
  say(`home: ${overlaps.labels} labels, ${overlaps.underBox.length} under a box, ${overlaps.overLabel.length} over another label`);
  if (overlaps.labels !== bmr.bound) throw new Error(`${overlaps.labels} labels for ${bmr.bound} edges`);
  if (overlaps.underBox.length) throw new Error(`labels under a box: ${JSON.stringify(overlaps.underBox)}`);
  if (overlaps.overLabel.length) throw new Error(`labels over each other: ${JSON.stringify(overlaps.overLabel)}`);
  // docs/dashboard.png: the home's pairing and the simulation, without
  // the long table above them.
  const clip = await page.evaluate(() => {
    const top = document.querySelector('#pairing-view').getBoundingClientRect().top + window.scrollY - 8;
    return { x: 0, y: top, width: document.documentElement.clientWidth, height: document.documentElement.scrollHeight - top };
  });
  await page.screenshot({ path: `${shots}/dashboard.png`, fullPage: true, clip });
  await audit(page, "the home's pairing view");

  // The rooms show their whole device lists.
  const rooms = await until(page, 'every room shows all its devices', async () => {
    const { scenes } = await (await fetch('/api/scenes')).json();
    await window.evatarDashboard.scenes();
    const homes = scenes.filter(s => s.kind === 'home');
    const shown = [...document.querySelectorAll('.scene-home')];
    if (!homes.length || shown.length !== homes.length) return { ok: false, homes: homes.length, shown: shown.length };
    const bad = [];
    let n = 0;
    homes.forEach((s, i) => s.rooms.forEach(r => {
      const room = shown[i].querySelector(`[data-room="${r.name}"]`);
      const want = r.devices.join(', ');
      const els = room ? [...room.querySelectorAll('*')].filter(e => e.textContent === want &&
        ![...e.children].some(c => c.textContent === want)) : [];
      n++;
      if (els.length !== 1) { bad.push(`${r.name}: ${els.length} elements with "${want}"`); return; }
      // The room's outline: itself, or its rectangle in a drawing.
      const [e] = els, box = (room.querySelector(':scope > rect') || room).getBoundingClientRect(), t = e.getBoundingClientRect();
      if (t.right > box.right + 0.5 || t.left < box.left - 0.5) bad.push(`${r.name}: "${want}" runs out of the room`);
      else if (e.scrollWidth > e.clientWidth) bad.push(`${r.name}: "${want}" clipped (${e.scrollWidth} > ${e.clientWidth})`);
    }));
    return { ok: bad.length === 0, rooms: n, bad };
  });
  say(`rooms: ${rooms.rooms} rooms, every device list shown whole`);

  // A phone: 390 px wide, with a 400-character pairing id and entity id.
  await page.setViewportSize({ width: 390, height: 844 });
  await page.evaluate(() => { location.hash = '#/'; });
  await page.waitForSelector(`#pairings tr[data-pairing="${longPairing}"]`, T);
  const phone = await until(page, 'the cluster view fits 390 px', () => ({
    ok: document.documentElement.scrollWidth <= 390 && document.querySelector('#pairings').getBoundingClientRect().width <= 390,
    page: document.documentElement.scrollWidth, table: Math.round(document.querySelector('#pairings').getBoundingClientRect().width) }), null, 5000);
  say(`phone, cluster view: page ${phone.page} px, table ${phone.table} px wide`);
  const full = await page.$eval(`#pairings tr[data-pairing="${longPairing}"] a`, a => a.title);
  if (full !== longPairing) throw new Error(`the long pairing id is not available whole: ${full.length} characters`);
  await audit(page, 'the cluster view on a phone');
  await page.evaluate(id => { location.hash = `#/pairing/${encodeURIComponent(id)}`; }, longPairing);
  await page.waitForSelector(`#entities li[data-entity="${longEntity}"]`, T);
  await page.waitForSelector(`#graph g.node[data-entity="${longEntity}"]`, T);
  const phone2 = await until(page, 'the long pairing fits 390 px', () => ({
    ok: document.documentElement.scrollWidth <= 390, page: document.documentElement.scrollWidth }), null, 5000);
  say(`phone, long pairing's view: page ${phone2.page} px wide`);
  const titles = await page.$eval(`#entities li[data-entity="${longEntity}"]`, l => [...l.querySelectorAll('[title]')].map(e => e.title));
  if (!titles.includes(longEntity)) throw new Error('the long entity id is not available whole');
  await page.screenshot({ path: `${shots}/dashboard-mobile.png` });
  await audit(page, "the long pairing's view on a phone");
  await page.setViewportSize({ width: 1280, height: 1000 });

  // The robots story: the arena shows the names its VAs anchored.
  await page.evaluate(() => { location.hash = '#/'; });
  say('robots');
  const names = await until(page, 'the robot VAs anchor names (GET /api/scenes)', async () => {
    const { scenes } = await (await fetch('/api/scenes')).json();
    await window.evatarDashboard.scenes();
    const symbols = scenes.filter(s => s.kind === 'anchors').flatMap(s => s.agents).flatMap(a => a.anchors).map(a => a.symbol);
    const drawn = [...document.querySelectorAll('.scene-arena svg text.anchor')].map(t => t.textContent);
    return { ok: symbols.length > 0 && symbols.every(s => drawn.includes(s)), symbols, drawn,
      arenas: scenes.filter(s => s.kind === 'arena').length };
  }, null, 150000);
  say(`arena shows the anchored names ${JSON.stringify(names.drawn)}`);
  await audit(page, 'the simulation with the robots');
  say('OK');
} catch (e) {
  say(`FAIL ${e.message.split('\n')[0]}`);
  code = 1;
} finally {
  await browser.close();
}
process.exit(code);
