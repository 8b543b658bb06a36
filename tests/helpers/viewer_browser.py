"""Drive nerfstudio's web viewer (`ns-viewer`) with headless Chromium as a user would: show the density output,
click a point it colours, copy its JSON, enable the crop box and press Mass.

Used by test_viewer_browser.py; as a script it takes docs/viewer.md's screenshots of a trained run:

    python tests/helpers/viewer_browser.py --load-config outputs/.../config.yml --out docs/

Needs Debian's `chromium` (`apt-get install chromium`) and the `playwright` Python package (only its driver is
used: Playwright's own browser download is never needed, the system Chromium is launched).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

CHROMIUM_ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]  # WebGL on the CPU


def chromium_path() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_viewer(config: Path, port: int, log: Path) -> subprocess.Popen:
    """`ns-viewer` on the CPU, as a user starts it (the project's PYTHONPATH is kept)."""
    exe = shutil.which("ns-viewer")
    cmd = [exe] if exe else [sys.executable, "-m", "nerfstudio.scripts.viewer.run_viewer"]
    cmd += ["--load-config", str(config), "--viewer.websocket-port", str(port)]
    env = dict(os.environ, OMP_NUM_THREADS=os.environ.get("OMP_NUM_THREADS", "1"))
    return subprocess.Popen(cmd, stdout=log.open("w"), stderr=subprocess.STDOUT, env=env)


def wait_http(port: int, proc: subprocess.Popen, timeout: float = 300) -> None:
    import urllib.request

    t0 = time.time()
    while time.time() - t0 < timeout:
        if proc.poll() is not None:
            raise RuntimeError(f"ns-viewer exited with code {proc.returncode}")
        try:
            urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=2)
            return
        except OSError:
            time.sleep(2)
    raise TimeoutError(f"ns-viewer did not serve http://127.0.0.1:{port}/ within {timeout} s")


def _wait(predicate, timeout: float, what: str, step: float = 1.0) -> Any:
    t0 = time.time()
    while time.time() - t0 < timeout:
        value = predicate()
        if value:
            return value
        time.sleep(step)
    raise TimeoutError(f"waited {timeout:.0f} s for {what}")


def _select(page, label: str, value: str) -> None:
    page.get_by_label(label, exact=True).first.click()
    page.get_by_role("option", name=value, exact=True).click()


def _panel_text(page) -> str:
    """The text of the "physical_properties" folder (its title's parent holds the folder's content)."""
    return page.get_by_text("physical_properties", exact=True).first.locator("xpath=..").inner_text()


def _panel_if(page, pattern: str) -> str | None:
    text = _panel_text(page)
    return text if re.search(pattern, text) else None


def _canvas(page, path: Path) -> tuple[dict, np.ndarray]:
    """Screenshot of the part of the 3-D canvas left of the GUI panel."""
    box = page.locator("canvas").first.bounding_box()
    panel = page.get_by_text("Connected").bounding_box()
    clip = {"x": box["x"], "y": box["y"], "width": panel["x"] - box["x"] - 10, "height": box["height"]}
    page.screenshot(path=str(path), clip=clip)
    return clip, np.asarray(Image.open(path).convert("RGB")).astype(float)


def _figure(page, path: Path, scroll_to: str) -> None:
    """The page, with the panel scrolled to the text ``scroll_to`` (the GUI panel scrolls on its own)."""
    page.get_by_text(scroll_to).first.evaluate("e => e.scrollIntoView({block: 'start'})")
    time.sleep(1)
    page.screenshot(path=str(path))


def _wait_render(page, timeout: float = 300) -> None:
    """The viewer's static frame at Max res has arrived (the stats line shows the full resolution)."""
    _wait(lambda: re.search(r"Resolution: (\d+)x\d+px", page.inner_text("body"))
          and int(re.search(r"Resolution: (\d+)x", page.inner_text("body")).group(1)) >= 256,  # type: ignore[union-attr]
          timeout, "the full-resolution render")  # fmt: skip


def drive(url: str, out: Path, *, mass_timeout: float = 900) -> dict[str, Any]:
    """The user session (module doc). Returns the point JSON, the panel's text after the click and after Mass,
    and the click's position; saves screenshots into ``out``."""
    from playwright.sync_api import sync_playwright

    out.mkdir(parents=True, exist_ok=True)
    res: dict[str, Any] = {}
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium_path(), headless=True, args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 1500, "height": 1100})
        page.goto(url, wait_until="domcontentloaded")
        page.get_by_text("physical_properties").wait_for(timeout=300_000)
        _select(page, "Output type", "density")
        time.sleep(2)
        _wait_render(page)
        clip, img = _canvas(page, out / "viewer_density_raw.png")
        # a known point: near the middle of the pixels the density output colours (turbo colours are bright and
        # saturated; where nothing was measured it shows RGB dimmed to 0.3)
        hi, lo = img.max(-1) / 255, img.min(-1) / 255
        ys, xs = np.nonzero((hi > 0.45) & ((hi - lo) / np.maximum(hi, 1e-6) > 0.45))
        if len(xs) == 0:
            raise AssertionError("the density output colours no pixel: nothing measured to click")
        order = np.argsort((xs - np.median(xs)) ** 2 + (ys - np.median(ys)) ** 2)
        x, y = float(xs[order[0]]), float(ys[order[0]])
        res["click_canvas_px"] = (x, y)
        page.get_by_role("button", name="Pick a point").click()
        time.sleep(1)
        page.mouse.click(clip["x"] + x, clip["y"] + y)
        res["point_text"] = _wait(lambda: _panel_if(page, r"Evidence|Not measured|failed"), 300, "the click's answer")
        field = page.locator("xpath=//label[normalize-space()='Point JSON']/following::input[1]")
        before = field.input_value()
        page.get_by_role("button", name="Point as JSON").click()
        res["json"] = json.loads(_wait(lambda: field.input_value() not in ("", before) and field.input_value(), 60,
                                       "the point JSON"))  # fmt: skip
        time.sleep(3)
        _wait_render(page)
        _figure(page, out / "viewer_click.png", "Pick a point")
        page.get_by_label("Enable", exact=True).nth(1).check()  # Crop Viewport (the second "Enable")
        time.sleep(3)
        page.get_by_role("button", name="Mass", exact=True).click()
        res["mass_text"] = _wait(lambda: _panel_if(page, r"interval \[|Mass failed"), mass_timeout, "the mass", step=3)
        time.sleep(3)
        _wait_render(page)
        res["mass_text"] = _panel_text(page)
        _figure(page, out / "viewer_mass.png", "Draw a rectangle")
        browser.close()
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--load-config", type=Path, required=True)
    ap.add_argument("--out", type=Path, default=Path("docs"))
    args = ap.parse_args()
    run_dir = args.load_config.parent
    port = free_port()
    proc = start_viewer(args.load_config, port, run_dir / "viewer_browser.log")
    try:
        wait_http(port, proc)
        res = drive(f"http://127.0.0.1:{port}", args.out)
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    print(json.dumps({k: v for k, v in res.items() if k != "json"}, indent=1))


if __name__ == "__main__":
    main()
