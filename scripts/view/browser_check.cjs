// Loads an `anerf view` page in headless Chromium (Debian's /usr/bin/chromium, driven by playwright-core)
// and checks what a user would see: the 3D view drew the avatar (pixels other than the background), the
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
      return v && (v.error || (v.indexed && (v.avatars === 0 || v.avatarFrames >= 3)));
    }, null, { timeout: TIMEOUT_MS });
    const state = await page.evaluate(() => window.anerfView);
    if (state.error) problems.push('the page reported: ' + state.error);
    if (state.avatars === 0) problems.push('the run has no exported avatar (anerf export <run>)');
    else if (state.avatarFrames < 3) problems.push(`the 3D view drew ${state.avatarFrames} frames`);

    // The avatar: pixels of the canvas (kept with preserveDrawingBuffer) that differ from the background.
    const avatar = await page.evaluate(async () => {
      const { BACKGROUND } = await import('/assets/glb_view.js');
      const c = document.getElementById('avatar');
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
    });
    if (!(avatar.fraction > 0.005)) problems.push(`the 3D view shows ${avatar.foreground} avatar pixels of ${avatar.width}x${avatar.height}`);

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
    console.log(JSON.stringify({ ok: problems.length === 0, avatar, curves, predictions, filtered, frames: state.avatarFrames, problems }));
  } catch (e) {
    problems.push(String(e));
    console.log(JSON.stringify({ ok: false, problems, consoleErrors }));
  } finally {
    await browser.close();
  }
  process.exit(problems.length ? 1 : 0);
})();
