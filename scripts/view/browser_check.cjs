// Loads an `anerf view` page in headless Chromium (Debian's /usr/bin/chromium, driven by playwright-core)
// and checks what a user would see: the 3D view drew the avatar (pixels other than the background), the
// baked avatar's Gaussians drew from the orbit and from a dataset camera, the
// training curves and at least one evaluation image loaded, the view filter shows that view's images only,
// and the console logged no error. Writes a screenshot; prints one JSON line; exits 1 on a failed check.
//
// usage: node scripts/view/browser_check.cjs <page-url> <screenshot.png>
// NODE_PATH must reach playwright-core (scripts/test.sh installs it into target/npm).
'use strict';
const { chromium } = require('playwright-core');

const [url, screenshot] = process.argv.slice(2);
if (!url || !screenshot) {
  console.error('usage: browser_check.cjs <page-url> <screenshot.png>');
  process.exit(2);
}
const TIMEOUT_MS = 40000;

/**
 * The Gaussian view at the first training frame from a training camera against `anerf eval --baked`'s
 * render of that image (anerf's own rasteriser): the overlap of the two silhouettes (intersection over
 * union), the distance of their centroids in the camera's pixels, and the mean colour difference (0–1)
 * where both are drawn. The canvas is sampled at the centre of each camera pixel it fits the image into.
 */
async function splatFidelity(page) {
  const pick = await page.evaluate(async () => {
    const index = await (await fetch('/api/run')).json();
    const motion = await (await fetch(index.splats.motion)).json();
    const base = '/run/baked/eval/training-view/';
    const response = await fetch(base + 'metrics.json');
    if (!response.ok) return { problem: 'no baked training-view evaluation (anerf eval <run> --baked --split training-view)' };
    const records = await response.json();
    const first = motion.dataset_frames[0];
    const record = records.find((r) => r.frame === first && motion.cameras[r.view]?.training);
    if (!record) return { problem: `the baked evaluation has no image of frame ${first} from a training camera` };
    const pad = (v, n) => String(v).padStart(n, '0');
    return { view: record.view, pred: `${base}images/training-view_frame${pad(first, 4)}_view${pad(record.view, 2)}_pred.png` };
  });
  if (pick.problem) return pick;
  // The first frame (the slider's start pauses the view there), seen from that camera.
  await page.$eval('#splat-scrub', (e) => { e.value = '0'; e.dispatchEvent(new Event('input')); });
  await page.selectOption('#splat-camera', String(pick.view));
  await page.waitForFunction((v) => {
    const shown = window.anerfView.splatShown;
    return shown && shown.camera === v && shown.time === 0;
  }, pick.view, { timeout: TIMEOUT_MS });
  return page.evaluate(async ({ view, pred }) => {
    const { BACKGROUND } = await import('/assets/view3d.js');
    const image = new Image();
    image.src = pred;
    await image.decode();
    const [cw, ch] = [image.naturalWidth, image.naturalHeight];
    const pixels = (source, w, h) => {
      const c = document.createElement('canvas');
      c.width = w; c.height = h;
      const ctx = c.getContext('2d');
      ctx.drawImage(source, 0, 0);
      return ctx.getImageData(0, 0, w, h).data;
    };
    const reference = pixels(image, cw, ch);
    const canvas = document.getElementById('splats');
    const [w, h] = [canvas.width, canvas.height];
    const drawn = pixels(canvas, w, h);
    const s = Math.min(w / cw, h / ch), ox = (w - cw * s) / 2, oy = (h - ch * s) / 2;
    let both = 0, either = 0, colour = 0;
    const centroid = { a: [0, 0, 0], b: [0, 0, 0] };
    for (let v = 0; v < ch; v++) for (let u = 0; u < cw; u++) {
      const r = 4 * (v * cw + u);
      const x = Math.min(w - 1, Math.floor(ox + (u + 0.5) * s)), y = Math.min(h - 1, Math.floor(oy + (v + 0.5) * s));
      const d = 4 * (y * w + x);
      const ours = [0, 1, 2].some((k) => Math.abs(drawn[d + k] - BACKGROUND[k]) > 24);
      const theirs = [0, 1, 2].some((k) => reference[r + k] > 24);
      if (ours) { centroid.a[0] += u; centroid.a[1] += v; centroid.a[2] += 1; }
      if (theirs) { centroid.b[0] += u; centroid.b[1] += v; centroid.b[2] += 1; }
      if (ours || theirs) either++;
      if (ours && theirs) {
        both++;
        // On the page's background against anerf's black: compare what each composited over its own.
        for (let k = 0; k < 3; k++) colour += Math.abs(drawn[d + k] - reference[r + k]) / 255 / 3;
      }
    }
    const at = (c) => [c[0] / Math.max(c[2], 1), c[1] / Math.max(c[2], 1)];
    const [a, b] = [at(centroid.a), at(centroid.b)];
    return {
      view, size: [cw, ch], iou: both / Math.max(either, 1), centroid: Math.hypot(a[0] - b[0], a[1] - b[1]),
      colour: colour / Math.max(both, 1), pixels: [centroid.a[2], centroid.b[2]],
    };
  }, pick);
}

