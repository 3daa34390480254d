#!/usr/bin/python3
"""The 3D viewer of a run's file in the browser (docs/viewer.md).

    tools/cvt_view.py results.h5                   # serves the viewer, prints its address, opens a browser
    tools/cvt_view.py results.h5 --port 0 --no-browser
    tools/cvt_view.py results.h5 --video run.webm  # records the 3D view with headless Chromium
    tools/cvt_view.py results.h5 --screenshot view.png --at 0.08   # the page at t = 0.08 s as PNG

The page (tools/viewer/) and its libraries (tools/viewer/node_modules: three.js and h5wasm,
installed by `make deps` from the lockfile) are served from the repository on loopback;
the file is served as run.h5. The run needs snapshots (run.snapshot_interval > 0).
"""
import argparse
import http.server
import os
import shutil
import subprocess
import sys
import threading
import urllib.parse
import webbrowser

VIEWER = os.path.join(os.path.dirname(os.path.abspath(__file__)), "viewer")
TYPES = {".js": "text/javascript", ".mjs": "text/javascript", ".html": "text/html", ".wasm": "application/wasm"}


def handler(run_file):
    class Handler(http.server.SimpleHTTPRequestHandler):
        def __init__(self, *a, **k):
            super().__init__(*a, directory=VIEWER, **k)

        def translate_path(self, path):
            if path.split("?")[0] == "/run.h5":
                return run_file
            return super().translate_path(path)

        def guess_type(self, path):
            return TYPES.get(os.path.splitext(path)[1]) or super().guess_type(path)

        def log_message(self, *a):
            pass
    return Handler


def serve(run_file, port):
    """The server on 127.0.0.1 (port 0: any free one), running in a thread."""
    srv = http.server.ThreadingHTTPServer(("127.0.0.1", port), handler(os.path.abspath(run_file)))
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    name = urllib.parse.quote(os.path.basename(run_file))
    return srv, f"http://127.0.0.1:{srv.server_address[1]}/index.html?name={name}"


def check(run_file):
    if not os.path.isfile(run_file):
        sys.exit(f"cvt_view: {run_file}: no such file")
    if not os.path.isdir(os.path.join(VIEWER, "node_modules", "three")):
        sys.exit("cvt_view: tools/viewer/node_modules is missing: run `make deps` (npm ci in tools/viewer)")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("file", help="a run's HDF5 file with snapshots")
    ap.add_argument("--port", type=int, default=8765, help="port on 127.0.0.1 (0: any free one)")
    ap.add_argument("--no-browser", action="store_true", help="do not open a browser")
    ap.add_argument("--video", help="record the 3D view to this WebM file with headless Chromium, then exit")
    ap.add_argument("--screenshot", help="a PNG of the whole page with headless Chromium, then exit")
    ap.add_argument("--at", default="", help="with --screenshot: the model time shown [s] (default: the last snapshot)")
    ap.add_argument("--fps", type=int, default=30, help="video frames per second (one snapshot per frame)")
    ap.add_argument("--size", default="1280x720", help="video size WxH")
    a = ap.parse_args()
    check(a.file)
    srv, url = serve(a.file, a.port)
    if a.video or a.screenshot:
        node = shutil.which("node")
        if not node:
            sys.exit("cvt_view: node is missing: run `make deps`")
        r = subprocess.run([node, os.path.join(VIEWER, "record.mjs"), url, a.video or a.screenshot, str(a.fps),
                            a.size, a.at])
        srv.shutdown()
        sys.exit(r.returncode)
    print(f"cvt_view: {a.file} at {url}  (Ctrl-C stops)", flush=True)
    if not a.no_browser:
        webbrowser.open(url)
    try:
        threading.Event().wait()
    except KeyboardInterrupt:
        srv.shutdown()


if __name__ == "__main__":
    main()
