// The data-driven PRT runtime in WebGL2, from a bundle's manifest.json alone: the reference
// engine integration (docs/bundle.md, "The runtime"). Per light:
//   1. shadow maps of the light (prtcore/runtime/shadows.py: six 90° views for point and spot
//      lights, one orthographic view for directional ones; R32F distance to the light);
//   2. the measurement points' supersample clusters shaded (albedo/π · E, shadowed) into a
//      small float target, read back and averaged per point -> x (P, 3);
//   3. u = M·x' + s·b and the plane weights in JS (prtcore/runtime/cpu.py plane_weights);
//   4. the basis planes (one RGBA16F DataArrayTexture layer per basis_XX.exr) blended with
//      those weights in the shaders of viewer.js, with direct light and the same shadows.
// The light formulas and shadow test are GLSL ES ports of prtcore/runtime/shaders/lights.glsl;
// tests/test_viewer.py holds them to the CPU runtime (`prtcore relight`).
import * as THREE from 'three';
import { EXRLoader } from 'three/addons/loaders/EXRLoader.js';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { chiangFibre, hairSphere, parseHair, strandGeometry } from './strands.js';

// prtcore/runtime/shadows.py: normal offset and depth bias, in shadow texels at the point.
export const SHADOW_NORMAL_OFFSET = 1.5;
export const SHADOW_DEPTH_BIAS = 1.0;
// Side of each shadow view (the Python runtime uses 1024; SwiftShader favours smaller).
export const SHADOW_RESOLUTION = 512;
// Width of the cluster target (clusters are laid out row by row).
const CLUSTER_ROW = 256;
// prtcore/runtime/shadows.py FACES: axis and up of the six views of a point or spot light.
const FACES = [[[1, 0, 0], [0, -1, 0]], [[-1, 0, 0], [0, -1, 0]], [[0, 1, 0], [0, 0, 1]],
  [[0, -1, 0], [0, 0, -1]], [[0, 0, 1], [0, -1, 0]], [[0, 0, -1], [0, -1, 0]]];
const LIGHT_CODE = { point: 0, spot: 1, directional: 2 };

export class BundleError extends Error {}

async function fetchOk(url) {
  const r = await fetch(url);
  if (!r.ok) throw new BundleError(`${url}: HTTP ${r.status}`);
  return r;
}

// A raw little-endian file as the manifest describes it ({file, dtype, shape}).
async function loadRaw(base, desc) {
  const buf = await (await fetchOk(base + desc.file)).arrayBuffer();
  const n = desc.shape.reduce((a, b) => a * b, 1);
  if (desc.dtype !== '<f4' && desc.dtype !== '<i4') {
    throw new BundleError(`${desc.file}: dtype ${desc.dtype} is not supported (<f4, <i4)`);
  }
  if (buf.byteLength !== 4 * n) {
    throw new BundleError(`${desc.file}: ${buf.byteLength} bytes, manifest shape ` +
                          `[${desc.shape}] needs ${4 * n}`);
  }
  const dv = new DataView(buf);
  const out = desc.dtype === '<i4' ? new Int32Array(n) : new Float32Array(n);
  for (let i = 0; i < n; i++) {
    out[i] = desc.dtype === '<i4' ? dv.getInt32(4 * i, true) : dv.getFloat32(4 * i, true);
  }
  return out;
}

