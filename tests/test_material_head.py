"""PhysGSModel's three material heads (`material_head`: logits, latent, lifted) on CPU: training steps, output
keys and shapes, the lifted map against an independent composite of the Dirichlet predictive, checkpoints of
one head loaded under another, and densification of the head tensors."""

from __future__ import annotations

import pytest
import torch
import yaml
from gsplat.strategy.ops import duplicate, remove, split
from nerfstudio.engine.optimizers import Optimizers
from helpers.nerfstudio_scenes import blob_datamanager, blob_model, write_blob_scene

from method_configs.physgs_config import physgs_lite_trainer_config
from physgs_nerfstudio.geometry.capture import viewmat_from_c2w
from physgs_nerfstudio.nerfstudio import PhysGSModelConfig
from physgs_nerfstudio.nerfstudio.model import PhysGSModel
from physgs_nerfstudio.nerfstudio.pipeline import lift_material_maps
from physgs_nerfstudio.render import rasterize
from physgs_nerfstudio.runfiles.keys import (
    DECODER_GROUP,
    EVIDENCE_KEY,
    FEATURES_KEY,
    LABELLED_KEY,
    LOGITS_KEY,
    WEIGHT_KEY,
)

HEADS = ("logits", "latent", "lifted")
EVAL_OUTPUTS = {"material_id": 1, "depth": 1, "accumulation": 1, "rgb": 3, "material": 3, "background": 3,
                "density": 3, "friction": 3, "hardness": 3, "stiffness": 3, "aleatoric": 3, "epistemic": 3,
                "total_uncertainty": 3}  # fmt: skip


@pytest.fixture(scope="module")
def blob_dm(tmp_path_factory):
    return blob_datamanager(tmp_path_factory.mktemp("blob"))


def make_model(dm, **config) -> PhysGSModel:
    return blob_model(dm, **config)


def attach_optimizers(model: PhysGSModel) -> Optimizers:
    opt = Optimizers(physgs_lite_trainer_config().optimizers, model.get_param_groups())
    model.step_cb(opt, 0)
    return opt


def lift(model: PhysGSModel, dm) -> None:
    cameras, views = dm.material_views("train")
    model.set_material_evidence(lift_material_maps(model, cameras, views))


def train(model: PhysGSModel, dm, steps: int) -> list[dict]:
    """nerfstudio's training step (outputs, losses, backward, optimizers, densification callback) `steps`
    times; returns each step's losses."""
    opt = attach_optimizers(model)
    model.train()
    history = []
    for step in range(steps):
        model.step_cb(opt, step)
        cam, batch = dm.next_train(step)
        losses = model.get_loss_dict(model.get_outputs(cam), batch)
        opt.zero_grad_all()
        sum(losses.values()).backward()
        opt.optimizer_step_all()
        model.step_post_backward(step)
        history.append({k: float(v.detach()) for k, v in losses.items()})
    return history


def eval_outputs(model: PhysGSModel, dm, index: int = 0) -> dict[str, torch.Tensor]:
    model.eval()
    with torch.no_grad():
        return model.get_outputs_for_camera(dm.eval_dataset.cameras[index : index + 1])


