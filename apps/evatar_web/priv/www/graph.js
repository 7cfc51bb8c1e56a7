// The Body Mapping Registry as an SVG graph (docs/dashboard.md): the VA's
// components on the left, the Avatars' on the right, one edge per bound
// entry, from the consumer to its provider (the arrow), each with its own
// label (category / type). Two components bound by several entries get
// several edges. An unbound entry ends in a dashed stub labelled with its
// reason. flash() lights the edge a signal travelled and counts it on the
// edge (data-traffic); the counts outlive the graph's periodic redraws.
//
// The layout is our own, made so that labels can never sit under a box:
// the boxes stand in two columns; every edge leaves its box at its own
// port, runs into the gutter between the columns, carries its label on a
// straight run in the gutter's middle lane (labels stacked so that no two
// overlap), and goes on to the other box. The gutter is as wide as the
// longest label; labels are monospace so that width is known before
// drawing. Right-hand boxes are ordered by where their partners stand on
// the left, which keeps most edges straight.

const NS = 'http://www.w3.org/2000/svg';
const COL_W = 200;          // a component's box
const PORT = 14;            // vertical space per edge at a box
const BOX_MIN = 34, BOX_GAP = 10, TOP = 26;
const CURVE = 46;           // the bend between a box and the label lane
const LABEL_H = 13;         // a label's line in the lane
const CHAR_W = 5.8;         // 9px monospace, rounded up
const COMP_CHARS = 27, ENT_CHARS = 34;

function el(name, attrs = {}, text) {
  const e = document.createElementNS(NS, name);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text !== undefined) e.textContent = text;
  return e;
}

// Long names are cut in the box; the full name is in the box's title.
const cut = (s, n) => (s.length > n ? s.slice(0, n - 1) + '…' : s);
const nodeKey = (entity, component) => `${entity}\u0000${component}`;
// Services are compared as keywords, as bil does (docs/bil.md section 4).
const kw = s => String(s || '').toUpperCase().replace(/[^A-Z0-9]/g, '');
const edgeKey = b => [b.consumer.entity, b.consumer.component, b.provider.entity,
  b.provider.component, kw(b.category), kw(b.type)].join('\u0000');
const MAX_SIGNALS = 2000;   // requests remembered to flash their answers

export class Graph {
  constructor(svg) {
    this.svg = svg;
    this.edges = [];          // [{key, b, group}]
    this.traffic = new Map(); // edge key -> signals seen
    this.signals = new Map(); // signal id -> edge key
  }

  // Forget the traffic counted so far (another pairing is shown).
  reset() { this.traffic = new Map(); this.signals = new Map(); }

