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
  const cols = Math.ceil(Math.sqrt(s.rooms.length || 1));
  const W = 200, H = 130;
  const rows = Math.ceil(s.rooms.length / cols) || 1;
  const svg = el('svg', { viewBox: `0 0 ${cols * W} ${rows * H}`, class: 'floorplan', role: 'img', 'aria-label': 'floor plan' });
  s.rooms.forEach((r, i) => {
    const x = (i % cols) * W, y = Math.floor(i / cols) * H;
    const g = el('g', { class: `room light-${r.light || 'none'}`, 'data-room': r.name });
    g.append(el('rect', { x: x + 2, y: y + 2, width: W - 4, height: H - 4 }));
    g.append(el('text', { x: x + 10, y: y + 22, class: 'room-name' }, r.name));
    g.append(el('text', { x: x + 10, y: y + 40, class: 'room-detail' },
      `light ${r.light || '-'} · motion ${time(r.last_motion)}`));
    g.append(el('text', { x: x + 10, y: y + 56, class: 'room-detail' }, r.devices.join(', ')));
    r.people.forEach((p, j) => {
      const cx = x + 24 + j * 46, cy = y + H - 30;
      g.append(el('circle', { cx, cy, r: 10, class: 'person' }));
      g.append(el('text', { x: cx, y: cy + 24, class: 'person-name', 'text-anchor': 'middle' }, p));
    });
    svg.append(g);
  });
  const a = s.alarm;
  const wrong = a.keypad.filter(k => k.wrong).length;
  return h('div', { class: 'panel wide', id: 'scene-home' },
    h('h3', {}, `Home · ${time(s.time)}`), svg,
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
      svg.append(el('text', { x: an.x + 45, y: Y(an.y) - 45, class: 'anchor' }, an.symbol));
    }
  }
  return h('div', { class: 'panel wide', id: 'scene-arena' }, h('h3', {}, `LEGO arena · ${time(s.time)}`), svg,
    h('ul', { class: 'anchors' }, ...agents.map(a =>
      h('li', {}, `${a.name}: ${a.anchors.map(x => `${x.symbol} (${x.colour})`).join(', ') || 'nothing anchored yet'}`))));
}