// Everything the viewer needs from a bundle directory served at `base` (ends with '/'):
// a surface bundle's meshes (asset.glb), or a hair bundle's strands (asset.hair, `hair`, and
// their line geometry, `strandGeometry`; `meshes` empty), or both for hair baked with a mesh
// (`withMesh`; the strands' planes in `strandBasis`).
export async function loadBundle(base) {
  const manifest = await (await fetchOk(base + 'manifest.json')).json();
  if (manifest.schema !== 'prtcore.bundle') {
    throw new BundleError(`${base}manifest.json: not a prtcore bundle`);
  }
  if ((manifest.method ?? 'data_driven') !== 'data_driven') {
    throw new BundleError(`method ${manifest.method}: this viewer shows data-driven bundles`);
  }
  const strands = manifest.strands ?? null;  // docs/hair.md: strand textures over asset.hair
  if (strands && strands.kind !== 'strands') {
    throw new BundleError(`strands.kind ${strands.kind}: expected strands`);
  }
  // hair baked with a mesh (docs/hair.md): asset.glb with its lightmap (basis.files), and
  // the hair (asset.hair.file) with its strand texture (strands.basis_files), one transfer
  const withMesh = Boolean(strands && strands.basis_files);
  if (manifest.transfer && manifest.transfer.learnt) {  // docs/bundle.md, fit.transfer "mlp"
    throw new BundleError('bundles with a learnt transfer (fit.transfer "mlp") are not shown ' +
                          'by this viewer yet; use `prtcore relight` or `prtcore render`');
  }
  // docs/bundle.md: EXR row 0 is the top row (TEXCOORD_1 v = 0). EXRLoader stores the file's
  // rows bottom-up, so a top-down file is sampled at (u, 1 - v).
  const rowOrder = manifest.atlas.exr_row_order ?? 'top_down';
  if (rowOrder !== 'top_down' && rowOrder !== 'bottom_up') {
    throw new BundleError(`atlas.exr_row_order ${rowOrder}: expected top_down or bottom_up`);
  }
  const exr = new EXRLoader().setDataType(THREE.HalfFloatType);
  const hairFile = withMesh ? manifest.asset.hair.file : manifest.asset.file;
  const [asset, layers, coverage, M, b, clusters, owner, points, holdout, hairAsset,
         strandLayers] = await Promise.all([
    strands && !withMesh ? null : new GLTFLoader().loadAsync(base + manifest.asset.file),
    Promise.all(manifest.basis.files.map((f) => exr.loadAsync(base + f))),
    exr.loadAsync(base + manifest.atlas.coverage),
    loadRaw(base, manifest.transfer.matrix),
    loadRaw(base, manifest.transfer.offset),
    loadRaw(base, manifest.points.clusters),
    loadRaw(base, manifest.points.clusters_owner),
    loadRaw(base, manifest.points.points),
    fetchOk(base + manifest.validation.holdout_lights).then((r) => r.json()),
    strands ? fetchOk(base + hairFile).then((r) => r.arrayBuffer())
      .then((buf) => parseHair(buf, hairFile)) : null,
    withMesh ? Promise.all(strands.basis_files.map((f) => exr.loadAsync(base + f))) : null,
  ]);
  const span = manifest.family ? await loadRaw(base, manifest.family.span) : null;
  // keyframe bundles: per keyframe, posed vertices (asset.glb order), clusters and points,
  // each row px py pz nx ny nz (docs/bundle.md; prtcore/keyframes/pose.py keyframe_files)
  const kf = manifest.keyframes;
  const keyframes = kf ? {
    times: kf.times, count: kf.count,
    vertices: await loadRaw(base, kf.vertices), clusters: await loadRaw(base, kf.clusters),
    points: await loadRaw(base, kf.points),
  } : null;
  const W = manifest.atlas.width, H = manifest.atlas.height;
  const basis = basisTexture(layers, manifest.basis.files, W, H, 'atlas');
  // a hair + mesh bundle's strand texture: the same planes, blended with the same weights
  const strandBasis = withMesh ? basisTexture(strandLayers, strands.basis_files,
                                              strands.width, strands.height,
                                              'strand texture') : null;
  coverage.minFilter = coverage.magFilter = THREE.NearestFilter;
  // (3, nB, P), or (keyframes, 3, nB, P) with one transfer per keyframe
  const [nB, P] = manifest.transfer.matrix.shape.slice(-2);
  const perKeyframe = manifest.transfer.matrix.shape.length === 4;
  const meshes = [];
  if (asset) {
    asset.scene.updateMatrixWorld(true);
    asset.scene.traverse((o) => { if (o.isMesh) meshes.push(o); });
  }
  for (const m of meshes) {
    if (!m.geometry.attributes.uv1) {
      throw new BundleError(`${manifest.asset.file}: mesh ${m.name} has no TEXCOORD_1`);
    }
  }
  if (keyframes) {
    const rows = meshes.reduce((a, m) => a + m.geometry.attributes.position.count, 0);
    if (rows * 6 * kf.count !== keyframes.vertices.length) {
      throw new BundleError(`${kf.vertices.file}: ${keyframes.vertices.length / 6 / kf.count} ` +
                            `vertices per keyframe, ${manifest.asset.file} has ${rows}`);
    }
  }
  const hair = hairAsset;
  const chiang = hair && manifest.fibre && manifest.fibre.chiang
    ? chiangFibre(manifest.fibre.chiang, hair) : null;
  const { center, radius } = !hair ? boundingSphere(meshes)
    : withMesh ? unionSphere(boundingSphere(meshes), hairSphere(hair)) : hairSphere(hair);
  return {
    manifest, meshes, hair, strands, withMesh, strandBasis,
    strandGeometry: hair ? strandGeometry(hair, chiang ? chiang.sigma : null) : null,
    fibreUniforms: chiang ? chiang.uniforms : { u_fibreModel: { value: 0 } }, basis, coverage, W, H, flipV: rowOrder === 'top_down',
    layers: layers.length, planes: manifest.basis.planes,
    planeElement: manifest.basis.plane_element, planeChannel: manifest.basis.plane_channel,
    nBasis: manifest.basis.count, M, b, nB, P, perKeyframe, keyframes, gamma: manifest.fit.gamma,
    clusters, owner, clusterCount: owner.length, points, span,
    warnAbove: manifest.family ? manifest.family.warn_above : null,
    holdoutLights: holdout.lights, center, radius,
  };
}

