"""Evidence lifting: hand-computed weights, additivity over views, linearity, chunking, label maps."""

from __future__ import annotations

import math

import pytest
import torch

from physgs_nerfstudio.lifting import LiftResult, label_evidence_maps, lift_evidence, lift_views
from physgs_nerfstudio.render import reference_rasterization

DT = torch.float64
F, CX, CY, S = 20.0, 8.0, 8.0, 16  # one 16x16 tile: the tile rule plays no role in the hand computation


def _camera(tx: float) -> tuple[torch.Tensor, torch.Tensor]:
    vm = torch.eye(4, dtype=DT)
    vm[0, 3] = tx
    return vm, torch.tensor([[F, 0, CX], [0, F, CY], [0, 0, 1]], dtype=DT)


def separated_scene() -> dict[str, torch.Tensor]:
    """Four small isotropic Gaussians ~8 px apart at depth 2 (no overlap), plus one behind the cameras."""
    uv = torch.tensor([[4.3, 4.1], [11.6, 4.4], [4.2, 11.8], [11.5, 11.4]], dtype=DT)
    z = 2.0
    means = torch.cat([(uv - torch.tensor([CX, CY], dtype=DT)) * z / F, torch.full((4, 1), z, dtype=DT)], 1)
    means = torch.cat([means, torch.tensor([[0.0, 0.0, -1.0]], dtype=DT)])
    return {
        "means": means,
        "quats": torch.tensor([[1.0, 0, 0, 0]], dtype=DT).repeat(5, 1),
        "scales": torch.full((5, 3), 0.05, dtype=DT),
        "opacities": torch.tensor([0.9, 0.6, 0.99, 0.3, 0.9], dtype=DT),
    }


def hand_weights(scene: dict[str, torch.Tensor], tx: float) -> torch.Tensor:
    """Per-Gaussian weight maps [N, H, W] for an unrotated camera shifted by tx, Gaussians not overlapping:
    weight = alpha = min(0.999, o * exp(-d^T Sigma^-1 d / 2)), zero below 1/255 (T = 1 everywhere)."""
    out = torch.zeros(len(scene["means"]), S, S, dtype=DT)
    ys, xs = torch.meshgrid(torch.arange(S, dtype=DT) + 0.5, torch.arange(S, dtype=DT) + 0.5, indexing="ij")
    for g, (mean, s, o) in enumerate(zip(scene["means"], scene["scales"][:, 0], scene["opacities"])):
        x, y, z = mean[0] + tx, mean[1], mean[2]
        if z < 0.01:
            continue
        J = torch.tensor([[F / z, 0, -F * x / z**2], [0, F / z, -F * y / z**2]], dtype=DT)
        cov = s**2 * J @ J.T + 0.3 * torch.eye(2, dtype=DT)
        inv = torch.linalg.inv(cov)
        dx, dy = xs - (F * x / z + CX), ys - (F * y / z + CY)
        sigma = 0.5 * (inv[0, 0] * dx**2 + 2 * inv[0, 1] * dx * dy + inv[1, 1] * dy**2)
        alpha = torch.clamp(o * torch.exp(-sigma), max=0.999)
        out[g] = torch.where(alpha >= 1 / 255, alpha, 0.0)
    return out


def _lift(scene, cams, maps, **kw) -> LiftResult:
    vms = torch.stack([c[0] for c in cams])
    Ks = torch.stack([c[1] for c in cams])
    return lift_evidence(
        scene["means"], scene["quats"], scene["scales"], scene["opacities"], vms, Ks, S, S, maps, **kw
    )


