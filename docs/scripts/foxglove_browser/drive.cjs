// Drives Debian's Chromium (headless, through playwright-core) over the host page that
// docs/scripts/foxglove_browser_check.py serves, and prints what the app showed as JSON.
// Argument: one JSON object {url, chromium, profile, timeout_ms, expected_topics, views: [{layout_id, time,
// screenshot}]}; every view opens `${url}&layoutId=...&time=...` in the same browser.
const { chromium } = require("playwright-core");

const CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
  "--disable-background-networking", "--disable-component-update", "--disable-sync"];

// The topics the app's Topics tab lists: a line "/name" followed by its schema name.
async function listedTopics(page) {
  return page.evaluate(() => {
    const filter = document.querySelector("#topic-filter");
    if (!filter) return null;
    let box = filter;
    while (box && !/\n\/\S+\n/.test(box.innerText ?? "")) box = box.parentElement;
    if (!box) return [];
    const lines = box.innerText.split("\n").map((s) => s.trim());
    return lines.filter((s, i) => /^\/\S+$/.test(s) && /^[\w.]+$/.test(lines[i + 1] ?? ""));
  });
}

// The errors shown in the settings tree of the panel whose settings are open (hovering each error icon).
async function settingsErrors(page) {
  const sidebar = page.locator(".MuiPaper-root", { has: page.locator("h2", { hasText: /panel settings/ }) }).first();
  const icons = sidebar.locator('button [data-testid="ErrorIcon"]');
  const out = [];
  for (let i = 0; i < (await icons.count()); i++) {
    await page.mouse.move(0, 0); // close the previous tooltip, which would cover the next icon
    await page.locator('[role="tooltip"]').waitFor({ state: "detached", timeout: 3000 }).catch(() => {});
    await icons.nth(i).hover({ timeout: 5000 });
    const tip = page.locator('[role="tooltip"]').last();
    await tip.waitFor({ timeout: 3000 }).catch(() => {});
    out.push((await tip.innerText().catch(() => "(no tooltip)")).trim());
  }
  await page.mouse.move(0, 0);
  return out;
}

async function openView(page, args, view, log) {
  const url = `${args.url}&layoutId=${encodeURIComponent(view.layout_id)}&time=${encodeURIComponent(view.time)}`;
  log.push({ type: "view", text: url });
  await page.goto(url);
  // the left sidebar's "Data source" page holds the Topics and Problems tabs
  const source = page.locator('button[data-sidebar-key="connection"]');
  await source.waitFor({ timeout: args.timeout_ms });
  if ((await source.getAttribute("aria-selected")) !== "true") await source.click();
  // loaded: every expected topic listed and the world panel's canvas present
  const deadline = Date.now() + args.timeout_ms;
  let topics = [];
  while (Date.now() < deadline) {
    topics = (await listedTopics(page)) ?? [];
    if (args.expected_topics.every((t) => topics.includes(t))) break;
    await page.waitForTimeout(500);
  }
  await page.waitForTimeout(4000); // the panels render the seeked frame
  // the app's one-time hints ("Open settings to configure topics and layers.") cover the panels
  for (let i = 0; i < 5; i++) {
    const dismiss = page.locator('[role="tooltip"] button[aria-label="Dismiss"]');
    if ((await dismiss.count()) === 0) break;
    await dismiss.first().click().catch(() => {});
    await page.waitForTimeout(300);
  }
  await page.mouse.move(0, 999);
  await page.waitForTimeout(500);
  if (view.screenshot) await page.screenshot({ path: view.screenshot });

  await page.getByRole("tab", { name: "Problems" }).click();
  await page.waitForTimeout(500);
  const problemsText = await page.evaluate(() => {
    const tab = [...document.querySelectorAll('[role="tab"]')].find((t) => /^Problems\b/.test(t.innerText.trim()));
    const tablist = tab?.closest('[role="tablist"]');
    if (!tablist) return "(problems list not found)";
    // the tab panel: the text that follows the tab list in its closest ancestor that has more
    let box = tablist;
    while (box && box.innerText.trim() === tablist.innerText.trim()) box = box.parentElement;
    if (!box) return "(problems list not found)";
    const text = box.innerText;
    return text.slice(text.indexOf(tablist.innerText) + tablist.innerText.length).trim();
  });
  const problems = problemsText === "No problems found" ? [] : problemsText.split("\n").filter((s) => s.trim());
  await page.getByRole("tab", { name: "Topics" }).click();

  // every 3D panel: open its settings and read the errors of its settings tree
  const panels = [];
  const containers = page.locator('[data-testid^="panel-mouseenter-container 3D!"]');
  for (let i = 0; i < (await containers.count()); i++) {
    const id = (await containers.nth(i).getAttribute("data-testid")).replace("panel-mouseenter-container ", "");
    await containers.nth(i).locator('[data-testid="SettingsIcon"]').first().click();
    await page.locator("h2", { hasText: "3D panel settings" }).first().waitFor({ timeout: 10000 });
    await page.waitForTimeout(800);
    panels.push({ panel: id, errors: await settingsErrors(page) });
  }
  return { url, topics, problems, panels };
}

(async () => {
  const args = JSON.parse(process.argv[2]);
  const context = await chromium.launchPersistentContext(args.profile, {
    executablePath: args.chromium, headless: true, viewport: { width: 1600, height: 1000 }, args: CHROMIUM_ARGS,
  });
  const page = await context.newPage();
  const log = [], pageErrors = [], failedRequests = [];
  page.on("console", (m) => log.push({ type: m.type(), text: m.text() }));
  page.on("pageerror", (e) => pageErrors.push(String(e)));
  // net::ERR_ABORTED is a request the page cancelled itself (the viewer's remote-file reader
  // drops range streams it no longer needs; leaving a page for the next view cancels the rest):
  // reported apart, as aborted_requests, and not a failure
  const aborted = [];
  page.on("requestfailed", (r) => {
    const why = r.failure()?.errorText;
    (why === "net::ERR_ABORTED" ? aborted : failedRequests).push(`${r.url()}: ${why}`);
  });
  page.on("response", (r) => { if (r.status() >= 400) failedRequests.push(`${r.url()}: HTTP ${r.status()}`); });
  const views = [];
  for (const view of args.views) {
    const start = log.length;
    const result = await openView(page, args, view, log);
    result.console = log.slice(start).filter((m) => m.type !== "view");
    views.push(result);
  }
  await context.close();
  process.stdout.write(JSON.stringify({ views, page_errors: pageErrors, failed_requests: failedRequests, aborted_requests: aborted }));
})().catch((e) => { console.error(e); process.exit(1); });
