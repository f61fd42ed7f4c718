// The prtcore viewer page: orbit a bake, drag its light, look at the terms of the runtime.
// Rendering is on demand (a frame after each change). runtime.js is the PRT runtime (the
// engine integration), shaders.js the page's GLSL, reference.js the heat map's reference.
// Test hook: window.prt (ready, error, x, u, s, familyResidual, referenceError, badge,
// pixel(), image(), atlas(), setLight(), setView(), set()), used by tests/test_viewer.py.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { TransformControls } from 'three/addons/controls/TransformControls.js';
import { loadReference, relativeError } from './reference.js';
import {
  LightPass, coefficients, familyResidual, loadBundle, normaliseLight, poseKeyframe,
} from './runtime.js';
import {
  ATLAS_FS, ATLAS_VS, POINTS_FS, POINTS_VS, STRAND_FS, STRAND_PROBE_FS, STRAND_PROBE_VS,
  STRAND_VS, SURFACE_FS, SURFACE_VS,
} from './shaders.js';

const MODES = { full: 0, direct: 1, indirect: 2, albedo: 3, element: 4, points: 0, checker: 6,
                uv: 7, error: 8 };
// Heat map: relative error |indirect - reference| / mean reference, red at this value.
const ERROR_FULL_SCALE = 0.5;
const TONEMAPS = { aces: 0, reinhard: 1, linear: 2 };
const $ = (id) => document.getElementById(id);
const prt = { ready: false, error: null, frames: 0 };
window.prt = prt;

function fail(text) {
  prt.error = text;
  const m = $('message');
  m.textContent = text;
  m.className = 'error';
}

