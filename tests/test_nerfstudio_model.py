"""PhysGSModel on CPU: outputs, densification of the per-Gaussian tensors, lifting / prior, checkpoints, loss."""

from __future__ import annotations

import pytest
import torch
from gsplat.strategy.ops import duplicate, remove, split
from nerfstudio.data.scene_box import SceneBox
from nerfstudio.engine.optimizers import Optimizers
from helpers.nerfstudio_scenes import blob_datamanager, blob_model

from method_configs.physgs_config import physgs_lite_trainer_config
from physgs_nerfstudio.bayes import vacuity
from physgs_nerfstudio.nerfstudio import PhysGSModelConfig
from physgs_nerfstudio.nerfstudio.model import EVIDENCE_KEY, LOGITS_KEY, WEIGHT_KEY, PhysGSModel
from physgs_nerfstudio.nerfstudio.pipeline import lift_material_maps

OUTPUTS_1CH = ("material_id", "depth", "accumulation")
OUTPUTS_3CH = ("rgb", "material", "background", "density", "friction", "hardness", "stiffness", "aleatoric",
               "epistemic", "total_uncertainty")  # property outputs are colours on fixed scales (viewer/display.py)


@pytest.fixture(scope="module")
def blob_dm(tmp_path_factory):
    return blob_datamanager(tmp_path_factory.mktemp("blob"))


def make_model(dm, **config) -> PhysGSModel:
    """A model with the "logits" material head (these tests are about its logits; test_material_head.py covers
    every head), whatever the default head is."""
    config.setdefault("material_head", "logits")
    return blob_model(dm, **config)


def lift(model: PhysGSModel, dm, confidence_scale: float = 1.0) -> torch.Tensor:
    """The pipeline's lifting pass over the training views (confidences scaled, labels unchanged), handed to the
    model; returns the evidence."""
    cameras, cached = dm.material_views("train")
    if confidence_scale != 1.0:
        cached = [dict(d, material_confidence=(d["material_confidence"].float() * confidence_scale).to(torch.uint8))
                  for d in cached]  # fmt: skip
    lifted = lift_material_maps(model, cameras, cached)
    model.set_material_evidence(lifted)
    return lifted.evidence


def attach_optimizers(model: PhysGSModel) -> Optimizers:
    opt = Optimizers(physgs_lite_trainer_config().optimizers, model.get_param_groups())
    model.step_cb(opt, 0)
    return opt


