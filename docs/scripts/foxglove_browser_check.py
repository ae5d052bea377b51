"""Open a recording in the prebuilt Foxglove web app in headless Chromium and check it.

The viewer is Foxglove Studio 1.48.0, whose prebuilt web bundle ships in the npm
package ``@foxglove/studio-base@1.48.0`` (a UMD library bundle: ``App`` and the data
sources on the window, React 17 as externals). ``foxglove_browser/index.html`` and
``boot.js`` host it the way Foxglove's own ``studio-web`` package does. The browser
is Debian's ``chromium``, driven by ``playwright-core`` (npm) through
``foxglove_browser/drive.cjs``; nothing downloads a browser.

Setup (once; see docs/foxglove.md)::

    apt-get install -y chromium nodejs npm
    npm install --prefix ~/.cache/torchnav/foxglove-web \\
        @foxglove/studio-base@1.48.0 react@17.0.2 react-dom@17.0.2 playwright-core@1.61.1

Run::

    python docs/scripts/foxglove_browser_check.py                    # a fresh recording
    python docs/scripts/foxglove_browser_check.py --recording runs/eval/x.mcap \\
        --screenshot docs/img/foxglove_browser.png --json result.json

It serves the recording, ``docs/foxglove_layout.json`` and the bundle on 127.0.0.1
(with HTTP range requests, which the viewer's remote-file source needs) and opens
``?ds=remote-file&ds.url=...&layoutId=torchnav&time=...`` twice: with the layout, and
with the layout's world view switched to the root frame ``world`` showing every
recorded env (``all_envs_layout``). For each it reports the topics the app lists, the
problems it shows, the errors in each 3D panel's settings tree and every console
message; it exits 1 when a topic is not listed, a problem or settings error is shown,
or the console has an error or a warning not in ``KNOWN_WARNINGS``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
from functools import partial
from http import HTTPStatus
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from torchnav.record.scene import ENV_SPACING  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent / "foxglove_browser"
LAYOUT = ROOT / "docs" / "foxglove_layout.json"
WEB_DIR = Path(os.environ.get("TORCHNAV_FOXGLOVE_WEB", Path.home() / ".cache" / "torchnav" / "foxglove-web"))
PACKAGES = {"@foxglove/studio-base": "1.48.0", "react": "17.0.2", "react-dom": "17.0.2", "playwright-core": "1.61.1"}
CHROMIUM = os.environ.get("TORCHNAV_CHROMIUM", "/usr/bin/chromium")
INSTALL_HINT = (
    "apt-get install -y chromium nodejs npm && npm install --prefix "
    f"{WEB_DIR} " + " ".join(f"{k}@{v}" for k, v in PACKAGES.items())
)


def missing_pieces(web_dir: Path = WEB_DIR) -> list[str]:
    """What this check needs and does not find (empty when it can run)."""
    missing = []
    if not Path(CHROMIUM).exists():
        missing.append(f"{CHROMIUM} (Debian package chromium)")
    node = shutil.which("node")
    if node is None:
        missing.append("node (Debian package nodejs)")
    else:
        version = subprocess.run([node, "--version"], capture_output=True, text=True).stdout.strip()
        major = re.match(r"v(\d+)\.", version)
        if major is None or int(major[1]) < 18:
            missing.append(f"node 18 or newer (found {version or 'no version'} at {node})")
    for name, version in PACKAGES.items():
        pkg = web_dir / "node_modules" / name / "package.json"
        if not pkg.exists():
            missing.append(f"npm package {name}@{version} in {web_dir}")
            continue
        found = json.loads(pkg.read_text())["version"]
        if found != version:
            missing.append(f"npm package {name}@{version} in {web_dir} (found {found})")
    return missing


class RangeHandler(SimpleHTTPRequestHandler):
    """Static files with single ``Range: bytes=a-b`` requests (206), which the viewer's
    remote-file source needs; ``routes`` maps URL prefixes to folders or files."""

    routes: dict[str, Path] = {}
    extensions_map = {**SimpleHTTPRequestHandler.extensions_map, ".wasm": "application/wasm",
                      ".js": "text/javascript", ".mjs": "text/javascript", ".mcap": "application/octet-stream"}

    def translate_path(self, path: str) -> str:
        path = path.split("?", 1)[0].split("#", 1)[0]
        for prefix, target in sorted(self.routes.items(), key=lambda kv: -len(kv[0])):
            if path == prefix or (target.is_dir() and prefix.endswith("/") and path.startswith(prefix)):
                rest = path[len(prefix):]
                resolved = (target / rest).resolve() if rest else target
                if target.is_dir() and not resolved.is_relative_to(target.resolve()):
                    return "/nonexistent"
                return str(resolved)
        return "/nonexistent"

    def send_head(self):
        spec = self.headers.get("Range")
        path = Path(self.translate_path(self.path))
        if spec is None or not path.is_file():
            return super().send_head()
        size = path.stat().st_size
        m = re.fullmatch(r"bytes=(\d*)-(\d*)", spec.strip())
        if m is None or (m[1] == "" and m[2] == ""):
            self.send_error(HTTPStatus.REQUESTED_RANGE_NOT_SATISFIABLE, f"unsupported Range {spec!r}")
            return None
        if m[1] == "":
            start, end = max(0, size - int(m[2])), size - 1
        else:
            start, end = int(m[1]), min(int(m[2]) if m[2] else size - 1, size - 1)
        if start >= size or start > end:
            self.send_response(HTTPStatus.REQUESTED_RANGE_NOT_SATISFIABLE)
            self.send_header("Content-Range", f"bytes */{size}")
            self.end_headers()
            return None
        f = path.open("rb")
        f.seek(start)
        self._remaining = end - start + 1
        self.send_response(HTTPStatus.PARTIAL_CONTENT)
        self.send_header("Content-Type", self.guess_type(str(path)))
        self.send_header("Content-Range", f"bytes {start}-{end}/{size}")
        self.send_header("Content-Length", str(self._remaining))
        self.send_header("Accept-Ranges", "bytes")
        self.end_headers()
        return f

    def end_headers(self):
        self.send_header("Accept-Ranges", "bytes")
        self.send_header("Cache-Control", "no-store")
        super().end_headers()

    def copyfile(self, source, outputfile):
        remaining = getattr(self, "_remaining", None)
        if remaining is None:
            return super().copyfile(source, outputfile)
        self._remaining = None
        while remaining > 0:
            chunk = source.read(min(remaining, 1 << 16))
            if not chunk:
                break
            outputfile.write(chunk)
            remaining -= len(chunk)

    def log_message(self, format, *args):  # noqa: A002 - the base class's name
        pass


def serve(routes: dict[str, Path]) -> tuple[ThreadingHTTPServer, str]:
    """Start a loopback server for ``routes`` in a daemon thread; returns it and its base URL."""
    handler = type("Handler", (RangeHandler,), {"routes": routes})
    server = ThreadingHTTPServer(("127.0.0.1", 0), partial(handler, directory=str(HERE)))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server, f"http://127.0.0.1:{server.server_address[1]}"


def make_recording(path: Path, episodes: int = 2) -> Path:
    """A fresh recording of the shipped arena policy, ``episodes`` episodes (envs 0 and 1), with
    odometry noise so that the odometry estimate drifts visibly away from the true pose."""
    cmd = [sys.executable, str(ROOT / "recipes" / "evaluate.py"), str(ROOT / "checkpoints" / "td3_arena_actor.pt"),
           "--episodes", "4", "--record", str(episodes), "--record-path", str(path), "--threads", "1",
           "--set", "robot.odom_v_noise=0.3", "robot.odom_omega_noise=0.6"]
    subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
    if not path.exists():
        raise RuntimeError(f"{' '.join(cmd)} wrote no recording at {path}")
    return path


def recorded_topics(path: Path) -> list[str]:
    from mcap.reader import make_reader

    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    if summary is None:
        raise RuntimeError(f"{path} has no summary section")
    return sorted(c.topic for c in summary.channels.values())


# Console warnings that are not about the recording or the layout, each with why it is harmless.
# Every other warning, and every error, fails the check.
KNOWN_WARNINGS = [
    (r"^Panel action resulted in identical config", "Foxglove's own notice when a layout is applied"),
    (r"^Disposing renderer$", "a 3D panel remounting while the app starts"),
    (r"GL Driver Message \(OpenGL, Performance, .*\): GPU stall due to ReadPixels",
     "Chromium's software WebGL (no GPU), on reading pixels back"),
    # A 3D panel starts before the first transform of the recording is read. Such an error stays
    # in the panel's settings tree until it is resolved, and the check reads those trees at the end
    # (``panels[i]["errors"]`` must be empty), so these lines are allowed only while that holds.
    (r'^\[general > followTf\] Frame "[^"]+" not found$', "3D panel started before the first transform"),
    (r"^\[layers > grid\] Missing transform from frame <[^>]+> to frame <\(none\)>$",
     "3D panel started before the first transform (no display frame yet)"),
]


def all_envs_layout(layout: dict, envs: list[int]) -> dict:
    """``layout`` with its world view in the root frame ``world``, showing every env in ``envs``
    side by side (scene and scan of each), zoomed out to fit them all."""
    out = json.loads(json.dumps(layout))
    view = out["configById"]["3D!world"]
    view["followTf"] = "world"
    span = ENV_SPACING * (len(envs) - 1)
    view["cameraState"].update(distance=max(view["cameraState"]["distance"], span + 20), targetOffset=[span / 2, 0, 0])
    for i in envs:
        for kind in ("scene", "scan"):
            view["topics"][f"/env{i}/{kind}"] = dict(view["topics"][f"/env0/{kind}"])
    return out


def seek_time(recording: Path, fraction: float = 0.7) -> float:
    """Seconds into ``recording`` at ``fraction`` of env 0's first episode (the robot under way)."""
    from torchnav.record import read_recording

    events = read_recording(recording).topic("/env0/events")
    if len(events) < 2:
        raise RuntimeError(f"{recording}: env 0 has no finished episode (events: {len(events)})")
    t0, t1 = events[0].log_time, events[1].log_time
    return (t0 + fraction * (t1 - t0)) / 1e9


