"""A real browser: `ns-viewer` on a tiny trained scene (CPU), opened in headless Chromium (Debian's `chromium`),
a click on a labelled point and the Mass button, checked against `physgs export` with the same selection.

Skipped without a system Chromium or the `playwright` package (tests/helpers/viewer_browser.py says how to get them).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from helpers.viewer_browser import chromium_path, drive, free_port, start_viewer, wait_http

pytestmark = pytest.mark.slow


def _physgs() -> list[str]:
    exe = shutil.which("physgs")
    return [exe] if exe else [sys.executable, "-m", "physgs_nerfstudio.cli"]


@pytest.mark.skipif(chromium_path() is None, reason="no system Chromium (apt-get install chromium)")
def test_click_and_mass_in_a_real_browser(viewer_run, tmp_path):
    pytest.importorskip("playwright.sync_api", reason="pip install playwright (its browser download is not needed)")
    config, data, _ = viewer_run
    names = [m["name"] for m in json.loads((data / "materials.json").read_text())["materials"]]
    shots = Path(os.environ.get("PHYSGS_VIEWER_SCREENSHOTS", tmp_path / "shots"))
    port = free_port()
    proc = start_viewer(config, port, tmp_path / "ns-viewer.log")
    try:
        wait_http(port, proc)
        res = drive(f"http://127.0.0.1:{port}", shots)
    finally:
        proc.terminate()
        proc.wait(timeout=60)
    log = (tmp_path / "ns-viewer.log").read_text()
    assert "Traceback" not in log, log[-3000:]

    # the click: a measured point, and the panel shows what the JSON holds
    q = res["json"]
    assert q["hit"] and q["measured"], res["point_text"]
    top = q["materials"][0]
    assert top["name"] in names and f"{top['name']} {top['probability']:.0%}" in res["point_text"]
    assert f"seen in {q['evidence']['views']:.1f} training views" in res["point_text"]
    for key in ("density", "kinetic_friction", "youngs_modulus"):
        assert q["properties"][key]["mean"] > 0 and q["properties"][key]["epistemic_std"] >= 0
    assert q["properties"]["shore_hardness"]["shore"]["scale"] in ("A", "D")

    # Mass: the panel's numbers are `physgs export`'s for the same box and point
    m = re.search(r"report: (\S+report\.json)", res["mass_text"])
    assert m, res["mass_text"]
    viewer_report = json.loads(Path(m.group(1)).read_text())
    assert Path(m.group(1)).parent.parent == config.parent / "viewer_mass"  # beside the config
    sel = viewer_report["selection"]
    assert sel["source"] == "crop box"
    cmd = _physgs() + ["export", "--load-config", str(config), "--output-dir", str(tmp_path / "export"),
                       "--outputs", "mass", "--mass.geometry.select.bbox", *map(repr, sel["bbox_scene"])]  # fmt: skip
    if viewer_report["point_scene"] is not None:
        cmd += ["--mass.geometry.select.point", *map(repr, viewer_report["point_scene"])]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=900, check=False)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    exported = json.loads((tmp_path / "export" / "report.json").read_text())["mass"]
    ours = viewer_report["mass"]
    for key in ("mean_kg", "median_kg", "interval_kg", "volume_m3"):
        assert ours[key] == pytest.approx(exported[key], rel=1e-9), key
    text = res["mass_text"]
    assert f"{exported['mean_kg']:.4g} kg" in text
    assert f"interval [{exported['interval_kg'][0]:.4g}, {exported['interval_kg'][1]:.4g}] kg" in text
    for mat in exported["materials"]:
        if mat["mass_share"] >= 1e-3 or mat["volume_share"] >= 1e-3:
            assert f"{mat['name']}: {mat['mass_share']:.0%} of the mass" in text, mat["name"]
    for name in ("viewer_click.png", "viewer_mass.png"):
        assert (shots / name).stat().st_size > 10_000
