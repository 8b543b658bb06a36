"""Active querying: the selection policy and the resumable run through the perception backends."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from helpers.perception_scene import make_scene

from physgs_nerfstudio.materials import load_library
from physgs_nerfstudio.perception import PerceptionConfig, run_perception
from physgs_nerfstudio.perception.active import ActiveConfig, ActiveSelector, run_active_perception
from physgs_nerfstudio.perception.replay import ReplayConfig
from physgs_nerfstudio.perception.segment import Mask
from physgs_nerfstudio.perception.simulated import SimulatedConfig


@pytest.fixture(scope="module")
def library():
    return load_library("indoor")


class PartSegmenter:
    """Masks from the scene's ground-truth part maps (one per part plus the whole object), by image hash."""

    def __init__(self, root: Path):
        from PIL import Image

        gt = json.loads((root / "ground_truth.json").read_text())
        self._maps = {}
        for fr in gt["frames"]:
            img = np.asarray(Image.open(root / fr["file_path"]).convert("RGB"))
            self._maps[hashlib.sha256(img.tobytes()).hexdigest()] = np.asarray(Image.open(root / (fr.get("part_path") or fr["part"])))

    def fingerprint(self) -> str:
        return "test-part-segmenter"

    def segment(self, image):
        part = self._maps[hashlib.sha256(np.ascontiguousarray(image).tobytes()).hexdigest()]
        out = [Mask(part > 0, int((part > 0).sum()), 1.0, 1.0, "whole")]
        for pid in (1, 2, 3):
            m = part == pid
            out.append(Mask(m, int(m.sum()), 1.0, 1.0, "part"))
        return out


def _selector(library, views=2, **cfg):
    # each view: two disjoint 4x4 masks (left / right) with different colours
    masks, levels, feats = {}, {}, {}
    for v in range(views):
        a = np.zeros((8, 8), bool)
        a[:, :4] = True
        masks[f"v{v}"] = np.stack([a, ~a])
        levels[f"v{v}"] = ["part", "part"]
        feats[f"v{v}"] = np.array([[50.0, 40.0, 0.0], [50.0, -40.0, 0.0]])
    return ActiveSelector([f"v{v}" for v in range(views)], masks, levels, feats, library, ActiveConfig(**cfg))


def rec(material, conf, density):
    return {"material": material, "confidence": conf,
            "properties": {"density": density, "kinetic_friction": 0.5, "shore_hardness": 100.0, "youngs_modulus": 1e9}}


def test_selector_scores_drop_where_labelled(library):
    sel = _selector(library, transfer=0.0)
    s0 = sel.scores()
    assert np.allclose(s0, s0[0])  # nothing known: all equal
    for _ in range(5):
        sel.done[0] = False  # allow repeated answers on the same mask (stronger evidence)
        sel.observe("v0", 0, [rec("ceramic", 1.0, 2300.0)])
    s = sel.scores(with_exploration=False)
    assert s[0] == -np.inf  # answered
    # v0's right mask: no pixel evidence -> still maximally uncertain; the exploration bonus now only
    # applies to v1
    s_expl = sel.scores()
    assert s_expl[2] > s_expl[1]
    # with transfer, the left mask of v1 (same colour as the answered one) becomes less uncertain
    sel_t = _selector(library, transfer=1.0)
    sel_t.observe("v0", 0, [rec("ceramic", 1.0, 2300.0)])
    st = sel_t.scores(with_exploration=False)
    assert st[2] < st[3]


def test_selector_batch_is_diverse_and_complete(library):
    sel = _selector(library, views=3, batch_size=2)
    first = sel.select(2)
    assert len(set(first)) == 2
    # diversity: the second pick does not have the colour of the first (same-colour masks are damped)
    f = [sel.features[sel.cand.index(q)] for q in first]
    assert not np.allclose(f[0], f[1])
    seen = set()
    batch = first
    while batch:
        for q in batch:
            assert q not in seen
            seen.add(q)
            sel.observe(*q, [rec("ceramic", 0.9, 2300.0)])
        batch = sel.select(2)
    assert len(seen) == 6 and sel.remaining() == 0
    assert sel.uncertainty() == 0.0


def test_property_term_decreases_with_observations(library):
    sel = _selector(library, transfer=0.0, w_material=0.0, exploration=0.0)
    k = sel.index["ceramic"]
    r0 = sel._ratio[k]
    vals = [2250.0, 2350.0, 2300.0, 2280.0, 2320.0, 2310.0]
    for i, d in enumerate(vals):
        sel.done[0] = False
        sel.observe("v0", 0, [rec("ceramic", 1.0, d)])
    assert sel._ratio[k] < r0 or r0 < 0.05
    assert 0 <= sel._ratio[k] < 1


def _config(root, **kw):
    return PerceptionConfig(data=root, vlm=SimulatedConfig(), progress=False, max_concurrency=2, **kw)


