"""Fusion: per-pixel Dirichlet maps, per-material NIG posteriors, dataset writer."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from physgs_nerfstudio.fusion import MapFusionConfig, fuse_properties, fuse_view, update_transforms
from physgs_nerfstudio.materials import PROPERTY_KEYS, load_library


def test_fuse_view_matches_a_per_pixel_loop():
    rng = np.random.default_rng(0)
    M, H, W, K = 5, 9, 11, 4
    masks = rng.random((M, H, W)) < 0.4
    levels = ["whole", "part", "subpart", "part", "whole"]
    om = rng.integers(0, M, 12)
    oc = rng.integers(0, K, 12)
    op = rng.random(12)
    cfg = MapFusionConfig()
    maps = fuse_view(masks, levels, om, oc, op, K, cfg)
    for y in range(H):
        for x in range(W):
            ev = np.zeros(K)
            for m, c, p in zip(om, oc, op):
                if masks[m, y, x]:
                    ev[c] += cfg.level_weights[levels[m]] * p
            if ev.sum() == 0:
                assert maps.labels[y, x] == 0 and maps.confidence[y, x] == 0
                continue
            pi = (cfg.alpha0 + cfg.lam * ev) / (cfg.alpha0 + cfg.lam * ev).sum()
            assert maps.labels[y, x] == pi.argmax() + 1
            assert maps.confidence[y, x] == pytest.approx(pi.max(), rel=1e-5)


def test_finer_level_wins_over_whole():
    masks = np.zeros((2, 4, 4), bool)
    masks[0] = True  # whole object says class 0
    masks[1, :2, :2] = True  # a part inside says class 1 with the same confidence
    maps = fuse_view(masks, ["whole", "part"], [0, 1], [0, 1], [0.9, 0.9], 2)
    assert (maps.labels[:2, :2] == 2).all() and (maps.labels[2:, 2:] == 1).all()


def _obs(material, conf, **props):
    p = {k: None for k in PROPERTY_KEYS}
    p.update(props)
    return {"view": "v", "mask_id": 0, "material": material, "confidence": conf, "properties": p}


def test_property_posteriors_closed_form_and_log_space():
    lib = load_library("indoor")
    obs = [
        _obs("steel", 0.8, density=7900.0, kinetic_friction=0.5),
        _obs("steel", 0.4, density=7700.0),
        _obs("oak", 1.0, kinetic_friction=0.3, density=float("nan")),
        _obs("unknown_thing", 1.0, density=1.0),
    ]
    post = fuse_properties(obs, lib)
    assert post.names == ["oak", "steel"] and post.num_observations == [1, 2]
    d = PROPERTY_KEYS.index("density")
    prior = lib.nig_prior(["steel"])
    k0, t0 = float(prior.kappa[0, d]), float(prior.tau[0, d])
    W = 1.2
    S = 0.8 * math.log(7900) + 0.4 * math.log(7700)
    assert float(post.posterior.kappa[1, d]) == pytest.approx(k0 + W)
    assert float(post.posterior.tau[1, d]) == pytest.approx((k0 * t0 + S) / (k0 + W))
    # oak's density was not reported: posterior = prior for that property
    oak_prior = lib.nig_prior(["oak"])
    assert float(post.posterior.tau[0, d]) == pytest.approx(float(oak_prior.tau[0, d]))
    f = PROPERTY_KEYS.index("kinetic_friction")
    assert float(post.posterior.kappa[0, f]) == pytest.approx(float(oak_prior.kappa[0, f]) + 1.0)


def test_update_transforms_keeps_every_key(tmp_path):
    data = {
        "camera_model": "OPENCV",
        "w": 4,
        "extra": {"nested": [1, 2]},
        "frames": [
            {"file_path": "images/a.png", "transform_matrix": [[1]], "mask_path": "m/a.png"},
            {"file_path": "images/b.png", "transform_matrix": [[2]]},
        ],
    }
    (tmp_path / "transforms.json").write_text(json.dumps(data))
    update_transforms(tmp_path, {"images/a.png": ("materials/labels/a.png", "materials/confidence/a.png")})
    out = json.loads((tmp_path / "transforms.json").read_text())
    assert out["extra"] == data["extra"] and list(out) == list(data)
    assert (
        out["frames"][0]["mask_path"] == "m/a.png"
        and out["frames"][0]["material_path"] == "materials/labels/a.png"
    )
    assert "material_path" not in out["frames"][1]
    assert json.loads((tmp_path / "transforms.json.bak").read_text()) == data
    update_transforms(tmp_path, {"images/b.png": ("x.png", "y.png")})
    assert json.loads((tmp_path / "transforms.json.bak").read_text()) == data  # backup of the original kept


def test_fuse_view_input_checks():
    with pytest.raises(ValueError, match="level weight"):
        fuse_view(np.ones((1, 2, 2), bool), ["tiny"], [0], [0], [1.0], 1)
    with pytest.raises(ValueError, match="mask ids"):
        fuse_view(np.ones((1, 2, 2), bool), ["part"], [3], [0], [1.0], 1)
    assert torch.is_tensor(torch.zeros(1))


def test_jsonable_gives_plain_json_types() -> None:
    from dataclasses import dataclass
    from pathlib import Path

    from physgs_nerfstudio.fusion.writer import jsonable

    @dataclass
    class Cfg:
        path: Path
        sizes: tuple[int, int]
        budget: float

    doc = jsonable({1: Cfg(Path("a/b"), (2, 3), math.inf), "x": [np.float32(0.5), np.int64(4), np.bool_(True)]})
    assert doc == {"1": {"path": "a/b", "sizes": [2, 3], "budget": None}, "x": [0.5, 4, True]}
    assert json.loads(json.dumps(doc, allow_nan=False)) == doc  # strict JSON: no Infinity / NaN
