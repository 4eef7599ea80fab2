// A WebGL2 viewer for skinned glTF 2.0 binaries: parses the .glb, plays its first animation (LINEAR, STEP
// or the values of CUBICSPLINE keys), skins the first skinned mesh on the GPU with up to four joints per
// vertex and shows COLOR_0 (linear, as glTF defines it; written to the screen as sRGB) with a head light.
// Drag to orbit, wheel to zoom; the camera follows the root joint. Written for `anerf export`'s files, it
// reads any glb that keeps to one skinned mesh with triangles.

import { BACKGROUND, M, animate, compile, dot, fitCanvas, sub } from './view3d.js';

const COMPONENTS = { SCALAR: 1, VEC2: 2, VEC3: 3, VEC4: 4, MAT4: 16 };
const ARRAYS = {
  5120: Int8Array, 5121: Uint8Array, 5122: Int16Array,
  5123: Uint16Array, 5125: Uint32Array, 5126: Float32Array,
};
const NORMALISE = { 5120: 127, 5121: 255, 5122: 32767, 5123: 65535 };

/** Splits a .glb into its JSON and binary chunks. */
function parseGlb(buffer) {
  const view = new DataView(buffer);
  if (view.getUint32(0, true) !== 0x46546c67) throw new Error('not a glTF binary (no "glTF" magic)');
  if (view.getUint32(4, true) !== 2) throw new Error('glTF binary version ' + view.getUint32(4, true) + ', expected 2');
  let json = null, bin = null;
  for (let at = 12; at + 8 <= buffer.byteLength;) {
    const length = view.getUint32(at, true), type = view.getUint32(at + 4, true);
    const chunk = buffer.slice(at + 8, at + 8 + length);
    if (type === 0x4e4f534a) json = JSON.parse(new TextDecoder().decode(chunk));
    else if (type === 0x004e4942) bin = chunk;
    at += 8 + length;
  }
  if (!json) throw new Error('the glb has no JSON chunk');
  return { json, bin };
}

/** Accessor `index` as a tightly packed typed array, with its component count. */
function readAccessor(gltf, bin, index) {
  const acc = gltf.accessors[index];
  const n = COMPONENTS[acc.type], Ctor = ARRAYS[acc.componentType];
  const out = new Ctor(acc.count * n);
  if (acc.bufferView === undefined) return { data: out, size: n, acc };
  const bv = gltf.bufferViews[acc.bufferView];
  if ((bv.buffer ?? 0) !== 0 || !bin) throw new Error('accessor ' + index + ' lies outside the glb');
  const base = (bv.byteOffset ?? 0) + (acc.byteOffset ?? 0);
  const elem = n * Ctor.BYTES_PER_ELEMENT, stride = bv.byteStride ?? elem;
  if (stride === elem && base % Ctor.BYTES_PER_ELEMENT === 0) {
    out.set(new Ctor(bin, base, acc.count * n));
  } else {
    const bytes = new Uint8Array(out.buffer);
    const src = new Uint8Array(bin);
    for (let i = 0; i < acc.count; i++) bytes.set(src.subarray(base + i * stride, base + i * stride + elem), i * elem);
  }
  return { data: out, size: n, acc };
}

/** Interpolates a sampler's keys at time `t` (clamped to its range). */
function sample(s, t) {
  const times = s.input, n = s.size, k = times.length;
  const value = (i) => {
    // CUBICSPLINE keys are (in-tangent, value, out-tangent); only the value is used.
    const at = s.cubic ? (i * 3 + 1) * n : i * n;
    return Array.from(s.output.subarray(at, at + n));
  };
  if (t <= times[0] || k === 1) return value(0);
  if (t >= times[k - 1]) return value(k - 1);
  let lo = 0, hi = k - 1;
  while (hi - lo > 1) { const mid = (lo + hi) >> 1; if (times[mid] <= t) lo = mid; else hi = mid; }
  const a = value(lo), b = value(hi);
  if (s.step) return a;
  const u = (t - times[lo]) / (times[hi] - times[lo]);
  if (s.path !== 'rotation') return a.map((v, i) => v + (b[i] - v) * u);
  // Spherical interpolation along the shorter arc.
  let d = dot(a, b) + a[3] * b[3];
  const sign = d < 0 ? -1 : 1; d *= sign;
  if (d > 0.9995) {
    const q = a.map((v, i) => v + (sign * b[i] - v) * u), l = Math.hypot(...q);
    return q.map((v) => v / l);
  }
  const th = Math.acos(d), sa = Math.sin((1 - u) * th) / Math.sin(th), sb = sign * Math.sin(u * th) / Math.sin(th);
  return a.map((v, i) => v * sa + b[i] * sb);
}