def test_outputs_on_cpu(blob_dm) -> None:
    model = make_model(blob_dm)
    K = model.num_materials
    assert K == 2 and LOGITS_KEY in model.gauss_params and EVIDENCE_KEY in model.gauss_params
    cam, batch = blob_dm.next_train(0)
    model.train()
    out = model.get_outputs(cam)
    H, W = batch["image"].shape[:2]
    md = model.config.material_downscale  # step 0: a material step; logits are rendered md x smaller
    assert out["rgb"].shape == (H, W, 3) and out["material_logits"].shape == (H // md, W // md, K)
    model.step = 1  # not a material step: splatfacto's RGB pass only
    assert "material_logits" not in model.get_outputs(cam)
    model.eval()
    with torch.no_grad():
        out = model.get_outputs_for_camera(blob_dm.eval_dataset.cameras[0:1])
    for key in OUTPUTS_1CH:
        assert out[key].shape == (H, W, 1), key
        assert torch.isfinite(out[key]).all(), key
    for key in OUTPUTS_3CH:
        assert out[key].shape == (H, W, 3), key
    assert "material_logits" not in out  # not a viewer output (K channels)
    # unlifted: nothing was measured, so no pixel gets a property colour (dimmed RGB everywhere)
    for key in ("density", "epistemic"):
        assert torch.allclose(out[key], model.viewer_settings.dim * out["rgb"]), key
    # unlifted: every Gaussian holds the prior -> density is the prior mixture mean everywhere
    props = model.gaussian_properties()
    assert torch.allclose(props["mean"], props["mean"][:1].expand_as(props["mean"]))


def test_loss_and_metrics(blob_dm) -> None:
    model = make_model(blob_dm)
    attach_optimizers(model)
    model.train()
    cam, batch = blob_dm.next_train(0)
    out = model.get_outputs(cam)
    losses = model.get_loss_dict(out, batch, model.get_metrics_dict(out, batch))
    assert "material_loss" in losses and float(losses["material_loss"]) > 0
    sum(losses.values()).backward()
    assert model.material_logits.grad is not None and model.material_logits.grad.abs().sum() > 0
    # a view without a material map: no material loss, no gradient into the logits
    model.material_logits.grad = None
    batch0 = dict(batch, material=torch.zeros_like(batch["material"]))
    out = model.get_outputs(cam)
    losses = model.get_loss_dict(out, batch0)
    assert float(losses["material_loss"]) == 0.0
    losses["material_loss"].backward()
    assert model.material_logits.grad is None or model.material_logits.grad.abs().sum() == 0


def test_densification_keeps_per_gaussian_tensors_in_sync(blob_dm) -> None:
    model = make_model(blob_dm)
    attach_optimizers(model)
    n0, K = model.num_points, model.num_materials
    with torch.no_grad():  # distinctive rows: row i carries i in every per-Gaussian extra
        ids = torch.arange(n0, dtype=torch.float32)[:, None]
        model.gauss_params[LOGITS_KEY].copy_(ids.expand(n0, K))
        model.gauss_params[EVIDENCE_KEY].copy_(ids.expand(n0, K) + 0.5)
        model.gauss_params[WEIGHT_KEY].copy_(ids + 0.25)
    # one real training step so that the optimizers have state, then force the strategy's operations
    model.train()
    cam, batch = blob_dm.next_train(0)
    out = model.get_outputs(cam)
    sum(model.get_loss_dict(out, batch).values()).backward()
    for o in model.optimizers.values():
        o.step()
    params, optim, state = model.gauss_params, model._strategy_optimizers(), {}
    dup_mask = torch.zeros(n0, dtype=torch.bool)
    dup_mask[:5] = True
    duplicate(params, optim, state, dup_mask)
    split_mask = torch.zeros(model.num_points, dtype=torch.bool)
    split_mask[5:8] = True
    split(params, optim, state, split_mask)
    prune_mask = torch.zeros(model.num_points, dtype=torch.bool)
    prune_mask[-1:] = True  # split children are appended as [a, b, c, a, b, c]: prunes the last c
    remove(params, optim, state, prune_mask)
    n1 = model.num_points
    assert n1 == n0 + 5 + 3 - 1
    for name, p in model.gauss_params.items():
        assert p.shape[0] == n1, name
    for name in ("means", LOGITS_KEY):
        st = model.optimizers[name].state[model.gauss_params[name]]
        assert st["exp_avg"].shape == model.gauss_params[name].shape
    rows = model.material_logits[:, 0].round().long()
    counts = torch.bincount(rows, minlength=n0)
    assert torch.all(counts[:5] == 2)  # duplicated: original + clone carry the same logits
    assert counts[5:8].tolist() == [2, 2, 1]  # split into two children (one pruned)
    assert torch.all(counts[8:] == 1)
    assert torch.equal(model.dirichlet_evidence[:, 0] - 0.5, model.material_logits[:, 0].detach())
    assert torch.equal(model.gauss_params[WEIGHT_KEY][:, 0] - 0.25, model.material_logits[:, 0].detach())
    # the model's own callback path (gsplat DefaultStrategy through step_post_backward) with forced growth
    model.strategy.refine_start_iter, model.strategy.grow_grad2d = 0, -1.0
    model.strategy.pause_refine_after_reset = 0
    model.step_cb(Optimizers(physgs_lite_trainer_config().optimizers, model.get_param_groups()), 100)
    out = model.get_outputs(cam)
    sum(model.get_loss_dict(out, batch).values()).backward()
    n_before = model.num_points
    model.step_post_backward(100)
    assert model.num_points > n_before
    for name, p in model.gauss_params.items():
        assert p.shape[0] == model.num_points, name
    assert not model.dirichlet_evidence.requires_grad and model.material_logits.requires_grad


def test_lifting_prior_for_unseen_and_checkpoint(blob_dm) -> None:
    model = make_model(blob_dm)
    n_scene = model.num_points
    with torch.no_grad():  # 50 Gaussians far outside every camera's view
        far = torch.randn(50, 3) * 0.1 + torch.tensor([0.0, 0.0, 40.0])
        for name, p in list(model.gauss_params.items()):
            extra = p[:50].clone() if name != "means" else far
            model.gauss_params[name] = torch.nn.Parameter(
                torch.cat([p, extra]), requires_grad=p.requires_grad
            )
    model.eval()
    evidence = lift(model, blob_dm)
    assert int(model.lifted_views) == len(blob_dm.train_dataset) - sum(
        int(d["material"].max()) == 0 for d in blob_dm.cached_train
    )
    alpha = model.dirichlet_alpha()
    unseen = slice(n_scene, None)
    assert torch.all(evidence[unseen] == 0)
    assert torch.allclose(alpha[unseen], torch.full_like(alpha[unseen], model.alpha0))
    assert torch.allclose(vacuity(alpha[unseen]), torch.ones(50))
    seen = evidence[:n_scene].sum(-1) > 0.05
    assert seen.float().mean() > 0.5
    props = model.gaussian_properties()
    epi = props["epistemic"]
    total = evidence[:n_scene].sum(-1)
    # well observed AND consistently labelled (a Gaussian on a material boundary stays ambiguous, rightly)
    strong = (total > 1.0) & (evidence[:n_scene].max(-1).values > 0.8 * total)
    assert strong.sum() > 50
    # never seen: the prior's epistemic (material ambiguity included), above every well-observed Gaussian's
    assert torch.allclose(epi[unseen], epi[unseen][:1].expand(50, -1))
    assert torch.all(epi[unseen][0] > epi[:n_scene][strong].max(0).values)
    # lifted material agrees with the blob each Gaussian was seeded from (first half sphere=1, then box=2)
    truth = torch.cat([torch.ones(n_scene // 2), 2 * torch.ones(n_scene - n_scene // 2)]).long()
    pred = alpha[:n_scene].argmax(-1) + 1
    assert (pred[seen] == truth[seen]).float().mean() > 0.9

    # checkpoint: a model of another size restores the head exactly
    state = {k: v.clone() for k, v in model.state_dict().items()}
    other = make_model(blob_dm)
    assert other.num_points != model.num_points
    other.load_state_dict(state)
    for key in (EVIDENCE_KEY, WEIGHT_KEY, LOGITS_KEY, "means"):
        assert torch.equal(other.gauss_params[key], model.gauss_params[key]), key
    assert int(other.lifted_views) == int(model.lifted_views)
    assert torch.equal(other.dirichlet_alpha(), alpha)
    assert not other.dirichlet_evidence.requires_grad


def test_model_needs_the_legend() -> None:
    with pytest.raises(ValueError, match="physgs perceive"):
        PhysGSModelConfig().setup(
            scene_box=SceneBox(torch.tensor([[-1.0, -1, -1], [1, 1, 1]])), num_train_data=1, metadata={}
        )


def test_labelled_fraction_ignores_confidence_and_old_checkpoints_fall_back(blob_dm) -> None:
    from physgs_nerfstudio.export.field import PropertyField
    from physgs_nerfstudio.nerfstudio.model import LABELLED_KEY

    model = make_model(blob_dm)
    model.eval()
    full = lift(model, blob_dm)
    frac = model.labelled_fraction()[:, 0].clone()
    seen = model.gauss_params[WEIGHT_KEY][:, 0] > 0.05
    assert seen.sum() > 50 and torch.all((frac >= 0) & (frac <= 1))
    # low-confidence answers: 3x less evidence, the same share of labelled pixels
    weak = lift(model, blob_dm, confidence_scale=0.3)
    assert float(weak.sum()) == pytest.approx(0.3 * float(full.sum()), rel=0.05)
    assert torch.allclose(model.labelled_fraction()[:, 0], frac, atol=1e-5)
    pf = PropertyField.from_model(model)
    assert pf.labelled is not None and torch.allclose(pf.labelled, frac, atol=1e-6)
    assert torch.allclose(pf.evidence, weak.sum(-1))
    # the blobs are labelled in every view with a map: most seen Gaussians are mostly seen in labelled pixels
    assert float(frac[seen].median()) > 0.5
    # a checkpoint from before labelled_weight still loads; the export then selects by geometry
    state = {k: v.clone() for k, v in model.state_dict().items() if not k.endswith(LABELLED_KEY)}
    other = make_model(blob_dm)
    other.load_state_dict(state)
    assert other.labelled_fraction_legacy
    assert PropertyField.from_model(other).labelled is None


def test_small_training_images_are_not_downscaled_into_splitting_every_gaussian(blob_dm) -> None:
    """splatfacto's schedule trains at 1/4 resolution first; on small captures the screen-size split then takes
    every Gaussian (issue 14's out-of-memory run). The model keeps the render and the target image at the same,
    safe, downscale, and switches the split off where even full resolution is too small for it."""
    from physgs_nerfstudio.nerfstudio.model import training_downscale

    model = make_model(blob_dm, num_downscales=2, stop_screen_size_at=4000, split_screen_size=0.05)
    cam, batch = blob_dm.next_train(0)
    long_side = int(max(cam.width.item(), cam.height.item()))
    model.train()
    out = model.get_outputs(cam)
    d = model._get_downscale_factor()
    assert d == training_downscale(4, long_side, 0.05, model.strategy.refine_scale2d_stop_iter > 0)
    assert out["rgb"].shape[:2] == model.get_gt_img(batch["image"]).shape[:2]
    assert long_side * 0.05 < 6.0  # the blob's 32 px: even full resolution is too small for the split
    assert model.strategy.refine_scale2d_stop_iter == 0 and d == 4  # split off; the schedule is then harmless


@pytest.mark.parametrize("size", [(32, 32), (513, 301), (1297, 731), (4032, 3024)])
@pytest.mark.parametrize("d", [1, 2, 4, 8])
def test_render_size_from_the_host_matches_nerfstudios_rescale(blob_dm, size, d, monkeypatch) -> None:
    """The training step computes the downscaled render size on the host (no `.item()` synchronisation); it must be
    the size that nerfstudio's `rescale_output_resolution` gives the camera, for odd sizes too."""
    model = make_model(blob_dm)
    monkeypatch.setattr(model, "_get_downscale_factor", lambda: d)

    def camera():  # a fresh camera of this size for each call (nerfstudio's rescale back floors odd sizes)
        from nerfstudio.cameras.cameras import Cameras

        cam, _ = blob_dm.next_train(0)
        return Cameras(camera_to_worlds=cam.camera_to_worlds.clone(), fx=cam.fx.clone(), fy=cam.fy.clone(),
                       cx=cam.cx.clone(), cy=cam.cy.clone(), width=torch.full_like(cam.width, size[0]),
                       height=torch.full_like(cam.height, size[1]), camera_type=cam.camera_type.clone())  # fmt: skip

    Ks_host, W, H = model._render_intrinsics(camera(), size)
    Ks_dev, W_dev, H_dev = model._render_intrinsics(camera())
    assert (W, H) == (W_dev, H_dev) == (size[0] // d, size[1] // d)
    assert torch.equal(Ks_host, Ks_dev)


def test_a_training_cameras_size_is_read_from_the_device_once(blob_dm, monkeypatch) -> None:
    model = make_model(blob_dm)
    model.train()
    reads = []
    real_item = torch.Tensor.item

    def counting_item(t):
        reads.append(t.shape)
        return real_item(t)

    cams = [blob_dm.next_train(i)[0] for i in range(3)]
    monkeypatch.setattr(torch.Tensor, "item", counting_item)
    for cam in cams + cams:
        assert model._camera_size(cam) == (int(real_item(cam.width)), int(real_item(cam.height)))
    assert len(reads) == 2 * len({c.metadata["cam_idx"] for c in cams})  # width and height, once per camera
    no_idx = cams[0].reshape(cams[0].shape)
    no_idx.metadata = None  # a camera from outside the training set (viewer) is read every time
    model._camera_size(no_idx)
    model._camera_size(no_idx)
    assert len(reads) == 2 * len({c.metadata["cam_idx"] for c in cams}) + 4


@pytest.mark.parametrize("per_call", [2, 3])
def test_lifting_several_views_per_call_gives_the_same_evidence(blob_dm, per_call) -> None:
    model = make_model(blob_dm)
    cameras, cached = blob_dm.material_views("train")
    assert len(cached) >= 3
    one = lift_material_maps(model, cameras, cached)
    many = lift_material_maps(model, cameras, cached, views_per_call=per_call)
    assert float(one.evidence.sum()) > 0 and one.views == many.views > 0
    for a, b in ((one.evidence, many.evidence), (one.weight, many.weight), (one.labelled, many.labelled)):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)