// The basis planes of `files` (RGBA EXR layers of w × h) as one half-float texture array,
// bilinear.
function basisTexture(layers, files, w, h, what) {
  const data = new Uint16Array(w * h * 4 * layers.length);
  layers.forEach((t, f) => {
    if (t.image.width !== w || t.image.height !== h) {
      throw new BundleError(`${files[f]}: ${t.image.width}×${t.image.height}, ` +
                            `${what} is ${w}×${h}`);
    }
    data.set(t.image.data, f * w * h * 4);
  });
  const basis = new THREE.DataArrayTexture(data, w, h, layers.length);
  basis.type = THREE.HalfFloatType;
  basis.format = THREE.RGBAFormat;
  basis.minFilter = basis.magFilter = THREE.LinearFilter;
  basis.needsUpdate = true;
  return basis;
}

// The sphere around two spheres' bounding boxes (a hair + mesh bundle's scale).
function unionSphere(a, b) {
  const box = new THREE.Box3();
  for (const s of [a, b]) {
    box.expandByPoint(s.center.clone().addScalar(-s.radius));
    box.expandByPoint(s.center.clone().addScalar(s.radius));
  }
  const center = box.getCenter(new THREE.Vector3());
  return { center, radius: Math.max(center.distanceTo(a.center) + a.radius,
                                    center.distanceTo(b.center) + b.radius) };
}

// Centre of the bounding box and the radius around it (prtcore.core.scene: the scale of
// the shadow views).
export function boundingSphere(meshes) {
  const box = new THREE.Box3(), v = new THREE.Vector3();
  for (const m of meshes) {
    const p = m.geometry.attributes.position;
    for (let i = 0; i < p.count; i++) box.expandByPoint(v.fromBufferAttribute(p, i).applyMatrix4(m.matrixWorld));
  }
  const center = box.getCenter(new THREE.Vector3());
  let radius = 0;
  for (const m of meshes) {
    const p = m.geometry.attributes.position;
    for (let i = 0; i < p.count; i++) {
      radius = Math.max(radius, v.fromBufferAttribute(p, i).applyMatrix4(m.matrixWorld)
        .distanceTo(center));
    }
  }
  return { center, radius: Math.max(radius, 1e-30) };
}

