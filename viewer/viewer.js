// The matlaber asset viewer (docs/export.md): asset.glb lit by the environments listed in
// viewer.json, a slider that turns the environment (the light) about +y, and unlit views of the
// kd / ks / roughness textures and of the normals. Everything is loaded from this folder; nothing
// from the network.
// A latent-mode asset (viewer.json names its decoder) gets the latent editor of latent.js: four
// sliders that offset every texel's code, decoded on the GPU into the maps the shading uses.
// window.viewer exposes the state for tests (ready, frames, renderNow, setRotation, setChannel,
// setEnvironment, setBackground, latent: { available, setOffset, setDecoded }).
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { HDRLoader } from 'three/addons/loaders/HDRLoader.js';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { loadLatent, makeEditor } from './latent.js';

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
async function setupLatent(url, pbr) {
  const data = await loadLatent(url);
  if (!data) return;   // a direct-mode asset: no editor
  const editor = makeEditor(renderer, data, pbr.map);
  const baked = { kd: pbr.map, ks: pbr.specularColorMap, mr: pbr.roughnessMap, metal: pbr.metalnessMap };
  const offset = [0, 0, 0, 0];
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
  const setDecoded = (on) => {
    decodedBox.checked = on;
    if (on) editor.decode(offset);
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
  document.getElementById('latent').hidden = false;
  window.viewer.latent = {
    available: true,
    setOffset: (values) => values.forEach((x, c) => { sliders[c].value = x; sliders[c].dispatchEvent(new Event('input')); }),
    setDecoded,
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
