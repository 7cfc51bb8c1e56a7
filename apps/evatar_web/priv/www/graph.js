// The Body Mapping Registry as an SVG graph: the VA's components on the
// left, the Avatars' on the right, one edge per bound entry (consumer to
// provider) labelled with its service; unbound entries end in a dashed
// stub. flash() lights the edge a signal travelled and counts it on the
// edge (data-traffic); the counts outlive the graph's periodic redraws.

const NS = 'http://www.w3.org/2000/svg';
const ROW = 34, COL_W = 230, GAP = 260, TOP = 24;

function el(name, attrs = {}, text) {
  const e = document.createElementNS(NS, name);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text !== undefined) e.textContent = text;
  return e;
}

const key = (entity, component) => `${entity}\u0000${component}`;

export class Graph {
  constructor(svg) { this.svg = svg; this.edges = new Map(); this.traffic = new Map(); }

  // Forget the traffic counted so far (another pairing is shown).
  reset() { this.traffic = new Map(); }

  render(g) {
    const svg = this.svg;
    svg.replaceChildren();
    this.edges = new Map();
    const side = role => g.entities.filter(e => e.role === role)
      .flatMap(e => e.components.map(c => ({ entity: e.id, component: c.id, attached: e.attached })));
    const left = side('agent'), right = side('avatar');
    const rows = Math.max(left.length, right.length, 1);
    const width = COL_W * 2 + GAP;
    svg.setAttribute('viewBox', `0 0 ${width} ${TOP + rows * ROW + 10}`);
    const pos = new Map();
    svg.append(el('text', { x: 4, y: 14, class: 'col-title' }, 'Virtual Agent'));
    svg.append(el('text', { x: width - 4, y: 14, class: 'col-title', 'text-anchor': 'end' }, 'Avatars'));
    const node = (n, i, x, anchor) => {
      const y = TOP + i * ROW + ROW / 2;
      pos.set(key(n.entity, n.component), { x: anchor === 'start' ? x + COL_W : x, y });
      const gEl = el('g', { class: 'node' + (n.attached === false ? ' detached' : ''), 'data-entity': n.entity, 'data-component': n.component });
      gEl.append(el('rect', { x, y: y - 13, width: COL_W, height: 26, rx: 5 }));
      gEl.append(el('text', { x: x + 8, y: y - 1, class: 'comp' }, n.component));
      gEl.append(el('text', { x: x + 8, y: y + 10, class: 'ent' }, n.entity));
      svg.append(gEl);
    };
    left.forEach((n, i) => node(n, i, 0, 'start'));
    right.forEach((n, i) => node(n, i, COL_W + GAP, 'end'));
    const edges = el('g', { class: 'edges' });
    svg.prepend(edges);
    // One edge per pair of components, whichever consumes from which; its
    // label lists every service bound between them.
    const pairs = new Map();
    for (const b of g.bound) {
      const [c1, c2] = [b.consumer.component, b.provider.component].sort();
      const k = `${c1}\u0000${c2}`;
      if (!pairs.has(k)) pairs.set(k, { a: b.consumer, p: b.provider, services: [] });
      const svc = `${b.category} / ${b.type}`;
      if (!pairs.get(k).services.includes(svc)) pairs.get(k).services.push(svc);
    }
    for (const [k, { a: ca, p: cp, services }] of pairs) {
      const a = pos.get(key(ca.entity, ca.component));
      const p = pos.get(key(cp.entity, cp.component));
      if (!a || !p) continue;
      const [from, to] = a.x < p.x ? [a, p] : [p, a];
      const mid = (from.x + to.x) / 2;
      const path = el('path', { d: `M${from.x},${from.y} C${mid},${from.y} ${mid},${to.y} ${to.x},${to.y}`, class: 'edge' });
      const label = el('text', { x: mid, y: (from.y + to.y) / 2 - 3, class: 'edge-label', 'text-anchor': 'middle' },
        services.join(' · '));
      const group = el('g', { class: 'bound', 'data-consumer': ca.component, 'data-provider': cp.component });
      // Redrawn every few seconds: the count so far is kept, not reset.
      const seen = this.traffic.get(k);
      if (seen) group.dataset.traffic = String(seen);
      group.append(el('title', {}, services.join('\n')), path, label);
      edges.append(group);
      this.edges.set(`${ca.component}\u0000${cp.component}`, group);
      this.edges.set(`${cp.component}\u0000${ca.component}`, group);
    }
    for (const u of g.unbound) {
      const a = pos.get(key(u.consumer.entity, u.consumer.component));
      if (!a) continue;
      const dir = a.x <= COL_W ? 1 : -1;
      edges.append(el('path', { d: `M${a.x},${a.y} l${dir * 60},0`, class: 'edge unbound-stub' }));
      edges.append(el('text', { x: a.x + dir * 64, y: a.y + 4, class: 'unbound-label', 'text-anchor': dir > 0 ? 'start' : 'end' }, u.reason));
    }
  }

  // A signal went from component `from' to component `to'.
  flash(from, to) {
    const g = this.edges.get(`${from}\u0000${to}`);
    if (!g) return false;
    g.classList.remove('flash');
    void g.getBoundingClientRect();
    g.classList.add('flash');
    const k = [from, to].sort().join('\u0000');
    const n = (this.traffic.get(k) || 0) + 1;
    this.traffic.set(k, n);
    g.dataset.traffic = String(n);
    return true;
  }
}