// Pose a keyframe bundle at keyframe k: the meshes' vertices and normals (asset.glb order:
// the meshes in file order, each in accessor order), the clusters and the points; the
// scene's bounding sphere follows. The light pass must be re-run afterwards.
export function poseKeyframe(bundle, k) {
  const kf = bundle.keyframes;
  if (!kf) return;
  const V = kf.vertices.length / kf.count / 6;
  let row = k * V;
  for (const m of bundle.meshes) {
    const pos = m.geometry.attributes.position, nrm = m.geometry.attributes.normal;
    for (let i = 0; i < pos.count; i++, row++) {
      pos.setXYZ(i, kf.vertices[6 * row], kf.vertices[6 * row + 1], kf.vertices[6 * row + 2]);
      nrm.setXYZ(i, kf.vertices[6 * row + 3], kf.vertices[6 * row + 4], kf.vertices[6 * row + 5]);
    }
    pos.needsUpdate = nrm.needsUpdate = true;
    m.geometry.computeBoundingSphere();
  }
  const s = bundle.clusterCount;
  for (let i = 0; i < s; i++) {
    for (let c = 0; c < 6; c++) bundle.clusters[12 * i + c] = kf.clusters[(k * s + i) * 6 + c];
  }
  for (let p = 0; p < bundle.P; p++) {
    for (let c = 0; c < 6; c++) bundle.points[12 * p + c] = kf.points[(k * bundle.P + p) * 6 + c];
  }
  Object.assign(bundle, boundingSphere(bundle.meshes));
  bundle.keyframe = k;
}

// A light-file light (docs/lights.md) as the uniforms of LIGHTS_GLSL need it.
export function normaliseLight(l) {
  if (!(l.type in LIGHT_CODE)) throw new BundleError(`light type ${l.type}: unknown`);
  const dir = new THREE.Vector3(...(l.direction ?? [0, 0, -1])).normalize();
  const c = l.color ?? [1, 1, 1], I = l.intensity ?? 1;
  const spot = l.spot ?? {};
  const ci = Math.cos(spot.innerConeAngle ?? 0), co = Math.cos(spot.outerConeAngle ?? Math.PI / 4);
  const scale = 1 / Math.max(1e-3, ci - co);
  return {
    type: l.type, code: LIGHT_CODE[l.type],
    position: new THREE.Vector3(...(l.position ?? [0, 0, 0])), direction: dir,
    radiant: new THREE.Vector3(c[0] * I, c[1] * I, c[2] * I), range: l.range ?? 0,
    spot: new THREE.Vector2(l.type === 'spot' ? scale : 0, l.type === 'spot' ? -co * scale : 0),
  };
}

// prtcore/reference/camera.py look_at, perspective, orthographic (OpenGL conventions).
function lookAt(eye, target, up) {
  const f = target.clone().sub(eye).normalize();
  const s = f.clone().cross(up).normalize();
  const u = s.clone().cross(f);
  return new THREE.Matrix4().set(
    s.x, s.y, s.z, -s.dot(eye), u.x, u.y, u.z, -u.dot(eye),
    -f.x, -f.y, -f.z, f.dot(eye), 0, 0, 0, 1);
}
function perspective(fovY, aspect, near, far) {
  const t = 1 / Math.tan(fovY / 2);
  return new THREE.Matrix4().set(t / aspect, 0, 0, 0, 0, t, 0, 0,
    0, 0, (far + near) / (near - far), 2 * far * near / (near - far), 0, 0, -1, 0);
}
function orthographic(hw, hh, near, far) {
  return new THREE.Matrix4().set(1 / hw, 0, 0, 0, 0, 1 / hh, 0, 0,
    0, 0, -2 / (far - near), -(far + near) / (far - near), 0, 0, 0, 1);
}

