// Hair bundles (docs/hair.md): asset.hair read in the page and drawn as line segments whose
// vertices carry the strand-texture coordinate (strand index, arc fraction from the root),
// the fibre's colour and its segment's direction. The sampling rule is the manifest's
// (prtcore/receivers/strands.py StrandSpace.layout, STRAND_GLSL in shaders.js).
import * as THREE from 'three';

// prtcore/io/hair/yuksel.py: the 128-byte header, array flags, the default segment count.
const HEADER_BYTES = 128;
const HAS_SEGMENTS = 1, HAS_POINTS = 2, HAS_THICKNESS = 4, HAS_TRANSPARENCY = 8, HAS_COLOR = 16;

export class HairError extends Error {}

// A cyHair `.hair` file (ArrayBuffer) → { strands, points (p, 3) Float32Array, offsets
// (strands + 1) Int32Array, color (p, 3) Float32Array }. Only what drawing needs; the
// bake's loader (prtcore/io/hair) has validated the file the bundle holds.
export function parseHair(buf, name = 'asset.hair') {
  if (buf.byteLength < HEADER_BYTES) throw new HairError(`${name}: shorter than its header`);
  const dv = new DataView(buf);
  const magic = String.fromCharCode(...new Uint8Array(buf, 0, 4));
  if (magic !== 'HAIR') throw new HairError(`${name}: not a .hair file (magic ${magic})`);
  const strands = dv.getUint32(4, true), count = dv.getUint32(8, true);
  const flags = dv.getUint32(12, true), dSegments = dv.getUint32(16, true);
  if (!(flags & HAS_POINTS)) throw new HairError(`${name}: no points array`);
  let at = HEADER_BYTES;
  const offsets = new Int32Array(strands + 1);
  for (let s = 0; s < strands; s++) {
    const seg = flags & HAS_SEGMENTS ? dv.getUint16(at + 2 * s, true) : dSegments;
    offsets[s + 1] = offsets[s] + seg + 1;
  }
  if (flags & HAS_SEGMENTS) at += 2 * strands;
  if (offsets[strands] !== count) {
    throw new HairError(`${name}: segments give ${offsets[strands]} points, header ${count}`);
  }
  const floats = (n) => {
    if (at + 4 * n > buf.byteLength) throw new HairError(`${name}: truncated`);
    const out = new Float32Array(n);
    for (let i = 0; i < n; i++) out[i] = dv.getFloat32(at + 4 * i, true);
    at += 4 * n;
    return out;
  };
  const points = floats(3 * count);
  if (flags & HAS_THICKNESS) at += 4 * count;
  if (flags & HAS_TRANSPARENCY) at += 4 * count;
  const color = flags & HAS_COLOR ? floats(3 * count)  // else the header's default colour
    : Float32Array.from({ length: 3 * count }, (_, i) => dv.getFloat32(28 + 4 * (i % 3), true));
  return { strands, count, points, offsets, color };
}

// The Chiang fibre of a bundle (manifest.fibre.chiang, docs/hair.md) as the viewer's
// shader needs it: σ_a per point (prtcore.core.bcsdf sigma_a_from_melanin, or
// sigma_a_from_color of the point's colour read as the hair volume's) and the uniforms of
// chiang.glsl (ChiangParams.variances, logistic_scale, the tilt in radians, the IOR).
const EUMELANIN = [0.419, 0.697, 1.37], PHEOMELANIN = [0.187, 0.4, 1.05];
export function chiangFibre(chiang, hair) {
  const bm = chiang.beta_m, bn = chiang.beta_n;
  const v0 = (0.726 * bm + 0.812 * bm * bm + 3.7 * bm ** 20) ** 2;
  const s = Math.sqrt(Math.PI / 8) * (0.265 * bn + 1.194 * bn * bn + 5.372 * bn ** 22);
  const sigma = new Float32Array(3 * hair.count);
  const d = 5.969 - 0.215 * bn + 2.532 * bn ** 2 - 10.73 * bn ** 3 + 5.574 * bn ** 4
    + 0.245 * bn ** 5;
  for (let i = 0; i < hair.count; i++) {
    for (let c = 0; c < 3; c++) {
      sigma[3 * i + c] = chiang.eumelanin === null || chiang.eumelanin === undefined
        ? (Math.log(Math.min(Math.max(hair.color[3 * i + c], 1e-4), 1)) / d) ** 2
        : chiang.eumelanin * EUMELANIN[c] + (chiang.pheomelanin ?? 0) * PHEOMELANIN[c];
    }
  }
  return { sigma, uniforms: {
    u_fibreModel: { value: 1 },
    chiang_v: { value: new THREE.Vector4(v0, 0.25 * v0, 4 * v0, 4 * v0) },
    chiang_s: { value: s }, chiang_alpha: { value: chiang.alpha_deg * Math.PI / 180 },
    chiang_eta: { value: chiang.eta } } };
}

