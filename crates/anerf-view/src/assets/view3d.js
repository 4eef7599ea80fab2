// What the page's two 3D views (the glb mesh and the baked Gaussians) share: column-major 4×4 matrices and
// 3-vectors, shader compilation, the drag-to-orbit and wheel-to-zoom input, and a draw loop that plays an
// animation and draws only when the picture changes (a paused view costs nothing).

// Column-major 4×4 matrices, as glTF and WebGL store them.
export const M = {
  identity: () => new Float32Array([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]),
  mul(a, b) {
    const o = new Float32Array(16);
    for (let c = 0; c < 4; c++) for (let r = 0; r < 4; r++) {
      let s = 0;
      for (let k = 0; k < 4; k++) s += a[k * 4 + r] * b[c * 4 + k];
      o[c * 4 + r] = s;
    }
    return o;
  },
  fromTrs(t, q, s) {
    const [x, y, z, w] = q;
    const o = new Float32Array([
      (1 - 2 * (y * y + z * z)) * s[0], 2 * (x * y + z * w) * s[0], 2 * (x * z - y * w) * s[0], 0,
      2 * (x * y - z * w) * s[1], (1 - 2 * (x * x + z * z)) * s[1], 2 * (y * z + x * w) * s[1], 0,
      2 * (x * z + y * w) * s[2], 2 * (y * z - x * w) * s[2], (1 - 2 * (x * x + y * y)) * s[2], 0,
      t[0], t[1], t[2], 1,
    ]);
    return o;
  },
  perspective(fovy, aspect, near, far) {
    const f = 1 / Math.tan(fovy / 2), nf = 1 / (near - far);
    return new Float32Array([f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * nf, -1, 0, 0, 2 * far * near * nf, 0]);
  },
  lookAt(eye, at, up) {
    const z = norm(sub(eye, at)), x = norm(cross(up, z)), y = cross(z, x);
    return new Float32Array([x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0,
      -dot(x, eye), -dot(y, eye), -dot(z, eye), 1]);
  },
};
export const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
export const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
export const scale = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
export const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
export const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
export const norm = (a) => { const l = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / l, a[1] / l, a[2] / l]; };

/** The background both views clear to (sRGB bytes; the browser test looks for anything else). */
export const BACKGROUND = [236, 239, 244];

/** Links a WebGL2 program from vertex and fragment source; throws with the compiler's log. */
export function compile(gl, vertex, fragment) {
  const program = gl.createProgram();
  for (const [type, text] of [[gl.VERTEX_SHADER, vertex], [gl.FRAGMENT_SHADER, fragment]]) {
    const s = gl.createShader(type);
    gl.shaderSource(s, text); gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error('shader: ' + gl.getShaderInfoLog(s));
    gl.attachShader(program, s);
  }
  gl.linkProgram(program);
  if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error('program: ' + gl.getProgramInfoLog(program));
  return program;
}

/**
 * The state and loop of an animated, orbitable view on `canvas`: `view.yaw`, `pitch` and `zoom` follow the
 * pointer and wheel; `view.time` advances while `view.playing` and the scene has a duration; `view.draw()`
 * is called when either changes (or `view.dirty` is set), then `onFrame(time, duration)`.
 */
export function animate(view, canvas, onFrame) {
  Object.assign(view, { yaw: 0.6, pitch: 0.15, zoom: 1, playing: true, time: 0, duration: 0, frames: 0, dirty: true });
  new ResizeObserver(() => { view.dirty = true; }).observe(canvas);
  let drag = null;
  canvas.addEventListener('pointerdown', (e) => { drag = [e.clientX, e.clientY]; canvas.setPointerCapture(e.pointerId); });
  canvas.addEventListener('pointerup', () => { drag = null; });
  canvas.addEventListener('pointermove', (e) => {
    if (!drag) return;
    view.yaw -= (e.clientX - drag[0]) * 0.01;
    view.pitch = Math.max(-1.4, Math.min(1.4, view.pitch + (e.clientY - drag[1]) * 0.01));
    drag = [e.clientX, e.clientY];
    view.dirty = true;
  });
  canvas.addEventListener('wheel', (e) => {
    e.preventDefault();
    view.zoom = Math.max(0.2, Math.min(5, view.zoom * Math.exp(e.deltaY * 0.001)));
    view.dirty = true;
  }, { passive: false });
  let last = performance.now();
  const tick = (now) => {
    const advance = view.scene && view.playing && view.duration > 0;
    if (advance) view.time = (view.time + (now - last) / 1000) % view.duration;
    last = now;
    if (view.scene && (advance || view.dirty)) {
      view.dirty = false;
      view.draw();
      view.frames += 1;
      onFrame(view.time, view.duration);
    }
    requestAnimationFrame(tick);
  };
  requestAnimationFrame(tick);
}

/** Sizes `canvas`'s drawing buffer to its displayed size in device pixels; returns [width, height]. */
export function fitCanvas(canvas) {
  const dpr = window.devicePixelRatio || 1;
  const w = Math.round(canvas.clientWidth * dpr), h = Math.round(canvas.clientHeight * dpr);
  if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
  return [w, h];
}