@pytest.mark.parametrize("head", HEADS)
def test_each_head_trains_and_renders_the_same_outputs(blob_dm, head) -> None:
    model = make_model(blob_dm, material_head=head, material_every=2)
    K = model.num_materials
    key = {"logits": LOGITS_KEY, "latent": FEATURES_KEY, "lifted": None}[head]
    others = {LOGITS_KEY, FEATURES_KEY} - {key}
    assert not others & set(model.gauss_params), "only the configured head's tensor exists"
    groups = model.get_param_groups()
    assert (DECODER_GROUP in groups) == (head == "latent")
    for name in dir(model):  # nerfstudio's viewer reads every attribute of the model: none may raise
        getattr(model, name)
    cam, batch = blob_dm.next_train(0)
    model.train()
    out = model.get_outputs(cam)
    H, W = batch["image"].shape[:2]
    if key is None:
        assert LOGITS_KEY not in out and not model.material_pass_due()
    else:
        width = K if head == "logits" else model.config.material_latent_dim
        assert model.gauss_params[key].shape == (model.num_points, width)
        assert out[LOGITS_KEY].shape == (H // 2, W // 2, K)
        before = model.gauss_params[key].detach().clone()
        decoder_before = None if model.material_decoder is None else model.material_decoder.weight.detach().clone()
    history = train(model, blob_dm, 4)
    assert all(("material_loss" in h) == (key is not None and step % 2 == 0) for step, h in enumerate(history))
    if key is not None:
        assert history[0]["material_loss"] > 0
        assert not torch.equal(model.gauss_params[key].detach(), before), "the head's tensor was trained"
        if decoder_before is not None:
            assert not torch.equal(model.material_decoder.weight.detach(), decoder_before)
    out = eval_outputs(model, blob_dm)
    assert set(out) == set(EVAL_OUTPUTS)
    for name, channels in EVAL_OUTPUTS.items():
        assert out[name].shape == (H, W, channels), name
        assert torch.isfinite(out[name]).all(), name
    if head == "lifted":  # no material before the first lifting, the lifted one after
        assert torch.all(out["material_id"] == 0)
        model.config.material_alpha_thresh = 0.2  # (4 steps of splatfacto-big's opacity schedule thin the blobs)
        lift(model, blob_dm)
        assert (eval_outputs(model, blob_dm)["material_id"] > 0).float().mean() > 0.05


def _composited_predictive_labels(model: PhysGSModel, camera) -> torch.Tensor:
    """The oracle: the lifted material map recomputed from the model's stored evidence with the formulas written
    out here (Dirichlet posterior, predictive, labelled fraction, thresholds) and one reference-rasterizer render."""
    g = model.gauss_params
    alpha = model.alpha0 + model.lam * g[EVIDENCE_KEY].detach()
    p = alpha / alpha.sum(-1, keepdim=True)
    w = g[WEIGHT_KEY].detach()
    frac = torch.where(w > 0, g[LABELLED_KEY].detach() / w.clamp_min(1e-12), torch.zeros_like(w)).clamp(0, 1)
    Ks = camera.get_intrinsics_matrices()
    render, acc, _ = rasterize(
        g["means"].detach(), g["quats"].detach(), torch.exp(g["scales"].detach()),
        torch.sigmoid(g["opacities"].detach()).squeeze(-1), torch.cat([p, frac], -1),
        viewmat_from_c2w(camera.camera_to_worlds), Ks, int(camera.width), int(camera.height), packed=False,
        near_plane=0.01, far_plane=1e10, backend="reference",
    )  # fmt: skip
    render, acc = render[0], acc[0, ..., 0]
    K = p.shape[1]
    known = (acc > model.config.material_alpha_thresh) & (
        render[..., K] / acc.clamp_min(1e-10) > model.config.material_min_labelled
    )
    return torch.where(known, render[..., :K].argmax(-1) + 1, 0), render[..., :K]


def test_lifted_map_is_the_composited_dirichlet_predictive(blob_dm) -> None:
    model = make_model(blob_dm, material_head="lifted", rasterize_backend="reference")
    model.eval()
    lift(model, blob_dm)
    with torch.no_grad():  # a second, distinct evidence pattern: not what any argmax of the logits would give
        ev = model.gauss_params[EVIDENCE_KEY]
        ev[::3] = ev[::3].flip(-1) * 3.0
    for index in range(len(blob_dm.eval_dataset)):
        camera = blob_dm.eval_dataset.cameras[index : index + 1]
        got = eval_outputs(model, blob_dm, index)["material_id"][..., 0].long()
        want, composite = _composited_predictive_labels(model, camera)
        top2 = composite.topk(2, dim=-1).values
        clear = (top2[..., 0] - top2[..., 1]) > 1e-5  # ties may break either way
        known = want > 0
        assert known.sum() > 20
        assert torch.all(got[~known] == 0)
        assert torch.equal(got[known & clear], want[known & clear])
        assert (known & clear).sum() > 0.9 * known.sum()


def test_lifted_map_agrees_with_the_blob_labels(blob_dm) -> None:
    model = make_model(blob_dm, material_head="lifted")
    lift(model, blob_dm)
    model.eval()
    hits = total = 0
    for camera, batch in blob_dm.fixed_indices_eval_dataloader:
        with torch.no_grad():
            pred = model.get_outputs_for_camera(camera)["material_id"][..., 0].long()
        labels = batch["material"][..., 0].long()
        valid = labels > 0
        hits += int((pred[valid] == labels[valid]).sum())
        total += int(valid.sum())
    assert total > 0 and hits / total > 0.7


@pytest.mark.parametrize(("written", "loaded"), [("logits", "lifted"), ("logits", "latent"),
                                                 ("latent", "logits"), ("lifted", "logits")])  # fmt: skip
def test_a_checkpoint_keeps_its_head_under_another_config(blob_dm, written, loaded) -> None:
    model = make_model(blob_dm, material_head=written, material_every=1)
    train(model, blob_dm, 2)
    lift(model, blob_dm)
    state = {k: v.clone() for k, v in model.state_dict().items()}
    want = eval_outputs(model, blob_dm)
    other = make_model(blob_dm, material_head=loaded)
    other.load_state_dict(state)  # strict: every key of the checkpoint has its place
    assert other.material_head == written
    assert set(other.state_dict()) == set(state)
    for k, v in state.items():
        assert torch.equal(other.state_dict()[k], v), k
    got = eval_outputs(other, blob_dm)
    for name in ("material_id", "rgb", "density"):
        assert torch.allclose(got[name], want[name], atol=1e-5), name


def test_old_run_loads_for_export_under_another_default(tmp_path, monkeypatch) -> None:
    """A run saved by the "logits" head with a config.yml from before `material_head` existed loads through the
    export's loader while the default names another head."""
    from physgs_nerfstudio.export.command import load_run
    from physgs_nerfstudio.runfiles.check import check_run
    from physgs_nerfstudio.runfiles.loader import load_run_model

    write_blob_scene(tmp_path / "data", num_views=6, size=32)
    config = physgs_lite_trainer_config()
    config.pipeline.datamanager.data = tmp_path / "data"
    config.pipeline.model.sh_degree = 1
    config.pipeline.model.material_head = "logits"  # the head runs had before the field existed
    config.output_dir, config.timestamp = tmp_path / "outputs", "t"
    config.set_experiment_name()
    pipeline = config.pipeline.setup(device="cpu", test_mode="val")
    with torch.no_grad():
        pipeline.model.gauss_params[LOGITS_KEY].copy_(torch.randn(pipeline.model.gauss_params[LOGITS_KEY].shape))
    base = config.get_base_dir()
    base.mkdir(parents=True)
    text = yaml.dump(config)
    assert "material_head: logits" in text
    (base / "config.yml").write_text(text.replace("    material_head: logits\n", ""), "utf8")
    pipeline.datamanager.train_dataparser_outputs.save_dataparser_transform(base / "dataparser_transforms.json")
    config.get_checkpoint_dir().mkdir(parents=True)
    torch.save({"step": 5, "pipeline": pipeline.state_dict(), "optimizers": {}, "scalers": {}},
               config.get_checkpoint_dir() / "step-000000005.ckpt")  # fmt: skip
    monkeypatch.setattr(PhysGSModelConfig, "material_head", "lifted")  # the flipped default
    files = check_run(base / "config.yml")
    assert files.trainer_config().pipeline.model.material_head == "lifted"  # the old config names no head
    field = load_run(base / "config.yml", capture=False).field  # the export's path: no model built
    assert field.num_gaussians == pipeline.model.num_points
    assert torch.equal(field.alpha, pipeline.model.dirichlet_alpha())
    rm = load_run_model(files.config, files.checkpoint)
    assert rm.model.material_head == "logits"
    assert torch.equal(rm.model.gauss_params[LOGITS_KEY], pipeline.model.gauss_params[LOGITS_KEY])


@pytest.mark.parametrize("head", ["latent", "lifted"])
def test_densification_keeps_the_head_tensors_in_sync(blob_dm, head) -> None:
    model = make_model(blob_dm, material_head=head, material_every=1)
    train(model, blob_dm, 1)  # the optimizers have state
    n0 = model.num_points
    with torch.no_grad():  # row i carries i in every per-Gaussian extra
        for name in (FEATURES_KEY, EVIDENCE_KEY):
            if name in model.gauss_params:
                model.gauss_params[name].copy_(torch.arange(n0, dtype=torch.float32)[:, None])
    params, optim, state = model.gauss_params, model._strategy_optimizers(), model.strategy_state
    duplicate(params, optim, state, torch.arange(n0) < 5)
    split(params, optim, state, (torch.arange(model.num_points) >= 5) & (torch.arange(model.num_points) < 8))
    remove(params, optim, state, torch.arange(model.num_points) == model.num_points - 1)
    n1 = model.num_points
    assert n1 == n0 + 5 + 3 - 1
    for name, p in model.gauss_params.items():
        assert p.shape[0] == n1, name
    again = model._strategy_optimizers()  # the no-op optimizers are kept: the ops swapped their tensors
    assert again[EVIDENCE_KEY] is optim[EVIDENCE_KEY]
    assert again[EVIDENCE_KEY].param_groups[0]["params"][0] is model.gauss_params[EVIDENCE_KEY]
    counts = torch.bincount(model.gauss_params[EVIDENCE_KEY][:, 0].round().long(), minlength=n0)
    assert torch.all(counts[:5] == 2) and counts[5:8].tolist() == [2, 2, 1] and torch.all(counts[8:] == 1)
    if head == "latent":
        feats = model.gauss_params[FEATURES_KEY]
        assert feats.shape == (n1, model.config.material_latent_dim) and feats.requires_grad
        assert torch.equal(feats[:, 0].detach(), model.gauss_params[EVIDENCE_KEY][:, 0])
        st = model.optimizers[FEATURES_KEY].state[feats]
        assert st["exp_avg"].shape == feats.shape == st["exp_avg_sq"].shape
    else:
        assert not {LOGITS_KEY, FEATURES_KEY} & set(model.gauss_params)
    train(model, blob_dm, 2)  # trains on after the resize
