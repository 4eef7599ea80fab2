// A WebGL2 renderer for the baked avatar as `anerf export --format ply` writes it: the canonical Gaussians
// of avatar.ply, skinned on the GPU (each by the blend of its four joints' matrices from skin.json and
// motion.json: canonical → world), projected by EWA splatting as anerf's own renderer projects them (the
// covariance through the projection's Jacobian at the mean, the off-screen clamp, 3DGS's 0.3 px² dilation
// in the pixels of the camera shown),
// coloured by harmonics of degree 0 or 1 of the view direction turned back into canonical space, and
// composited back to front after a depth sort on the CPU every drawn frame (a counting sort on 16-bit keys
// of the skinned means). Seen from an orbit about the world's up or from one of the dataset's cameras, whose
// image is fitted into the canvas.

import { BACKGROUND, add, animate, compile, cross, dot, fitCanvas, norm, scale, sub } from './view3d.js';

const C0 = 0.2820948, C1 = 0.4886025;
/** Variance (pixels²) added to every projected covariance: 3DGS's low-pass filter, as anerf's renderer. */
const DILATION = 0.3;
/** Texels (RGBA32F) per Gaussian: mean + opacity, covariance (2), colour coefficients (3), joints, weights. */
const TEXELS = 8;
/** Gaussians per texture row. */
const PER_ROW = 256;

/** Parses a binary little-endian PLY of float vertex properties: its row count and a column per name. */
export function parsePly(buffer) {
  const bytes = new Uint8Array(buffer);
  const marker = new TextEncoder().encode('end_header\n');
  let end = -1;
  for (let i = 0; i + marker.length <= Math.min(bytes.length, 1 << 16) && end < 0; i++) {
    if (marker.every((b, k) => bytes[i + k] === b)) end = i + marker.length;
  }
  if (end < 0) throw new Error('avatar.ply: no end_header in its first 64 KiB');
  const header = new TextDecoder().decode(bytes.subarray(0, end)).split('\n');
  if (header[0] !== 'ply' || !header.includes('format binary_little_endian 1.0')) {
    throw new Error('avatar.ply: not a binary little-endian PLY');
  }
  let count = 0;
  const names = [];
  for (const line of header) {
    const words = line.trim().split(/\s+/);
    if (words[0] === 'element') {
      if (words[1] !== 'vertex' || names.length) throw new Error('avatar.ply: expected one vertex element');
      count = Number(words[2]);
    } else if (words[0] === 'property') {
      if (words[1] !== 'float') throw new Error(`avatar.ply: property ${words[2]} is ${words[1]}, expected float`);
      names.push(words[2]);
    }
  }
  const stride = names.length;
  if (!Number.isInteger(count) || count < 0 || buffer.byteLength - end < count * stride * 4) {
    throw new Error(`avatar.ply: ${count} rows of ${stride} floats do not fit its ${buffer.byteLength - end} bytes`);
  }
  const rows = new Float32Array(buffer.slice(end, end + count * stride * 4));
  const column = (name) => {
    const k = names.indexOf(name);
    if (k < 0) throw new Error(`avatar.ply has no property ${name}`);
    return (i) => rows[i * stride + k];
  };
  return { count, names, column };
}

/**
 * The per-Gaussian values the shader reads, packed in texels: canonical mean and opacity; the canonical
 * covariance `R S² Rᵀ` (xx xy xz yy, yz zz); the colour coefficients (`k₀ rgb, k₁ rgb, k₂ rgb, k₃ rgb`,
 * zeros past the file's degree); the four joints and weights.
 */
