// The matlaber asset viewer (docs/export.md): asset.glb lit by the environments listed in
// viewer.json, a slider that turns the environment (the light) about +y, and unlit views of the
// kd / ks / roughness textures and of the normals. Everything is loaded from this folder; nothing
// from the network.
// A latent-mode asset (viewer.json names its decoder) gets the latent editor of latent.js: four
// sliders that offset the codes of a region (the whole asset, or the material picked by a click),
// decoded on the GPU into the maps the shading uses; served, also a move toward another job's
// material and "save as a new job".
// window.viewer exposes the state for tests (ready, frames, renderNow, setRotation, setChannel,
// setEnvironment, setBackground, latent: { available, setOffset, setDecoded, pickTexel, setRadius, setToward, ... }).
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { HDRLoader } from 'three/addons/loaders/HDRLoader.js';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { loadLatent, makeEditor, meanCode } from './latent.js';

const statusEl = document.getElementById('status');
const setStatus = (text) => { statusEl.textContent = text; };

const container = document.getElementById('view');
// preserveDrawingBuffer: screenshots (and the headless test) read the last frame
const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio);
renderer.setSize(container.clientWidth, container.clientHeight);
renderer.outputColorSpace = THREE.SRGBColorSpace;
renderer.toneMapping = THREE.NoToneMapping;   // as matlaber's own renders: linear, clamped, sRGB
container.appendChild(renderer.domElement);

const scene = new THREE.Scene();
scene.background = new THREE.Color(0x202124);
const camera = new THREE.PerspectiveCamera(35, container.clientWidth / container.clientHeight, 0.01, 100);
camera.position.set(0, 0.6, 3);
const controls = new OrbitControls(camera, renderer.domElement);
controls.enableDamping = true;

// Frames are drawn on demand (a change of view, light or map), not continuously.
let dirty = true;
const requestRender = () => { dirty = true; };
controls.addEventListener('change', requestRender);

const pmrem = new THREE.PMREMGenerator(renderer);
const envCache = new Map();   // name -> { equirect, pmrem }
let showBackground = true;
let currentEnv = null;

function loadEnvironment(env) {
  if (envCache.has(env.name)) return envCache.get(env.name);
  const p = new HDRLoader().loadAsync(env.file).then((tex) => {
    tex.mapping = THREE.EquirectangularReflectionMapping;
    const filtered = pmrem.fromEquirectangular(tex).texture;
    return { equirect: tex, pmrem: filtered };
  });
  envCache.set(env.name, p);
  return p;
}

async function setEnvironment(env) {
  const maps = await loadEnvironment(env);
  currentEnv = maps;
  scene.environment = maps.pmrem;
  scene.background = showBackground ? maps.equirect : new THREE.Color(0x202124);
  requestRender();
}

function setRotation(degrees) {
  const r = THREE.MathUtils.degToRad(degrees);
  // the environment turns about +y, right-handed, as mlb_envmap_set_rotation
  scene.environmentRotation.set(0, r, 0);
  scene.backgroundRotation.set(0, r, 0);
  document.getElementById('rotation-value').textContent = `${Math.round(degrees)}°`;
  requestRender();
}

// ---- the asset and its map views ----
let mesh = null;
const materials = {};

const roughnessView = (tex) => new THREE.ShaderMaterial({
  uniforms: { map: { value: tex } },
  vertexShader: 'varying vec2 vUv; void main() { vUv = uv; gl_Position = projectionMatrix * modelViewMatrix * vec4(position, 1.0); }',
  // roughness is linear data in the green channel (glTF metallicRoughness): shown as grey, as stored
  fragmentShader: 'uniform sampler2D map; varying vec2 vUv; void main() { gl_FragColor = vec4(vec3(texture2D(map, vUv).g), 1.0); }',
});

function setChannel(name) {
  if (!mesh || !materials[name]) return;
  mesh.material = materials[name];
  requestRender();
}

function frameObject(object) {
  const box = new THREE.Box3().setFromObject(object);
  const sphere = box.getBoundingSphere(new THREE.Sphere());
  const r = sphere.radius > 0 ? sphere.radius : 1;
  const d = r / Math.sin(THREE.MathUtils.degToRad(camera.fov / 2)) * 1.1;
  controls.target.copy(sphere.center);
  camera.position.copy(sphere.center).add(new THREE.Vector3(0, 0.35, 1).normalize().multiplyScalar(d));
  camera.near = d / 100;
  camera.far = d * 100;
  camera.updateProjectionMatrix();
  controls.update();
}

