// Validates .glb files with the Khronos glTF-Validator (npm gltf-validator, installed in viewer/
// by scripts/build.sh). Usage: node tests/gltf_validate.mjs FILE.glb...
// Prints the issue counts and every message; exit 0 when no file has an error, 1 otherwise, 77
// when the package is missing (the calling cli test reports a skip).
import { createRequire } from 'node:module';
import { readFileSync } from 'node:fs';
import { fileURLToPath } from 'node:url';
import path from 'node:path';

const here = path.dirname(fileURLToPath(import.meta.url));
const require = createRequire(path.join(here, '..', 'viewer', 'package.json'));
let validator;
try {
  validator = require('gltf-validator');
} catch (e) {
  console.log(`skip: gltf-validator not installed in viewer/node_modules (${e.code || e.message})`);
  process.exit(77);
}

let failed = false;
for (const file of process.argv.slice(2)) {
  const report = await validator.validateBytes(new Uint8Array(readFileSync(file)), {
    uri: path.basename(file),
    maxIssues: 100,
    externalResourceFunction: (uri) => Promise.reject(new Error(`external resource ${uri} not expected`)),
  });
  const is = report.issues;
  console.log(`${file}: validator ${report.validatorVersion}: ${is.numErrors} errors, ${is.numWarnings} warnings, ` +
              `${is.numInfos} infos, ${is.numHints} hints`);
  const info = report.info || {};
  console.log(`  ${info.drawCallCount} draw calls, ${info.totalVertexCount} vertices, ${info.totalTriangleCount} triangles, ` +
              `${info.materialCount} materials; extensions: ${(info.extensionsUsed || []).join(', ')}; ` +
              `resources: ${(info.resources || []).map((r) => `${r.pointer} ${r.mimeType || ''} ${r.image ? r.image.width + 'x' + r.image.height + ' ' + r.image.format : ''}`.trim()).join('; ')}`);
  if (!(info.totalVertexCount > 0)) { console.log('  the validator saw no vertices'); failed = true; }
  for (const m of is.messages) console.log(`  [${['error', 'warning', 'info', 'hint'][m.severity]}] ${m.code}: ${m.message} (${m.pointer || ''})`);
  if (is.numErrors > 0) failed = true;
}
process.exit(failed ? 1 : 0);
