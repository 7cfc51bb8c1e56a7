// The simulated worlds of GET /api/scenes: the home as a floor plan, the
// LEGO arena with its robots, balls, zones and the names the agents
// anchored.

const NS = 'http://www.w3.org/2000/svg';
function el(name, attrs = {}, text) {
  const e = document.createElementNS(NS, name);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text !== undefined) e.textContent = text;
  return e;
}
function h(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  e.append(...children);
  return e;
}
const time = ms => (ms ? new Date(ms).toISOString().slice(11, 19) : 'never');

export function renderScenes(container, scenes) {
  container.replaceChildren();
  const anchors = scenes.filter(s => s.kind === 'anchors').flatMap(s => s.agents);
  for (const s of scenes) {
    if (s.kind === 'home') container.append(home(s));
    else if (s.kind === 'arena') container.append(arena(s, anchors));
  }
}

function home(s) {
  // The rooms as an HTML grid, not SVG text: a room's list of devices
  // wraps instead of being cut at the room's edge.
  const cols = Math.ceil(Math.sqrt(s.rooms.length || 1));
  const plan = h('div', { class: 'floorplan', role: 'list', 'aria-label': 'floor plan',
    style: `grid-template-columns: repeat(${cols}, minmax(0, 1fr))` },
    ...s.rooms.map(r => h('div', { class: `room light-${r.light || 'none'}`, 'data-room': r.name, role: 'listitem' },
      h('div', { class: 'room-name' }, r.name),
      h('div', { class: 'room-detail' }, `light ${r.light || '-'} · motion ${time(r.last_motion)}`),
      h('div', { class: 'room-devices' }, r.devices.join(', ')),
      h('div', { class: 'people' }, ...r.people.map(p => h('span', { class: 'person' }, p))))));
  const a = s.alarm;
  const wrong = a.keypad.filter(k => k.wrong).length;
  return h('div', { class: 'panel wide scene-home' },
    h('h3', {}, `Home · ${time(s.time)}`), plan,
    h('p', { class: wrong ? 'alarm on' : 'alarm' },
      `alarm: ${a.attempts} attempts, ${wrong} wrong code(s); ${a.played.length} sound(s) played; ${a.emails} e-mail(s), ${a.sms} SMS`),
    h('ul', { class: 'photos' }, ...s.photos.slice(-8).map(p =>
      h('li', {}, `${p.id} · ${p.room} · ${time(p.time)}${p.people.length ? ' · ' + p.people.join(', ') : ''}`))));
}

function arena(s, agents) {
  const svg = el('svg', { viewBox: `0 0 ${s.width} ${s.height}`, class: 'arena', role: 'img', 'aria-label': 'LEGO arena' });
  const Y = y => s.height - y; // the arena's y grows upwards
  svg.append(el('rect', { x: 0, y: 0, width: s.width, height: s.height, class: 'arena-floor' }));
  for (const z of s.zones) {
    svg.append(el('circle', { cx: z.x, cy: Y(z.y), r: z.r, class: 'zone' }));
    svg.append(el('text', { x: z.x, y: Y(z.y) + 8, class: 'zone-name', 'text-anchor': 'middle' }, z.name));
  }
  for (const b of s.balls) {
    svg.append(el('circle', { cx: b.x, cy: Y(b.y), r: 40, class: 'ball', fill: b.colour, 'data-colour': b.colour }));
  }
  for (const r of s.robots) {
    const g = el('g', { class: 'robot', transform: `translate(${r.x} ${Y(r.y)}) rotate(${-r.heading})`, 'data-entity': r.entity });
    g.append(el('rect', { x: -70, y: -55, width: 140, height: 110, rx: 12 }));
    g.append(el('path', { d: 'M70,-20 L110,0 L70,20 Z', class: 'claw' }));
    svg.append(g);
    svg.append(el('text', { x: r.x, y: Y(r.y) - 70, class: 'robot-name', 'text-anchor': 'middle' },
      `${r.entity}${r.holding ? ' · ' + r.holding : ''}`));
  }
  for (const a of agents) {
    for (const an of a.anchors) {
      svg.append(el('text', { x: an.x + 45, y: Y(an.y) - 45, class: 'anchor', 'data-symbol': an.symbol }, an.symbol));
    }
  }
  return h('div', { class: 'panel wide scene-arena' }, h('h3', {}, `LEGO arena · ${time(s.time)}`), svg,
    h('ul', { class: 'anchors' }, ...agents.map(a =>
      h('li', {}, `${a.name}: ${a.anchors.map(x => `${x.symbol} (${x.colour})`).join(', ') || 'nothing anchored yet'}`))));
}
