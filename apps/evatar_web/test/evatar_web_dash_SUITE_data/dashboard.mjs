// Run by evatar_web_dash_SUITE: opens the dashboard in Debian's chromium
// (headless, through playwright-core) and checks what a person would see.
// Usage: node dashboard.mjs URL PAIRING SCREENSHOT_DIR
// Prints one line per step; after "ready" it waits for the suite to send a
// request and for that request to appear in the live tail. Exits 0 when
// every check passed; otherwise prints "FAIL ..." and exits 1.
import { chromium } from 'playwright-core';

const [url, pairing, shots] = process.argv.slice(2);
const executablePath = process.env.CHROMIUM || '/usr/bin/chromium';
const say = s => console.log(s);
const T = { timeout: 30000 };

const browser = await chromium.launch({ executablePath, headless: true, args: ['--no-sandbox'] });
let code = 0;
try {
  const page = await browser.newPage({ viewport: { width: 1280, height: 1000 } });
  page.on('console', m => { if (m.type() === 'error') say(`console error: ${m.text()}`); });
  page.on('pageerror', e => say(`page error: ${e.message}`));
  await page.goto(url);
  await page.waitForSelector(`#pairings tr[data-pairing="${pairing}"]`, T);
  say('cluster view shows the pairing');
  await page.click(`#pairings tr[data-pairing="${pairing}"] a`);
  await page.waitForSelector('#entities li[data-entity]', T);
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
  // The suite sends a request now; it must appear live, and its edge flash.
  await page.waitForSelector('#tail li[data-kind="request"]', T);
  const row = await page.$eval('#tail li[data-kind="request"]', l => l.textContent);
  say(`live request: ${row}`);
  await page.waitForSelector('#graph g.bound[data-traffic]', T);
  // The element is marked: the graph's periodic redraw replaces it.
  const flashed = await page.$eval('#graph g.bound[data-traffic]',
    g => { g.dataset.drawnBefore = ''; return Number(g.dataset.traffic); });
  say(`edge flashed (${flashed} signals on it)`);
  await page.screenshot({ path: `${shots}/dashboard.png`, fullPage: true });
  await page.setViewportSize({ width: 390, height: 844 });
  await page.waitForTimeout(300);
  const overflow = await page.evaluate(() => document.documentElement.scrollWidth - window.innerWidth);
  say(`mobile width overflow: ${overflow}px`);
  if (overflow > 0) throw new Error(`the page is wider than a 390 px screen by ${overflow} px`);
  await page.screenshot({ path: `${shots}/dashboard-mobile.png`, fullPage: true });
  // The graph is redrawn every 5 s; the edge's count of signals outlives
  // the redraw (a redraw once wiped it, and with it the check above when
  // the redraw came between the flash and the check).
  await page.waitForSelector('#graph g.bound:not([data-drawn-before])', T);
  const kept = await page.$eval('#graph g.bound', g => Number(g.dataset.traffic || 0));
  say(`after a redraw the edge counts ${kept} signals`);
  if (kept < flashed) throw new Error(`the redraw lost the edge's traffic: ${kept} < ${flashed}`);
  say('OK');
} catch (e) {
  say(`FAIL ${e.message.split('\n')[0]}`);
  code = 1;
} finally {
  await browser.close();
}
process.exit(code);
