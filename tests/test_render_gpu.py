"""Reference rasterizer vs gsplat.rasterization on CUDA (skipped without a GPU)."""

from __future__ import annotations

import pytest
import torch

from physgs_nerfstudio.lifting import lift_evidence, lift_views
from physgs_nerfstudio.render import rasterize

pytestmark = [
    pytest.mark.gpu,
    pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU for gsplat"),
]
W, H = 64, 48


def _scene(seed: int, n: int = 400, sh: bool = True) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g) - 0.5) * torch.tensor([2.0, 1.6, 1.0])
    means[:, 2] += 3.0
    vm2 = torch.eye(4)
    c, s = torch.cos(torch.tensor(0.3)), torch.sin(torch.tensor(0.3))
    vm2[:3, :3] = torch.tensor([[c, 0, -s], [0, 1, 0], [s, 0, c]])
    vm2[:3, 3] = torch.tensor([0.9, 0.1, 0.2])
    K = torch.tensor([[50.0, 0, 32.3], [0, 52.0, 23.6], [0, 0, 1]])
    scene = {
        "means": means,
        "quats": torch.randn(n, 4, generator=g),
        "scales": 0.01 + 0.06 * torch.rand(n, 3, generator=g),
        "opacities": 0.05 + 0.9 * torch.rand(n, generator=g),
        "colors": torch.randn(n, 16, 3, generator=g) * 0.4 if sh else torch.rand(n, 5, generator=g),
        "viewmats": torch.stack([torch.eye(4), vm2]),
        "Ks": torch.stack([K, K]),
    }
    return {k: v.cuda() for k, v in scene.items()}


def _max_diff(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).abs().max())


@pytest.mark.parametrize(
    ("sh", "mode", "raster_mode"),
    [(True, "RGB+ED", "classic"), (False, "RGB+D", "antialiased"), (True, "RGB", "classic")],
)
def test_reference_matches_gsplat(sh, mode, raster_mode):
    scene = _scene(0)
    if not sh:
        scene = _scene(1, sh=False)
    bg = torch.rand(2, 3 if sh else 5, device="cuda")
    outs = {}
    for backend in ("gsplat", "reference"):
        p = {k: v.clone().requires_grad_(k not in ("viewmats", "Ks")) for k, v in scene.items()}
        img, alpha, meta = rasterize(
            p["means"], p["quats"], p["scales"], p["opacities"], p["colors"], p["viewmats"], p["Ks"], W, H,
            sh_degree=3 if sh else None, render_mode=mode, backgrounds=bg, packed=False,
            rasterize_mode=raster_mode, absgrad=True, backend=backend,
        )  # fmt: skip
        meta["means2d"].retain_grad()
        g = torch.Generator(device="cuda").manual_seed(3)
        loss = (img * torch.randn(img.shape, generator=g, device="cuda")).sum() + (
            alpha * torch.randn(alpha.shape, generator=g, device="cuda")
        ).sum()
        loss.backward()
        outs[backend] = (
            img.detach(),
            alpha.detach(),
            meta,
            {k: v.grad for k, v in p.items() if v.grad is not None},
        )
    (img_g, a_g, m_g, gr_g), (img_r, a_r, m_r, gr_r) = outs["gsplat"], outs["reference"]
    report = {
        "colors": _max_diff(img_g[..., :3], img_r[..., :3]),
        "alphas": _max_diff(a_g, a_r),
        "radii": _max_diff(m_g["radii"].float(), m_r["radii"].float()),
        "means2d.grad": _max_diff(m_g["means2d"].grad, m_r["means2d"].grad),
        "means2d.absgrad": _max_diff(m_g["means2d"].absgrad, m_r["means2d"].absgrad),
    }
    if "D" in mode:
        report["depth"] = _max_diff(img_g[..., -1], img_r[..., -1])
    for k in gr_g:
        report[f"grad {k}"] = _max_diff(gr_g[k], gr_r[k]) / max(float(gr_g[k].abs().max()), 1e-12)
    print(f"\n[{mode} {raster_mode} sh={sh}] max abs diffs (grads relative to max |grad|):")
    for k, v in report.items():
        print(f"  {k:20s} {v:.3e}")
    assert report["radii"] == 0
    assert report["colors"] < 2e-4 and report["alphas"] < 2e-4
    if "ED" in mode:
        assert report["depth"] < 2e-3
    elif "D" in mode:
        assert report["depth"] < 1e-3
    for k in gr_g:
        assert report[f"grad {k}"] < 2e-3, k
    scale = float(m_g["means2d"].grad.abs().max())
    assert report["means2d.grad"] < 2e-3 * scale and report["means2d.absgrad"] < 2e-3 * scale


