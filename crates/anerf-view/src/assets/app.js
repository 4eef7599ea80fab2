// The viewer page: polls the run's index (/api/run) and redraws whatever changed, so a run that is
// training refreshes by itself. window.anerfView tells a test (or a curious user) what has been shown.

import { GlbView } from './glb_view.js';
import { SplatView } from './splat_view.js';

const POLL_MS = 2000;
const $ = (id) => document.getElementById(id);
const el = (tag, attrs = {}, children = []) => {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === 'text') e.textContent = v; else e.setAttribute(k, v);
  }
  for (const c of children) e.append(c);
  return e;
};
const fmt = (v, digits) => (v === null || v === undefined ? '–' : Number(v).toFixed(digits));

const state = { version: null, index: null, avatar: null, view: null, splats: null, splatView: null, shown: {} };
/** True when `data` differs from what section `name` shows now (file URLs carry their own stamps). */
const changed = (name, data) => {
  const text = JSON.stringify(data);
  if (state.shown[name] === text) return false;
  state.shown[name] = text;
  return true;
};
window.anerfView = { indexed: false, avatars: 0, avatarFrames: 0, splats: false, splatFrames: 0, error: null };

function showStatus(index) {
  $('run-name').textContent = index.name;
  $('run-name').title = index.folder;
  document.title = 'anerf view: ' + index.name;
  const s = $('status');
  const last = index.last;
  // A run that trains writes its log every few seconds: the dot says it is being written now.
  const age = index.log_age_s;
  s.textContent = last
    ? `stage ${last.stage}, step ${last.step}: loss ${fmt(last.loss, 5)}` + (last.psnr !== undefined ? `, PSNR ${fmt(last.psnr, 2)} dB` : '')
      + (age !== null && age < 600 ? ` (logged ${Math.round(age)} s ago)` : '')
    : 'no step logged yet';
  s.classList.toggle('training', age !== null && age < 30);
}

function showCurves(index) {
  const box = $('curves');
  box.replaceChildren(...index.curves.map((url) => el('img', { src: url, alt: url.split('?')[0].split('/').pop(), class: 'curve' })));
  if (!index.curves.length) box.append(el('p', { class: 'muted', text: 'No step logged yet.' }));
}

function options(select, values, label) {
  const keep = select.value;
  select.replaceChildren(el('option', { value: '', text: 'all' }), ...values.map((v) => el('option', { value: String(v), text: label(v) })));
  if (values.map(String).includes(keep)) select.value = keep;
}

function showEvaluation(index) {
  const evals = index.evaluations;
  // The silhouette figures (edge band's PSNR, the rest's, rendered/true area) where the evaluation has them.
  const sil = (e, key, digits) => fmt(e.silhouette ? e.silhouette[key] : null, digits);
  const rows = evals.map((e) => el('tr', {}, [e.split, fmt(e.psnr, 2), fmt(e.ssim, 3), sil(e, 'band_psnr', 2), sil(e, 'outside_band_psnr', 2), sil(e, 'area_ratio', 3), String(e.images.length)].map((text) => el('td', { text }))));
  $('summary').replaceChildren(el('tr', {}, ['split', 'PSNR (dB)', 'SSIM', 'edge band (dB)', 'rest (dB)', 'area ratio', 'images'].map((h) => el('th', { text: h }))), ...rows);
  if (!evals.length) $('summary').replaceChildren(el('caption', { class: 'muted', text: 'Not evaluated yet: anerf eval <run>' }));
  $('charts').replaceChildren(...evals.flatMap((e) => e.charts.map((url) => el('img', { src: url, alt: `${e.split} ${url.split('?')[0].split('/').pop()}` }))));
  const all = evals.flatMap((e) => e.images.map((im) => ({ ...im, split: e.split })));
  options($('filter-split'), evals.map((e) => e.split), (v) => v);
  options($('filter-view'), [...new Set(all.map((im) => im.view))].sort((a, b) => a - b), (v) => `view ${v}`);
  options($('filter-frame'), [...new Set(all.map((im) => im.frame))].sort((a, b) => a - b), (v) => `frame ${v}`);
  showImages();
}

/** The evaluation images that pass the split / view / frame filters. */
function showImages() {
  if (!state.index) return;
  const [split, view, frame] = ['filter-split', 'filter-view', 'filter-frame'].map((id) => $(id).value);
  const shown = state.index.evaluations
    .filter((e) => !split || e.split === split)
    .flatMap((e) => e.images.map((im) => ({ ...im, split: e.split })))
    .filter((im) => (!view || String(im.view) === view) && (!frame || String(im.frame) === frame));
  $('filter-count').textContent = `${shown.length} image${shown.length === 1 ? '' : 's'}`;
  $('images').replaceChildren(...shown.map((im) => el('figure', { class: 'eval' }, [
    el('div', { class: 'row' }, [['pred', 'prediction'], ['gt', 'ground truth'], ['error', 'error']]
      .filter(([key]) => im[key])
      .map(([key, alt]) => el('img', { src: im[key], alt, title: alt, loading: 'lazy', class: `eval-${key}` }))),
    el('figcaption', { text: `${im.split}, frame ${im.frame}, view ${im.view}: ${fmt(im.psnr, 2)} dB, SSIM ${fmt(im.ssim, 3)}` }),
  ])));
}