// Clip-from-world matrices of a light's shadow views and the world texel size for
// directional lights (prtcore/runtime/shadows.py light_views).
export function lightViews(light, center, R, res) {
  if (light.type === 'directional') {
    const d = light.direction;
    const up = Math.abs(d.y) < 0.9 ? new THREE.Vector3(0, 1, 0) : new THREE.Vector3(1, 0, 0);
    const half = 1.01 * R;
    const view = lookAt(center.clone().addScaledVector(d, -2 * R), center, up);
    return { views: [orthographic(half, half, 0.5 * R, 3.5 * R).multiply(view)],
             texel: 2 * half / res };
  }
  const pos = light.position, dist = pos.distanceTo(center);
  const proj = perspective(Math.PI / 2, 1, 1e-4 * (R + dist), dist + 1.5 * R);
  return { views: FACES.map(([a, u]) => proj.clone().multiply(
    lookAt(pos, pos.clone().add(new THREE.Vector3(...a)), new THREE.Vector3(...u)))), texel: 0 };
}

// GLSL ES port of prtcore/runtime/shaders/lights.glsl for one light (uniforms instead of the
// light table; the shadow atlas has one row).
export const LIGHTS_GLSL = `
const float PI = 3.14159265358979323846;
uniform int u_lightType;      // 0 point, 1 spot, 2 directional
uniform vec3 u_lightPos;
uniform vec3 u_lightDir;      // unit direction the light travels
uniform float u_lightRange;   // 0: none
uniform vec3 u_lightRadiant;  // colour * intensity
uniform vec2 u_spot;          // cone scale, offset
uniform float u_dirTexel;     // directional: world size of a shadow texel
uniform mat4 u_views[6];
uniform highp sampler2D u_shadow;
uniform int u_shadowRes;
uniform int u_useShadows;
uniform float u_biasNormal;
uniform float u_biasConst;

int cube_face(vec3 v) {
  vec3 a = abs(v);
  if (a.x >= a.y && a.x >= a.z) return v.x > 0.0 ? 0 : 1;
  if (a.y >= a.z) return v.y > 0.0 ? 2 : 3;
  return v.z > 0.0 ? 4 : 5;
}

float visibility(vec3 p, vec3 ng) {
  vec3 to_light = u_lightType == 2 ? -u_lightDir : normalize(u_lightPos - p);
  float side = dot(ng, to_light) >= 0.0 ? 1.0 : -1.0;
  float texel = u_lightType == 2 ? u_dirTexel
                                 : 2.0 * length(u_lightPos - p) / float(u_shadowRes);
  vec3 q = p + ng * (side * u_biasNormal * texel);
  int face = 0;
  float dq;
  if (u_lightType == 2) {
    dq = dot(q, u_lightDir);
  } else {
    vec3 v = q - u_lightPos;
    dq = length(v);
    face = cube_face(v);
  }
  vec4 clip = u_views[face] * vec4(q, 1.0);
  vec2 ndc = clip.xy / clip.w;
  ivec2 t = clamp(ivec2(floor((ndc * 0.5 + 0.5) * float(u_shadowRes))), ivec2(0),
                  ivec2(u_shadowRes - 1));
  t.x += face * u_shadowRes;
  float stored = texelFetch(u_shadow, t, 0).r;
  return dq <= stored + u_biasConst * texel ? 1.0 : 0.0;
}

vec3 irradiance(vec3 p, vec3 n, vec3 ng) {
  float att;
  if (u_lightType == 2) {
    att = max(dot(n, -u_lightDir), 0.0);
  } else {
    vec3 d = u_lightPos - p;
    float r2 = dot(d, d);
    if (!(r2 > 0.0)) return vec3(0.0);
    float r = sqrt(r2);
    vec3 w = d / r;
    att = max(dot(n, w), 0.0);
    if (u_lightRange > 0.0) {
      float x = clamp(1.0 - pow(r / u_lightRange, 4.0), 0.0, 1.0);
      att *= x * x;
    }
    if (u_lightType == 1) {
      float a = clamp(dot(-w, u_lightDir) * u_spot.x + u_spot.y, 0.0, 1.0);
      att *= a * a;
    }
    att /= r2;
  }
  if (att > 0.0 && u_useShadows != 0) att *= visibility(p, ng);
  return att * u_lightRadiant;
}
`;

