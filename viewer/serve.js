// The page of `matlaber serve` (docs/server.md) over its API: POST /api/jobs from the form, the
// queue from GET /api/jobs, a job's progress from its server-sent events (the lines of generate
// --progress json), and the finished asset in the viewer of `matlaber view` (/view/ID/).
// window.serveApp exposes the state for tests.
const $ = (id) => document.getElementById(id);

// Under --token: the page is opened as /?token=T; the token goes into a cookie for the requests
// that cannot carry a header (EventSource, links, the viewer's own fetches) and into every fetch.
const token = new URLSearchParams(location.search).get('token');
if (token) document.cookie = `matlaber_token=${token}; SameSite=Strict; path=/`;
const api = async (path, options = {}) => {
  const headers = { ...(options.headers || {}) };
  if (token) headers.Authorization = `Bearer ${token}`;
  const r = await fetch(path, { ...options, headers });
  const body = await r.json().catch(() => ({}));
  if (!r.ok) throw new Error(body.error || `HTTP ${r.status}`);
  return body;
};

const app = { selected: null, events: 0, last: null, source: null, shown: null };
window.serveApp = app;

const STAGES = { queued: 'waiting in the queue', running: 'running', done: 'done', failed: 'failed',
                 cancelled: 'cancelled', stopped: 'stopped (a run made outside the server)' };

function fmtSeconds(s) {
  if (!(s >= 0)) return '';
  return s < 90 ? `${Math.round(s)} s` : `${Math.floor(s / 60)} min ${Math.round(s % 60)} s`;
}

// a job in the list: its prompt, and for a saved latent edit the job it was made from
const describe = (job) => `${job.prompt || '(run folder)'}${job.request?.edit_of ? ` (edit of ${job.request.edit_of})` : ''}`;

// ---- the queue ----
async function refreshJobs() {
  let list;
  try { list = await api('/api/jobs'); } catch (e) { $('error').textContent = e.message; return; }
  const table = $('jobs');
  table.textContent = '';
  for (const job of list.jobs.slice().reverse()) {
    const tr = table.insertRow();
    tr.dataset.id = job.id;
    if (job.id === app.selected) tr.className = 'selected';
    const p = job.progress;
    const frac = p && p.total ? p.done / p.total : job.state === 'done' ? 1 : 0;
    tr.insertCell().textContent = job.id;
    tr.insertCell().textContent = describe(job);
    const cell = tr.insertCell();
    cell.textContent = job.state;
    const bar = document.createElement('div');
    bar.className = 'bar';
    bar.innerHTML = '<div></div>';
    bar.firstChild.style.width = `${Math.round(100 * frac)}%`;
    cell.appendChild(bar);
    tr.addEventListener('click', () => select(job.id));
  }
  app.jobs = list.jobs;
  // the finished jobs another may be compared with, side by side
  const compare = $('compare'), keep = compare.value;
  compare.length = 1;
  for (const job of list.jobs) if (job.state === 'done') compare.add(new Option(`${job.id}: ${describe(job)}`, job.id));
  compare.value = [...compare.options].some((o) => o.value === keep) ? keep : '';
}

$('compare').addEventListener('change', () => {
  const id = $('compare').value, view2 = $('view2');
  view2.hidden = !id;
  if (id) view2.src = `/view/${id}/`;
});

// ---- one job: its events, its files, its asset ----
function showProgress(ev) {
  if (!ev.total) return;
  $('job-bar').style.width = `${Math.round(100 * ev.done / ev.total)}%`;
  const parts = [`${ev.label}: ${ev.done} / ${ev.total} ${ev.unit || 'steps'}`];
  if (ev.rate) parts.push(`${ev.rate.toFixed(2)} /s`);
  if (ev.eta_s !== undefined && ev.event === 'progress') parts.push(`ETA ${fmtSeconds(ev.eta_s)}`);
  if (ev.status) parts.push(ev.status);
  $('job-status').textContent = parts.join(' · ');
}

function refreshPreview(id) {
  const now = Date.now();
  const img = $('preview');
  img.onload = () => { img.style.display = 'block'; };
  img.onerror = () => { img.style.display = 'none'; };
  img.src = `/api/jobs/${id}/files/preview.png?t=${now}`;
}

