// The latent material editor (docs/export.md "Latent codes", docs/server.md): a latent-mode asset
// comes with asset.latent.bin (its codes z, 4 float32 per texel, over the .glb's UV atlas) and
// asset.decoder.json (the BRDF prior's frozen decoder 4 -> ... -> 7). A full-screen pass per map
// runs the decoder on (z + offset) at every texel, on the GPU, into half-float textures that then
// replace the .glb's kd / ks / roughness maps, so the viewer's own shading and relighting apply.
// Decoding per texel, not per pixel, keeps the MLP's cost to one pass per edit.
// An edit (the same as `matlaber serve` re-applies when it is saved, src/export/latent_edit.c): a
// texel is in the region when radius < 0 (the whole asset) or when its code is within radius of the
// picked code; there z becomes (1 - t) z + t target + offset, elsewhere it is kept. The region is
// decided per texel from its own code in the decode pass (the mask), and "highlight" tints it.
import * as THREE from 'three';

// GLSL of the activations the decoder may use (the names of mlb_activation_name)
const ACT = {
  identity: 'x',
  relu: 'max(x, 0.0)',
  leaky_relu: '(x < 0.0 ? 0.01 * x : x)',
  sigmoid: '1.0 / (1.0 + exp(-x))',
  tanh: 'tanh(x)',
  silu: 'x / (1.0 + exp(-x))',
  softplus: '(max(x, 0.0) + log(1.0 + exp(-abs(x))))',
  elu: '(x < 0.0 ? exp(x) - 1.0 : x)',
};

// The decoder's weights as a float texture: layer l's output o is row rowOf[l] + o, its weights in
// columns 0..in-1 and its bias in column `in` (texelFetch: exact float32, no filtering).
function weightTexture(dec) {
  const width = Math.max(...dec.layers.map((L) => L.in + 1));
  const height = dec.layers.reduce((n, L) => n + L.out, 0);
  const data = new Float32Array(width * height);
  const rowOf = [];
  let row = 0;
  for (const L of dec.layers) {
    rowOf.push(row);
    for (let o = 0; o < L.out; o++, row++) {
      for (let i = 0; i < L.in; i++) data[row * width + i] = L.weight[o * L.in + i];
      data[row * width + L.in] = L.bias[o];
    }
  }
  const tex = new THREE.DataTexture(data, width, height, THREE.RedFormat, THREE.FloatType);
  tex.needsUpdate = true;
  return { tex, rowOf };
}

// The fragment shader of one map: which = 0 kd, 1 ks, 2 roughness as glTF stores it (G; B metalness 0).
function decoderShader(dec, rowOf) {
  const maxDim = Math.max(...dec.layers.map((L) => Math.max(L.in, L.out)));
  const act = (name) => { if (!(name in ACT)) throw new Error(`decoder activation ${name} not supported`); return ACT[name]; };
  const lo = dec.range_lo.map((v) => v.toFixed(9)).join(', '), hi = dec.range_hi.map((v) => v.toFixed(9)).join(', ');
  let body = '';
  dec.layers.forEach((L, l) => {
    const last = l === dec.layers.length - 1;
    body += `  for (int o = 0; o < ${L.out}; o++) {
    float x = texelFetch(weights, ivec2(${L.in}, ${rowOf[l]} + o), 0).r;
    for (int i = 0; i < ${L.in}; i++) x += texelFetch(weights, ivec2(i, ${rowOf[l]} + o), 0).r * a[i];
    b[o] = ${last ? act(dec.output_activation) : act(dec.hidden_activation)};
  }
  for (int i = 0; i < ${L.out}; i++) a[i] = b[i];
`;
  });
  return `precision highp float;
precision highp int;
uniform sampler2D latent;
uniform sampler2D weights;
uniform vec4 offset;
uniform vec4 pick;
uniform float radius;
uniform vec4 target;
uniform float t;
uniform int highlight;
uniform int which;
const float LO[7] = float[7](${lo});
const float HI[7] = float[7](${hi});
void main() {
  float a[${maxDim}], b[${maxDim}];
  vec4 z = texelFetch(latent, ivec2(gl_FragCoord.xy), 0);
  bool inside = radius < 0.0 || distance(z, pick) <= radius;
  if (inside) z = mix(z, target, t) + offset;
  for (int i = 0; i < ${maxDim}; i++) { a[i] = 0.0; b[i] = 0.0; }
  a[0] = z.x; a[1] = z.y; a[2] = z.z; a[3] = z.w;
${body}  float k[7];
  for (int c = 0; c < 7; c++) k[c] = LO[c] + (HI[c] - LO[c]) * a[c];
  if (which == 0 && inside && highlight != 0) gl_FragColor = vec4(mix(vec3(k[0], k[1], k[2]), vec3(1.0, 0.35, 0.0), 0.6), 1.0);
  else if (which == 0) gl_FragColor = vec4(k[0], k[1], k[2], 1.0);
  else if (which == 1) gl_FragColor = vec4(k[3], k[4], k[5], 1.0);
  else gl_FragColor = vec4(1.0, k[6], 0.0, 1.0);
}
`;
}

