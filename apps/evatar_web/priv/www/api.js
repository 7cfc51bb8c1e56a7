// The node's JSON API and its event stream (docs/api.md, docs/dashboard.md).
// The operator token, when one is needed, is kept in sessionStorage and sent
// as a Bearer header; the event stream is read with fetch() rather than
// EventSource for that reason (EventSource cannot send headers).

const TOKEN_KEY = 'evatar-operator-token';

export function token() { return sessionStorage.getItem(TOKEN_KEY) || ''; }
export function setToken(t) {
  if (t) sessionStorage.setItem(TOKEN_KEY, t); else sessionStorage.removeItem(TOKEN_KEY);
}

function headers() {
  const t = token();
  return t ? { Authorization: `Bearer ${t}` } : {};
}

export async function getJSON(path) {
  const res = await fetch(path, { headers: headers(), cache: 'no-store' });
  const body = await res.json().catch(() => ({ error: 'bad_json', message: res.statusText }));
  if (!res.ok) {
    const err = new Error(body.message || res.statusText);
    err.status = res.status; err.body = body;
    throw err;
  }
  return body;
}

// Opens GET /api/events and calls onItem for each item; onState with
// 'open', 'closed' or an Error. Returns a function that closes the stream.
export function events(params, onItem, onState) {
  const ctl = new AbortController();
  const qs = new URLSearchParams(params).toString();
  (async () => {
    try {
      const res = await fetch(`/api/events?${qs}`, { headers: headers(), signal: ctl.signal });
      if (!res.ok) {
        const body = await res.json().catch(() => ({}));
        throw new Error(body.message || res.statusText);
      }
      onState('open');
      const reader = res.body.getReader();
      const dec = new TextDecoder();
      let buf = '';
      for (;;) {
        const { value, done } = await reader.read();
        if (done) break;
        buf += dec.decode(value, { stream: true });
        let i;
        while ((i = buf.indexOf('\n\n')) >= 0) {
          const chunk = buf.slice(0, i);
          buf = buf.slice(i + 2);
          const data = chunk.split('\n').filter(l => l.startsWith('data: ')).map(l => l.slice(6)).join('\n');
          if (data) onItem(JSON.parse(data));
        }
      }
      onState('closed');
    } catch (e) {
      if (e.name !== 'AbortError') onState(e);
    }
  })();
  return () => ctl.abort();
}