const VERTEX = (joints) => `#version 300 es
in vec3 position; in vec3 color; in uvec4 joints; in vec4 weights;
uniform mat4 viewProjection; uniform mat4 model; uniform mat4 jointMatrix[${Math.max(joints, 1)}];
uniform bool skinned;
out vec3 vColor; out vec3 vWorld;
void main() {
  mat4 m = model;
  if (skinned) m = weights.x * jointMatrix[joints.x] + weights.y * jointMatrix[joints.y]
                 + weights.z * jointMatrix[joints.z] + weights.w * jointMatrix[joints.w];
  vec4 world = m * vec4(position, 1.0);
  vWorld = world.xyz; vColor = color;
  gl_Position = viewProjection * world;
}`;
const FRAGMENT = `#version 300 es
precision highp float;
in vec3 vColor; in vec3 vWorld; uniform vec3 eye; out vec4 outColor;
void main() {
  vec3 n = normalize(cross(dFdx(vWorld), dFdy(vWorld)));
  float light = 0.7 + 0.3 * abs(dot(n, normalize(eye - vWorld)));
  vec3 linear = vColor * light;
  outColor = vec4(mix(12.92 * linear, 1.055 * pow(linear, vec3(1.0 / 2.4)) - 0.055, step(0.0031308, linear)), 1.0);
}`;

/** The background the canvas is cleared to (re-exported for the browser test). */
export { BACKGROUND };

export class GlbView {
  /** Draws into `canvas`; `onFrame(time, duration)` is told each drawn frame's animation time. */
  constructor(canvas, onFrame = () => {}) {
    const gl = canvas.getContext('webgl2', { antialias: true, preserveDrawingBuffer: true });
    if (!gl) throw new Error('this browser has no WebGL2');
    this.gl = gl; this.canvas = canvas; this.scene = null;
    animate(this, canvas, onFrame);
  }

  /** Fetches and shows the .glb at `url`. */
  async load(url) {
    const response = await fetch(url);
    if (!response.ok) throw new Error(url + ': HTTP ' + response.status);
    const { json, bin } = parseGlb(await response.arrayBuffer());
    this.scene = this.build(json, bin);
    this.time = 0;
    this.dirty = true;
  }