const HEADER = 'precision highp float;\nprecision highp int;\n';

// The uniforms LIGHTS_GLSL reads, shared by every material that includes it.
export function lightUniforms() {
  return {
    u_lightType: { value: 0 }, u_lightPos: { value: new THREE.Vector3() },
    u_lightDir: { value: new THREE.Vector3(0, -1, 0) }, u_lightRange: { value: 0 },
    u_lightRadiant: { value: new THREE.Vector3() }, u_spot: { value: new THREE.Vector2() },
    u_dirTexel: { value: 0 }, u_views: { value: Array.from({ length: 6 }, () => new THREE.Matrix4()) },
    u_shadow: { value: null }, u_shadowRes: { value: SHADOW_RESOLUTION },
    u_useShadows: { value: 1 }, u_biasNormal: { value: SHADOW_NORMAL_OFFSET },
    u_biasConst: { value: SHADOW_DEPTH_BIAS },
  };
}

// Shadow maps, the cluster pass and the coefficients of one bundle in one renderer.
export class LightPass {
  constructor(renderer, bundle) {
    this.renderer = renderer;
    this.bundle = bundle;
    this.uniforms = lightUniforms();
    const res = SHADOW_RESOLUTION;
    this.shadowTarget = new THREE.WebGLRenderTarget(6 * res, res, {
      type: THREE.FloatType, format: THREE.RedFormat, depthBuffer: true,
      minFilter: THREE.NearestFilter, magFilter: THREE.NearestFilter });
    this.uniforms.u_shadow.value = this.shadowTarget.texture;
    this.shadowMaterial = new THREE.RawShaderMaterial({
      glslVersion: THREE.GLSL3, side: THREE.DoubleSide,
      uniforms: { u_clip: { value: new THREE.Matrix4() }, u_lightType: this.uniforms.u_lightType,
                  u_lightPos: this.uniforms.u_lightPos, u_lightDir: this.uniforms.u_lightDir },
      vertexShader: `${HEADER}uniform mat4 modelMatrix; uniform mat4 u_clip;
in vec3 position; out vec3 v_pos;
void main() { v_pos = (modelMatrix * vec4(position, 1.0)).xyz; gl_Position = u_clip * vec4(v_pos, 1.0); }`,
      fragmentShader: `${HEADER}uniform int u_lightType; uniform vec3 u_lightPos; uniform vec3 u_lightDir;
in vec3 v_pos; out vec4 f_dist;
void main() { f_dist = vec4(u_lightType == 2 ? dot(v_pos, u_lightDir) : length(v_pos - u_lightPos), 0.0, 0.0, 1.0); }`,
    });
    this.shadowScene = new THREE.Scene();
    for (const m of bundle.meshes) {
      const s = new THREE.Mesh(m.geometry, this.shadowMaterial);
      s.matrixAutoUpdate = false;
      s.matrix.copy(m.matrixWorld);
      s.frustumCulled = false;
      this.shadowScene.add(s);
    }
    if (bundle.strandGeometry) {  // hair: the fibres' axes as lines (a 1-texel-wide occluder)
      const lines = new THREE.LineSegments(bundle.strandGeometry, this.shadowMaterial);
      lines.frustumCulled = false;
      this.shadowScene.add(lines);
    }
    // clusters: one pixel each, row by row from the bottom of the target
    const n = bundle.clusterCount, rows = Math.ceil(n / CLUSTER_ROW);
    const g = new THREE.BufferGeometry();
    for (const name of ['position', 'c_normal', 'c_albedo']) {
      g.setAttribute(name, new THREE.BufferAttribute(new Float32Array(3 * n), 3));
    }
    this.clusterGeometry = g;
    this.updateClusters();
    this.clusterTarget = new THREE.WebGLRenderTarget(CLUSTER_ROW, rows, {
      type: THREE.FloatType, format: THREE.RGBAFormat, depthBuffer: false,
      minFilter: THREE.NearestFilter, magFilter: THREE.NearestFilter });
    const clusterPoints = new THREE.Points(g, new THREE.RawShaderMaterial({
      glslVersion: THREE.GLSL3, depthTest: false, depthWrite: false, uniforms: {
        ...this.uniforms, u_size: { value: new THREE.Vector2(CLUSTER_ROW, rows) },
        // Hair bundles' points lie on the convex hull of the fibre tubes with the hull's
        // normals (docs/hair.md): a light they face is outside the hull, so nothing of the
        // hair can shadow them (the CPU runtime's ray-traced x agrees; tests/test_viewer.py).
        // The line shadow maps, made for the fibres, would shadow them wrongly.
        u_useShadows: { value: bundle.strands ? 0 : 1 } },
      vertexShader: `${HEADER}uniform vec2 u_size;
in vec3 position; in vec3 c_normal; in vec3 c_albedo;
out vec3 v_pos; out vec3 v_nrm; out vec3 v_albedo;
void main() {
  v_pos = position; v_nrm = c_normal; v_albedo = c_albedo;
  int row = gl_VertexID / int(u_size.x);
  vec2 px = vec2(float(gl_VertexID - row * int(u_size.x)), float(row)) + 0.5;
  gl_Position = vec4(px / u_size * 2.0 - 1.0, 0.0, 1.0);
  gl_PointSize = 1.0;
}`,
      fragmentShader: `${HEADER}${LIGHTS_GLSL}
in vec3 v_pos; in vec3 v_nrm; in vec3 v_albedo; out vec4 f_color;
// prtcore/runtime/shaders/points_cs.glsl: albedo/pi * E, shading normal = geometric normal
void main() { f_color = vec4(v_albedo / PI * irradiance(v_pos, v_nrm, v_nrm), 1.0); }`,
    }));
    clusterPoints.frustumCulled = false;
    this.clusterScene = new THREE.Scene().add(clusterPoints);
    this.camera = new THREE.Camera();  // the passes use their own matrices
    this.pixels = new Float32Array(4 * CLUSTER_ROW * rows);
  }