async function main() {
  const config = await (await fetch('viewer.json')).json();
  document.title = config.title;
  document.getElementById('title').textContent = config.title;
  const envSelect = document.getElementById('env');
  for (const env of config.environments) envSelect.add(new Option(env.name, env.name));
  const byName = (n) => config.environments.find((e) => e.name === n);

  const gltf = await new GLTFLoader().loadAsync(config.asset);
  scene.add(gltf.scene);
  gltf.scene.traverse((o) => { if (o.isMesh && !mesh) mesh = o; });
  if (!mesh) throw new Error(`${config.asset}: no mesh`);
  const pbr = mesh.material;
  materials.shaded = pbr;
  materials.kd = new THREE.MeshBasicMaterial({ map: pbr.map });
  materials.ks = new THREE.MeshBasicMaterial({ map: pbr.specularColorMap || null, color: pbr.specularColorMap ? 0xffffff : 0x000000 });
  materials.roughness = roughnessView(pbr.roughnessMap);
  materials.normals = new THREE.MeshNormalMaterial();   // the surface's view-space normals as colours
  frameObject(gltf.scene);
  if (config.decoder) await setupLatent(config.decoder, pbr);

  await setEnvironment(config.environments[0]);
  envSelect.addEventListener('change', () => setEnvironment(byName(envSelect.value)).catch(fail));
  window.viewer.setEnvironment = async (name) => { envSelect.value = name; await setEnvironment(byName(name)); };
  const slider = document.getElementById('rotation');
  slider.addEventListener('input', () => setRotation(Number(slider.value)));
  const channel = document.getElementById('channel');
  channel.addEventListener('change', () => setChannel(channel.value));
  document.getElementById('background').addEventListener('change', (ev) => {
    showBackground = ev.target.checked;
    if (currentEnv) scene.background = showBackground ? currentEnv.equirect : new THREE.Color(0x202124);
    requestRender();
  });
  setRotation(Number(slider.value));

  renderer.setAnimationLoop(() => {
    controls.update();   // damping: fires 'change' while the view still moves
    if (dirty) renderNow();
  });
  window.viewer.ready = true;
  setStatus(`${config.asset}: ${mesh.geometry.attributes.position.count} vertices — drag to orbit, wheel to zoom`);
}

// ---- the latent editor ----
// Served by `matlaber serve` (/view/ID/): the job's id, for "toward another job" and "save as new"
const servedId = (location.pathname.match(/^\/view\/([A-Za-z0-9._-]+)\/$/) || [])[1] || null;