  render(g) {
    const svg = this.svg;
    svg.replaceChildren();
    this.edges = [];
    const side = role => g.entities.filter(e => e.role === role)
      .flatMap(e => e.components.map(c => ({ entity: e.id, component: c.id, attached: e.attached, links: [] })));
    const left = side('agent'), right = side('avatar');
    const where = new Map();
    left.forEach((n, i) => where.set(nodeKey(n.entity, n.component), { n, side: 0, i }));
    right.forEach((n, i) => where.set(nodeKey(n.entity, n.component), { n, side: 1, i }));
    const at = r => where.get(nodeKey(r.entity, r.component));

    // Links: one per bound entry between a left and a right box, one per
    // unbound entry (a stub from its consumer).
    const links = [];
    for (const b of g.bound) {
      const c = at(b.consumer), p = at(b.provider);
      if (!c || !p || c.side === p.side) continue;
      const [l, r] = c.side === 0 ? [c, p] : [p, c];
      links.push({ kind: 'bound', b, l, r, toRight: c.side === 0,
        label: `${c.side === 0 ? '→' : '←'} ${b.category} / ${b.type}` });
    }
    for (const u of g.unbound) {
      const c = at(u.consumer);
      if (!c) continue;
      links.push({ kind: 'unbound', u, end: c, label: `${u.reason}: ${u.category} / ${u.type}` });
    }
    // Right boxes follow their partners on the left.
    const bary = new Map();
    for (const k of links.filter(k => k.kind === 'bound')) {
      const s = bary.get(k.r.n) || [0, 0];
      bary.set(k.r.n, [s[0] + k.l.i, s[1] + 1]);
    }
    const rank = n => (bary.has(n) ? bary.get(n)[0] / bary.get(n)[1] : Infinity);
    right.map((n, i) => ({ n, i })).sort((a, b) => rank(a.n) - rank(b.n) || a.i - b.i)
      .forEach(({ n }, i) => { where.get(nodeKey(n.entity, n.component)).i = i; });
    right.sort((a, b) => at(a).i - at(b).i);

    // Ports: each box's links, ordered by where their other end stands.
    const other = (k, n) => (k.kind === 'unbound' ? -1 : (k.l.n === n ? k.r.i : k.l.i));
    for (const k of links) {
      if (k.kind === 'bound') { k.l.n.links.push(k); k.r.n.links.push(k); } else k.end.n.links.push(k);
    }
    const place = (col, x) => {
      let y = TOP;
      for (const n of col) {
        n.links.sort((a, b) => other(a, n) - other(b, n) || a.label.localeCompare(b.label));
        const h = Math.max(BOX_MIN, n.links.length * PORT + 8);
        Object.assign(n, { x, y, h });
        n.links.forEach((k, j) => { (k.ports ||= new Map()).set(n, y + (h - n.links.length * PORT) / 2 + PORT * (j + 0.5)); });
        y += h + BOX_GAP;
      }
      return y;
    };
    const laneW = Math.max(120, ...links.map(k => k.label.length * CHAR_W + 10));
    const gutter = laneW + 2 * CURVE;
    const rightX = COL_W + gutter;
    const width = rightX + COL_W;
    const bottom = Math.max(place(left, 0), place(right, rightX));

    // Labels: wanted halfway between their ports, then pushed apart.
    for (const k of links) {
      const ys = [...k.ports.values()];
      k.want = ys.reduce((a, b) => a + b, 0) / ys.length;
    }
    const lane = [...links].sort((a, b) => a.want - b.want);
    let last = -Infinity;
    for (const k of lane) { k.ly = Math.max(k.want, last + LABEL_H); last = k.ly; }
    const height = Math.max(bottom, last + LABEL_H) + 6;
    // A pixel each side: the boxes' outer stroke is not cut.
    svg.setAttribute('viewBox', `-1 0 ${width + 2} ${height}`);
    svg.style.aspectRatio = `${width + 2} / ${height}`;

    const defs = el('defs');
    const marker = el('marker', { id: 'bmr-arrow', viewBox: '0 0 10 10', refX: 10, refY: 5,
      markerWidth: 7, markerHeight: 7, orient: 'auto-start-reverse' });
    marker.append(el('path', { d: 'M0,0 L10,5 L0,10 z', class: 'arrow' }));
    defs.append(marker);
    svg.append(defs);
    svg.append(el('text', { x: 4, y: 14, class: 'col-title' }, 'Virtual Agent'));
    svg.append(el('text', { x: width - 4, y: 14, class: 'col-title', 'text-anchor': 'end' }, 'Avatars'));

    const edges = el('g', { class: 'edges' });
    svg.append(edges);
    const x1 = COL_W, xa = COL_W + CURVE, xb = xa + laneW, x2 = rightX;
    for (const k of links) {
      const ly = k.ly;
      const label = el('g', { class: 'label' });
      label.append(el('rect', { x: xa, y: ly - LABEL_H / 2, width: laneW, height: LABEL_H - 1, rx: 2, class: 'label-bg' }));
      if (k.kind === 'bound') {
        const y1 = k.ports.get(k.l.n), y2 = k.ports.get(k.r.n);
        const d = `M${x1},${y1} C${x1 + CURVE / 2},${y1} ${xa - CURVE / 2},${ly} ${xa},${ly} L${xb},${ly} ` +
          `C${xb + CURVE / 2},${ly} ${x2 - CURVE / 2},${y2} ${x2},${y2}`;
        const b = k.b, key = edgeKey(b);
        const group = el('g', { class: 'bound', 'data-consumer': b.consumer.component,
          'data-provider': b.provider.component, 'data-consumer-entity': b.consumer.entity,
          'data-provider-entity': b.provider.entity, 'data-category': b.category, 'data-type': b.type });
        // Redrawn every few seconds: the count so far is kept, not reset.
        const seen = this.traffic.get(key);
        if (seen) group.dataset.traffic = String(seen);
        group.append(el('title', {}, `${b.consumer.component} (${b.consumer.entity}) consumes ` +
          `${b.category} / ${b.type} from ${b.provider.component} (${b.provider.entity})`),
          el('path', { d, class: 'edge', [k.toRight ? 'marker-end' : 'marker-start']: 'url(#bmr-arrow)' }));
        label.append(el('text', { x: xa + laneW / 2, y: ly + 3, class: 'edge-label', 'text-anchor': 'middle' }, k.label));
        group.append(label);
        edges.append(group);
        this.edges.push({ key, b, group });
      } else {
        const n = k.end.n, y = k.ports.get(n), onLeft = k.end.side === 0;
        const [from, to] = onLeft ? [x1, xa] : [x2, xb];
        const d = `M${from},${y} C${(from + to) / 2},${y} ${(from + to) / 2},${ly} ${to},${ly}`;
        const group = el('g', { class: 'unbound-entry', 'data-consumer': k.u.consumer.component, 'data-reason': k.u.reason });
        group.append(el('title', {}, `${k.u.consumer.component} (${k.u.consumer.entity}) consumes ` +
          `${k.u.category} / ${k.u.type}: unbound, ${k.u.reason}`),
          el('path', { d, class: 'edge unbound-stub' }));
        label.append(el('text', { x: onLeft ? xa + 4 : xb - 4, y: ly + 3, class: 'unbound-label',
          'text-anchor': onLeft ? 'start' : 'end' }, k.label));
        group.append(label);
        edges.append(group);
      }
    }
    for (const n of [...left, ...right]) {
      const gEl = el('g', { class: 'node' + (n.attached === false ? ' detached' : ''),
        'data-entity': n.entity, 'data-component': n.component });
      const mid = n.y + n.h / 2;
      gEl.append(el('title', {}, `${n.component} (${n.entity})`),
        el('rect', { x: n.x, y: n.y, width: COL_W, height: n.h, rx: 5 }),
        el('text', { x: n.x + 8, y: mid - 1, class: 'comp' }, cut(n.component, COMP_CHARS)),
        el('text', { x: n.x + 8, y: mid + 10, class: 'ent' }, cut(n.entity, ENT_CHARS)));
      svg.append(gEl);
    }
  }