// Loads the editor's files; null when the asset has none (a direct-mode run: 204 or 404).
export async function loadLatent(decoderUrl) {
  const r = await fetch(decoderUrl);
  if (r.status !== 200) return null;
  const dec = await r.json();
  const binUrl = decoderUrl.replace(/\.decoder\.json$/, '.latent.bin');
  const b = await fetch(binUrl);
  if (b.status !== 200) throw new Error(`${binUrl}: HTTP ${b.status}`);
  const buf = await b.arrayBuffer();
  const S = dec.latent.size;
  if (buf.byteLength !== S * S * 16) throw new Error(`${binUrl}: ${buf.byteLength} bytes, expected ${S * S * 16}`);
  return { dec, codes: new Float32Array(buf), size: S };   // little-endian as every WebGL host
}

// The editor on a loaded asset: decode(offset) renders the three maps; maps() names them.
export function makeEditor(renderer, { dec, codes, size }, like) {
  const latent = new THREE.DataTexture(codes, size, size, THREE.RGBAFormat, THREE.FloatType);
  latent.needsUpdate = true;
  const { tex: weights, rowOf } = weightTexture(dec);
  const material = new THREE.ShaderMaterial({
    uniforms: { latent: { value: latent }, weights: { value: weights }, offset: { value: new THREE.Vector4() },
                pick: { value: new THREE.Vector4() }, radius: { value: -1 }, target: { value: new THREE.Vector4() },
                t: { value: 0 }, highlight: { value: 0 }, which: { value: 0 } },
    vertexShader: 'void main() { gl_Position = vec4(position.xy, 0.0, 1.0); }',
    fragmentShader: decoderShader(dec, rowOf),
    depthTest: false,
    depthWrite: false,
  });
  const quad = new THREE.Mesh(new THREE.PlaneGeometry(2, 2), material);
  const scene = new THREE.Scene();
  scene.add(quad);
  const camera = new THREE.OrthographicCamera(-1, 1, 1, -1, 0, 1);
  const target = () => {
    const rt = new THREE.WebGLRenderTarget(size, size, {
      type: THREE.HalfFloatType, depthBuffer: false, generateMipmaps: true,
      minFilter: THREE.LinearMipmapLinearFilter, magFilter: THREE.LinearFilter,
    });
    rt.texture.colorSpace = THREE.LinearSRGBColorSpace;   // linear values: the shader reads them as they are
    rt.texture.wrapS = like?.wrapS ?? THREE.RepeatWrapping;
    rt.texture.wrapT = like?.wrapT ?? THREE.RepeatWrapping;
    return rt;
  };
  const targets = [target(), target(), target()];
  // edit: { offset [4], radius (< 0: whole asset), pick [4], target [4], t, highlight }
  const decode = (edit) => {
    const u = material.uniforms;
    u.offset.value.set(...edit.offset);
    u.radius.value = edit.radius ?? -1;
    u.pick.value.set(...(edit.pick || [0, 0, 0, 0]));
    u.target.value.set(...(edit.target || [0, 0, 0, 0]));
    u.t.value = edit.t || 0;
    u.highlight.value = edit.highlight ? 1 : 0;
    const saved = renderer.getRenderTarget();
    for (let w = 0; w < 3; w++) {
      material.uniforms.which.value = w;
      renderer.setRenderTarget(targets[w]);
      renderer.render(scene, camera);
    }
    renderer.setRenderTarget(saved);
  };
  // The decoded maps as 8-bit PNG blobs in the OBJ export's encodings (kd, ks sRGB; roughness
  // linear grey), rows top first as the .glb's images: what "save" downloads.
  const srgb = (v) => (v <= 0.0031308 ? 12.92 * v : 1.055 * Math.pow(v, 1 / 2.4) - 0.055);
  const toPng = async () => {
    const half = new Uint16Array(size * size * 4), out = {};
    for (const [w, name] of [[0, 'kd'], [1, 'ks'], [2, 'roughness']]) {
      renderer.readRenderTargetPixels(targets[w], 0, 0, size, size, half);
      const canvas = Object.assign(document.createElement('canvas'), { width: size, height: size });
      const g = canvas.getContext('2d'), img = g.createImageData(size, size);
      for (let t = 0; t < size * size; t++) {
        for (let c = 0; c < 3; c++) {
          const v = THREE.DataUtils.fromHalfFloat(half[4 * t + (w === 2 ? 1 : c)]);
          const e = w === 2 ? v : srgb(Math.min(Math.max(v, 0), 1));
          img.data[4 * t + c] = Math.round(Math.min(Math.max(e, 0), 1) * 255);
        }
        img.data[4 * t + 3] = 255;
      }
      g.putImageData(img, 0, 0);
      out[name] = await new Promise((res) => canvas.toBlob(res, 'image/png'));
    }
    return out;
  };
  // the code of texel (x, y), y counted from the top row as the .bin's rows and glTF's v
  const codeAt = (x, y) => Array.from(codes.subarray(4 * (y * size + x), 4 * (y * size + x) + 4));
  return { decode, toPng, codeAt, size, maps: { kd: targets[0].texture, ks: targets[1].texture, mr: targets[2].texture },
           min: dec.latent.min, max: dec.latent.max };
}

// The mean code of a loaded asset (in double): what "toward another asset" moves a region to.
export function meanCode({ codes }) {
  const m = [0, 0, 0, 0], n = codes.length / 4;
  for (let i = 0; i < codes.length; i++) m[i % 4] += codes[i];
  return m.map((v) => v / n);
}