async function showJob(id) {
  const job = await api(`/api/jobs/${id}`);
  if (app.selected !== id) return;
  $('job-title').textContent = `${job.id}: ${describe(job)} (${STAGES[job.state] || job.state})`;
  $('cancel').hidden = !(job.state === 'queued' || job.state === 'running');
  if (job.progress) showProgress(job.progress);
  if (job.message) $('job-status').textContent = job.message;
  const links = $('downloads');
  links.textContent = '';
  for (const name of job.files || []) {
    if (!/\.(glb|obj|mtl|png|json|csv)$/.test(name) || /^(kd|ks|normal|roughness|shaded)_\d/.test(name)) continue;
    const a = document.createElement('a');
    a.href = `/api/jobs/${id}/files/${name}`;
    a.download = `${id}-${name}`;
    a.textContent = name;
    links.appendChild(a);
  }
  if ((job.files || []).includes('preview.png')) refreshPreview(id);   // only a listed file: no 404s
  const view = $('view');
  if (job.state === 'done' && (job.files || []).includes('asset.glb')) {
    if (app.shown !== id) { view.src = `/view/${id}/`; app.shown = id; }
    view.hidden = false;
    $('empty').hidden = true;
  }
  return job;
}

// while the events come, the job's files (the newest preview sheet) are looked at every 3 s
let shownAt = 0;
function follow(id) {
  if (app.source) app.source.close();
  const source = new EventSource(`/api/jobs/${id}/events`);
  app.source = source;
  source.onmessage = (msg) => {
    const ev = JSON.parse(msg.data);
    app.events++;
    app.last = ev;
    if (ev.event === 'begin' || ev.event === 'progress' || ev.event === 'end') {
      showProgress(ev);
      if (Date.now() - shownAt > 3000) { shownAt = Date.now(); showJob(id).catch(() => {}); }
    } else if (ev.event === 'error') {
      $('job-status').textContent = ev.message;
    } else if (ev.event === 'job') {   // the server's last word on the job: the stream ends here
      source.close();
      showJob(id).catch((e) => { $('error').textContent = e.message; });
      refreshJobs();
    }
  };
}

async function select(id) {
  app.selected = id;
  app.events = 0;
  $('job-bar').style.width = '0';
  $('job-status').textContent = '';
  $('preview').style.display = 'none';
  const job = await showJob(id);
  follow(id);
  refreshJobs();
  return job;
}

// ---- make ----
// a file as base64, in slices (String.fromCharCode takes a bounded number of arguments)
async function base64Of(file) {
  const bytes = new Uint8Array(await file.arrayBuffer());
  let text = '';
  for (let i = 0; i < bytes.length; i += 0x8000) text += String.fromCharCode(...bytes.subarray(i, i + 0x8000));
  return btoa(text);
}

$('make').addEventListener('submit', async (ev) => {
  ev.preventDefault();
  $('error').textContent = '';
  const request = { prompt: $('prompt').value.trim(), seed: Number($('seed').value || 0) };
  if ($('preset').value) request.preset = $('preset').value;
  try {
    const file = $('mesh').files[0];   // a mesh: the job paints it (paint) instead of making one
    if (file) request.mesh = { format: file.name.toLowerCase().endsWith('.glb') ? 'glb' : 'obj', data: await base64Of(file) };
    const extra = $('extra').value.trim();
    if (extra) Object.assign(request, JSON.parse(extra));
    const job = await api('/api/jobs', { method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(request) });
    await select(job.id);
  } catch (e) {
    $('error').textContent = e.message;
  }
});

$('cancel').addEventListener('click', async () => {
  if (!app.selected) return;
  try { await api(`/api/jobs/${app.selected}`, { method: 'DELETE' }); } catch (e) { $('error').textContent = e.message; }
  showJob(app.selected);
});

// The captions the project's own model reads, offered as the person types: its catalogue's
// materials and classes (`matlaber catalogue list`; the server refuses other words with a message)
const MATERIALS = ['gold', 'silver', 'copper', 'red', 'blue', 'white', 'stone', 'green'];
const CLASSES = ['goblet', 'vase', 'bowl', 'mug', 'bottle', 'mushroom', 'table', 'stool', 'lamp', 'ring', 'teapot'];
for (const m of MATERIALS) for (const c of CLASSES) $('words').appendChild(new Option(`a ${m} ${c}`));

app.refresh = refreshJobs;   // the viewer's "save as a new job" lists its job at once
app.select = select;
refreshJobs();
setInterval(refreshJobs, 3000);