  build(gltf, bin) {
    const gl = this.gl;
    const meshNode = (gltf.nodes ?? []).findIndex((n) => n.mesh !== undefined && n.skin !== undefined);
    const nodeIndex = meshNode >= 0 ? meshNode : (gltf.nodes ?? []).findIndex((n) => n.mesh !== undefined);
    if (nodeIndex < 0) throw new Error('the glb has no mesh');
    const node = gltf.nodes[nodeIndex];
    const prim = gltf.meshes[node.mesh].primitives[0];
    if ((prim.mode ?? 4) !== 4) throw new Error('only triangle meshes are shown');
    const skin = node.skin !== undefined ? gltf.skins[node.skin] : null;
    const joints = skin ? skin.joints.length : 0;
    const program = compile(gl, VERTEX(joints), FRAGMENT);
    const vao = gl.createVertexArray();
    gl.bindVertexArray(vao);
    const attribute = (name, accessorIndex, fallback) => {
      const loc = gl.getAttribLocation(program, name);
      if (loc < 0) return;
      if (accessorIndex === undefined) { gl.disableVertexAttribArray(loc); gl.vertexAttrib4f(loc, ...fallback); return; }
      const { data, size, acc } = readAccessor(gltf, bin, accessorIndex);
      const buffer = gl.createBuffer();
      gl.bindBuffer(gl.ARRAY_BUFFER, buffer);
      gl.enableVertexAttribArray(loc);
      if (name === 'joints') {
        gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
        gl.vertexAttribIPointer(loc, size, acc.componentType, 0, 0);
      } else {
        const floats = data instanceof Float32Array ? data
          : Float32Array.from(data, (v) => v / (NORMALISE[acc.componentType] ?? 1));
        gl.bufferData(gl.ARRAY_BUFFER, floats, gl.STATIC_DRAW);
        gl.vertexAttribPointer(loc, size, gl.FLOAT, false, 0, 0);
      }
    };
    const a = prim.attributes;
    attribute('position', a.POSITION);
    attribute('color', a.COLOR_0, [0.6, 0.6, 0.6, 1]);
    attribute('weights', skin ? a.WEIGHTS_0 : undefined, [1, 0, 0, 0]);
    if (skin) attribute('joints', a.JOINTS_0);
    else if (gl.getAttribLocation(program, 'joints') >= 0) gl.vertexAttribI4ui(gl.getAttribLocation(program, 'joints'), 0, 0, 0, 0);
    let count;
    let indexType = null;
    if (prim.indices !== undefined) {
      const { data, acc } = readAccessor(gltf, bin, prim.indices);
      const buffer = gl.createBuffer();
      gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, buffer);
      gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, data, gl.STATIC_DRAW);
      count = acc.count; indexType = acc.componentType;
    } else {
      count = gltf.accessors[a.POSITION].count;
    }
    gl.bindVertexArray(null);
    const pos = gltf.accessors[a.POSITION];
    const size = pos.max && pos.min ? Math.hypot(...sub(pos.max, pos.min)) : 2;
    const samplers = [];
    const animation = (gltf.animations ?? [])[0];
    let duration = 0;
    for (const ch of animation?.channels ?? []) {
      if (ch.target.node === undefined || ch.target.path === 'weights') continue;
      const sm = animation.samplers[ch.sampler];
      const input = readAccessor(gltf, bin, sm.input).data;
      const out = readAccessor(gltf, bin, sm.output);
      const output = out.data instanceof Float32Array ? out.data
        : Float32Array.from(out.data, (v) => Math.max(v / (NORMALISE[out.acc.componentType] ?? 1), -1));
      duration = Math.max(duration, input[input.length - 1]);
      samplers.push({ node: ch.target.node, path: ch.target.path, input, output, size: out.size,
        step: sm.interpolation === 'STEP', cubic: sm.interpolation === 'CUBICSPLINE' });
    }
    this.duration = duration;
    const inverseBind = skin?.inverseBindMatrices !== undefined ? readAccessor(gltf, bin, skin.inverseBindMatrices).data : null;
    const parents = new Array(gltf.nodes.length).fill(-1);
    gltf.nodes.forEach((n, i) => (n.children ?? []).forEach((c) => { parents[c] = i; }));
    return { gltf, program, vao, count, indexType, skin, joints, inverseBind, samplers, parents, nodeIndex, size };
  }

  /** Every node's world matrix at animation time `t`. */
  worldMatrices(t) {
    const { gltf, samplers, parents } = this.scene;
    const trs = gltf.nodes.map((n) => ({
      t: n.translation ?? [0, 0, 0], r: n.rotation ?? [0, 0, 0, 1], s: n.scale ?? [1, 1, 1], m: n.matrix,
    }));
    for (const s of samplers) {
      const key = { translation: 't', rotation: 'r', scale: 's' }[s.path];
      trs[s.node][key] = sample(s, t);
      trs[s.node].m = undefined;
    }
    const local = trs.map((x) => (x.m ? new Float32Array(x.m) : M.fromTrs(x.t, x.r, x.s)));
    const world = new Array(local.length);
    const resolve = (i) => world[i] ?? (world[i] = parents[i] < 0 ? local[i] : M.mul(resolve(parents[i]), local[i]));
    local.forEach((_, i) => resolve(i));
    return world;
  }

  draw() {
    const gl = this.gl, sc = this.scene, canvas = this.canvas;
    const [w, h] = fitCanvas(canvas);
    gl.viewport(0, 0, w, h);
    gl.clearColor(...BACKGROUND.map((c) => c / 255), 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.enable(gl.DEPTH_TEST);
    const world = this.worldMatrices(this.time);
    // Follow the skeleton's root (or the mesh node) and orbit around it, +Y up as glTF defines.
    const followed = sc.skin ? world[sc.skin.joints[0]] : world[sc.nodeIndex];
    const target = [followed[12], followed[13], followed[14]];
    const r = sc.size * 1.3 * this.zoom;
    const eye = [target[0] + r * Math.cos(this.pitch) * Math.sin(this.yaw), target[1] + r * Math.sin(this.pitch),
      target[2] + r * Math.cos(this.pitch) * Math.cos(this.yaw)];
    const viewProjection = M.mul(M.perspective(0.8, w / Math.max(h, 1), sc.size * 0.01, sc.size * 20), M.lookAt(eye, target, [0, 1, 0]));
    gl.useProgram(sc.program);
    const u = (name) => gl.getUniformLocation(sc.program, name);
    gl.uniformMatrix4fv(u('viewProjection'), false, viewProjection);
    gl.uniform3fv(u('eye'), eye);
    gl.uniform1i(u('skinned'), sc.skin ? 1 : 0);
    gl.uniformMatrix4fv(u('model'), false, world[sc.nodeIndex]);
    if (sc.skin) {
      const all = new Float32Array(16 * sc.joints);
      sc.skin.joints.forEach((j, k) => {
        const ibm = sc.inverseBind ? sc.inverseBind.subarray(16 * k, 16 * k + 16) : M.identity();
        all.set(M.mul(world[j], ibm), 16 * k);
      });
      gl.uniformMatrix4fv(u('jointMatrix'), false, all);
    }
    gl.bindVertexArray(sc.vao);
    if (sc.indexType !== null) gl.drawElements(gl.TRIANGLES, sc.count, sc.indexType, 0);
    else gl.drawArrays(gl.TRIANGLES, 0, sc.count);
    gl.bindVertexArray(null);
  }
}
