"""Reference rasterizer vs an independent brute-force oracle (float64, loop over depth-sorted Gaussians)."""

from __future__ import annotations

import math

import pytest
import torch
from gsplat.cuda._torch_impl import _spherical_harmonics  # pure torch, CPU-safe, independent SH code

from physgs_nerfstudio.render import rasterize, reference_rasterization

W, H = 12, 10
DT = torch.float64


# ----------------------------------------------------------------------------------------------------------
# Oracle: written directly from gsplat's documented semantics, one Gaussian at a time, all pixels at once.
# ----------------------------------------------------------------------------------------------------------
def _rotation(q: torch.Tensor) -> torch.Tensor:
    """Rotate the basis vectors with v' = q v q*, column by column."""
    q = q / torch.sqrt((q * q).sum())
    w, u = q[0], q[1:]
    cols = []
    for e in torch.eye(3, dtype=q.dtype):
        cols.append(
            e + 2 * w * torch.linalg.cross(u, e) + 2 * torch.linalg.cross(u, torch.linalg.cross(u, e))
        )
    return torch.stack(cols, dim=1)


def oracle(means, quats, scales, opac, colors, viewmats, Ks, width, height, *, sh_degree=None, backgrounds=None,
           mode="RGB", tile_size=16, eps2d=0.3, near=0.01, far=1e10, antialiased=False):  # fmt: skip
    N, C = means.shape[0], viewmats.shape[0]
    imgs, alphas = [], []
    ys, xs = torch.meshgrid(torch.arange(height, dtype=DT), torch.arange(width, dtype=DT), indexing="ij")
    tile_x, tile_y = (
        torch.div(xs, tile_size, rounding_mode="floor"),
        torch.div(ys, tile_size, rounding_mode="floor"),
    )
    for c in range(C):
        Rv, tv = viewmats[c, :3, :3], viewmats[c, :3, 3]
        fx, fy, cx, cy = Ks[c, 0, 0], Ks[c, 1, 1], Ks[c, 0, 2], Ks[c, 1, 2]
        cam_center = -Rv.T @ tv
        recs = []
        for n in range(N):
            p = Rv @ means[n] + tv
            if not (near <= p[2].item() <= far):
                continue
            Rg = _rotation(quats[n])
            cov = Rv @ Rg @ torch.diag(scales[n] ** 2) @ Rg.T @ Rv.T
            limx = (width - cx) / fx + 0.15 * width / fx, cx / fx + 0.15 * width / fx
            limy = (height - cy) / fy + 0.15 * height / fy, cy / fy + 0.15 * height / fy
            u = torch.clamp(p[0] / p[2], -limx[1].item(), limx[0].item()) * p[2]
            v = torch.clamp(p[1] / p[2], -limy[1].item(), limy[0].item()) * p[2]
            J = torch.stack([torch.stack([fx / p[2], 0 * fx, -fx * u / p[2] ** 2]),
                             torch.stack([0 * fy, fy / p[2], -fy * v / p[2] ** 2])])  # fmt: skip
            cov2 = J @ cov @ J.T
            cov2b = cov2 + eps2d * torch.eye(2, dtype=DT)
            det = torch.linalg.det(cov2b)
            if det.item() <= 0:
                continue
            lam = torch.linalg.eigvalsh(cov2b.detach()).max().item()
            b = 0.5 * cov2b.trace().item()
            v1 = b + math.sqrt(max(0.01, b * b - det.item()))
            assert v1 >= lam - 1e-9
            r = math.ceil(3 * math.sqrt(v1))
            mu = torch.stack([fx * p[0] / p[2] + cx, fy * p[1] / p[2] + cy])
            if mu[0] + r <= 0 or mu[0] - r >= width or mu[1] + r <= 0 or mu[1] - r >= height:
                continue
            o = opac[n] * (torch.sqrt(torch.linalg.det(cov2) / det) if antialiased else 1.0)
            if sh_degree is None:
                col = colors[n]
            else:
                col = torch.clamp_min(
                    _spherical_harmonics(sh_degree, means[n] - cam_center, colors[n]) + 0.5, 0
                )
            if mode in ("D", "ED"):
                col = p[2:3]
            elif mode in ("RGB+D", "RGB+ED"):
                col = torch.cat([col, p[2:3]])
            tx0, tx1 = math.floor((mu[0].item() - r) / tile_size), math.ceil((mu[0].item() + r) / tile_size)
            ty0, ty1 = math.floor((mu[1].item() - r) / tile_size), math.ceil((mu[1].item() + r) / tile_size)
            in_tiles = (tile_x >= tx0) & (tile_x < tx1) & (tile_y >= ty0) & (tile_y < ty1)
            recs.append((p[2].item(), n, mu, torch.linalg.inv(cov2b), o, col, in_tiles))
        recs.sort(key=lambda rec: (rec[0], rec[1]))
        D = 1 if mode in ("D", "ED") else (colors.shape[-1] if sh_degree is None else 3) + ("+" in mode)
        acc = torch.zeros(height, width, D, dtype=DT)
        T = torch.ones(height, width, dtype=DT)
        done = torch.zeros(height, width, dtype=torch.bool)
        for _, _, mu, conic, o, col, in_tiles in recs:
            dx, dy = mu[0] - (xs + 0.5), mu[1] - (ys + 0.5)
            sigma = 0.5 * (conic[0, 0] * dx * dx + conic[1, 1] * dy * dy) + conic[0, 1] * dx * dy
            alpha = torch.clamp(o * torch.exp(-sigma), max=0.999)
            active = in_tiles & ~done & (sigma >= 0) & (alpha >= 1 / 255)
            t_next = T * (1 - alpha)
            stop = active & (t_next <= 1e-4)
            done = done | stop
            use = active & ~stop
            acc = acc + torch.where(use[..., None], (alpha * T)[..., None] * col, 0.0)
            T = torch.where(use, t_next, T)
        if backgrounds is not None:
            bg = backgrounds[c] if mode not in ("D", "ED") else torch.zeros(1, dtype=DT)
            if mode in ("RGB+D", "RGB+ED"):
                bg = torch.cat([bg, torch.zeros(1, dtype=DT)])
            acc = acc + T[..., None] * bg
        a = (1 - T)[..., None]
        if mode in ("ED", "RGB+ED"):
            acc = torch.cat([acc[..., :-1], acc[..., -1:] / a.clamp_min(1e-10)], -1)
        imgs.append(acc)
        alphas.append(a)
    return torch.stack(imgs), torch.stack(alphas)