async function setupLatent(url, pbr) {
  const data = await loadLatent(url);
  if (!data) return;   // a direct-mode asset: no editor
  const editor = makeEditor(renderer, data, pbr.map);
  const baked = { kd: pbr.map, ks: pbr.specularColorMap, mr: pbr.roughnessMap, metal: pbr.metalnessMap };
  const offset = [0, 0, 0, 0];
  // the edit: region (null: the whole asset; else the picked texel and its code), toward (another
  // asset's mean code and t), highlight
  const edit = { region: null, radius: 0, toward: null, t: 0, highlight: false };
  const decodedBox = document.getElementById('decoded');
  const useMaps = (decoded) => {
    const m = decoded ? editor.maps : baked;
    pbr.map = m.kd;
    pbr.specularColorMap = m.ks;
    pbr.roughnessMap = m.mr;
    if (baked.metal) pbr.metalnessMap = m.mr;   // glTF's metallicRoughness texture (B: metalness 0)
    pbr.needsUpdate = true;
    materials.kd.map = m.kd;
    materials.ks.map = m.ks;
    materials.roughness.uniforms.map.value = m.mr;
    requestRender();
  };
  const decodeNow = () => editor.decode({
    offset, radius: edit.region ? edit.radius : -1, pick: edit.region?.code,
    target: edit.toward?.code, t: edit.toward ? edit.t : 0, highlight: edit.highlight,
  });
  const setDecoded = (on) => {
    decodedBox.checked = on;
    if (on) decodeNow();
    useMaps(on);
  };
  const box = document.getElementById('latent-sliders');
  const sliders = offset.map((_, c) => {
    const span = Math.max(editor.max[c] - editor.min[c], 1);   // as far again as the asset's own codes spread
    const label = document.createElement('label');
    label.textContent = `z${c} `;
    const s = Object.assign(document.createElement('input'), { type: 'range', min: -span, max: span, step: span / 200, value: 0 });
    const v = document.createElement('span');
    v.textContent = '0.00';
    s.addEventListener('input', () => {
      offset[c] = Number(s.value);
      v.textContent = offset[c].toFixed(2);
      setDecoded(true);
    });
    label.append(s, ' ', v);
    box.append(label);
    return s;
  });
  decodedBox.addEventListener('change', () => setDecoded(decodedBox.checked));
  document.getElementById('latent-reset').addEventListener('click', () => {
    sliders.forEach((s) => { s.value = 0; s.dispatchEvent(new Event('input')); });
  });

  // the region: a click (not a drag) on the asset picks the texel under it
  const regionEl = document.getElementById('latent-region');
  const showRegion = () => {
    regionEl.textContent = edit.region ? `the material at texel (${edit.region.texel.join(', ')}), within ${edit.radius.toFixed(2)} of its code` : 'the whole asset';
  };
  const pickTexel = (x, y) => {
    edit.region = { texel: [x, y], code: editor.codeAt(x, y) };
    showRegion();
    setDecoded(true);
  };
  // the texel under a point of the canvas (client coordinates), or null off the asset
  const texelAt = (clientX, clientY) => {
    const r = renderer.domElement.getBoundingClientRect();
    const ndc = new THREE.Vector2(((clientX - r.left) / r.width) * 2 - 1, -((clientY - r.top) / r.height) * 2 + 1);
    const ray = new THREE.Raycaster();
    ray.setFromCamera(ndc, camera);
    const hit = ray.intersectObject(mesh, false)[0];
    if (!hit || !hit.uv) return null;
    // glTF's uv as three.js keeps it (v down, textures not flipped): row y of the codes is v
    const S = editor.size, clamp = (v) => Math.min(Math.max(Math.floor(v * S), 0), S - 1);
    return [clamp(hit.uv.x - Math.floor(hit.uv.x)), clamp(hit.uv.y - Math.floor(hit.uv.y))];
  };
  let down = null;
  renderer.domElement.addEventListener('pointerdown', (ev) => { down = [ev.clientX, ev.clientY]; });
  renderer.domElement.addEventListener('pointerup', (ev) => {
    if (!down || Math.hypot(ev.clientX - down[0], ev.clientY - down[1]) > 4) return;   // a drag orbits
    const t = texelAt(ev.clientX, ev.clientY);
    if (t) pickTexel(...t);
  });
  const radius = document.getElementById('latent-radius');
  // the radius's scale: the asset's own codes' spread; it starts at a quarter of it
  const spread = Math.max(...editor.max.map((hi, c) => hi - editor.min[c]), 0.01);
  Object.assign(radius, { max: spread, step: spread / 200, value: spread / 4 });
  edit.radius = spread / 4;
  document.getElementById('latent-radius-value').textContent = edit.radius.toFixed(2);
  radius.addEventListener('input', () => {
    edit.radius = Number(radius.value);
    document.getElementById('latent-radius-value').textContent = edit.radius.toFixed(2);
    showRegion();
    if (edit.region) setDecoded(true);
  });
  document.getElementById('latent-whole').addEventListener('click', () => { edit.region = null; showRegion(); setDecoded(true); });
  document.getElementById('latent-highlight').addEventListener('change', (ev) => { edit.highlight = ev.target.checked; setDecoded(true); });

  // toward another finished job's material (served only: the jobs come from the API)
  const towardSel = document.getElementById('latent-toward'), towardT = document.getElementById('latent-t');
  const setToward = async (id) => {
    if (id && ![...towardSel.options].some((o) => o.value === id)) towardSel.add(new Option(id, id));   // (a job newer than the list)
    towardSel.value = id || '';
    edit.toward = null;
    if (id) {
      const other = await loadLatent(`/view/${id}/asset.decoder.json`);
      if (!other) { setStatus(`${id} has no latent codes (a direct-mode material)`); return false; }
      edit.toward = { job: id, code: meanCode(other) };
    }
    setDecoded(true);
    return true;
  };
  towardSel.addEventListener('change', () => setToward(towardSel.value).catch(fail));
  towardT.addEventListener('input', () => {
    edit.t = Number(towardT.value);
    document.getElementById('latent-t-value').textContent = edit.t.toFixed(2);
    setDecoded(true);
  });
  if (servedId) {
    const list = await fetch('/api/jobs').then((r) => (r.ok ? r.json() : { jobs: [] })).catch(() => ({ jobs: [] }));
    for (const j of list.jobs) if (j.state === 'done' && j.id !== servedId) towardSel.add(new Option(`${j.id}: ${j.prompt || '(run folder)'}`, j.id));
    document.getElementById('latent-served').hidden = false;
  }

  // save: the edited maps downloaded as PNGs (asset_kd.png, ... as `matlaber export --format obj` names them)
  document.getElementById('latent-save').addEventListener('click', async () => {
    if (!decodedBox.checked) setDecoded(true);
    const pngs = await editor.toPng();
    for (const [name, blob] of Object.entries(pngs)) {
      const a = Object.assign(document.createElement('a'), { href: URL.createObjectURL(blob), download: `asset_${name}.png` });
      a.click();
      setTimeout(() => URL.revokeObjectURL(a.href), 10000);
    }
  });
  // save as a new job: the edit's parameters sent to the server, which re-applies them to the
  // job's own codes and writes a new run (docs/server.md, POST /api/jobs/ID/edits)
  const saveAsNew = async () => {
    const body = {
      offset,
      region: edit.region ? { texel: edit.region.texel, radius: edit.radius } : null,
      toward: edit.toward ? { job: edit.toward.job, t: edit.t } : null,
    };
    const r = await fetch(`/api/jobs/${servedId}/edits`, { method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(body) });
    const job = await r.json();
    if (!r.ok) throw new Error(job.error || `HTTP ${r.status}`);
    document.getElementById('latent-saved').textContent = `saved as ${job.id}`;
    window.parent?.serveApp?.refresh?.();   // the page's list shows it at once
    return job;
  };
  document.getElementById('latent-save-new').addEventListener('click', () => saveAsNew().catch(fail));
  showRegion();
  document.getElementById('latent').hidden = false;
  window.viewer.latent = {
    available: true,
    setOffset: (values) => values.forEach((x, c) => { sliders[c].value = x; sliders[c].dispatchEvent(new Event('input')); }),
    setDecoded,
    texelAt,
    pickTexel,
    whole: () => document.getElementById('latent-whole').click(),
    setRadius: (r) => { radius.value = r; radius.dispatchEvent(new Event('input')); },
    setHighlight: (on) => { const h = document.getElementById('latent-highlight'); h.checked = on; h.dispatchEvent(new Event('change')); },
    setToward,
    setT: (t) => { towardT.value = t; towardT.dispatchEvent(new Event('input')); },
    saveAsNew,
    edit,
  };
}

function renderNow() {
  dirty = false;
  renderer.render(scene, camera);
  window.viewer.frames++;
}
const fail = (err) => { setStatus(`error: ${err.message}`); console.error(err); };

window.viewer = {
  ready: false,
  frames: 0,
  renderNow,
  internals: () => ({ THREE, scene, camera, controls, mesh }),   // for tests and the console
  latent: { available: false },
  setRotation: (deg) => { const s = document.getElementById('rotation'); s.value = deg; s.dispatchEvent(new Event('input')); },
  setChannel: (name) => { const c = document.getElementById('channel'); c.value = name; c.dispatchEvent(new Event('change')); },
  setBackground: (on) => { const b = document.getElementById('background'); b.checked = on; b.dispatchEvent(new Event('change')); },
};

window.addEventListener('resize', () => {
  camera.aspect = container.clientWidth / container.clientHeight;
  camera.updateProjectionMatrix();
  renderer.setSize(container.clientWidth, container.clientHeight);
  requestRender();
});

main().catch(fail);