  // Copy the clusters' position, normal and albedo from the bundle (again after
  // poseKeyframe).
  updateClusters() {
    const cl = this.bundle.clusters, a = this.clusterGeometry.attributes;
    for (let k = 0; k < this.bundle.clusterCount; k++) {
      for (let c = 0; c < 3; c++) {
        a.position.array[3 * k + c] = cl[12 * k + c];
        a.c_normal.array[3 * k + c] = cl[12 * k + 3 + c];
        a.c_albedo.array[3 * k + c] = cl[12 * k + 6 + c];
      }
    }
    for (const name of ['position', 'c_normal', 'c_albedo']) a[name].needsUpdate = true;
  }

  // Set the light's uniforms and render its shadow maps.
  setLight(light) {
    const u = this.uniforms, b = this.bundle, res = SHADOW_RESOLUTION;
    u.u_lightType.value = light.code;
    u.u_lightPos.value.copy(light.position);
    u.u_lightDir.value.copy(light.direction);
    u.u_lightRange.value = light.range;
    u.u_lightRadiant.value.copy(light.radiant);
    u.u_spot.value.copy(light.spot);
    const { views, texel } = lightViews(light, b.center, b.radius, res);
    u.u_dirTexel.value = texel;
    views.forEach((v, k) => u.u_views.value[k].copy(v));
    const r = this.renderer, autoClear = r.autoClear;
    r.autoClear = false;  // the six views go into one target, cleared once
    r.setRenderTarget(this.shadowTarget);
    // far = 3e38 everywhere before the views are drawn (as the Python runtime's clear)
    r.setClearColor(new THREE.Color(3e38, 0, 0), 1);
    r.clear(true, true, false);
    r.setClearColor(0x000000, 1);
    for (let k = 0; k < views.length; k++) {
      this.shadowTarget.viewport.set(k * res, 0, res, res);
      r.setRenderTarget(this.shadowTarget);
      this.shadowMaterial.uniforms.u_clip.value.copy(views[k]);
      r.render(this.shadowScene, this.camera);
    }
    this.shadowTarget.viewport.set(0, 0, 6 * res, res);
    r.setRenderTarget(null);
    r.autoClear = autoClear;
  }