def run_check(recording: Path, screenshot: Path | None = None, all_envs_screenshot: Path | None = None,
              web_dir: Path = WEB_DIR, timeout_s: float = 120, layout: Path = LAYOUT) -> dict:
    """Open ``recording`` in headless Chromium twice: with ``layout`` (view ``"layout"``) and with
    ``all_envs_layout`` of it (view ``"all_envs"``). Returns what the browser showed:
    ``expected_topics`` (the recording's), ``page_errors``, ``failed_requests`` and per view ``topics``
    (listed by the app), ``problems`` (its problems list), ``panels`` (each 3D panel's settings-tree
    errors) and ``console`` (every console message, ``{"type", "text"}``)."""
    missing = missing_pieces(web_dir)
    if missing:
        raise RuntimeError("missing: " + "; ".join(missing) + f". Install with: {INSTALL_HINT}")
    recording = Path(recording).resolve()
    expected = recorded_topics(recording)
    envs = sorted({int(m[1]) for t in expected if (m := re.match(r"/env(\d+)/", t))})
    data = json.loads(Path(layout).read_text())
    t = seek_time(recording)
    time = f"1970-01-01T00:00:{t:012.9f}Z"
    with tempfile.TemporaryDirectory(prefix="torchnav-foxglove-") as tmp:
        layouts = Path(tmp) / "layouts.json"
        layouts.write_text(json.dumps({"torchnav": data, "torchnav-all-envs": all_envs_layout(data, envs)}))
        server, base = serve({
            "/": HERE / "index.html",
            "/boot.js": HERE / "boot.js",
            "/layouts.json": layouts,
            "/vendor/": web_dir / "node_modules",
            "/recording.mcap": recording,
        })
        try:
            views = [{"name": "layout", "layout_id": "torchnav", "time": time, "screenshot": screenshot},
                     {"name": "all_envs", "layout_id": "torchnav-all-envs", "time": time, "screenshot": all_envs_screenshot}]
            args = {"url": f"{base}/?ds=remote-file&ds.url={base}/recording.mcap", "chromium": CHROMIUM,
                    "profile": str(Path(tmp) / "profile"), "timeout_ms": int(timeout_s * 1000), "expected_topics": expected,
                    "views": [{**v, "screenshot": str(Path(v["screenshot"]).resolve()) if v["screenshot"] else None} for v in views]}
            proc = subprocess.run(["node", str(HERE / "drive.cjs"), json.dumps(args)], capture_output=True, text=True,
                                  cwd=web_dir, env={**os.environ, "NODE_PATH": str(web_dir / "node_modules")},
                                  timeout=len(views) * (timeout_s + 60))
        finally:
            server.shutdown()
            server.server_close()
    if proc.returncode != 0:
        raise RuntimeError(f"drive.cjs failed ({proc.returncode}):\n{proc.stderr[-4000:]}")
    result = json.loads(proc.stdout)
    for view, spec in zip(result["views"], views):
        view["name"] = spec["name"]
    result["expected_topics"] = expected
    result["time_s"] = t
    return result