# ----------------------------------------------------------------------------------------------------------
def look_at(eye, target) -> torch.Tensor:
    """World-to-camera (OpenCV: x right, y down, z forward)."""
    eye, target = torch.tensor(eye, dtype=DT), torch.tensor(target, dtype=DT)
    f = (target - eye) / (target - eye).norm()
    r = torch.linalg.cross(f, torch.tensor([0.0, -1.0, 0.0], dtype=DT))
    r = r / r.norm()
    d = torch.linalg.cross(f, r)
    R = torch.stack([r, d, f])
    vm = torch.eye(4, dtype=DT)
    vm[:3, :3], vm[:3, 3] = R, -R @ eye
    return vm


def make_scene(seed: int, n: int = 24, feat: tuple[int, ...] = (3,)) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g, dtype=DT) - 0.5) * torch.tensor([1.6, 1.4, 1.0], dtype=DT)
    means[0] = torch.tensor([0.0, 0.0, 0.0])  # an opaque stack on the axis of camera 0: early termination
    means[1] = torch.tensor([0.0, 0.0, 0.1])
    means[2] = torch.tensor([0.01, 0.0, 0.2])
    means[3] = torch.tensor([0.0, 0.0, -3.5])  # behind camera 0
    scales = 0.04 + 0.12 * torch.rand(n, 3, generator=g, dtype=DT)
    scales[:3] = 0.25
    quats = torch.randn(n, 4, generator=g, dtype=DT)
    opacities = 0.05 + 0.9 * torch.rand(n, generator=g, dtype=DT)
    opacities[:3] = 0.98
    colors = torch.rand(n, *feat, generator=g, dtype=DT) - (0.3 if len(feat) == 2 else 0.0)
    viewmats = torch.stack([look_at([0.0, 0.0, -3.0], [0, 0, 0]), look_at([2.2, -0.6, -1.8], [0.1, 0, 0.1])])
    Ks = torch.tensor(
        [[[11.0, 0, 6.1], [0, 10.0, 4.8], [0, 0, 1]], [[9.0, 0, 5.7], [0, 9.5, 5.2], [0, 0, 1]]], dtype=DT
    )
    return {
        "means": means,
        "quats": quats,
        "scales": scales,
        "opacities": opacities,
        "colors": colors,
        "viewmats": viewmats,
        "Ks": Ks,
    }


def _args(scene):
    return [scene[k] for k in ("means", "quats", "scales", "opacities", "colors", "viewmats", "Ks")]


