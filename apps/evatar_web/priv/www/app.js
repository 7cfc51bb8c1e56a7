// The dashboard: the cluster, a pairing (entities, its Body Mapping
// Registry as a graph, unbound entries and why, the live signal tail) and
// the simulation when avatar_sim runs. Plain ES modules, no build step
// (docs/dashboard.md section 6).
import { getJSON, events, token, setToken } from './api.js';
import { Graph } from './graph.js';
import { renderScenes } from './scenes.js';

const $ = sel => document.querySelector(sel);
const KINDS = ['request', 'feedback', 'progress', 'sensor_data', 'event', 'error', 'refusal',
  'timeout', 'void', 'late', 'drop', 'entity', 'bindings'];
const MAX_ROWS = 300;

const graph = new Graph($('#graph'));
let current = null;       // the pairing shown
let closeTail = null;
let paused = false;
let graphTimer = null;

function h(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === 'class') e.className = v; else e.setAttribute(k, v);
  }
  e.append(...children.filter(c => c !== null && c !== undefined));
  return e;
}

// An id as text: ids longer than `max' characters are cut in the middle,
// the full id in the title (shown on hover, read by screen readers).
const MAX_ID = 40;
function idText(id, max = MAX_ID) {
  const s = String(id);
  if (s.length <= max) return h('span', { class: 'id' }, s);
  const keep = Math.floor((max - 1) / 2);
  return h('span', { class: 'id cut', title: s }, `${s.slice(0, keep)}…${s.slice(-keep)}`);
}

// --- cluster ----------------------------------------------------------------

async function refreshCluster() {
  try {
    const c = await getJSON('/api/cluster');
    $('#cluster-error').hidden = true;
    $('#node').textContent = c.node;
    $('#quorum').textContent = c.quorum ? 'quorum' : 'no quorum';
    $('#quorum').className = 'badge ' + (c.quorum ? 'ok' : 'bad');
    $('#nodes').replaceChildren(...c.nodes.map(n =>
      h('span', { class: 'chip ' + (n.suspected ? 'bad' : n.up ? 'ok' : 'muted') },
        `${n.node}${n.self ? ' (this node)' : ''} · ${n.suspected ? 'suspected' : n.up ? 'up' : 'down'}`)));
    $('#pairings tbody').replaceChildren(...c.pairings.map(p =>
      h('tr', { 'data-pairing': p.id },
        h('td', {}, h('a', { href: `#/pairing/${encodeURIComponent(p.id)}`, title: p.id }, idText(p.id))),
        h('td', {}, p.active ? idText(p.active) : '—'), h('td', {}, p.standby ? idText(p.standby) : '—'),
        h('td', {}, String(p.epoch)), h('td', {}, p.standby ? (p.synced ? 'yes' : 'no') : '—'))));
  } catch (e) {
    $('#cluster-error').hidden = false;
    $('#cluster-error').textContent = `cluster: ${e.message}`;
  }
}

// --- a pairing ---------------------------------------------------------------

async function refreshGraph() {
  if (!current) return;
  try {
    const g = await getJSON(`/api/pairings/${encodeURIComponent(current)}/graph`);
    $('#pairing-state').textContent = `${g.state} · node ${g.node}`;
    $('#entities').replaceChildren(...g.entities.map(e =>
      h('li', { class: e.attached ? 'attached' : 'detached', 'data-entity': e.id },
        h('b', {}, idText(e.id)), ` ${e.role} · `,
        e.attached ? 'connected' : 'detached', ' · ',
        e.registered ? `described (${e.components.length} components)` : 'not described',
        ` · ${e.delivered} delivered`)));
    graph.render(g);
    if (!g.unbound.length) $('#unbound').replaceChildren(h('li', { class: 'muted' }, 'none: every entry is bound'));
    else $('#unbound').replaceChildren(...g.unbound.map(u =>
      h('li', { 'data-reason': u.reason },
        h('b', {}, `${u.consumer.component}`), ` (${u.consumer.entity}) consumes `,
        h('code', {}, `${u.category} / ${u.type}`), ': ',
        h('span', { class: 'reason' }, u.reason),
        u.parameters.length ? h('span', {}, ' wanting ',
          h('code', {}, u.parameters.map(([n, v]) => `${n}=${v}`).join(', '))) : null,
        u.candidates.length ? h('ul', {}, ...u.candidates.map(c =>
          h('li', {}, `${c.provider.component} (${c.provider.entity}) offers `,
            ...c.mismatches.map(f => h('code', { class: 'mismatch' },
              `${f.name}: wanted ${f.wanted}, offered ${f.offered.length ? f.offered.join(' | ') : 'nothing'}`))))) : null,
        u.more_candidates ? h('span', {}, ` and ${u.more_candidates} more providers`) : null)));
  } catch (e) {
    $('#pairing-state').textContent = e.message;
  }
}

