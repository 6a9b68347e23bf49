"""What the 3-D page (``tensegrity-sim view``) weighs and how fast it plays, in headless chromium.

    python3 bench/bench_view.py [--duration 10] [--scenes icosahedron,tower20]

For each scene: a logged run of ``--duration`` s (the structure kicked at 1 s so that it moves), then
``view``. Prints the page's size and frames, the CPU time to read the log and write the page, the
wall-clock time the browser takes to show it, and the frame rate of stepping through the first
``--frames`` frames (each ``Plotly.animate`` awaited, no pause between frames: the fastest the page
can play), per second of wall-clock time and per second of the browser's CPU time (all its processes:
what a loaded machine changes least). The browser is Debian's chromium, headless, with software WebGL
(``--disable-gpu``): a desktop with a GPU draws faster, so the rates are a floor. It is driven over the
DevTools protocol with websocket-client (the "test" extra).
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np
import websocket
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from tensegrity_sim import formfinding, load_scene  # noqa: E402
from tensegrity_sim.cli import main  # noqa: E402
from tensegrity_sim.ros.record import read_log  # noqa: E402
from tensegrity_sim.viz.page import write_page  # noqa: E402

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run", "--window-size=1200,900",
         # a page nobody looks at gets its timers cut to one a second, and Plotly.animate waits on timers
         "--disable-background-timer-throttling", "--disable-renderer-backgrounding",
         "--disable-backgrounding-occluded-windows"]

PLAY = """(async () => {
  const gd = document.getElementById('tensegrity-view');
  const names = gd.layout.sliders[0].steps.map(s => s.args[0][0]).slice(0, %d);
  const t0 = performance.now();
  for (const n of names) {
    await Plotly.animate(gd, [n], {frame: {duration: 0, redraw: true}, transition: {duration: 0},
                                   mode: 'immediate'});
  }
  return JSON.stringify({frames: names.length, seconds: (performance.now() - t0) / 1000});
})()"""


def scene_file(name: str, folder: Path) -> str:
    """A built-in scene, or ``towerN``: an N-stage tower from form-finding, without gravity (tall ones
    buckle under it), as bench_steps.py builds them."""
    if name.startswith("tower") and name[5:].isdigit():
        path = folder / f"{name}.yaml"
        path.write_text(yaml.safe_dump(formfinding.tower(int(name[5:]), gravity=(0.0, 0.0, 0.0))))
        return str(path)
    return name


def kick(scene: str, folder: Path) -> Path:
    """A schedule pushing the top node sideways for 50 ms at 1 s (10 N per kg of the structure)."""
    s = load_scene(scene)
    top = int(np.argmax(s.positions[:, 2]))
    force = 10.0 * float(s.masses.sum())
    path = folder / "kick.yaml"
    path.write_text(yaml.safe_dump([{"time": 1.0, "forces": {s.node_names[top]: [force, 0.0, 0.0]}},
                                    {"time": 1.05, "forces": {s.node_names[top]: [0.0, 0.0, 0.0]}}]))
    return path


class Browser:
    """Headless chromium with its DevTools protocol on a local port, one page driven over WebSocket."""

    def __init__(self, chromium: str, profile: Path):
        self.proc = subprocess.Popen([chromium, *FLAGS, f"--user-data-dir={profile}", "--remote-debugging-port=0",
                                      "about:blank"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        port_file = profile / "DevToolsActivePort"
        deadline = time.monotonic() + 60
        while not (port_file.exists() and port_file.read_text().strip()):
            if time.monotonic() > deadline:
                raise RuntimeError("chromium did not open its DevTools port")
            time.sleep(0.1)
        port = int(port_file.read_text().split()[0])
        targets = json.load(urllib.request.urlopen(f"http://127.0.0.1:{port}/json"))
        url = next(t["webSocketDebuggerUrl"] for t in targets if t["type"] == "page")
        self.ws = websocket.create_connection(url, timeout=600, suppress_origin=True)
        self.next_id = 0

    def call(self, method: str, **params):
        self.next_id += 1
        self.ws.send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        while True:
            reply = json.loads(self.ws.recv())
            if reply.get("id") == self.next_id:
                return reply.get("result")

    def evaluate(self, expression: str):
        result = self.call("Runtime.evaluate", expression=expression, awaitPromise=True, returnByValue=True)
        return result["result"].get("value")

    def close(self):
        self.ws.close()
        self.proc.terminate()
        self.proc.wait()


def cpu_seconds(pid: int) -> float:
    """User + system CPU time (s) of process ``pid`` and all its descendants, from /proc."""
    total = 0.0
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        total = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        for task in Path(f"/proc/{pid}/task").iterdir():
            total += sum(cpu_seconds(int(c)) for c in (task / "children").read_text().split())
    except (FileNotFoundError, ProcessLookupError):
        pass  # a process that has just ended
    return total


def measure(browser: Browser, page: Path, frames: int) -> dict:
    start = time.perf_counter()
    browser.call("Page.navigate", url=page.as_uri())
    while not browser.evaluate("!!(window.Plotly && document.getElementById('tensegrity-view') && "
                               "document.getElementById('tensegrity-view')._fullLayout)"):
        time.sleep(0.05)
    shown = time.perf_counter() - start
    cpu = cpu_seconds(browser.proc.pid)
    played = json.loads(browser.evaluate(PLAY % frames))
    cpu = cpu_seconds(browser.proc.pid) - cpu
    return {"shown_s": shown, "fps": played["frames"] / played["seconds"], "fps_cpu": played["frames"] / cpu}


def run(args) -> None:
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        sys.exit("bench_view: no chromium (apt-get install chromium)")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        browser = Browser(chromium, folder / "profile")
        try:
            print(f"{'scene':<12} {'struts':>6} {'cables':>6} {'frames':>6} {'page MB':>8} {'write CPU s':>11} "
                  f"{'shown s':>8} {'frames/s':>9} {'frames/CPU s':>12}")
            for name in args.scenes.split(","):
                scene = scene_file(name, folder)
                log = folder / f"{name}.mcap"
                with contextlib.redirect_stdout(io.StringIO()):  # the run's summary: not the table's
                    assert main(["run", scene, "--duration", str(args.duration), "--quiet", "--log", str(log),
                                 "--commands", str(kick(scene, folder))]) == 0
                page = folder / f"{name}.html"
                start = time.process_time()  # CPU time: what a loaded machine does not change
                _, frames = write_page(read_log(log), page)
                written = time.process_time() - start
                s = load_scene(scene)
                m = measure(browser, page, args.frames)
                print(f"{name:<12} {len(s.struts):>6} {len(s.cables):>6} {frames:>6} "
                      f"{page.stat().st_size / 1e6:>8.1f} {written:>11.1f} {m['shown_s']:>8.1f} {m['fps']:>9.1f} "
                      f"{m['fps_cpu']:>12.1f}", flush=True)
        finally:
            browser.close()


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=10.0, help="simulated time per run, s (default: 10)")
    parser.add_argument("--frames", type=int, default=60, help="frames played for the rate (default: 60)")
    parser.add_argument("--scenes", default="icosahedron,tower20",
                        help="built-in scenes or towerN, comma-separated (default: icosahedron,tower20)")
    run(parser.parse_args())