def _check(
    scene, *, sh_degree=None, mode="RGB", backgrounds=None, tile_size=16, antialiased=False, packed=False
):
    params = {k: v.clone().requires_grad_(k not in ("viewmats", "Ks")) for k, v in scene.items()}
    bg = None if backgrounds is None else backgrounds.clone().requires_grad_(True)
    img, alpha, meta = reference_rasterization(
        *_args(params), W, H, sh_degree=sh_degree, render_mode=mode, backgrounds=bg, tile_size=tile_size,
        rasterize_mode="antialiased" if antialiased else "classic", packed=packed)  # fmt: skip
    meta["means2d"].retain_grad()
    params_o = {k: v.clone().requires_grad_(k not in ("viewmats", "Ks")) for k, v in scene.items()}
    bg_o = None if backgrounds is None else backgrounds.clone().requires_grad_(True)
    img_o, alpha_o = oracle(*_args(params_o), W, H, sh_degree=sh_degree, mode=mode, backgrounds=bg_o,
                            tile_size=tile_size, antialiased=antialiased)  # fmt: skip
    assert img.shape == img_o.shape and alpha.shape == alpha_o.shape == (2, H, W, 1)
    torch.testing.assert_close(img, img_o, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(alpha, alpha_o, rtol=1e-5, atol=1e-5)
    assert (alpha > 0.5).any() and (alpha < 0.01).any(), "scene should have both covered and empty pixels"

    g = torch.Generator().manual_seed(7)
    wi, wa = torch.randn(img.shape, generator=g, dtype=DT), torch.randn(alpha.shape, generator=g, dtype=DT)
    ((img * wi).sum() + (alpha * wa).sum()).backward()
    ((img_o * wi).sum() + (alpha_o * wa).sum()).backward()
    for k in ("means", "quats", "scales", "opacities", "colors"):
        got, want = params[k].grad, params_o[k].grad
        if mode in ("D", "ED") and k == "colors":
            assert got is None or not got.any()
            continue
        assert want is not None and want.abs().max() > 0, k
        torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-5 * float(want.abs().max()), msg=k)
    if backgrounds is not None and mode not in ("D", "ED"):
        torch.testing.assert_close(bg.grad, bg_o.grad, rtol=1e-5, atol=1e-7)
    grad2d = meta["means2d"].grad
    assert grad2d is not None and grad2d.shape == meta["means2d"].shape
    visible = meta["radii"] > 0
    assert grad2d[visible].abs().sum() > 0 and not grad2d[~visible].any()
    return meta


@pytest.mark.parametrize("sh_degree", [0, 1, 2, 3])
def test_sh_colors_match_oracle(sh_degree):
    scene = make_scene(sh_degree, feat=(16, 3))
    meta = _check(
        scene, sh_degree=sh_degree, backgrounds=torch.tensor([[0.2, 0.5, 0.9], [1.0, 0.0, 0.3]], dtype=DT)
    )
    assert meta["radii"].dtype == torch.int32 and meta["radii"].shape == (2, 24)
    assert meta["radii"][0, 3] == 0, "Gaussian behind camera 0 must be culled"


@pytest.mark.parametrize("mode", ["RGB", "D", "ED", "RGB+D", "RGB+ED"])
def test_render_modes_nd_features(mode):
    bg = torch.tensor([[0.1] * 5, [0.7] * 5], dtype=DT)
    _check(make_scene(11, feat=(5,)), mode=mode, backgrounds=bg if mode != "D" else None)


def test_small_tiles_antialiased_packed():
    meta = _check(make_scene(3, n=30), tile_size=4, antialiased=True, packed=True)
    assert meta["means2d"].dim() == 2 and meta["gaussian_ids"] is not None
    assert meta["camera_ids"].shape == meta["gaussian_ids"].shape == meta["radii"].shape


def test_tile_rule_excludes_pixels_outside_touched_tiles():
    """Beyond its 3-sigma square a big Gaussian still has alpha >= 1/255 but only counts in touched tiles."""
    width, height = 40, 8
    scene = {
        "means": torch.tensor(
            [[0.0, 0.0, 1.0]], dtype=DT
        ),  # mean2d x = cx = -3.2, radius 19: only tile 0 touched
        "quats": torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=DT),
        "scales": torch.full((1, 3), 0.3, dtype=DT),  # 6 px standard deviation
        "opacities": torch.tensor([0.95], dtype=DT),
        "colors": torch.tensor([[1.0, 0.5, 0.25]], dtype=DT),
        "viewmats": torch.eye(4, dtype=DT)[None],
        "Ks": torch.tensor([[[20.0, 0, -3.2], [0, 20.0, 4.0], [0, 0, 1]]], dtype=DT),
    }
    img, alpha, meta = reference_rasterization(*_args(scene), width, height, packed=False)
    img_o, alpha_o = oracle(*_args(scene), width, height)
    torch.testing.assert_close(alpha, alpha_o, rtol=1e-6, atol=1e-9)
    torch.testing.assert_close(img, img_o, rtol=1e-6, atol=1e-9)
    assert alpha[0, 4, 15, 0] > 1 / 255 and alpha[0, 4, 16, 0] == 0, "tile 1 must be left out"
    (a, b, c), (mx, my) = meta["conics"][0, 0], meta["means2d"][0, 0]
    dx, dy = 16.5 - mx, 4.5 - my
    assert meta["radii"][0, 0] == 19
    assert 0.95 * torch.exp(-(0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy)) > 1 / 255