function showVideos(index) {
  const box = $('videos');
  box.replaceChildren(...index.videos.map((v) => el('figure', {}, [
    v.kind === 'mp4' ? el('video', { src: v.url, controls: '', loop: '', muted: '' })
      : el('img', { src: v.url, alt: v.name }),
    el('figcaption', { text: v.name }),
  ])));
  if (!index.videos.length) box.append(el('p', { class: 'muted', text: 'No video rendered yet: anerf render <run> --orbit, or --motion <file>.' }));
}

async function showAvatar(index) {
  const select = $('avatar-file');
  options(select, index.avatars, (url) => decodeURIComponent(url.split('?')[0].split('/').pop()));
  select.firstChild?.remove();
  if (!index.avatars.length) {
    $('avatar-note').textContent = 'No avatar exported yet: anerf export <run> writes <run>/export/avatar.glb.';
    return;
  }
  const key = select.value || index.avatars[0];
  if (state.avatar === key) return;
  state.avatar = key;
  state.view ??= new GlbView($('avatar'), (t, d) => {
    window.anerfView.avatarFrames = state.view.frames;
    $('clock').textContent = d > 0 ? `${t.toFixed(2)} / ${d.toFixed(2)} s` : 'no animation';
    if (state.view.playing) $('scrub').value = d > 0 ? String(Math.round((t / d) * 1000)) : '0';
  });
  await state.view.load(key);
  $('avatar-note').textContent = 'Drag to orbit, wheel to zoom.';
}

/** The baked avatar's panel: its Gaussians, played and seen from an orbit or a dataset camera. */
async function showSplats(index) {
  const files = index.splats;
  if (!files) {
    $('splat-note').textContent = 'No baked avatar exported yet: anerf bake <run>, then anerf export <run> --format ply.';
    return;
  }
  const key = JSON.stringify(files);
  if (state.splats === key) return;
  state.splats = key;
  const times = [];
  state.splatView ??= new SplatView($('splats'), (t, d) => {
    const view = state.splatView;
    window.anerfView.splatFrames = view.frames;
    window.anerfView.splatShown = { camera: view.camera, time: t };
    $('splat-clock').textContent = d > 0 ? `${t.toFixed(2)} / ${d.toFixed(2)} s` : 'one frame';
    if (view.playing) $('splat-scrub').value = d > 0 ? String(Math.round((t / d) * 1000)) : '0';
    times.push(performance.now());
    if (times.length > 30) times.shift();
    const fps = times.length > 1 ? (1000 * (times.length - 1)) / (times[times.length - 1] - times[0]) : 0;
    $('splat-rate').textContent = `${fps.toFixed(0)} frames/s (sort and draw calls ${view.cpuMs.toFixed(1)} ms)`;
  });
  await state.splatView.load(files);
  const cameras = state.splatView.scene.motion.cameras;
  const select = $('splat-camera');
  const keep = select.value;
  select.replaceChildren(el('option', { value: '', text: 'orbit' }),
    ...cameras.map((c, k) => el('option', { value: String(k), text: `view ${c.view}${c.training ? ' (training)' : ''}` })));
  if (keep && Number(keep) < cameras.length) select.value = keep;
  state.splatView.camera = select.value === '' ? null : Number(select.value);
  window.anerfView.splats = true;
  $('splat-note').textContent = `${state.splatView.scene.count} Gaussians, harmonics of degree ${state.splatView.scene.degree}. Drag to orbit, wheel to zoom.`;
}

async function poll() {
  try {
    const response = await fetch('/api/run', { cache: 'no-store' });
    if (!response.ok) throw new Error('/api/run: HTTP ' + response.status + ': ' + (await response.text()));
    const index = await response.json();
    showStatus(index);
    if (index.version !== state.version) {
      state.version = index.version; state.index = index;
      if (changed('curves', index.curves)) showCurves(index);
      if (changed('evaluations', index.evaluations)) showEvaluation(index);
      if (changed('videos', index.videos)) showVideos(index);
      $('config').textContent = index.config;
      await showAvatar(index);
      await showSplats(index);
      window.anerfView.avatars = index.avatars.length;
      window.anerfView.indexed = true;
    }
  } catch (e) {
    window.anerfView.error = String(e);
    console.error('anerf view:', e);
  }
  setTimeout(poll, POLL_MS);
}

for (const id of ['filter-split', 'filter-view', 'filter-frame']) $(id).addEventListener('change', showImages);
/** Wires a 3D view's play button and time slider; `current()` is the view once it exists. */
function playControls(current, play, scrub) {
  $(play).addEventListener('click', () => {
    const view = current();
    if (!view) return;
    view.playing = !view.playing;
    $(play).textContent = view.playing ? 'Pause' : 'Play';
  });
  $(scrub).addEventListener('input', (e) => {
    const view = current();
    if (!view) return;
    view.playing = false; $(play).textContent = 'Play';
    view.time = (Number(e.target.value) / 1000) * view.duration;
    view.dirty = true;
  });
}
playControls(() => state.view, 'play', 'scrub');
playControls(() => state.splatView, 'splat-play', 'splat-scrub');
$('splat-camera').addEventListener('change', (e) => {
  if (!state.splatView) return;
  state.splatView.camera = e.target.value === '' ? null : Number(e.target.value);
  state.splatView.dirty = true;
});
$('avatar-file').addEventListener('change', () => { state.avatar = null; showAvatar(state.index); });
poll();