function tailRow(i) {
  const when = new Date(i.at).toISOString().slice(11, 23);
  let what;
  switch (i.kind) {
    case 'entity': what = `${i.from_entity} ${i.what}${i.message ? ' (' + i.message + ')' : ''}`; break;
    case 'bindings': what = `rebound: ${i.bound} bound, ${i.unbound} unbound`; break;
    case 'drop': what = `${i.to_entity} dropped: ${i.code} ${i.message || ''}`; break;
    case 'dropped': what = `${i.count} items not shown (the page was too slow)`; break;
    case 'moved': what = `the pairing's active moved (${i.role}); following it`; break;
    case 'attached': what = `watching again on ${i.node}`; break;
    default:
      what = `${i.from} → ${i.to} ${i.category || ''}/${i.type || ''}` +
        (i.signal ? ` #${i.signal}` : '') + (i.in_reply_to ? ` re ${i.in_reply_to}` : '') +
        (i.message ? ` — ${i.message}` : '') +
        (i.parameters && i.parameters.length ? ` {${i.parameters.map(([n, v]) => `${n}=${v}`).join(', ')}}` : '');
  }
  return h('li', { class: `item kind-${i.kind}`, 'data-kind': i.kind },
    h('time', {}, when), h('span', { class: 'kind' }, i.kind), h('span', { class: 'what' }, what));
}

function onItem(i) {
  if (i.kind === 'hello') { $('#tail-status').textContent = `live on ${i.node}`; return; }
  if (i.from && i.to) graph.flash(i);
  if (i.kind === 'bindings' || i.kind === 'entity') scheduleGraph();
  if (paused) return;
  const list = $('#tail');
  list.prepend(tailRow(i));
  while (list.children.length > MAX_ROWS) list.lastChild.remove();
}

function scheduleGraph() {
  clearTimeout(graphTimer);
  graphTimer = setTimeout(refreshGraph, 150);
}

function openTail() {
  if (closeTail) closeTail();
  const kinds = [...document.querySelectorAll('#kinds input:checked')].map(c => c.value);
  const params = { pairing: current };
  if (kinds.length && kinds.length < KINDS.length) params.kind = kinds.join(',');
  const entity = $('#entity-filter').value.trim();
  if (entity) params.entity = entity;
  $('#tail-status').textContent = 'connecting…';
  closeTail = events(params, onItem, s => {
    if (s === 'closed') $('#tail-status').textContent = 'stream closed';
    else if (s instanceof Error) $('#tail-status').textContent = `stream: ${s.message}`;
  });
}

function showPairing(id) {
  current = id;
  $('#pairing-id').replaceChildren(idText(id, 60));
  $('#tail').replaceChildren();
  graph.reset();
  refreshGraph();
  openTail();
}

// --- simulation --------------------------------------------------------------

async function refreshScenes() {
  try {
    const { scenes } = await getJSON('/api/scenes');
    $('#scenes-view').hidden = scenes.length === 0;
    if (scenes.length) renderScenes($('#scenes'), scenes);
  } catch (e) {
    $('#scenes-view').hidden = true;
  }
}

// --- routing -----------------------------------------------------------------

function route() {
  const m = location.hash.match(/^#\/pairing\/(.+)$/);
  if (m) {
    $('#pairing-view').hidden = false;
    const id = decodeURIComponent(m[1]);
    if (id !== current) {
      showPairing(id);
      // The view is below the cluster's table, which can be long: bring it
      // into the window and give it the focus (keyboard and screen reader).
      $('#pairing-view').scrollIntoView({ block: 'start' });
      $('#pairing-heading').focus({ preventScroll: true });
    }
  } else {
    $('#pairing-view').hidden = true;
    if (closeTail) { closeTail(); closeTail = null; }
    current = null;
  }
}

function setup() {
  $('#kinds').append(...KINDS.map(k =>
    h('label', {}, h('input', { type: 'checkbox', value: k, checked: '' }), k)));
  $('#tail-filters').addEventListener('submit', e => { e.preventDefault(); if (current) openTail(); });
  $('#tail-pause').addEventListener('click', () => {
    paused = !paused;
    $('#tail-pause').textContent = paused ? 'resume' : 'pause';
  });
  $('#token-button').addEventListener('click', () => {
    $('#token-input').value = token();
    $('#token-dialog').showModal();
  });
  $('#token-dialog').addEventListener('close', () => {
    if ($('#token-dialog').returnValue === 'save') setToken($('#token-input').value.trim());
  });
  window.addEventListener('hashchange', route);
  route();
  refreshCluster();
  refreshScenes();
  setInterval(refreshCluster, 3000);
  setInterval(refreshScenes, 1000);
  setInterval(refreshGraph, 5000);
}

// The views' periodic refreshes now, as their timers would run them, each
// resolved once its view is redrawn: `refresh()' all of them, or one
// (`cluster', `graph', `scenes'). For the browser's console and for tests
// (evatar_web_dash_SUITE fires them instead of waiting for the period).
window.evatarDashboard = {
  cluster: refreshCluster, graph: refreshGraph, scenes: refreshScenes,
  refresh: () => Promise.all([refreshCluster(), refreshGraph(), refreshScenes()]),
};

setup();