def test_absgrad_and_meta_keys():
    scene = make_scene(4)
    params = {k: v.clone().requires_grad_(k == "means") for k, v in scene.items()}
    img, alpha, meta = reference_rasterization(
        *_args(params), W, H, packed=False, absgrad=True, max_pairs=150
    )
    for key in ("radii", "means2d", "depths", "width", "height", "n_cameras", "gaussian_ids", "tile_size",
                "camera_ids", "conics", "opacities"):  # fmt: skip
        assert key in meta
    assert (
        meta["width"] == W and meta["height"] == H and meta["n_cameras"] == 2 and meta["gaussian_ids"] is None
    )
    meta["means2d"].retain_grad()
    img.sum().backward()
    grad, absgrad = meta["means2d"].grad, meta["means2d"].absgrad
    assert (absgrad >= grad.abs() - 1e-12).all() and (absgrad > grad.abs() + 1e-6).any()
    # chunked + checkpointed (max_pairs=40) equals the single-chunk render
    params2 = {k: v.clone().requires_grad_(k == "means") for k, v in scene.items()}
    img2, alpha2, _meta2 = reference_rasterization(*_args(params2), W, H, packed=False)
    img2.sum().backward()
    torch.testing.assert_close(img, img2)
    torch.testing.assert_close(alpha, alpha2)
    torch.testing.assert_close(params["means"].grad, params2["means"].grad)


def test_float32_matches_float64():
    scene = make_scene(9)
    img64, a64, _ = reference_rasterization(*_args(scene), W, H)
    img32, a32, _ = reference_rasterization(*[t.float() for t in _args(scene)], W, H)
    assert img32.dtype == torch.float32
    torch.testing.assert_close(img32.double(), img64, atol=2e-5, rtol=1e-4)
    torch.testing.assert_close(a32.double(), a64, atol=2e-5, rtol=1e-4)


def test_dispatch_and_errors():
    scene = make_scene(1)
    img, _, meta = rasterize(*_args(scene), W, H)  # auto on CPU = reference
    assert meta["backend"] == "reference" and img.shape == (2, H, W, 3)
    from physgs_nerfstudio.render.projection import covariance_3d

    cov = covariance_3d(scene["quats"], scene["scales"])
    img_cov, _, _ = reference_rasterization(scene["means"], None, None, *_args(scene)[3:], W, H, covars=cov)
    torch.testing.assert_close(img_cov, img)
    with pytest.raises(RuntimeError, match="CUDA"):
        rasterize(*_args(scene), W, H, backend="gsplat")
    with pytest.raises(ValueError, match="backend"):
        rasterize(*_args(scene), W, H, backend="vulkan")
    with pytest.raises(NotImplementedError, match="pinhole"):
        reference_rasterization(*_args(scene), W, H, camera_model="fisheye")
    with pytest.raises(ValueError, match="SH"):
        reference_rasterization(*_args(scene), W, H, sh_degree=1)


def test_candidate_boxes_stay_inside_the_image_for_gaussians_beyond_its_edges():
    """Regression: a Gaussian centred past the right/bottom edge must give an empty, in-range box."""
    from physgs_nerfstudio.render.composite import _live_pixels_in_boxes, candidate_boxes

    width, height = 20, 12
    means2d = torch.tensor([[35.0, 5.0], [5.0, 30.0], [-9.0, -9.0], [10.0, 6.0]])
    covars2d = torch.tensor([[4.0, 0.0, 4.0]]).repeat(4, 1)
    opacities = torch.full((4,), 0.9)
    radii = torch.full((4,), 8, dtype=torch.int32)
    x0, x1, y0, y1 = candidate_boxes(means2d, covars2d, opacities, radii, width, height, tile_size=4)
    assert bool((x0 >= 0).all() and (x1 <= width).all() and (y0 >= 0).all() and (y1 <= height).all())
    done = torch.zeros(width * height, dtype=torch.bool)
    live = _live_pixels_in_boxes(done, (x0, x1, y0, y1), width, height)
    assert live[3] > 0 and bool((live >= 0).all())
