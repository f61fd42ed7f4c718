// A path-traced reference for the error heat map (prtcore view --reference): loading it
// and the relative RMS error of an indirect lightmap against it.
import * as THREE from 'three';
import { EXRLoader } from 'three/addons/loaders/EXRLoader.js';

// A path-traced reference served with the bundle (prtcore view --reference): its indirect
// lightmap (written top-down like the bundle's EXRs, so sampled like the basis), its light,
// and its covered texels (A > 0) in image order with their mean radiance.
export async function loadReference(base, bundle) {
  if (!base) return null;
  const [texture, lights] = await Promise.all([
    new EXRLoader().setDataType(THREE.FloatType).loadAsync(base + 'reference.exr'),
    fetch(base + 'light.json').then((r) => { if (!r.ok) throw new Error(`${base}light.json: HTTP ${r.status}`); return r.json(); }),
  ]);
  const { width: W, height: H, data } = texture.image;
  if (W !== bundle.W || H !== bundle.H) {
    throw new Error(`reference.exr is ${W}×${H}, the atlas ${bundle.W}×${bundle.H}`);
  }
  texture.minFilter = texture.magFilter = THREE.NearestFilter;
  const image = new Float32Array(4 * W * H);  // EXRLoader rows are bottom-up
  for (let r = 0; r < H; r++) image.set(data.subarray(4 * W * r, 4 * W * (r + 1)), 4 * W * (H - 1 - r));
  let sum = 0, n = 0;
  for (let i = 0; i < W * H; i++) {
    if (image[4 * i + 3] > 0) { sum += (image[4 * i] + image[4 * i + 1] + image[4 * i + 2]) / 3; n++; }
  }
  return { texture, image, light: lights.lights ? lights.lights[0] : lights, mean: n ? sum / n : 1 };
}

// Relative RMS error of an indirect lightmap (H, W, 4; row 0 at the top) against the
// reference over the reference's covered texels.
export function relativeError(atlas, reference) {
  let num = 0, den = 0;
  const ref = reference.image;
  for (let i = 0; i < ref.length; i += 4) {
    if (!(ref[i + 3] > 0)) continue;
    for (let c = 0; c < 3; c++) { num += (atlas[i + c] - ref[i + c]) ** 2; den += ref[i + c] ** 2; }
  }
  return den > 0 ? Math.sqrt(num / den) : 0;
}