def test_hand_computed_evidence_two_views():
    scene = separated_scene()
    cams = [_camera(0.0), _camera(0.13)]
    maps = torch.rand(2, S, S, 3, generator=torch.Generator().manual_seed(0), dtype=DT)
    res = _lift(scene, cams, maps, channel_chunk=2)
    want_e = torch.zeros(5, 3, dtype=DT)
    want_v = torch.zeros(5, dtype=DT)
    for v, (vm, _) in enumerate(cams):
        w = hand_weights(scene, float(vm[0, 3]))
        assert (w[:4].flatten(1) > 0).sum(0).max() <= 1, "hand computation assumes no overlap"
        want_e += torch.einsum("nhw,hwc->nc", w, maps[v])
        want_v += w.sum((1, 2))
    torch.testing.assert_close(res.evidence, want_e, rtol=1e-9, atol=1e-12)
    torch.testing.assert_close(res.visibility, want_v, rtol=1e-9, atol=1e-12)
    assert res.visibility[4] == 0 and not res.evidence[4].any(), "Gaussian behind the cameras sees nothing"
    assert (res.visibility[:4] > 1.0).all()


def _random_scene(seed: int, n: int = 40) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g, dtype=DT) - 0.5) * torch.tensor([1.6, 1.6, 0.8], dtype=DT)
    means[:, 2] += 2.0
    means[-1] = torch.tensor([5.0, 0.0, 2.0])  # far outside every view
    return {
        "means": means,
        "quats": torch.randn(n, 4, generator=g, dtype=DT),
        "scales": 0.03 + 0.1 * torch.rand(n, 3, generator=g, dtype=DT),
        "opacities": 0.1 + 0.85 * torch.rand(n, generator=g, dtype=DT),
    }


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_additive_over_views_and_linear_in_maps(seed):
    scene = _random_scene(seed)
    g = torch.Generator().manual_seed(seed + 100)
    cams = [_camera(0.0), _camera(-0.2), _camera(0.25)]
    e1, e2 = torch.rand(2, 3, S, S, 4, generator=g, dtype=DT)
    a, b = 0.7, -1.9
    full = _lift(scene, cams, a * e1 + b * e2)
    r1, r2 = _lift(scene, cams, e1), _lift(scene, cams, e2)
    torch.testing.assert_close(full.evidence, a * r1.evidence + b * r2.evidence, rtol=1e-9, atol=1e-10)
    torch.testing.assert_close(full.visibility, r1.visibility)
    per_view = [_lift(scene, [cams[v]], e1[v : v + 1]) for v in range(3)]
    torch.testing.assert_close(sum(r.evidence for r in per_view), r1.evidence, rtol=1e-9, atol=1e-10)
    torch.testing.assert_close(sum(r.visibility for r in per_view), r1.visibility, rtol=1e-9, atol=1e-10)
    assert r1.visibility[-1] == 0 and not r1.evidence[-1].any()
    assert (r1.visibility[:-1] > 0).sum() > 20

    # sum over Gaussians of the weights at a pixel is the rendered alpha
    vms, Ks = torch.stack([c[0] for c in cams]), torch.stack([c[1] for c in cams])
    _, alphas, _ = reference_rasterization(scene["means"], scene["quats"], scene["scales"], scene["opacities"],
                                           torch.zeros(len(scene["means"]), 1, dtype=DT), vms, Ks, S, S)  # fmt: skip
    torch.testing.assert_close(r1.visibility.sum(), alphas.sum(), rtol=1e-9, atol=1e-9)


def test_channel_chunking_and_pixel_weights():
    scene = _random_scene(4)
    cams = [_camera(0.0), _camera(0.1)]
    g = torch.Generator().manual_seed(5)
    maps = torch.rand(2, S, S, 7, generator=g, dtype=DT)
    ref = _lift(scene, cams, maps, channel_chunk=32)
    for chunk in (1, 3, 7, 8):
        res = _lift(scene, cams, maps, channel_chunk=chunk)
        torch.testing.assert_close(res.evidence, ref.evidence, rtol=1e-12, atol=1e-13)
        torch.testing.assert_close(res.visibility, ref.visibility, rtol=1e-12, atol=1e-13)
    mask = (torch.rand(2, S, S, generator=g) > 0.5).to(DT)
    masked = _lift(scene, cams, maps, pixel_weights=mask)
    torch.testing.assert_close(masked.evidence, _lift(scene, cams, maps * mask[..., None]).evidence)
    assert (
        masked.visibility <= ref.visibility + 1e-12
    ).all() and masked.visibility.sum() < ref.visibility.sum()