  // x (P, 3) float64, point-major: the clusters shaded and averaged per point.
  direct() {
    const r = this.renderer, b = this.bundle, t = this.clusterTarget;
    r.setRenderTarget(t);
    r.setClearColor(0x000000, 0);
    r.clear(true, false, false);
    r.render(this.clusterScene, this.camera);
    r.readRenderTargetPixels(t, 0, 0, t.width, t.height, this.pixels);
    r.setRenderTarget(null);
    const x = new Float64Array(3 * b.P), count = new Float64Array(b.P);
    for (let k = 0; k < b.clusterCount; k++) {
      const p = b.owner[k];
      count[p] += 1;
      for (let c = 0; c < 3; c++) x[3 * p + c] += this.pixels[4 * k + c];
    }
    for (let p = 0; p < b.P; p++) {
      for (let c = 0; c < 3; c++) x[3 * p + c] /= Math.max(count[p], 1);
    }
    return x;
  }
}

// prtcore/runtime/cpu.py plane_weights: s, u (3, nB) and the RGB weight of every plane (q, 3),
// using n elements (mean included).
export function coefficients(b, x, n) {
  const g = b.gamma, nB = b.nB, P = b.P;
  const k = b.perKeyframe ? (b.keyframe ?? 0) : 0;  // the keyframe's transfer
  const mOff = k * 3 * nB * P, bOff = k * 3 * nB;
  const xg = new Float64Array(x.length);
  for (let i = 0; i < x.length; i++) {
    xg[i] = g === null || g === 1 ? x[i] : Math.sign(x[i]) * Math.abs(x[i]) ** (1 / g);
  }
  let s = 0;
  for (const v of xg) s += v * v;
  s = Math.sqrt(s);
  const use = Math.max(0, Math.min(n - 1, nB));
  const u = new Float64Array(3 * nB);
  for (let c = 0; c < 3; c++) {
    for (let i = 0; i < use; i++) {
      let acc = 0;
      const row = mOff + (c * nB + i) * P;
      for (let p = 0; p < P; p++) acc += b.M[row + p] * xg[3 * p + c];
      u[c * nB + i] = acc + s * b.b[bOff + c * nB + i];
    }
  }
  const w = new Float32Array(4 * b.planes);
  for (let j = 0; j < b.planes; j++) {
    const el = b.planeElement[j], ch = b.planeChannel[j];
    if (el === 0) w[4 * j + ch] = s;
    else if (ch < 0) for (let c = 0; c < 3; c++) w[4 * j + c] = u[c * nB + el - 1];
    else w[4 * j + ch] = u[ch * nB + el - 1];
  }
  return { s, u, w };
}

// prtcore/runtime/family.py family_residual: |x - Q Qᵀ x| / |x| with the span's rows Qᵀ (r, 3P).
export function familyResidual(b, x) {
  if (!b.span) return null;
  const n3 = 3 * b.P, r = b.span.length / n3;
  let nx = 0;
  for (const v of x) nx += v * v;
  if (nx === 0) return 0;
  const res = Float64Array.from(x);
  for (let i = 0; i < r; i++) {
    let d = 0;
    for (let k = 0; k < n3; k++) d += b.span[i * n3 + k] * x[k];
    for (let k = 0; k < n3; k++) res[k] -= d * b.span[i * n3 + k];
  }
  let nr = 0;
  for (const v of res) nr += v * v;
  return Math.sqrt(nr / nx);
}