(async () => {
  const browser = await chromium.launch({
    executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
    args: [
      '--no-sandbox', '--disable-quic', '--no-first-run', '--disable-background-networking',
      '--disable-component-update', '--disable-sync',
      // WebGL2 without a GPU: ANGLE on SwiftShader, Chromium's software renderer.
      '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist',
    ],
  });
  const problems = [];
  const consoleErrors = [];
  try {
    const page = await browser.newPage({ viewport: { width: 1280, height: 1000 } });
    page.on('console', (m) => { if (m.type() === 'error') consoleErrors.push(m.text()); });
    page.on('pageerror', (e) => consoleErrors.push('uncaught: ' + e.message));
    page.on('response', (r) => { if (r.status() >= 400) consoleErrors.push(`HTTP ${r.status()} for ${r.url()}`); });
    await page.goto(url);
    await page.waitForFunction(() => {
      const v = window.anerfView;
      return v && (v.error || (v.indexed && (v.avatars === 0 || v.avatarFrames >= 3) && (!v.splats || v.splatFrames >= 3)));
    }, null, { timeout: TIMEOUT_MS });
    const state = await page.evaluate(() => window.anerfView);
    if (state.error) problems.push('the page reported: ' + state.error);
    if (state.avatars === 0) problems.push('the run has no exported avatar (anerf export <run>)');
    else if (state.avatarFrames < 3) problems.push(`the 3D view drew ${state.avatarFrames} frames`);

    // A 3D view's pixels (kept with preserveDrawingBuffer) that differ from the background.
    const drawn = (id) => page.evaluate(async (id) => {
      const { BACKGROUND } = await import('/assets/view3d.js');
      const c = document.getElementById(id);
      const copy = document.createElement('canvas');
      copy.width = c.width; copy.height = c.height;
      const ctx = copy.getContext('2d');
      ctx.drawImage(c, 0, 0);
      const d = ctx.getImageData(0, 0, copy.width, copy.height).data;
      let foreground = 0;
      for (let i = 0; i < d.length; i += 4) {
        if (Math.max(Math.abs(d[i] - BACKGROUND[0]), Math.abs(d[i + 1] - BACKGROUND[1]), Math.abs(d[i + 2] - BACKGROUND[2])) > 24) foreground++;
      }
      return { width: copy.width, height: copy.height, foreground, fraction: foreground / (copy.width * copy.height) };
    }, id);
    const avatar = await drawn('avatar');
    if (!(avatar.fraction > 0.005)) problems.push(`the 3D view shows ${avatar.foreground} avatar pixels of ${avatar.width}x${avatar.height}`);

    // The baked Gaussians: drawn from the orbit, then (paused, so that the frame is the one asked for) from
    // the first dataset camera.
    let splats = null;
    if (!state.splats) {
      problems.push('the run has no exported baked avatar (anerf bake <run>; anerf export <run> --format ply)');
    } else {
      const orbit = await drawn('splats');
      await page.click('#splat-play');
      const cameras = await page.$$eval('#splat-camera option', (os) => os.map((o) => o.value).filter((v) => v));
      let camera = null;
      if (cameras.length) {
        await page.selectOption('#splat-camera', cameras[0]);
        await page.waitForFunction((v) => window.anerfView.splatShown?.camera === v, Number(cameras[0]), { timeout: TIMEOUT_MS });
        camera = await drawn('splats');
      } else {
        problems.push('the baked avatar offers no dataset camera');
      }
      const fidelity = await splatFidelity(page);
      splats = { orbit, camera, fidelity, frames: await page.evaluate(() => window.anerfView.splatFrames) };
      if (fidelity.problem) problems.push(fidelity.problem);
      else if (!(fidelity.iou > 0.8 && fidelity.centroid < 1.5 && fidelity.colour < 0.08)) {
        problems.push('the Gaussian view from a training camera differs from anerf\'s render of it: ' + JSON.stringify(fidelity));
      }
      if (!(orbit.fraction > 0.002)) problems.push(`the Gaussian view shows ${orbit.foreground} pixels from the orbit`);
      if (camera && !(camera.fraction > 0.002)) problems.push(`the Gaussian view shows ${camera.foreground} pixels from camera ${cameras[0]}`);
    }

    // Curves and evaluation images: decoded, with a size.
    const loaded = (selector) => page.evaluate(async (sel) => {
      const imgs = [...document.querySelectorAll(sel)];
      imgs.forEach((i) => { i.loading = 'eager'; });
      await Promise.all(imgs.map((i) => i.decode().catch(() => {})));
      return imgs.filter((i) => i.naturalWidth > 0).length;
    }, selector);
    const curves = await loaded('#curves img');
    if (curves < 1) problems.push('no training curve loaded');
    await page.locator('#images figure').first().scrollIntoViewIfNeeded();
    const predictions = await loaded('#images img.eval-pred');
    if (predictions < 1) problems.push('no evaluation image loaded');

    // The view filter: every image shown afterwards is of that view.
    const views = await page.$$eval('#filter-view option', (os) => os.map((o) => o.value).filter((v) => v));
    let filtered = null;
    if (views.length) {
      await page.selectOption('#filter-view', views[0]);
      filtered = await page.$$eval('#images figcaption', (cs, v) => ({
        shown: cs.length, others: cs.filter((c) => !c.textContent.includes(`view ${v}:`)).length,
      }), views[0]);
      if (filtered.shown < 1 || filtered.others > 0) problems.push(`filter view ${views[0]}: ${JSON.stringify(filtered)}`);
      await page.selectOption('#filter-view', '');
    } else {
      problems.push('the view filter offers no view');
    }

    // Paused (the button a user presses), the page stops drawing, so the screenshot's frame comes at once
    // even on a loaded machine.
    await page.evaluate(() => window.scrollTo(0, 0));
    await page.click('#play');
    if ((await page.textContent('#play')) !== 'Play') problems.push('the pause button did not pause');
    await page.screenshot({ path: screenshot, timeout: 60000 });
    if (consoleErrors.length) problems.push('console errors: ' + consoleErrors.join(' | '));
    console.log(JSON.stringify({ ok: problems.length === 0, avatar, splats, curves, predictions, filtered, frames: state.avatarFrames, problems }));
  } catch (e) {
    problems.push(String(e));
    console.log(JSON.stringify({ ok: false, problems, consoleErrors }));
  } finally {
    await browser.close();
  }
  process.exit(problems.length ? 1 : 0);
})();
