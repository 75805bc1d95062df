// The page of `lcc-stream ui`: plain JavaScript, no library. Everything it shows comes from
// the tool's API (/api/...), which runs the same code as the command line.
'use strict';

const token = new URLSearchParams(location.search).get('token');
const KINDS = ['alias', 'node', 'snip', 'datagram', 'stream', 'event', 'raw'];
const MOST_LINES = 2000;
const MOST_REPORTS = 500;

const state = {
  me: '',
  nodes: [],
  reports: [],
  identified: [],
  lines: [],
  monitorOff: null,
  skipped: 0,
  paused: false,
  job: null,
  clock: null,
};

// ---- helpers ----

function el(tag, attrs, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (v === null || v === undefined || v === false) continue;
    if (k === 'class') e.className = v;
    else if (k.startsWith('on')) e.addEventListener(k.slice(2), v);
    else if (k === 'text') e.textContent = v;
    else e.setAttribute(k, v === true ? '' : v);
  }
  for (const c of children.flat(Infinity)) {
    if (c === null || c === undefined) continue;
    e.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return e;
}

function withToken(path) {
  return token ? path + (path.includes('?') ? '&' : '?') + 'token=' + encodeURIComponent(token) : path;
}

// A request to the API; a failure throws an Error with the tool's words.
async function api(method, path, body, type) {
  const headers = { 'X-LCC-UI': token || '1' };
  let payload = body;
  if (body !== undefined && type === undefined) {
    headers['Content-Type'] = 'application/json';
    payload = JSON.stringify(body);
  } else if (type) {
    headers['Content-Type'] = type;
  }
  const response = await fetch(withToken(path), { method, headers, body: payload });
  const text = await response.text();
  let json = null;
  try { json = text ? JSON.parse(text) : null; } catch (e) { json = null; }
  if (!response.ok) {
    throw new Error(json && json.error ? json.error : `${response.status} ${response.statusText}`);
  }
  return json === null ? text : json;
}

function say(text, kind) {
  const box = document.getElementById('message');
  box.replaceChildren(el('p', { class: kind || 'ok', id: 'message-text', text }));
}

function sayError(error) {
  say(error.message || String(error), 'error');
}

function bytes(n) {
  if (n >= 1e6) return (n / 1e6).toFixed(2) + ' MB';
  if (n >= 1e3) return (n / 1e3).toFixed(1) + ' kB';
  return n + ' B';
}

function nodeName(report) {
  const s = report.snip;
  if (!s) return '';
  return s.user_name || s.model || '';
}

// ---- live updates ----

function connectLive() {
  const source = new EventSource(withToken('/api/live'));
  source.addEventListener('nodes', (e) => { state.nodes = JSON.parse(e.data); if (route().view === 'nodes') render(); });
  source.addEventListener('event', (e) => {
    state.reports.push(JSON.parse(e.data));
    if (state.reports.length > MOST_REPORTS) state.reports.shift();
    if (route().view === 'events') drawReports();
  });
  source.addEventListener('identified', (e) => {
    state.identified.push(JSON.parse(e.data));
    if (route().view === 'events') drawIdentified();
  });
  source.addEventListener('monitor', (e) => {
    if (state.paused) { state.skipped += 1; return; }
    state.lines.push(JSON.parse(e.data));
    if (state.lines.length > MOST_LINES) state.lines.shift();
    if (route().view === 'monitor') drawLines();
  });
  source.addEventListener('skipped', (e) => {
    state.skipped += Number(e.data) || 0;
    if (route().view === 'monitor') drawLines();
  });
  source.addEventListener('clock', (e) => { state.clock = JSON.parse(e.data); drawClock(); });
  source.addEventListener('job', (e) => { state.job = JSON.parse(e.data); drawJob(); });
  source.addEventListener('notice', (e) => { const n = JSON.parse(e.data); if (n.error) say(n.error, 'error'); });
}

function drawJob() {
  const bar = document.getElementById('job');
  const job = state.job;
  bar.hidden = !job;
  if (!job) return;
  document.getElementById('job-what').textContent = job.what;
  const progress = document.getElementById('job-progress');
  if (job.total) {
    progress.max = job.total;
    progress.value = job.bytes;
  } else {
    progress.removeAttribute('value');
  }
  document.getElementById('job-bytes').textContent = job.bytes ? bytes(job.bytes) + (job.total ? ' of ' + bytes(job.total) : '') : '';
}