def test_views_per_call_keeps_the_views_apart():
    """Several cameras in one rasterizer call, each with its own feature rows: every view's evidence is what the
    call of that view alone gives, for any group size, with channel chunks and pixel weights."""
    scene = _random_scene(6)
    cams = [_camera(0.0), _camera(-0.2), _camera(0.25), _camera(0.1), _camera(-0.05)]
    g = torch.Generator().manual_seed(7)
    maps = torch.rand(5, S, S, 3, generator=g, dtype=DT)
    weights = (torch.rand(5, S, S, generator=g) > 0.3).to(DT)
    vms, Ks = torch.stack([c[0] for c in cams]), torch.stack([c[1] for c in cams])
    args = (scene["means"], scene["quats"], scene["scales"], scene["opacities"], vms, Ks, S, S, maps)
    alone = [_lift(scene, [cams[v]], maps[v : v + 1], pixel_weights=weights[v : v + 1], channel_chunk=2)
             for v in range(5)]  # fmt: skip
    for per_call in (1, 2, 3, 5, 8):
        seen = []
        for views, ev, vis in lift_views(*args, pixel_weights=weights, channel_chunk=2, views_per_call=per_call):
            assert ev.shape == (len(views), 40, 3) and vis.shape == (len(views), 40)
            for k, v in enumerate(views):
                torch.testing.assert_close(ev[k], alone[v].evidence, rtol=1e-12, atol=1e-13)
                torch.testing.assert_close(vis[k], alone[v].visibility, rtol=1e-12, atol=1e-13)
                seen.append(v)
        assert seen == list(range(5))
    assert sum(float(r.visibility.sum()) for r in alone) > 1.0
    with pytest.raises(ValueError, match="views_per_call"):
        next(lift_views(*args, views_per_call=0))


def test_no_gradient_into_geometry_and_errors():
    scene = {k: v.clone().requires_grad_(True) for k, v in _random_scene(6).items()}
    cams = [_camera(0.0)]
    with torch.no_grad():  # works inside no_grad too
        res = _lift(scene, cams, torch.ones(1, S, S, 2, dtype=DT))
    evidence, visibility = res
    assert evidence.shape == (40, 2) and visibility.shape == (40,)
    assert not res.evidence.requires_grad and all(v.grad is None for v in scene.values())
    torch.testing.assert_close(res.evidence[:, 0], res.visibility)
    with pytest.raises(ValueError, match="evidence_maps"):
        _lift(scene, cams, torch.ones(1, S, S + 1, 2, dtype=DT))
    with pytest.raises(RuntimeError, match="CUDA"):
        _lift(scene, cams, torch.ones(1, S, S, 2, dtype=DT), backend="gsplat")


def test_label_evidence_maps():
    labels = torch.tensor([[[0, 1], [3, 2]]])
    conf = torch.tensor([[[0.9, 0.5], [0.25, 1.0]]])
    ev = label_evidence_maps(labels, conf, num_classes=3)
    want = torch.tensor([[[[0, 0, 0], [0.5, 0, 0]], [[0, 0, 0.25], [0, 1.0, 0]]]])
    torch.testing.assert_close(ev, want)
    with pytest.raises(ValueError, match=r"\[0, 2\]"):
        label_evidence_maps(labels, conf, num_classes=2)
    with pytest.raises(ValueError, match="shape"):
        label_evidence_maps(labels, conf[..., :1], num_classes=3)
    assert math.isclose(float(ev.sum()), 1.75)


def test_group_views_runs_of_one_size_in_order():
    from physgs_nerfstudio.lifting import group_views

    sizes = [(8, 6), (8, 6), (8, 6), (4, 3), (8, 6), (8, 6)]
    assert group_views(sizes, 2) == [[0, 1], [2], [3], [4, 5]]
    assert group_views(sizes, 8) == [[0, 1, 2], [3], [4, 5]]
    assert group_views(sizes, 1) == [[i] for i in range(6)]
    assert group_views([], 4) == []