// The strands as THREE.LineSegments geometry (two vertices per segment): position, s_strand
// (strand index), s_arc (arc length from the root / the strand's length, float64 sums as
// prtcore.core.hair), s_tangent (the segment's unit direction), s_albedo (the fibre colour
// clamped to [0, 0.99] as prtcore.core.materials.clamp_albedo, or for the Chiang fibre
// ``sigma`` (3 per point): its σ_a).
export function strandGeometry(hair, sigma = null) {
  const { strands, points, offsets, color } = hair;
  const segs = offsets[strands] - strands;
  const pos = new Float32Array(6 * segs), tan = new Float32Array(6 * segs);
  const alb = new Float32Array(6 * segs), sid = new Float32Array(2 * segs);
  const arc = new Float32Array(2 * segs);
  let k = 0;
  for (let s = 0; s < strands; s++) {
    const a = offsets[s], e = offsets[s + 1];
    const cum = new Float64Array(e - a);
    for (let i = a + 1; i < e; i++) {
      const dx = points[3 * i] - points[3 * i - 3], dy = points[3 * i + 1] - points[3 * i - 2];
      const dz = points[3 * i + 2] - points[3 * i - 1];
      cum[i - a] = cum[i - a - 1] + Math.hypot(dx, dy, dz);
    }
    const length = cum[e - a - 1];
    for (let i = a; i < e - 1; i++, k++) {
      const d = [0, 1, 2].map((c) => points[3 * (i + 1) + c] - points[3 * i + c]);
      const ln = Math.hypot(...d);
      for (let v = 0; v < 2; v++) {
        const p = i + v, o = 2 * k + v;
        for (let c = 0; c < 3; c++) {
          pos[3 * o + c] = points[3 * p + c];
          tan[3 * o + c] = ln > 0 ? d[c] / ln : (c === 1 ? 1 : 0);
          alb[3 * o + c] = sigma ? sigma[3 * p + c]
            : Math.min(Math.max(color[3 * p + c], 0), 0.99);
        }
        sid[o] = s;
        arc[o] = length > 0 ? cum[p - a] / length : 0;
      }
    }
  }
  const g = new THREE.BufferGeometry();
  g.setAttribute('position', new THREE.BufferAttribute(pos, 3));
  g.setAttribute('s_tangent', new THREE.BufferAttribute(tan, 3));
  g.setAttribute('s_albedo', new THREE.BufferAttribute(alb, 3));
  g.setAttribute('s_strand', new THREE.BufferAttribute(sid, 1));
  g.setAttribute('s_arc', new THREE.BufferAttribute(arc, 1));
  return g;
}

// Centre of the points' bounding box and the radius around it (as boundingSphere for meshes).
export function hairSphere(hair) {
  const box = new THREE.Box3(), v = new THREE.Vector3();
  for (let i = 0; i < hair.count; i++) box.expandByPoint(v.fromArray(hair.points, 3 * i));
  const center = box.getCenter(new THREE.Vector3());
  let radius = 0;
  for (let i = 0; i < hair.count; i++) radius = Math.max(radius, v.fromArray(hair.points, 3 * i).distanceTo(center));
  return { center, radius: Math.max(radius, 1e-30) };
}