  // A signal item of the tail went from one component to another: light
  // the entry it travels on (a request: the entry of its service; an
  // answer: its request's entry).
  flash(i) {
    const from = { entity: i.from_entity, component: i.from }, to = { entity: i.to_entity, component: i.to };
    const same = (a, b) => a.entity === b.entity && a.component === b.component;
    let key = i.in_reply_to ? this.signals.get(i.in_reply_to) : undefined;
    if (!key) {
      const hit = this.edges.find(e => same(e.b.consumer, from) && same(e.b.provider, to) &&
          kw(e.b.category) === kw(i.category) && kw(e.b.type) === kw(i.type)) ||
        this.edges.find(e => same(e.b.consumer, from) && same(e.b.provider, to)) ||
        this.edges.find(e => same(e.b.consumer, to) && same(e.b.provider, from));
      if (!hit) return false;
      key = hit.key;
    }
    if (i.signal) {
      this.signals.set(i.signal, key);
      if (this.signals.size > MAX_SIGNALS) this.signals.delete(this.signals.keys().next().value);
    }
    const n = (this.traffic.get(key) || 0) + 1;
    this.traffic.set(key, n);
    const e = this.edges.find(x => x.key === key);
    if (!e) return false;
    const g = e.group;
    g.classList.remove('flash');
    void g.getBoundingClientRect();
    g.classList.add('flash');
    g.dataset.traffic = String(n);
    return true;
  }
}