def failures(result: dict) -> list[str]:
    """What is wrong in ``run_check``'s result (empty when the recording opened cleanly)."""
    out = [f"page error: {e}" for e in result["page_errors"]]
    out += [f"request failed: {r}" for r in result["failed_requests"]]
    for view in result["views"]:
        name = view["name"]
        out += [f"{name}: topic {t} is not listed by the app" for t in result["expected_topics"] if t not in view["topics"]]
        out += [f"{name}: problem shown: {p}" for p in view["problems"]]
        if not any(p["panel"].startswith("3D") for p in view["panels"]):
            out.append(f"{name}: no 3D panel settings could be read")
        out += [f"{name}: {p['panel']} settings error: {e}" for p in view["panels"] for e in p["errors"]]
        for msg in view["console"]:
            if msg["type"] == "error" or (msg["type"] == "warning" and not known_warning(msg["text"])):
                out.append(f"{name}: console {msg['type']}: {msg['text']}")
    return out


def known_warning(text: str) -> str | None:
    """Why ``text`` is a harmless warning (``KNOWN_WARNINGS``), or None."""
    return next((why for pattern, why in KNOWN_WARNINGS if re.search(pattern, text)), None)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--recording", type=Path, help="MCAP file (default: a fresh recording, see make_recording)")
    p.add_argument("--screenshot", type=Path, help="write a PNG of the window with the layout here")
    p.add_argument("--all-envs-screenshot", type=Path, help="write a PNG of the all-envs view here")
    p.add_argument("--web-dir", type=Path, default=WEB_DIR, help=f"npm install folder (default {WEB_DIR})")
    p.add_argument("--json", type=Path, help="write the full result as JSON here")
    a = p.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="torchnav-foxglove-") as tmp:
        recording = a.recording or make_recording(Path(tmp) / "episodes.mcap")
        result = run_check(recording, a.screenshot, a.all_envs_screenshot, a.web_dir)
    if a.json:
        a.json.write_text(json.dumps(result, indent=1))
    print(f"recording topics ({len(result['expected_topics'])}), opened at {result['time_s']:.2f} s")
    for view in result["views"]:
        print(f"[{view['name']}] {view['url']}")
        print(f"  topics listed ({len(view['topics'])}): {', '.join(view['topics'])}")
        print(f"  problems: {view['problems'] or 'none'}")
        for panel in view["panels"]:
            print(f"  {panel['panel']} settings errors: {panel['errors'] or 'none'}")
        for msg in view["console"]:
            if msg["type"] in ("error", "warning"):
                why = known_warning(msg["text"]) if msg["type"] == "warning" else None
                print(f"  console {msg['type']}: {msg['text']}" + (f"   [known: {why}]" if why else ""))
    for line in result["page_errors"] + result["failed_requests"]:
        print(" ", line)
    bad = failures(result)
    for line in bad:
        print("FAIL:", line)
    print("OK" if not bad else f"{len(bad)} failure(s)")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