function pack(ply, skin) {
  const n = ply.count;
  const degree = ply.names.includes('f_rest_0') ? 1 : 0;
  if (skin.joints.length !== n || skin.weights.length !== n) {
    throw new Error(`skin.json holds ${skin.joints.length} joints and ${skin.weights.length} weights for ${n} Gaussians`);
  }
  const col = Object.fromEntries(['x', 'y', 'z', 'opacity', 'scale_0', 'scale_1', 'scale_2', 'rot_0', 'rot_1', 'rot_2', 'rot_3',
    'f_dc_0', 'f_dc_1', 'f_dc_2'].map((name) => [name, ply.column(name)]));
  // Degree 1: f_rest holds channel by channel (r: k₁ k₂ k₃, then g, then b).
  const rest = degree ? [...Array(9).keys()].map((k) => ply.column(`f_rest_${k}`)) : [];
  const rows = Math.max(1, Math.ceil(n / PER_ROW));
  const data = new Float32Array(PER_ROW * TEXELS * rows * 4);
  const means = new Float32Array(3 * n);
  for (let i = 0; i < n; i++) {
    const at = (i * TEXELS) * 4;
    const o = 1 / (1 + Math.exp(-col.opacity(i)));
    const mean = [col.x(i), col.y(i), col.z(i)];
    means.set(mean, 3 * i);
    data.set([...mean, o], at);
    const s = [0, 1, 2].map((k) => Math.exp(col[`scale_${k}`](i)));
    let [w, x, y, z] = [col.rot_0(i), col.rot_1(i), col.rot_2(i), col.rot_3(i)];
    const l = Math.hypot(w, x, y, z) || 1;
    [w, x, y, z] = [w / l, x / l, y / l, z / l];
    const r = [
      [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
      [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
      [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ];
    const cov = (a, b) => r[a][0] * r[b][0] * s[0] * s[0] + r[a][1] * r[b][1] * s[1] * s[1] + r[a][2] * r[b][2] * s[2] * s[2];
    data.set([cov(0, 0), cov(0, 1), cov(0, 2), cov(1, 1), cov(1, 2), cov(2, 2)], at + 4);
    const sh = new Array(12).fill(0);
    sh[0] = col.f_dc_0(i); sh[1] = col.f_dc_1(i); sh[2] = col.f_dc_2(i);
    for (let c = 0; c < 3 && degree; c++) for (let k = 0; k < 3; k++) sh[3 * (k + 1) + c] = rest[3 * c + k](i);
    data.set(sh, at + 12);
    data.set(skin.joints[i], at + 24);
    data.set(skin.weights[i], at + 28);
  }
  return { data, rows, means, degree };
}

const VERTEX = (joints) => `#version 300 es
precision highp float; precision highp int; precision highp sampler2D;
uniform sampler2D gaussians;
uniform mat4 jointMatrix[${joints}];
uniform mat3 rotation; uniform vec3 translation; // world → camera (x right, y down, z forward)
uniform vec4 intrinsics; // fx fy cx cy, canvas pixels
uniform vec2 limit; // off-screen clamp of x/z and y/z
uniform vec2 viewport;
uniform float dilation; // variance added on the screen's axes, canvas pixels²
uniform vec3 eye; // camera centre, world
in vec2 corner; in uint index;
out vec4 vColor; out vec2 vOffset; out vec3 vConic;
const int TEXELS = ${TEXELS}; const int PER_ROW = ${PER_ROW};
vec4 texel(int k) {
  int i = int(index);
  return texelFetch(gaussians, ivec2((i % PER_ROW) * TEXELS + k, i / PER_ROW), 0);
}
void main() {
  vec4 meanOpacity = texel(0), c0 = texel(1), c1 = texel(2), joints = texel(6), weights = texel(7);
  mat4 b = weights.x * jointMatrix[int(joints.x)] + weights.y * jointMatrix[int(joints.y)]
         + weights.z * jointMatrix[int(joints.z)] + weights.w * jointMatrix[int(joints.w)];
  vec3 world = (b * vec4(meanOpacity.xyz, 1.0)).xyz;
  vec3 cam = rotation * world + translation;
  gl_Position = vec4(0.0, 0.0, 2.0, 1.0); // culled unless it is drawn below
  if (cam.z < 0.01) return;
  mat3 sigma = mat3(c0.x, c0.y, c0.z, c0.y, c0.w, c1.x, c0.z, c1.x, c1.y);
  mat3 wl = rotation * mat3(b);
  mat3 sc = wl * sigma * transpose(wl);
  float z = cam.z;
  vec2 t = clamp(cam.xy / z, -limit, limit) * z;
  // Jacobian rows (fx/z, 0, -fx tx/z²) and (0, fy/z, -fy ty/z²), as columns of a mat3x2 in GLSL.
  mat3x2 jac = mat3x2(intrinsics.x / z, 0.0, 0.0, intrinsics.y / z,
                      -intrinsics.x * t.x / (z * z), -intrinsics.y * t.y / (z * z));
  mat2 cov = jac * sc * transpose(jac);
  cov[0][0] += dilation; cov[1][1] += dilation;
  float det = cov[0][0] * cov[1][1] - cov[0][1] * cov[0][1];
  if (det <= 0.0) return;
  vConic = vec3(cov[1][1], -cov[0][1], cov[0][0]) / det;
  float opacity = meanOpacity.w;
  if (opacity < 1.0 / 255.0) return;
  // The box of the 1/255 alpha ellipse, along the covariance's axes.
  float mid = 0.5 * (cov[0][0] + cov[1][1]);
  float spread = sqrt(max(mid * mid - det, 0.0));
  float big = mid + spread, small = max(mid - spread, 0.0);
  vec2 axis = abs(cov[0][1]) > 1e-9 ? normalize(vec2(big - cov[1][1], cov[0][1]))
            : (cov[0][0] >= cov[1][1] ? vec2(1.0, 0.0) : vec2(0.0, 1.0));
  float reach = sqrt(2.0 * log(255.0 * opacity));
  vOffset = corner.x * reach * sqrt(big) * axis + corner.y * reach * sqrt(small) * vec2(-axis.y, axis.x);
  // Pixel centres at integer coordinates (anerf's convention); GL's lie at half-integers.
  vec2 pixel = intrinsics.xy * cam.xy / z + intrinsics.zw + vOffset + 0.5;
  gl_Position = vec4(2.0 * pixel.x / viewport.x - 1.0, 1.0 - 2.0 * pixel.y / viewport.y, 0.0, 1.0);
  vec3 d = normalize(transpose(mat3(b)) * (world - eye));
  vec4 k0 = texel(3), k1 = texel(4), k2 = texel(5);
  vec3 colour = 0.5 + C0 * k0.xyz + C1 * (-d.y * vec3(k0.w, k1.xy) + d.z * vec3(k1.zw, k2.x) - d.x * k2.yzw);
  vColor = vec4(max(colour, 0.0), opacity);
}`.replace(/\bC0\b/g, C0.toFixed(7)).replace(/\bC1\b/g, C1.toFixed(7));

const FRAGMENT = `#version 300 es
precision highp float;
in vec4 vColor; in vec2 vOffset; in vec3 vConic; out vec4 outColor;
void main() {
  float power = -0.5 * (vConic.x * vOffset.x * vOffset.x + vConic.z * vOffset.y * vOffset.y) - vConic.y * vOffset.x * vOffset.y;
  if (power > 0.0) discard;
  float alpha = min(0.99, vColor.a * exp(power));
  if (alpha < 1.0 / 255.0) discard;
  outColor = vec4(vColor.rgb * alpha, alpha);
}`;

export class SplatView {
  /** Draws into `canvas`; `onFrame(time, duration)` is told each drawn frame's animation time. */
  constructor(canvas, onFrame = () => {}) {
    const gl = canvas.getContext('webgl2', { antialias: false, preserveDrawingBuffer: true });
    if (!gl) throw new Error('this browser has no WebGL2');
    this.gl = gl; this.canvas = canvas; this.scene = null;
    /** `null` for the orbit, else the index of a dataset camera in motion.json. */
    this.camera = null;
    /** Milliseconds the last frames' sorts and draws took (CPU side), for the page's figure. */
    this.cpuMs = 0;
    animate(this, canvas, onFrame);
  }

  /** Fetches and shows the avatar of `files` (`ply`, `skin`, `motion` URLs). */
  async load(files) {
    const get = async (url) => {
      const r = await fetch(url);
      if (!r.ok) throw new Error(url + ': HTTP ' + r.status);
      return r;
    };
    const [ply, skin, motion] = await Promise.all([
      get(files.ply).then((r) => r.arrayBuffer()).then(parsePly),
      get(files.skin).then((r) => r.json()),
      get(files.motion).then((r) => r.json()),
    ]);
    this.scene = this.build(ply, skin, motion);
    this.duration = motion.frames.length > 1 ? motion.frames.length / motion.fps : 0;
    this.time = 0;
    this.dirty = true;
  }

  build(ply, skin, motion) {
    const gl = this.gl;
    const joints = skin.rest_joints.length;
    const packed = pack(ply, skin);
    for (const frame of motion.frames) {
      if (frame.length !== joints) throw new Error(`motion.json has ${frame.length} joint matrices per frame, skin.json ${joints} joints`);
    }
    const program = compile(gl, VERTEX(joints), FRAGMENT);
    const texture = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, texture);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, PER_ROW * TEXELS, packed.rows, 0, gl.RGBA, gl.FLOAT, packed.data);
    const vao = gl.createVertexArray();
    gl.bindVertexArray(vao);
    const corners = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, corners);
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([-1, -1, 1, -1, -1, 1, 1, 1]), gl.STATIC_DRAW);
    const cornerAt = gl.getAttribLocation(program, 'corner');
    gl.enableVertexAttribArray(cornerAt);
    gl.vertexAttribPointer(cornerAt, 2, gl.FLOAT, false, 0, 0);
    const order = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, order);
    gl.bufferData(gl.ARRAY_BUFFER, ply.count * 4, gl.DYNAMIC_DRAW);
    const indexAt = gl.getAttribLocation(program, 'index');
    gl.enableVertexAttribArray(indexAt);
    gl.vertexAttribIPointer(indexAt, 1, gl.UNSIGNED_INT, 0, 0);
    gl.vertexAttribDivisor(indexAt, 1);
    gl.bindVertexArray(null);
    // The orbit's size: the canonical means' extent.
    let lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
    for (let i = 0; i < ply.count; i++) for (let a = 0; a < 3; a++) {
      lo[a] = Math.min(lo[a], packed.means[3 * i + a]); hi[a] = Math.max(hi[a], packed.means[3 * i + a]);
    }
    const size = ply.count ? Math.hypot(...sub(hi, lo)) : 2;
    return {
      program, texture, vao, order, count: ply.count, means: packed.means, degree: packed.degree,
      joints: skin.joints, weights: skin.weights, rest: skin.rest_joints, motion, size,
      depths: new Float32Array(ply.count), sorted: new Uint32Array(ply.count), counts: new Uint32Array(65536),
    };
  }

  /** The joint matrices at animation time `t`: the frames' linear blend between the two nearest. */
  jointMatrices(t) {
    const frames = this.scene.motion.frames, k = frames.length;
    const at = this.duration > 0 ? Math.min(t * this.scene.motion.fps, k - 1) : 0;
    const a = Math.floor(at), b = Math.min(a + 1, k - 1), u = at - a;
    const out = new Float32Array(16 * frames[a].length);
    frames[a].forEach((m, j) => { for (let e = 0; e < 16; e++) out[16 * j + e] = m[e] * (1 - u) + frames[b][j][e] * u; });
    return out;
  }

  /** World → camera rotation (rows), translation and pixel intrinsics of the view in a `w × h` canvas. */
  viewCamera(w, h, matrices) {
    const motion = this.scene.motion;
    const cam = this.camera === null ? null : motion.cameras[this.camera];
    if (cam) {
      // The dataset image, fitted into the canvas and centred.
      const s = Math.min(w / cam.width, h / cam.height);
      const k = cam.intrinsics;
      return {
        rotation: cam.rotation, translation: cam.translation,
        intrinsics: [k[0][0] * s, k[1][1] * s, k[0][2] * s + (w - cam.width * s) / 2, k[1][2] * s + (h - cam.height * s) / 2],
        // The camera's pixel footprint, as anerf's renderer gives it in the camera's own pixels.
        dilation: DILATION * s * s,
      };
    }
    // Orbit the skinned root joint about the world's up.
    const root = this.scene.rest[0], m = matrices;
    const target = [0, 1, 2].map((r) => m[r] * root[0] + m[4 + r] * root[1] + m[8 + r] * root[2] + m[12 + r]);
    const up = norm(motion.up);
    const side = norm(cross(up, Math.abs(up[2]) < 0.9 ? [0, 0, 1] : [1, 0, 0]));
    const front = cross(side, up);
    const r = this.scene.size * 1.3 * this.zoom;
    const around = add(scale(side, Math.sin(this.yaw)), scale(front, Math.cos(this.yaw)));
    const eye = add(target, add(scale(around, r * Math.cos(this.pitch)), scale(up, r * Math.sin(this.pitch))));
    const forward = norm(sub(target, eye)), right = norm(cross(forward, up)), down = cross(forward, right);
    const rotation = [right, down, forward];
    const f = 0.5 * h / Math.tan(0.4);
    return { rotation, translation: rotation.map((row) => -dot(row, eye)), intrinsics: [f, f, w / 2, h / 2], dilation: DILATION };
  }

  /** Back-to-front order of the skinned means along the camera's axis (a counting sort on 16-bit depths). */
  sort(matrices, forward, offset) {
    const sc = this.scene, n = sc.count, { depths, sorted, counts } = sc;
    // The depth of an affine blend is the blend of the joints' depth rows.
    const joints = matrices.length / 16;
    const rows = new Float32Array(4 * joints);
    for (let j = 0; j < joints; j++) for (let c = 0; c < 4; c++) {
      rows[4 * j + c] = forward[0] * matrices[16 * j + 4 * c] + forward[1] * matrices[16 * j + 4 * c + 1]
        + forward[2] * matrices[16 * j + 4 * c + 2] + (c === 3 ? offset : 0);
    }
    let lo = Infinity, hi = -Infinity;
    for (let i = 0; i < n; i++) {
      const x = sc.means[3 * i], y = sc.means[3 * i + 1], z = sc.means[3 * i + 2];
      const js = sc.joints[i], ws = sc.weights[i];
      let d = 0;
      for (let s = 0; s < 4; s++) {
        const q = 4 * js[s];
        d += ws[s] * (rows[q] * x + rows[q + 1] * y + rows[q + 2] * z + rows[q + 3]);
      }
      depths[i] = d;
      if (d < lo) lo = d;
      if (d > hi) hi = d;
    }
    const bucket = 65535 / Math.max(hi - lo, 1e-9);
    counts.fill(0);
    // Far first: key = 65535 at the nearest.
    const key = (i) => 65535 - Math.min(65535, Math.floor((depths[i] - lo) * bucket));
    for (let i = 0; i < n; i++) counts[key(i)]++;
    for (let k = 1; k < 65536; k++) counts[k] += counts[k - 1];
    for (let i = n - 1; i >= 0; i--) sorted[--counts[key(i)]] = i;
    return sorted;
  }

  draw() {
    const gl = this.gl, sc = this.scene;
    const started = performance.now();
    const [w, h] = fitCanvas(this.canvas);
    gl.viewport(0, 0, w, h);
    gl.clearColor(...BACKGROUND.map((c) => c / 255), 1);
    gl.clear(gl.COLOR_BUFFER_BIT);
    const matrices = this.jointMatrices(this.time);
    const view = this.viewCamera(w, h, matrices);
    const order = this.sort(matrices, view.rotation[2], view.translation[2]);
    gl.bindBuffer(gl.ARRAY_BUFFER, sc.order);
    gl.bufferSubData(gl.ARRAY_BUFFER, 0, order);
    gl.useProgram(sc.program);
    const u = (name) => gl.getUniformLocation(sc.program, name);
    gl.uniformMatrix4fv(u('jointMatrix'), false, matrices);
    // GLSL's mat3 is column-major: the rows of R are its transpose's columns.
    gl.uniformMatrix3fv(u('rotation'), true, view.rotation.flat());
    gl.uniform3fv(u('translation'), view.translation);
    gl.uniform4fv(u('intrinsics'), view.intrinsics);
    const [fx, fy, cx, cy] = view.intrinsics;
    gl.uniform2f(u('limit'), 1.3 * Math.max(cx, w - cx) / fx, 1.3 * Math.max(cy, h - cy) / fy);
    gl.uniform2f(u('viewport'), w, h);
    gl.uniform1f(u('dilation'), view.dilation);
    const r = view.rotation, t = view.translation;
    gl.uniform3fv(u('eye'), [0, 1, 2].map((c) => -(r[0][c] * t[0] + r[1][c] * t[1] + r[2][c] * t[2])));
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_2D, sc.texture);
    gl.uniform1i(u('gaussians'), 0);
    gl.enable(gl.BLEND);
    // Premultiplied colour, back to front: over what is already drawn.
    gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA);
    gl.bindVertexArray(sc.vao);
    gl.drawArraysInstanced(gl.TRIANGLE_STRIP, 0, 4, sc.count);
    gl.bindVertexArray(null);
    this.cpuMs = performance.now() - started;
  }
}
