// Renders Foxglove Studio's <App> the way the studio-web package of 1.48.0 does
// (packages/studio-web/src/index.tsx and Root.tsx), with two stand-ins for the pieces
// studio-web keeps to itself: an in-memory layout storage that already holds the layouts
// served as /layouts.json ({id: layout}, e.g. docs/foxglove_layout.json as "torchnav"),
// and an in-memory app configuration. The page is opened with
//   ?ds=remote-file&ds.url=<recording URL>&layoutId=torchnav
// so the app opens the recording and selects that layout, as a deep link does.
/* global React, ReactDOM */
(async () => {
  const fx = window; // the UMD bundle put its exports on the window
  for (const name of ["App", "migrateLayout", "initI18n", "overwriteFetch", "waitForFonts",
                      "RemoteDataSourceFactory", "McapLocalDataSourceFactory"]) {
    if (fx[name] == undefined) {
      throw new Error(`@foxglove/studio-base bundle does not export ${name}`);
    }
  }
  const response = await fetch("/layouts.json");
  if (!response.ok) {
    throw new Error(`GET /layouts.json: ${response.status}`);
  }
  const now = new Date().toISOString();
  const layouts = Object.entries(await response.json()).map(([id, data]) => fx.migrateLayout({
    id, name: id, permission: "CREATOR_WRITE",
    baseline: { data, savedAt: now }, working: undefined, syncInfo: undefined,
  }));

  class MemoryLayoutStorage {
    constructor() { this.byNamespace = new Map([["local", new Map(layouts.map((l) => [l.id, l]))]]); }
    async list(ns) { return Array.from(this.byNamespace.get(ns)?.values() ?? []); }
    async get(ns, id) { return this.byNamespace.get(ns)?.get(id); }
    async put(ns, item) {
      if (!this.byNamespace.has(ns)) { this.byNamespace.set(ns, new Map()); }
      this.byNamespace.get(ns).set(item.id, item);
      return item;
    }
    async delete(ns, id) { this.byNamespace.get(ns)?.delete(id); }
    async importLayouts() {}
  }

  class MemoryAppConfiguration {
    constructor() { this.values = new Map(); this.listeners = new Map(); }
    get(key) { return this.values.get(key); }
    async set(key, value) {
      this.values.set(key, value);
      for (const cb of this.listeners.get(key) ?? []) { cb(value); }
    }
    addChangeListener(key, cb) {
      if (!this.listeners.has(key)) { this.listeners.set(key, new Set()); }
      this.listeners.get(key).add(cb);
    }
    removeChangeListener(key, cb) { this.listeners.get(key)?.delete(cb); }
  }

  fx.overwriteFetch();
  await fx.waitForFonts();
  await fx.initI18n();
  const app = React.createElement(fx.App, {
    deepLinks: [window.location.href],
    dataSources: [new fx.RemoteDataSourceFactory(), new fx.McapLocalDataSourceFactory()],
    appConfiguration: new MemoryAppConfiguration(),
    layoutStorage: new MemoryLayoutStorage(),
    extensionLoaders: [],
    enableGlobalCss: true,
  });
  ReactDOM.render(React.createElement(React.StrictMode, null, app), document.getElementById("root"));
  console.debug("torchnav host page rendered the app");
})().catch((err) => {
  console.error(`torchnav host page: ${err && err.stack ? err.stack : err}`);
});