async function main() {
  const canvas = $('view');
  const gl = canvas.getContext('webgl2');
  if (!gl) {
    fail('This viewer needs WebGL2, which this browser does not provide (or has turned ' +
         'off). Open it in a browser with WebGL2, or use `prtcore render`.');
    return;
  }
  if (!gl.getExtension('EXT_color_buffer_float')) {
    fail('This viewer needs float render targets (EXT_color_buffer_float), which this ' +
         'browser does not provide.');
    return;
  }
  const renderer = new THREE.WebGLRenderer({ canvas, context: gl, antialias: false,
                                             preserveDrawingBuffer: true });
  renderer.setPixelRatio(1);
  renderer.setSize(canvas.width, canvas.height, false);
  renderer.autoClear = true;
  const bundle = await loadBundle(document.body.dataset.bundle);
  const m = bundle.manifest;
  const reference = await loadReference(document.body.dataset.reference, bundle);
  if (!reference || bundle.hair) $('mode').querySelector('option[value=error]').remove();
  if (bundle.hair && !bundle.withMesh) {  // no TEXCOORD_1
    $('mode').querySelector('option[value=uv]').remove();
  }
  poseKeyframe(bundle, 0);  // keyframe bundles: the first keyframe (as relight without --time)
  const pass = new LightPass(renderer, bundle);
  const weights = new THREE.DataTexture(new Float32Array(4 * bundle.planes), bundle.planes, 1,
                                        THREE.RGBAFormat, THREE.FloatType);
  weights.minFilter = weights.magFilter = THREE.NearestFilter;
  const view = {
    u_basis: { value: bundle.basis }, u_weights: { value: weights },
    u_planes: { value: bundle.planes }, u_gamma: { value: bundle.gamma ?? 0 },
    u_flipV: { value: bundle.flipV ? 1 : 0 }, u_output: { value: 1 },
    u_exposure: { value: 0 }, u_tonemap: { value: 0 }, u_mode: { value: 0 },
    u_elementScale: { value: 1 }, u_eye: { value: new THREE.Vector3() },
    u_reference: { value: reference ? reference.texture : null },
    u_referenceScale: { value: reference ? 1 / (reference.mean * ERROR_FULL_SCALE) : 1 },
    u_atlasSize: { value: new THREE.Vector2(bundle.W, bundle.H) },
    u_texelsPerStrand: { value: bundle.strands ? bundle.strands.texels_per_strand : 1 },
    u_strandsPerRow: { value: bundle.strands ? bundle.strands.strands_per_row : 1 },
  };
  const defines = { N_LAYERS: bundle.layers };
  const scene = new THREE.Scene();
  const meshes = [];
  for (const src of bundle.meshes) {
    const mat = src.material, map = mat.map ?? null;
    if (map) map.updateMatrix();
    const g = src.geometry;
    if (!g.attributes.uv) g.setAttribute('uv', new THREE.Float32BufferAttribute(new Float32Array(2 * g.attributes.position.count), 2));
    if (!g.attributes.normal) g.computeVertexNormals();
    const material = new THREE.RawShaderMaterial({
      glslVersion: THREE.GLSL3, side: THREE.DoubleSide, defines,
      uniforms: { ...pass.uniforms, ...view,
        u_baseColor: { value: new THREE.Vector3(mat.color.r, mat.color.g, mat.color.b) },
        u_hasMap: { value: map ? 1 : 0 }, u_mapChannel: { value: map ? map.channel : 0 },
        u_mapTransform: { value: map ? map.matrix : new THREE.Matrix3() }, u_map: { value: map } },
      vertexShader: SURFACE_VS, fragmentShader: SURFACE_FS,
    });
    const mesh = new THREE.Mesh(g, material);
    mesh.matrixAutoUpdate = false;
    mesh.matrix.copy(src.matrixWorld);
    scene.add(mesh);
    meshes.push(mesh);
  }
  let strandProbe = null;
  // hair baked with a mesh: the lines read the strand texture (its own size), the meshes
  // the lightmap; one set of plane weights
  const strandView = bundle.withMesh ? { ...view, u_basis: { value: bundle.strandBasis },
    u_atlasSize: { value: new THREE.Vector2(bundle.strands.width, bundle.strands.height) },
  } : view;
  if (bundle.hair) {  // hair: the strands as lines sampling the strand texture
    const lines = new THREE.LineSegments(bundle.strandGeometry, new THREE.RawShaderMaterial({
      glslVersion: THREE.GLSL3, defines,
      uniforms: { ...pass.uniforms, ...strandView, ...bundle.fibreUniforms },
      vertexShader: STRAND_VS, fragmentShader: STRAND_FS }));
    lines.frustumCulled = false;
    scene.add(lines);
    strandProbe = makeStrandProbe();
  }
  // The test hook's read-back of the lines' sampling: each line vertex's indirect at its
  // strand-texture coordinate, one pixel per vertex.
  function makeStrandProbe() {
    const n = bundle.strandGeometry.attributes.position.count, cols = 256;
    const rows = Math.ceil(n / cols);
    const probe = { value: 0 };
    const target = new THREE.WebGLRenderTarget(cols, rows, {
      type: THREE.FloatType, format: THREE.RGBAFormat, depthBuffer: false,
      minFilter: THREE.NearestFilter, magFilter: THREE.NearestFilter });
    const points = new THREE.Points(bundle.strandGeometry, new THREE.RawShaderMaterial({
      glslVersion: THREE.GLSL3, defines, depthTest: false, depthWrite: false,
      uniforms: { ...pass.uniforms, ...strandView, ...bundle.fibreUniforms,
                  u_output: { value: 0 }, u_probe: probe, u_useShadows: { value: 0 },
                  u_size: { value: new THREE.Vector2(cols, rows) } },
      vertexShader: STRAND_PROBE_VS, fragmentShader: STRAND_PROBE_FS }));
    points.frustumCulled = false;
    const probeScene = new THREE.Scene().add(points), raw = new Float32Array(4 * cols * rows);
    return (what = 0) => {
      probe.value = what;
      renderer.setRenderTarget(target);
      renderer.setClearColor(0x000000, 0);
      renderer.clear(true, false, false);
      renderer.render(probeScene, new THREE.Camera());
      renderer.readRenderTargetPixels(target, 0, 0, cols, rows, raw);
      renderer.setRenderTarget(null);
      const out = new Float32Array(3 * n);
      for (let i = 0; i < n; i++) for (let c = 0; c < 3; c++) out[3 * i + c] = raw[4 * i + c];
      return out;
    };
  }
  // measurement points as dots, coloured by their direct light, lifted off the surface
  const P = bundle.P;
  const dotsGeometry = new THREE.BufferGeometry();
  dotsGeometry.setAttribute('position', new THREE.BufferAttribute(new Float32Array(3 * P), 3));
  function placeDots() {
    const pp = dotsGeometry.attributes.position;
    for (let p = 0; p < P; p++) {
      for (let c = 0; c < 3; c++) {
        pp.array[3 * p + c] = bundle.points[12 * p + c] + 2e-3 * bundle.radius * bundle.points[12 * p + 3 + c];
      }
    }
    pp.needsUpdate = true;
  }
  placeDots();
  dotsGeometry.setAttribute('color', new THREE.BufferAttribute(new Float32Array(3 * P), 3));
  const dots = new THREE.Points(dotsGeometry, new THREE.RawShaderMaterial({
    glslVersion: THREE.GLSL3, defines, uniforms: view, vertexShader: POINTS_VS,
    fragmentShader: POINTS_FS }));
  dots.visible = false;
  scene.add(dots);
  // UV layout: triangle edges in TEXCOORD_1 space over the lightmap
  const uvScene = new THREE.Scene();
  for (const mesh of meshes) {
    uvScene.add(new THREE.Mesh(mesh.geometry, mesh.material));
    const uv1 = mesh.geometry.attributes.uv1, flat = new THREE.BufferGeometry();
    const pos = new Float32Array(3 * uv1.count);
    for (let i = 0; i < uv1.count; i++) {
      pos[3 * i] = 2 * uv1.getX(i) - 1;
      pos[3 * i + 1] = 1 - 2 * uv1.getY(i);
    }
    flat.setAttribute('position', new THREE.BufferAttribute(pos, 3));
    flat.setIndex(mesh.geometry.index);
    uvScene.add(new THREE.LineSegments(new THREE.WireframeGeometry(flat),
                                       new THREE.LineBasicMaterial({ color: 0x4fa3ff })));
  }
  const uvCamera = new THREE.OrthographicCamera(-1, 1, 1, -1, -1, 1);
  // atlas pass (test hook and the UV layout's read-back)
  const atlasTarget = new THREE.WebGLRenderTarget(bundle.W, bundle.H, {
    type: THREE.FloatType, format: THREE.RGBAFormat, depthBuffer: false,
    minFilter: THREE.NearestFilter, magFilter: THREE.NearestFilter });
  const atlasScene = new THREE.Scene();
  const tri = new THREE.BufferGeometry();
  tri.setAttribute('position', new THREE.BufferAttribute(new Float32Array([-1, -1, 0, 3, -1, 0, -1, 3, 0]), 3));
  const atlasMesh = new THREE.Mesh(tri, new THREE.RawShaderMaterial({
    glslVersion: THREE.GLSL3, defines, depthTest: false,
    uniforms: { ...view, u_output: { value: 0 }, u_coverage: { value: bundle.coverage } },
    vertexShader: ATLAS_VS,
    fragmentShader: ATLAS_FS }));
  atlasMesh.frustumCulled = false;
  atlasScene.add(atlasMesh);

  // The indirect lightmap (H, W, 4) float32, row 0 at the top, A = coverage.
  function readAtlas() {
    renderer.setRenderTarget(atlasTarget);
    renderer.render(atlasScene, uvCamera);
    renderer.setRenderTarget(null);
    const W = bundle.W, H = bundle.H, raw = new Float32Array(4 * W * H), out = new Float32Array(4 * W * H);
    renderer.readRenderTargetPixels(atlasTarget, 0, 0, W, H, raw);
    for (let r = 0; r < H; r++) {  // read-back rows come bottom first
      out.set(raw.subarray(4 * W * r, 4 * W * (r + 1)), 4 * W * (H - 1 - r));
    }
    return out;
  }

  // camera and controls
  const camera = new THREE.PerspectiveCamera(40, 1, 1e-3 * bundle.radius, 20 * bundle.radius);
  const controls = new OrbitControls(camera, canvas);
  function frame() {
    camera.position.copy(bundle.center).add(new THREE.Vector3(0, 0, 2.9 * bundle.radius));
    camera.up.set(0, 1, 0);
    controls.target.copy(bundle.center);
    camera.lookAt(bundle.center);
    controls.update();
    requestRender();
  }
  // the light: a gizmo whose position and -Z axis are the light's
  const trainedTypes = [...new Set((m.spec?.lights?.families ?? []).map((f) => f.type))];
  const start = reference?.light ?? bundle.holdoutLights[0] ?? { type: trainedTypes[0] ?? 'point', intensity: 1,
    position: [bundle.center.x, bundle.center.y + bundle.radius, bundle.center.z] };
  const lightObj = new THREE.Object3D();
  const marker = new THREE.Mesh(new THREE.SphereGeometry(0.03 * bundle.radius, 12, 8),
                                new THREE.MeshBasicMaterial({ color: 0xffdd44 }));
  const arrow = new THREE.ArrowHelper(new THREE.Vector3(0, 0, -1), new THREE.Vector3(),
                                      0.3 * bundle.radius, 0xffdd44);
  lightObj.add(marker, arrow);
  scene.add(lightObj);
  const gizmo = new TransformControls(camera, canvas);
  gizmo.attach(lightObj);
  gizmo.setSize(0.6);
  scene.add(gizmo.getHelper());
  gizmo.addEventListener('dragging-changed', (e) => { controls.enabled = !e.value; });
  gizmo.addEventListener('objectChange', () => { lightFromGizmo(); });
  gizmo.addEventListener('change', () => requestRender());
  controls.addEventListener('change', () => requestRender());

  const state = { light: null, mode: 'full', basis: bundle.nBasis, element: 0, keyframe: 0 };
  let x = null;

  function placeGizmo(light) {
    const p = light.type === 'directional'
      ? bundle.center.clone().addScaledVector(light.direction, -1.5 * bundle.radius)
      : light.position.clone();
    lightObj.position.copy(p);
    lightObj.lookAt(p.clone().sub(light.direction));  // -Z along the light's direction
    lightObj.updateMatrixWorld(true);
    arrow.visible = light.type !== 'point';
  }
  // The current light as a light-file object, placed where the gizmo is.
  function lightDict() {
    const l = state.light;
    const dir = new THREE.Vector3(0, 0, -1).transformDirection(lightObj.matrixWorld);
    const pos = l.type === 'directional' ? l.position.toArray() : lightObj.position.toArray();
    return { type: l.type, color: state.color, intensity: state.intensity, position: pos,
      direction: dir.toArray(), range: l.range || undefined, spot: state.spot };
  }
  function lightFromGizmo() { applyLight(lightDict(), false); }
  // Set the light: shadow maps, cluster pass, coefficients, badge; then a frame.
  function applyLight(dict, moveGizmo = true) {
    const light = normaliseLight(dict);
    state.atReference = dict === reference?.light;
    state.light = light;
    state.color = dict.color ?? [1, 1, 1];
    state.intensity = dict.intensity ?? 1;
    state.spot = dict.spot;
    const t0 = performance.now();
    pass.setLight(light);
    x = pass.direct();
    prt.lightMs = performance.now() - t0;
    updateCoefficients();
    const colours = dotsGeometry.attributes.color;
    for (let i = 0; i < 3 * P; i++) colours.array[i] = x[i];
    colours.needsUpdate = true;
    if (moveGizmo) placeGizmo(light);
    badge(light);
    if (reference) {
      prt.referenceError = relativeError(readAtlas(), reference);
    }
    $('light-type').value = light.type;
    $('light-intensity').value = String(+Number(state.intensity).toPrecision(4));
    $('light-color').value = '#' + new THREE.Color().setRGB(...state.color).getHexString();
    requestRender();
  }
  function updateCoefficients() {
    if (x === null) return;  // no light yet
    const sel = state.mode === 'element';
    const c = coefficients(bundle, x, state.basis);
    prt.x = Array.from(x);
    prt.u = Array.from(c.u);
    prt.s = c.s;
    if (sel) {  // the planes of one element, unit weights per channel
      weights.image.data.fill(0);
      for (let j = 0; j < bundle.planes; j++) {
        if (bundle.planeElement[j] !== state.element) continue;
        const ch = bundle.planeChannel[j];
        for (let k = 0; k < 3; k++) weights.image.data[4 * j + k] = ch < 0 || ch === k ? 1 : 0;
      }
      view.u_gamma.value = -1;  // a basis element is signed: shown unclamped
      view.u_elementScale.value = elementScale(state.element);
    } else {
      weights.image.data.set(c.w);
      view.u_gamma.value = bundle.gamma ?? 0;
    }
    weights.needsUpdate = true;
  }
  function elementScale(e) {  // 1 / max |plane| of the element, from the EXR data
    let peak = 0;
    const data = bundle.basis.image.data, n = bundle.W * bundle.H;
    for (let j = 0; j < bundle.planes; j++) {
      if (bundle.planeElement[j] !== e) continue;
      const f = j >> 2, k = j & 3;
      for (let i = 0; i < n; i++) {
        peak = Math.max(peak, Math.abs(THREE.DataUtils.fromHalfFloat(data[(f * n + i) * 4 + k])));
      }
    }
    return peak > 0 ? 1 / peak : 1;
  }
  function badge(light) {
    const notes = [];
    if (trainedTypes.length && !trainedTypes.includes(light.type)) {
      notes.push(`${light.type} light: the bake was trained on ${trainedTypes.join(', ')} lights`);
    }
    const r = familyResidual(bundle, x);
    prt.familyResidual = r;
    if (r !== null && r > bundle.warnAbove) {
      notes.push(`light outside the trained family: ${(100 * r).toFixed(1)} % of its direct ` +
                 `vector lies outside the training lights' span (warning above ` +
                 `${(100 * bundle.warnAbove).toFixed(1)} %)`);
    }
    $('badge').hidden = notes.length === 0;
    $('badge').textContent = notes.join('; ');
    prt.badge = notes.join('; ');
  }

  // rendering, on demand
  let pending = false;
  function requestRender() {
    if (pending) return;
    pending = true;
    requestAnimationFrame(() => { pending = false; renderNow(); });
  }
  function draw(target, output) {
    const mode = MODES[state.mode];
    view.u_mode.value = mode;
    view.u_output.value = output;
    view.u_eye.value.copy(camera.position);
    dots.visible = state.mode === 'points';
    gizmo.getHelper().visible = output === 1;
    lightObj.visible = output === 1;
    renderer.setRenderTarget(target);
    renderer.setClearColor(0x000000, output === 1 ? 1 : 0);  // read-back: A = 0 off the asset
    if (state.mode === 'uv') renderer.render(uvScene, uvCamera);
    else renderer.render(scene, camera);
    renderer.setRenderTarget(null);
  }
  function renderNow() {
    const t0 = performance.now();
    draw(null, 1);
    prt.frames += 1;
    prt.frameMs = performance.now() - t0;
    $('stats').textContent = `${bundle.P} points, ${bundle.clusterCount} supersamples, ` +
      `${state.basis}/${bundle.nBasis} basis elements\nlight pass ${prt.lightMs.toFixed(1)} ms, ` +
      `frame ${prt.frameMs.toFixed(1)} ms` +
      (prt.familyResidual === null ? '' : `\nout-of-family measure ${(100 * prt.familyResidual).toFixed(1)} %`) +
      (reference ? `\nindirect vs path-traced reference: ${(100 * prt.referenceError).toFixed(1)} % ` +
        (state.atReference ? '(its light)' : '(the light has moved: the heat map compares with the reference light\'s)') : '');
  }

  // controls
  const basis = $('basis');
  basis.max = String(bundle.nBasis);
  if (bundle.keyframes) {  // keyframe bundles: a time slider over the keyframes
    $('time-row').hidden = false;
    $('time').max = String(bundle.keyframes.count - 1);
  }
  basis.value = String(bundle.nBasis);
  $('element').max = String(bundle.nBasis - 1);
  const sync = () => {
    state.mode = $('mode').value;
    state.basis = Number(basis.value);
    state.element = Math.min(Math.max(Number($('element').value) | 0, 0), bundle.nBasis - 1);
    view.u_exposure.value = Number($('exposure').value);
    view.u_tonemap.value = TONEMAPS[$('tonemap').value];
    $('basis-out').textContent = basis.value;
    $('exposure-out').textContent = `${Number($('exposure').value) >= 0 ? '+' : ''}${$('exposure').value} EV`;
    gizmo.setMode($('gizmo').value);
    const k = Number($('time').value) | 0;
    if (bundle.keyframes) {
      $('time-out').textContent = `${bundle.keyframes.times[k].toFixed(2)} s (${k + 1}/${bundle.keyframes.count})`;
    }
    if (bundle.keyframes && k !== state.keyframe) {  // pose, then the light pass again
      state.keyframe = k;
      poseKeyframe(bundle, k);
      pass.updateClusters();
      placeDots();
      if (state.light) { applyLight(lightDict(), false); return; }
    }
    updateCoefficients();
    requestRender();
  };
  for (const id of ['mode', 'basis', 'element', 'exposure', 'tonemap', 'gizmo', 'time']) {
    $(id).addEventListener('input', sync);
  }
  // A field of the light's form changed: only that property of the light changes (the
  // colour picker holds 8-bit sRGB; it is read only when it is the field that changed).
  const relightFromForm = (e) => {
    const d = lightDict(), v = e.target.value;
    if (e.target.id === 'light-color') {
      const c = new THREE.Color(v);
      d.color = [c.r, c.g, c.b];
    } else if (e.target.id === 'light-intensity') {
      d.intensity = Number(v);
    } else {
      d.type = v;
      d.position = lightObj.position.toArray();
      d.spot = v === 'spot' ? (state.spot ?? { innerConeAngle: 0.2, outerConeAngle: 0.7 }) : undefined;
    }
    applyLight(d, false);
    arrow.visible = d.type !== 'point';
  };
  for (const id of ['light-type', 'light-color', 'light-intensity']) {
    $(id).addEventListener('change', relightFromForm);
  }
  $('frame').addEventListener('click', frame);
  $('reset').addEventListener('click', () => { applyLight(start); frame(); });

  // the test hook
  const readTarget = new THREE.WebGLRenderTarget(canvas.width, canvas.height, {
    type: THREE.FloatType, format: THREE.RGBAFormat, depthBuffer: true });
  Object.assign(prt, {
    bundle: { P: bundle.P, nB: bundle.nB, nBasis: bundle.nBasis, W: bundle.W, H: bundle.H,
              flipV: bundle.flipV, keyframes: bundle.keyframes ? bundle.keyframes.count : 0,
              strands: bundle.hair ? bundle.hair.strands : 0 },
    setLight(dict) { applyLight(dict); renderNow(); return { x: prt.x, u: prt.u, s: prt.s }; },
    setView({ position, target, up = [0, 1, 0], fov_y_deg = 40 }) {
      camera.position.set(...position);
      camera.up.set(...up);
      camera.fov = fov_y_deg;
      camera.updateProjectionMatrix();
      controls.target.set(...target);
      camera.lookAt(controls.target);
      controls.update();
      renderNow();
    },
    set(options) {
      for (const [k, v] of Object.entries(options)) $(k).value = String(v);
      sync();
      renderNow();
    },
    // linear float RGBA of canvas pixel (px, py), py from the top, in `mode`
    pixel(mode, px, py) {
      const keep = state.mode;
      state.mode = mode;
      draw(readTarget, 0);
      state.mode = keep;
      const out = new Float32Array(4);
      renderer.readRenderTargetPixels(readTarget, px, canvas.height - 1 - py, 1, 1, out);
      return Array.from(out);
    },
    // the canvas in `mode` as linear float RGBA (H, W, 4), row 0 at the top, A = 0 where
    // no surface is seen: base64 of the little-endian float32 bytes (a quarter million
    // numbers travel faster so than as JSON)
    image(mode) {
      const bytes = new Uint8Array(readCanvas(mode).buffer);
      let text = '';
      for (let i = 0; i < bytes.length; i += 0x8000) {
        text += String.fromCharCode.apply(null, bytes.subarray(i, i + 0x8000));
      }
      return btoa(text);
    },
    // the indirect lightmap (H, W, 4) float, row 0 at the top, A = coverage
    atlas() { return Array.from(readAtlas()); },
    // hair bundles: the indirect (v, 3) that the lines read at their vertices (two per
    // segment, strands in file order), the direct light a line pixel would take there
    // (v, 3; unshadowed), and those vertices' (strand, arc
    // fraction) (v, 2)
    strands() {
      if (!strandProbe) return null;
      const a = bundle.strandGeometry.attributes, n = a.s_strand.count, coord = new Float64Array(2 * n);
      for (let i = 0; i < n; i++) { coord[2 * i] = a.s_strand.array[i]; coord[2 * i + 1] = a.s_arc.array[i]; }
      return { indirect: Array.from(strandProbe(0)), direct: Array.from(strandProbe(1)),
               coord: Array.from(coord) };
    },
  });

  // The canvas in `mode` as linear float RGBA (H, W, 4), row 0 at the top, A = 0 off the
  // asset.
  function readCanvas(mode) {
    const keep = state.mode;
    state.mode = mode;
    draw(readTarget, 0);
    state.mode = keep;
    const W = canvas.width, H = canvas.height, raw = new Float32Array(4 * W * H);
    renderer.readRenderTargetPixels(readTarget, 0, 0, W, H, raw);
    const out = new Float32Array(4 * W * H);
    for (let r = 0; r < H; r++) out.set(raw.subarray(4 * W * r, 4 * W * (r + 1)), 4 * W * (H - 1 - r));
    return out;
  }
  // Exposure (quarter-EV steps, within the slider's range) that puts the 95th percentile of
  // the visible radiance (full mode, luminance) at 0.8 before tone mapping.
  function autoExposure() {
    const img = readCanvas('full'), lum = [];
    for (let i = 0; i < img.length; i += 4) {
      if (img[i + 3] > 0) lum.push(0.2126 * img[i] + 0.7152 * img[i + 1] + 0.0722 * img[i + 2]);
    }
    lum.sort((a, b) => a - b);
    const p = lum.length ? lum[Math.floor(0.95 * (lum.length - 1))] : 0;
    if (!(p > 0)) return;
    $('exposure').value = String(Math.min(Math.max(Math.round(4 * Math.log2(0.8 / p)) / 4, -10), 10));
    sync();
  }
  $('auto-exposure').addEventListener('click', autoExposure);

  // the current light as a light-file object (where the gizmo has put it)
  Object.defineProperty(prt, 'light', { get: () => (state.light ? lightDict() : null) });

  sync();
  applyLight(start);
  frame();
  autoExposure();
  renderNow();
  const texture = bundle.withMesh
    ? `${m.atlas.width}×${m.atlas.height} atlas and ${bundle.hair.strands} strands, ` +
      `${bundle.strands.width}×${bundle.strands.height} strand texture`
    : bundle.hair
      ? `${bundle.hair.strands} strands, ${m.atlas.width}×${m.atlas.height} strand texture`
      : `${m.atlas.width}×${m.atlas.height} atlas`;
  $('message').textContent = `${m.asset.source}: ${texture}, ` +
    `${bundle.nBasis} basis elements. Drag the light; T/R: move/aim.`;
  window.addEventListener('keydown', (e) => {
    if (e.key === 't') { $('gizmo').value = 'translate'; sync(); }
    if (e.key === 'r') { $('gizmo').value = 'rotate'; sync(); }
  });
  prt.ready = true;
}

main().catch((e) => {
  fail(`cannot show this bundle: ${e.message}`);
  console.error(String(e.stack));
});