def test_lifting_both_backends():
    scene = _scene(2, sh=False)
    maps = torch.rand(2, H, W, 5, device="cuda")
    args = [scene[k] for k in ("means", "quats", "scales", "opacities", "viewmats", "Ks")]
    res = {b: lift_evidence(*args, W, H, maps, backend=b, channel_chunk=4) for b in ("gsplat", "reference")}
    e_diff = _max_diff(res["gsplat"].evidence, res["reference"].evidence)
    v_diff = _max_diff(res["gsplat"].visibility, res["reference"].visibility)
    print(f"\n[lifting] evidence max abs diff {e_diff:.3e}, visibility {v_diff:.3e}, "
          f"max visibility {float(res['gsplat'].visibility.max()):.2f}")  # fmt: skip
    assert e_diff < 1e-3 * float(res["gsplat"].evidence.abs().max())
    assert v_diff < 1e-3 * float(res["gsplat"].visibility.max())


def test_lifting_views_in_one_call_match_the_reference_view_by_view():
    """gsplat with both cameras in one call (per-camera feature rows) against the reference rasterizer's views
    one at a time (lift_views)."""
    scene = _scene(3, sh=False)
    maps = torch.rand(2, H, W, 3, device="cuda")
    args = [scene[k] for k in ("means", "quats", "scales", "opacities", "viewmats", "Ks")]
    (_, ev, vis), = list(lift_views(*args, W, H, maps, backend="gsplat", views_per_call=2))
    ref = list(lift_views(*args, W, H, maps, backend="reference", views_per_call=1))
    for k, (_, ev_r, vis_r) in enumerate(ref):
        assert _max_diff(ev[k], ev_r[0]) < 1e-3 * float(ev_r.abs().max())
        assert _max_diff(vis[k], vis_r[0]) < 1e-3 * float(vis_r.max())
    assert float(vis[0].sum()) > 1.0 and float(vis[1].sum()) > 1.0


def test_depth_renders_of_views_in_one_call_match_one_view_at_a_time():
    """geometry.render_depth on gsplat with both views in one call against gsplat one view at a time, and its
    surface depth against the reference rasterizer's."""
    from types import SimpleNamespace

    from physgs_nerfstudio.geometry.capture import CaptureView
    from physgs_nerfstudio.geometry.gaussians import render_depth

    scene = _scene(5, sh=False)
    views = [CaptureView(scene["viewmats"][i].cpu(), scene["Ks"][i].cpu(), W, H, torch.zeros(H, W, dtype=torch.bool),
                         name=f"v{i}") for i in range(2)]  # fmt: skip
    g = SimpleNamespace(**{k: scene[k] for k in ("means", "quats", "scales", "opacities")})
    g_cpu = SimpleNamespace(**{k: v.cpu() for k, v in vars(g).items()})
    batched = render_depth(g, views, backend="gsplat")
    single = [render_depth(g, [v], backend="gsplat")[0] for v in views]
    ref = render_depth(g_cpu, views, backend="reference")
    for a, b, r in zip(batched, single, ref):
        solid = r.alpha > 0.5
        assert int(solid.sum()) > 50
        for x, y in ((a.alpha, b.alpha), (a.depth[solid], b.depth[solid])):
            torch.testing.assert_close(x, y, rtol=1e-4, atol=1e-4)
        assert _max_diff(a.alpha.cpu(), r.alpha) < 2e-3
        assert _max_diff(a.depth.cpu()[solid], r.depth[solid]) < 2e-3 * float(r.depth[solid].max())