def test_run_active_budget_resume_and_outputs(tmp_path, library):
    root = make_scene(tmp_path / "scene", num_views=3)
    seg = PartSegmenter(root)
    res = run_active_perception(_config(root), ActiveConfig(budget=5, batch_size=2), segmenter=seg, library=library)
    assert res.candidates == 12
    assert res.answered == 5 and len(res.queried) == 5
    assert res.calls == 5 and res.stop_reason.startswith("query budget")
    lines = [json.loads(x) for x in (root / "observations.jsonl").read_text().splitlines()]
    assert lines and {"view", "mask_id", "level", "material", "confidence", "properties", "backend", "model",
                      "simulated", "request_key"} <= set(lines[0])
    assert all(x["simulated"] for x in lines)
    assert len({(x["view"], x["mask_id"]) for x in lines}) <= 5
    assert (root / "materials.json").is_file()
    log = json.loads((root / "perception" / "active.json").read_text())
    assert log["answered"] == 5
    # resume with a larger budget: only new masks are queried
    res2 = run_active_perception(_config(root), ActiveConfig(budget=8, batch_size=2), segmenter=seg, library=library)
    assert res2.resumed_masks == 5 and res2.answered == 8 and len(res2.queried) == 3
    assert not set(map(tuple, res.queried)) & set(map(tuple, res2.queried))
    # the exhaustive pipeline continues from the same store (same fingerprint) and answers the rest
    full = run_perception(_config(root), segmenter=seg, library=library)
    assert full.resumed_masks == 8 and full.calls == 4


def test_run_active_stop_uncertainty_and_replay(tmp_path, library):
    root = make_scene(tmp_path / "scene", num_views=2)
    seg = PartSegmenter(root)
    res = run_active_perception(_config(root), ActiveConfig(stop_uncertainty=10.0), segmenter=seg, library=library)
    assert res.answered == 0 and "uncertainty" in res.stop_reason
    # fill the cache, then replay answers everything from it without calling the simulator
    run_active_perception(_config(root, overwrite=True), ActiveConfig(budget=4), segmenter=seg, library=library)
    rep = run_active_perception(
        PerceptionConfig(data=root, vlm=ReplayConfig(source="simulated"), progress=False, overwrite=True),
        ActiveConfig(budget=4), segmenter=seg, library=library,
    )
    assert rep.answered == 4 and rep.calls == 0 and rep.cache_hits == 4


def test_perceive_command_active_flags(tmp_path):
    """`physgs perceive --active --query-budget N --stop-uncertainty X --active-batch-size B` parses into an
    ActiveConfig and runs run_active_perception (builtin segmenter, simulated VLM)."""
    import tyro

    from physgs_nerfstudio.perception import ActiveConfig as ExportedActiveConfig
    from physgs_nerfstudio.perception import run_active_perception as exported_run
    from physgs_nerfstudio.perception.command import PerceiveCommand, summary_table

    assert ExportedActiveConfig is ActiveConfig and exported_run is run_active_perception
    root = make_scene(tmp_path / "scene", num_views=2)
    cmd = tyro.cli(PerceiveCommand, args=["--data", str(root), "--no-progress", "--active",
                                          "--query-budget", "3", "--stop-uncertainty", "0.01",
                                          "--active-batch-size", "2", "vlm:simulated"])
    assert cmd.active_config() == ActiveConfig(budget=3, stop_uncertainty=0.01, batch_size=2)
    res = cmd.run()
    assert res.answered == 3 and len(res.queried) == 3 and res.stop_reason.startswith("query budget")
    assert res.candidates > 3  # the budget, not the candidates, stopped it
    assert json.loads((root / "perception" / "active.json").read_text())["config"]["batch_size"] == 2
    assert (root / "materials.json").is_file()
    import io

    from rich.console import Console

    console = Console(record=True, width=200, file=io.StringIO())
    console.print(summary_table(res))
    assert "active: masks answered / candidates" in console.export_text()
    # without --active the same command is the exhaustive run (it resumes the 3 answered masks)
    full = tyro.cli(PerceiveCommand, args=["--data", str(root), "--no-progress", "vlm:simulated"]).run()
    assert not hasattr(full, "stop_reason") and full.resumed_masks == 3
    with pytest.raises(ValueError, match="only apply with --active"):
        PerceiveCommand(data=root, vlm=SimulatedConfig(), query_budget=3)
    with pytest.raises(ValueError, match="batch_size"):
        PerceiveCommand(data=root, vlm=SimulatedConfig(), active=True, active_batch_size=0)


def test_save_masks_round_trips_an_empty_mask_list(tmp_path):
    from physgs_nerfstudio.perception.segment import load_masks, save_masks

    path = tmp_path / "m.npz"
    save_masks(path, [], (6, 9), "fp")
    assert load_masks(path, "fp") == []
    m = np.zeros((6, 9), bool)
    m[1:3, 2:7] = True
    save_masks(path, [Mask(m, int(m.sum()), 0.9, 0.8, "part")], (6, 9), "fp")
    (back,) = load_masks(path, "fp")
    assert np.array_equal(back.segmentation, m) and back.level == "part" and back.area == 10