// ---- routing ----

function route() {
  const parts = location.hash.replace(/^#\/?/, '').split('/').filter(Boolean).map(decodeURIComponent);
  if (parts[0] === 'node' && parts[1]) return { view: parts[2] === 'config' ? 'config' : 'node', node: parts[1] };
  if (parts[0] === 'events') return { view: 'events' };
  if (parts[0] === 'monitor') return { view: 'monitor' };
  if (parts[0] === 'clock') return { view: 'clock' };
  if (parts[0] === 'throttle') return { view: 'throttle' };
  return { view: 'nodes' };
}

let configView = null;

function render() {
  const r = route();
  for (const [id, view] of [['nav-nodes', 'nodes'], ['nav-events', 'events'], ['nav-monitor', 'monitor'], ['nav-clock', 'clock'], ['nav-throttle', 'throttle']]) {
    document.getElementById(id).classList.toggle('here', r.view === view);
  }
  const main = document.getElementById('view');
  if (r.view !== 'config') configView = null;
  if (r.view === 'nodes') main.replaceChildren(nodesView());
  else if (r.view === 'node') main.replaceChildren(nodeView(r.node));
  else if (r.view === 'config') {
    if (!configView || configView.node !== r.node) {
      configView = { node: r.node };
      main.replaceChildren(el('p', { class: 'muted', text: 'Reading the configuration…' }));
      loadConfig(r.node);
    }
  } else if (r.view === 'events') main.replaceChildren(eventsView());
  else if (r.view === 'monitor') main.replaceChildren(monitorView());
  else if (r.view === 'clock') main.replaceChildren(clockView());
  else if (r.view === 'throttle') main.replaceChildren(throttleView());
}

// ---- nodes ----

function nodesView() {
  const refresh = el('button', { type: 'button', id: 'refresh', onclick: async (e) => {
    e.target.disabled = true;
    try { state.nodes = (await api('POST', '/api/nodes/refresh')).nodes; say(`${state.nodes.length} node(s) answered`); render(); }
    catch (error) { sayError(error); }
    finally { e.target.disabled = false; }
  } }, 'Refresh');
  const rows = state.nodes.map((n) => {
    const s = n.snip || {};
    const open = () => { location.hash = '#/node/' + encodeURIComponent(n.node_id); };
    return el('tr', { class: 'node', tabindex: '0', 'data-node': n.node_id, onclick: open,
      onkeydown: (e) => { if (e.key === 'Enter') open(); } },
      el('td', {}, el('a', { href: '#/node/' + encodeURIComponent(n.node_id) }, n.node_id)),
      el('td', { class: 'wide' }, n.alias || ''),
      el('td', {}, s.user_name || ''),
      el('td', {}, s.manufacturer || ''),
      el('td', {}, s.model || ''),
      el('td', { class: 'wide' }, [s.hardware_version, s.software_version].filter(Boolean).join(' / ')),
      el('td', { class: 'wide' }, s.user_description || ''),
      el('td', { class: 'wide' }, n.protocols ? n.protocols.join(' ') : '(no PIP)'));
  });
  return el('section', {},
    el('h1', {}, 'Nodes ', el('span', { class: 'muted', text: `(${state.nodes.length})` })),
    el('div', { class: 'row' }, refresh),
    el('div', { class: 'scroll' }, el('table', { id: 'nodes' },
      el('thead', {}, el('tr', {}, ['Node ID', 'Alias', 'Name', 'Manufacturer', 'Model', 'HW / SW', 'Description', 'Protocols']
        .map((h, i) => el('th', { class: [1, 5, 6, 7].includes(i) ? 'wide' : null }, h)))),
      el('tbody', {}, rows))),
    state.nodes.length ? null : el('p', { class: 'muted', text: 'No node yet: Refresh asks again.' }));
}

function nodeView(id) {
  const known = state.nodes.find((x) => x.node_id === id);
  if (!known) {
    // Not in the table (yet): ask the node itself.
    api('GET', '/api/nodes/' + encodeURIComponent(id)).then((report) => {
      if (report && !state.nodes.some((x) => x.node_id === id)) state.nodes.push(report);
      if (report && route().view === 'node' && route().node === id) render();
    }).catch(sayError);
  }
  const n = known || { node_id: id };
  const s = n.snip;
  const base = '/api/nodes/' + encodeURIComponent(id);
  const command = (name, words, body) => async (e) => {
    e.target.disabled = true;
    try { say((await api('POST', `${base}/command/${name}`, body || {})).message); }
    catch (error) { sayError(error); }
    finally { e.target.disabled = false; }
  };
  const restoreFile = el('input', { type: 'file', id: 'restore-file', accept: '.txt,text/plain' });
  const plan = el('div', { id: 'restore-plan' });
  const firmwareFile = el('input', { type: 'file', id: 'firmware-file' });
  const events = el('div', { id: 'node-events' });
  const showPlan = (p, text) => {
    const list = el('ul', {}, p.writes.map((w) => el('li', {}, `${w.key}: ${w.old} → ${w.new}`)),
      p.unknown_keys.map((k) => el('li', { class: 'muted' }, `not in the CDI, left alone: ${k}`)));
    const apply = el('button', { type: 'button', class: 'primary', id: 'restore-apply', disabled: p.writes.length ? null : true, onclick: async (e) => {
      e.target.disabled = true;
      try {
        const done = await api('POST', `${base}/restore?apply=true`, text, 'text/plain');
        say(`restored: wrote ${done.writes.length} setting(s)` + (done.warning ? `; warning: ${done.warning}` : ''));
        plan.replaceChildren();
      } catch (error) { sayError(error); e.target.disabled = false; }
    } }, `Write ${p.writes.length} change(s)`);
    plan.replaceChildren(el('p', {}, `${p.writes.length} to change, ${p.unchanged} unchanged, ${p.unknown_keys.length} not in the CDI`), list, apply);
  };
  return el('section', {},
    el('h1', {}, id, ' ', el('span', { class: 'muted' }, nodeName(n))),
    s ? el('dl', { id: 'snip' },
      ['Manufacturer', s.manufacturer, 'Model', s.model, 'Hardware', s.hardware_version, 'Software', s.software_version,
        'Name', s.user_name, 'Description', s.user_description, 'Alias', n.alias || '—']
        .map((v, i) => el(i % 2 ? 'dd' : 'dt', {}, v || ''))) : el('p', { class: 'muted', text: 'No SNIP (yet).' }),
    el('p', {}, el('strong', {}, 'Protocols: '), n.protocols ? n.protocols.join(', ') : '(no PIP)'),
    (n.errors || []).length ? el('p', { class: 'muted' }, n.errors.join('; ')) : null,
    el('div', { class: 'row' },
      el('a', { class: 'button', id: 'configure', href: '#/node/' + encodeURIComponent(id) + '/config' }, 'Configure'),
      el('a', { class: 'button', id: 'backup', href: withToken(base + '/backup'), download: `config-${id.replaceAll('.', '-')}.txt` }, 'Backup'),
      el('button', { type: 'button', id: 'update-complete', onclick: command('update-complete') }, 'Update Complete'),
      el('button', { type: 'button', id: 'reboot', onclick: command('reboot') }, 'Reboot'),
      el('button', { type: 'button', class: 'danger', id: 'factory-reset', onclick: (e) => {
        if (confirm(`Put every setting of ${id} back to its default? (Backup saves them first.)`)) command('factory-reset', '', { yes: true })(e);
      } }, 'Factory Reset')),
    el('h2', {}, 'Restore a backup'),
    el('div', { class: 'row' }, restoreFile, el('button', { type: 'button', id: 'restore-show', onclick: async () => {
      const file = restoreFile.files[0];
      if (!file) { say('choose a backup file first', 'error'); return; }
      try { const text = await file.text(); showPlan(await api('POST', `${base}/restore`, text, 'text/plain'), text); }
      catch (error) { sayError(error); }
    } }, 'Show what would change')),
    plan,
    el('h2', {}, 'Firmware'),
    el('div', { class: 'row' }, firmwareFile, el('button', { type: 'button', id: 'firmware-upload', onclick: async (e) => {
      const file = firmwareFile.files[0];
      if (!file) { say('choose a firmware image first', 'error'); return; }
      if (!confirm(`Upgrade the firmware of ${id} with ${file.name} (${bytes(file.size)})?`)) return;
      e.target.disabled = true;
      try { say((await api('POST', `${base}/firmware`, await file.arrayBuffer(), 'application/octet-stream')).message); }
      catch (error) { sayError(error); }
      finally { e.target.disabled = false; }
    } }, 'Upgrade')),
    el('h2', {}, 'Events'),
    el('div', { class: 'row' }, el('button', { type: 'button', id: 'node-identify', onclick: async (e) => {
      e.target.disabled = true;
      events.replaceChildren(el('p', { class: 'muted', text: 'Asking…' }));
      try { events.replaceChildren(identifiedTable((await api('POST', `${base}/events`)).identified)); }
      catch (error) { sayError(error); events.replaceChildren(); }
      finally { e.target.disabled = false; }
    } }, 'What it produces and consumes')),
    events);
}

// ---- configuration ----

function controlFor(entry) {
  const attrs = { 'data-key': entry.key, id: 'cfg-' + entry.key, 'aria-label': entry.name || entry.key };
  const original = entry.value === null || entry.value === undefined ? '' : String(entry.value);
  let input;
  if (entry.map && entry.map.length && entry.type === 'int') {
    input = el('select', attrs, entry.map.map((m) => el('option', { value: m.value }, m.label)));
    if (!entry.map.some((m) => m.value === original)) input.append(el('option', { value: original }, `${original} (not in the list)`));
  } else if (entry.type === 'int' || entry.type === 'float') {
    input = el('input', Object.assign({ type: 'number', inputmode: entry.type === 'int' ? 'numeric' : 'decimal',
      step: entry.type === 'int' ? '1' : 'any', min: entry.min, max: entry.max }, attrs));
  } else if (entry.type === 'string') {
    input = el('input', Object.assign({ type: 'text', maxlength: Math.max(0, entry.size - 1) }, attrs));
  } else if (entry.type === 'eventid') {
    input = el('input', Object.assign({ type: 'text', spellcheck: 'false', autocapitalize: 'characters',
      pattern: '([0-9A-Fa-f]{2}[.:]?){7}[0-9A-Fa-f]{2}' }, attrs));
  } else {
    return { node: el('span', { class: 'muted' }, `(${entry.type})`), input: null };
  }
  input.value = original;
  input.dataset.original = original;
  input.addEventListener('input', () => { input.classList.toggle('changed', input.value !== input.dataset.original); countChanges(); });
  input.addEventListener('change', () => { input.classList.toggle('changed', input.value !== input.dataset.original); countChanges(); });
  const parts = [input];
  if (entry.type === 'eventid') {
    parts.push(el('button', { type: 'button', title: 'Copy', onclick: () => navigator.clipboard && navigator.clipboard.writeText(input.value) }, 'Copy'));
    parts.push(el('button', { type: 'button', title: 'Paste', onclick: async () => {
      if (!navigator.clipboard) return;
      input.value = (await navigator.clipboard.readText()).trim();
      input.dispatchEvent(new Event('input'));
    } }, 'Paste'));
  }
  if (entry.default !== null && entry.default !== undefined) {
    parts.push(el('button', { type: 'button', title: 'Put the default back', onclick: () => { input.value = String(entry.default); input.dispatchEvent(new Event('input')); } }, 'Default'));
  }
  return { node: el('span', { class: 'control' }, parts), input };
}

function entryHelp(entry) {
  const notes = [];
  if (entry.type === 'string') notes.push(`text, at most ${Math.max(0, entry.size - 1)} bytes`);
  if (entry.type === 'eventid') notes.push('Event ID, 8 hex bytes');
  if (entry.min !== null && entry.min !== undefined || entry.max !== null && entry.max !== undefined) notes.push(`${entry.min ?? ''} to ${entry.max ?? ''}`);
  if (entry.default !== null && entry.default !== undefined) notes.push(`default ${entry.default}`);
  const text = [entry.description, notes.join('; ')].filter(Boolean).join('\n');
  return text ? el('div', { class: 'help' }, text) : null;
}

// Groups are shown open, unless there are many of them side by side (a replication of
// hundreds of copies): then each is a line to open, which keeps a large CDI quick to draw.
const MOST_OPEN_GROUPS = 16;

function groupNode(group, depth, open) {
  const groups = group.children.filter((child) => child.children).length;
  const children = group.children.map((child) => child.children
    ? groupNode(child, depth + 1, groups <= MOST_OPEN_GROUPS && depth < 2)
    : entryNode(child));
  const title = group.name || group.key;
  const body = [group.description ? el('p', { class: 'description' }, group.description) : null, children];
  if (depth === 0) return el('fieldset', { 'data-group': group.key }, el('legend', {}, title), body);
  return el('details', { 'data-group': group.key, open: open ? true : null }, el('summary', {}, title), body);
}

function entryNode(entry) {
  const { node } = controlFor(entry);
  return el('div', { class: 'entry' }, el('label', { for: 'cfg-' + entry.key }, entry.name || entry.key), node, entryHelp(entry));
}

function changedInputs() {
  return [...document.querySelectorAll('[data-key]')].filter((i) => i.value !== i.dataset.original);
}

function countChanges() {
  const save = document.getElementById('save');
  if (!save) return;
  const n = changedInputs().length;
  save.disabled = n === 0;
  save.textContent = n ? `Save ${n} change(s)` : 'Save';
}

async function loadConfig(id) {
  const main = document.getElementById('view');
  const started = performance.now();
  try {
    const config = await api('GET', '/api/nodes/' + encodeURIComponent(id) + '/config');
    if (!configView || configView.node !== id) return;
    const save = el('button', { type: 'button', class: 'primary', id: 'save', disabled: true, onclick: () => saveConfig(id) }, 'Save');
    const reload = el('button', { type: 'button', id: 'reload', onclick: () => { configView = null; render(); } }, 'Read again');
    const segments = config.segments.map((s) => groupNode(s, 0, true));
    main.replaceChildren(el('section', { id: 'config' },
      el('h1', {}, 'Configure ', el('a', { href: '#/node/' + encodeURIComponent(id) }, id)),
      segments,
      el('div', { class: 'savebar' }, save, reload)));
    const entries = document.querySelectorAll('[data-key]').length;
    requestAnimationFrame(() => {
      configView.shownMs = performance.now() - started;
      document.getElementById('config').dataset.shownMs = String(Math.round(configView.shownMs));
      document.getElementById('config').dataset.entries = String(entries);
    });
  } catch (error) {
    main.replaceChildren(el('p', { class: 'error', id: 'config-error' }, error.message));
    sayError(error);
  }
}

async function saveConfig(id) {
  const inputs = changedInputs();
  const changes = inputs.map((i) => ({ key: i.dataset.key, value: i.value }));
  const save = document.getElementById('save');
  save.disabled = true;
  try {
    const done = await api('POST', '/api/nodes/' + encodeURIComponent(id) + '/config', { changes });
    for (const i of inputs) { i.dataset.original = i.value; i.classList.remove('changed'); }
    say(`saved: ${done.written.length} setting(s) written and read back` + (done.warning ? `; warning: ${done.warning}` : ''));
  } catch (error) {
    sayError(error);
  } finally {
    countChanges();
  }
}

// ---- events ----

function identifiedTable(rows) {
  if (!rows.length) return el('p', { class: 'muted', text: 'No answer.' });
  return el('div', { class: 'scroll' }, el('table', { class: 'identified' },
    el('thead', {}, el('tr', {}, ['Node', 'Role', 'Event', 'State'].map((h) => el('th', {}, h)))),
    el('tbody', {}, rows.map((r) => el('tr', {},
      el('td', {}, r.node), el('td', {}, r.role),
      el('td', {}, (r.event === r.last ? r.event : `${r.event} … ${r.last}`) + (r.name ? ` (${r.name})` : '')),
      el('td', {}, r.state || 'range'))))));
}

function drawReports() {
  const box = document.getElementById('reports');
  if (!box) return;
  box.textContent = state.reports.slice().reverse().map((r) =>
    `${r.time.toFixed(3).padStart(10)}  ${r.event}${r.name ? ' (' + r.name + ')' : ''}${r.payload ? ' +' + r.payload : ''}  from ${r.from}${r.from_name ? ' "' + r.from_name + '"' : ''}`).join('\n');
}

function drawIdentified() {
  const box = document.getElementById('identified');
  if (box) box.replaceChildren(identifiedTable(state.identified));
}

function eventsView() {
  const event = el('input', { type: 'text', id: 'send-event', placeholder: '05.01.01.01.22.00.00.01', spellcheck: 'false', 'aria-label': 'Event ID' });
  const payload = el('input', { type: 'text', id: 'send-payload', placeholder: 'payload (hex, optional)', 'aria-label': 'Payload' });
  const view = el('section', {},
    el('h1', {}, 'Events'),
    el('form', { class: 'row', onsubmit: async (e) => {
      e.preventDefault();
      try { say((await api('POST', '/api/events/send', { event: event.value, payload: payload.value })).message); }
      catch (error) { sayError(error); }
    } }, event, payload, el('button', { type: 'submit', class: 'primary', id: 'send' }, 'Send'),
    el('button', { type: 'button', id: 'identify', onclick: async () => {
      try { state.identified = []; drawIdentified(); await api('POST', '/api/events/identify'); say('Identify Events sent: the answers follow'); }
      catch (error) { sayError(error); }
    } }, 'Identify all')),
    el('h2', {}, 'Reports (newest first)'),
    el('div', { class: 'lines', id: 'reports' }),
    el('h2', {}, 'Producers and consumers'),
    el('div', { id: 'identified' }));
  queueMicrotask(() => { drawReports(); drawIdentified(); });
  return view;
}

// ---- monitor ----

const filter = { node: '', kind: '' };

function keeps(line) {
  if (filter.kind && line.kind !== filter.kind) return false;
  if (!filter.node) return true;
  const f = filter.node.trim().toUpperCase();
  return [line.source_alias, line.source, line.destination_alias, line.destination].some((v) => v && v.toUpperCase() === f);
}

function lineText(l) {
  const named = (alias, node) => node ? `${alias} ${node}` : alias;
  const to = l.destination_alias ? ` -> ${named(l.destination_alias, l.destination)}` : '';
  return `${l.time.toFixed(3).padStart(10)}  ${named(l.source_alias, l.source)}${to}  ${l.message}${l.detail ? ': ' + l.detail : ''}${l.raw ? ' [' + l.raw + ']' : ''}`;
}

function drawLines() {
  const box = document.getElementById('lines');
  if (!box) return;
  box.textContent = state.lines.filter(keeps).map(lineText).join('\n');
  box.scrollTop = box.scrollHeight;
  const skipped = document.getElementById('skipped');
  skipped.textContent = state.skipped ? `${state.skipped} line(s) not shown (paused, or faster than this page)` : '';
}

function monitorView() {
  const node = el('input', { type: 'text', id: 'filter-node', placeholder: 'node or alias', value: filter.node, 'aria-label': 'Node filter',
    oninput: (e) => { filter.node = e.target.value; drawLines(); } });
  const kind = el('select', { id: 'filter-kind', 'aria-label': 'Kind filter', onchange: (e) => { filter.kind = e.target.value; drawLines(); } },
    el('option', { value: '' }, 'every kind'), KINDS.map((k) => el('option', { value: k, selected: filter.kind === k ? true : null }, k)));
  const pause = el('button', { type: 'button', id: 'pause', onclick: (e) => { state.paused = !state.paused; e.target.textContent = state.paused ? 'Resume' : 'Pause'; } }, state.paused ? 'Resume' : 'Pause');
  const view = el('section', {},
    el('h1', {}, 'Monitor'),
    state.monitorOff ? el('p', { class: 'error' }, state.monitorOff) : null,
    el('div', { class: 'row' }, node, kind, pause,
      el('button', { type: 'button', onclick: () => { state.lines = []; state.skipped = 0; drawLines(); } }, 'Clear'),
      el('a', { class: 'button', id: 'trace', href: withToken('/api/monitor/trace'), download: 'lcc-trace.txt' }, 'Download the trace')),
    el('p', { class: 'muted', id: 'skipped' }),
    el('div', { class: 'lines', id: 'lines' }));
  queueMicrotask(drawLines);
  return view;
}

// ---- clock ----

function drawClock() {
  const time = document.getElementById('clock-time');
  if (!time) return;
  const c = state.clock;
  if (!c) { time.textContent = '—'; document.getElementById('clock-status').textContent = 'no clock'; return; }
  time.textContent = c.time;
  document.getElementById('clock-status').textContent = !c.synchronized
    ? `${c.clock}: waiting for its generator`
    : (c.running ? `${c.clock}: running at ${c.rate}x` : `${c.clock}: stopped`);
}

function clockView() {
  const ask = (body) => async (e) => {
    if (e && e.preventDefault) e.preventDefault();
    try { say((await api('POST', '/api/clock', body())).message); } catch (error) { sayError(error); }
  };
  const rate = el('input', { type: 'text', id: 'clock-rate', inputmode: 'decimal', placeholder: '4', size: '6', 'aria-label': 'Rate' });
  const time = el('input', { type: 'time', id: 'clock-set-time', 'aria-label': 'Time of day' });
  const view = el('section', {},
    el('h1', {}, 'Clock'),
    el('div', { id: 'clock-time' }, '—'),
    el('p', { id: 'clock-status', class: 'muted' }),
    el('div', { class: 'row' },
      el('button', { type: 'button', id: 'clock-start', onclick: ask(() => 'start') }, 'Start'),
      el('button', { type: 'button', id: 'clock-stop', onclick: ask(() => 'stop') }, 'Stop')),
    el('form', { class: 'row', onsubmit: ask(() => ({ rate: rate.value })) }, rate, el('button', { type: 'submit', id: 'clock-rate-set' }, 'Set rate')),
    el('form', { class: 'row', onsubmit: ask(() => ({ time: time.value })) }, time, el('button', { type: 'submit', id: 'clock-time-set' }, 'Set time')));
  api('GET', '/api/clock').then((c) => { state.clock = c; drawClock(); }).catch(sayError);
  queueMicrotask(drawClock);
  return view;
}

// ---- throttle ----

function throttleView() {
  const ask = (body) => async (e) => {
    if (e && e.preventDefault) e.preventDefault();
    try {
      const answer = await api('POST', '/api/throttle', body());
      say(answer.message);
      if (answer.train !== undefined || body() === 'release') drawThrottle();
    } catch (error) { sayError(error); }
  };
  const address = el('input', { type: 'number', id: 'throttle-address', min: '1', max: '10239', value: '3', 'aria-label': 'DCC address' });
  const long = el('input', { type: 'checkbox', id: 'throttle-long', 'aria-label': 'Long address' });
  const speed = el('input', { type: 'range', id: 'throttle-speed', min: '-120', max: '120', step: '1', value: '0', 'aria-label': 'Speed (km/h)' });
  const shown = el('span', { id: 'throttle-speed-value' }, '0 km/h');
  speed.addEventListener('input', () => { shown.textContent = speed.value + ' km/h'; });
  speed.addEventListener('change', ask(() => ({ speed: Number(speed.value) })));
  const functions = el('div', { class: 'row', id: 'throttle-functions' });
  for (let number = 0; number <= 8; number++) {
    const button = el('button', { type: 'button', id: 'throttle-f' + number, 'aria-pressed': 'false' }, 'F' + number);
    button.addEventListener('click', async () => {
      const on = button.getAttribute('aria-pressed') !== 'true';
      await ask(() => ({ function: { number, on } }))();
      button.setAttribute('aria-pressed', String(on));
    });
    functions.append(button);
  }
  const view = el('section', {},
    el('h1', {}, 'Throttle'),
    el('p', { id: 'throttle-train', class: 'muted' }, 'No train held.'),
    el('form', { class: 'row', onsubmit: ask(() => ({ acquire: { address: Number(address.value), long: long.checked } })) },
      address, el('label', {}, long, ' long'), el('button', { type: 'submit', id: 'throttle-acquire' }, 'Acquire')),
    el('div', { class: 'row' }, speed, shown),
    el('div', { class: 'row' },
      el('button', { type: 'button', id: 'throttle-stop', onclick: () => { speed.value = '0'; shown.textContent = '0 km/h'; ask(() => ({ speed: 0 }))(); } }, 'Stop'),
      el('button', { type: 'button', id: 'throttle-estop', onclick: ask(() => 'estop') }, 'E-stop'),
      el('button', { type: 'button', id: 'throttle-release', onclick: ask(() => 'release') }, 'Release')),
    functions);
  drawThrottle();
  return view;
}

async function drawThrottle() {
  try {
    const held = await api('GET', '/api/throttle');
    const line = document.getElementById('throttle-train');
    if (line) line.textContent = held.train ? `DCC ${held.address} is ${held.train}: this page drives it.` : 'No train held.';
  } catch (error) { sayError(error); }
}

// ---- start ----

async function start() {
  document.getElementById('job-cancel').addEventListener('click', async () => {
    try { await api('POST', '/api/cancel'); } catch (error) { sayError(error); }
  });
  window.addEventListener('hashchange', () => { document.getElementById('message').replaceChildren(); render(); });
  try {
    const s = await api('GET', '/api/state');
    Object.assign(state, { me: s.node_id, nodes: s.nodes, reports: s.reports, identified: s.identified, lines: s.lines,
      monitorOff: s.monitor_off, job: s.job });
    document.getElementById('me').textContent = 'as node ' + s.node_id;
  } catch (error) {
    sayError(error);
  }
  connectLive();
  drawJob();
  render();
}

start();
