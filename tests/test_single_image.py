"""Single-image mode (`physgs image`): dense maps from masks + (simulated) VLM answers + per-image fusion."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from physgs_nerfstudio.perception.replay import ReplayConfig
from physgs_nerfstudio.perception.vlm import OpenAIConfig
from physgs_nerfstudio.perception.config import PerceptionConfig
from physgs_nerfstudio.materials import PROPERTY_KEYS, from_canonical, load_library
from physgs_nerfstudio.perception.cache import ResponseCache
from physgs_nerfstudio.perception.simulated import SimulatedBackend, SimulatedConfig
from physgs_nerfstudio.perception.vlm import CachedBackend, VLMError, VLMResponse
from physgs_nerfstudio.single_image import NPZ_KEYS, SingleImageConfig, compute_image_maps, run_single_image
from physgs_nerfstudio.single_image.inputs import InputError
from physgs_nerfstudio.single_image.pipeline import ViewAliasBackend
from physgs_nerfstudio.synth import SynthConfig, generate_scene

H = W = 128



def _pc(**kw) -> PerceptionConfig:
    """Perception settings of a single-image run (its data is the output directory)."""
    return PerceptionConfig(data=Path("."), progress=False, **kw)

@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("si_scene") / "mug"
    return generate_scene(SynthConfig(out=root, object="mug", views=1, resolution=H, num_points=200, background_points=0))


@pytest.fixture(scope="module")
def run(scene, tmp_path_factory):
    out = tmp_path_factory.mktemp("si_out") / "run"
    # a folder of images; the simulated VLM is told to be right 90% of the time (with one view and a handful
    # of masks per part, fusion cannot undo a wrong answer for a part's only mask)
    cfg = SingleImageConfig(path=scene / "images", output_dir=out, ground_truth=scene, dpi=60,
                            perception=_pc(vlm=SimulatedConfig(p_correct=0.9)))
    return cfg, run_single_image(cfg)


def _truth(scene: Path, frame: str) -> tuple[np.ndarray, list[str]]:
    gt = json.loads((scene / "ground_truth.json").read_text())
    rec = next(f for f in gt["frames"] if f["file_path"] == f"images/{frame}.png")
    return np.asarray(Image.open(scene / rec["material_path"])).astype(np.int64), [m["name"] for m in gt["materials"]]


def test_outputs_exist_with_documented_keys_shapes_units(run):
    cfg, result = run
    assert [r.name for r in result.images] == ["frame_00000"]
    top = json.loads((cfg.output_dir / "summary.json").read_text())
    assert top["simulated"] is True and top["backend"] == "simulated" and len(top["images"]) == 1
    for r in result.images:
        assert not r.skipped and r.masks > 0 and r.observations > 0
        summary = json.loads((r.out_dir / "summary.json").read_text())
        for name, rel in summary["files"].items():
            path = r.out_dir / rel
            assert path.is_file() and path.stat().st_size > 1000, name
        for key in PROPERTY_KEYS:
            for stat in ("mean", "aleatoric", "epistemic", "total"):
                assert f"{key}_{stat}" in summary["files"]
        with Image.open(r.out_dir / "overview.png") as im:
            assert im.size[0] > 3 * im.size[1]  # five panels side by side
        assert summary["units"] == {"density": "kg/m^3", "kinetic_friction": "1", "shore_hardness": "Shore D", "youngs_modulus": "Pa"}
        assert summary["npz_keys"] == NPZ_KEYS
        with np.load(r.out_dir / "maps.npz") as z:
            expected = {k for k in NPZ_KEYS if "<key>" not in k}
            expected |= {k.replace("<key>", p) for k in NPZ_KEYS if "<key>_" in k and "<stat>" not in k for p in PROPERTY_KEYS}
            expected |= {f"{p}_log10_{s}" for p in ("density", "youngs_modulus") for s in ("mean", "aleatoric", "epistemic", "total")}
            assert set(z.files) == expected
            K = len(z["legend_names"]) - 1
            assert z["legend_names"][0] == "unknown" and z["legend_colors"].shape == (K + 1, 3)
            assert list(z["legend_names"][1:]) == [m["name"] for m in summary["materials"]]
            assert z["rgb"].shape == (H, W, 3) and z["rgb"].dtype == np.uint8
            assert z["material"].shape == (H, W) and z["material"].max() <= K
            assert z["covered"].dtype == bool and z["mask_count"].dtype == np.uint16
            assert z["evidence"].shape == (H, W, K)
            assert list(z["units"]) == [summary["units"][k] for k in PROPERTY_KEYS]
            meta = json.loads(str(z["meta_json"]))
            assert meta["hardness_scale"] == "D" and meta["simulated"] is True
            for key in PROPERTY_KEYS:
                for stat in ("mean", "aleatoric", "epistemic", "total"):
                    a = z[f"{key}_{stat}"]
                    assert a.shape == (H, W) and a.dtype == np.float32 and np.isfinite(a).all()
                np.testing.assert_allclose(z[f"{key}_total"], z[f"{key}_aleatoric"] + z[f"{key}_epistemic"], rtol=1e-4)
                assert (z[f"{key}_aleatoric"] >= 0).all() and (z[f"{key}_epistemic"] >= 0).all()
            # units are what they say: friction is a coefficient, density in kg/m^3, modulus in Pa
            cov = z["covered"]
            assert 0.05 < np.median(z["kinetic_friction_mean"][cov]) < 1.5
            assert 300 < np.median(z["density_mean"][cov]) < 20000
            assert 1e8 < np.median(z["youngs_modulus_mean"][cov]) < 1e12
            assert 0 <= np.median(z["shore_hardness_mean"][cov]) <= 100


def test_material_matches_ground_truth_on_foreground(run, scene):
    _, result = run
    for r in result.images:
        with np.load(r.out_dir / "maps.npz") as z:
            material, names = z["material"].astype(np.int64), list(z["legend_names"])
        truth, truth_names = _truth(scene, r.name)
        lut = np.array([-1] + [names.index(n) if n in names else -2 for n in truth_names])
        fg = truth > 0
        accuracy = float((material[fg] == lut[truth[fg]]).mean())
        assert accuracy > 0.8, (r.name, accuracy)
        summary = json.loads((r.out_dir / "summary.json").read_text())
        assert summary["ground_truth_check"]["foreground_accuracy"] == pytest.approx(accuracy)


def test_uncovered_pixels_get_the_flat_prior_and_more_uncertainty(run):
    _, result = run
    n_library = len(load_library("indoor").names)
    for r in result.images:
        with np.load(r.out_dir / "maps.npz") as z:
            cov = z["covered"]
            assert cov.any() and (~cov).any()
            np.testing.assert_array_equal(cov, z["evidence"].sum(-1) > 0)
            assert (z["material"][~cov] == 0).all() and (z["material"][cov] > 0).all()
            np.testing.assert_allclose(z["material_confidence"][~cov], 1.0 / n_library, rtol=1e-6)
            assert (z["material_confidence"][cov] > 1.0 / n_library).all()
            for key in PROPERTY_KEYS:
                total = z[f"{key}_total"]
                assert np.ptp(total[~cov]) == 0  # one prior for every uncovered pixel
                # properties spanning decades: compare the spread in decades (a stiff, well-known part has a
                # larger deviation in Pa than a region that may be anything)
                u = z[f"{key}_log10_total"] if f"{key}_log10_total" in z.files else total
                assert u[~cov].min() > u[cov].max(), key


def test_rerun_makes_no_new_vlm_call(run, tmp_path):
    cfg, first = run
    again = run_single_image(SingleImageConfig(**{**cfg.__dict__, "figures": False}))
    assert again.perception.calls == 0
    assert again.perception.resumed_masks == first.perception.masks > 0
    # a fresh output directory sharing the response cache: every answer is a cache hit
    fresh = SingleImageConfig(**{**cfg.__dict__, "figures": False, "output_dir": tmp_path / "fresh",
                                 "perception": replace(cfg.perception, cache_dir=cfg.output_dir / "perception" / "cache")})
    res = run_single_image(fresh)
    assert res.perception.calls == 0 and res.perception.cache_hits == first.perception.masks
    for a, b in zip(first.images, res.images):
        with np.load(a.out_dir / "maps.npz") as za, np.load(b.out_dir / "maps.npz") as zb:
            np.testing.assert_array_equal(za["material"], zb["material"])
            np.testing.assert_array_equal(za["kinetic_friction_total"], zb["kinetic_friction_total"])


class _Flaky:
    """The simulated VLM, except one mask gets an unparseable answer and another a failed request."""

    name, model, variant, simulated = "simulated", "simulated", "flaky-test", True

    def __init__(self, inner, garbage: int, error: int):
        self.inner, self.garbage, self.error = inner, garbage, error

    def cost_usd(self, usage) -> float:
        return 0.0

    def query(self, request):
        if request.mask_id == self.garbage:
            return VLMResponse(text="I believe this is some kind of metal {not json", simulated=True)
        if request.mask_id == self.error:
            raise VLMError(f"{request.describe()}: HTTP 500 after retries")
        return self.inner.query(request)


def test_bad_vlm_response_for_one_mask_does_not_abort(scene, tmp_path):
    out = tmp_path / "flaky"
    cfg = SingleImageConfig(path=scene / "images" / "frame_00000.png", output_dir=out, ground_truth=scene,
                            figures=False, perception=_pc(vlm=SimulatedConfig()))
    library = load_library("indoor")
    inner = ViewAliasBackend(SimulatedBackend(scene, library), {"images/frame_00000.png": "images/frame_00000.png"})
    backend = CachedBackend(_Flaky(inner, garbage=1, error=2), ResponseCache(tmp_path / "cache"))
    result = run_single_image(cfg, backend=backend, library=library)
    (img,) = result.images
    assert len(result.perception.failed) == 1 and "HTTP 500" in result.perception.failed[0]
    assert img.masks > 3 and not img.skipped and (img.out_dir / "maps.npz").is_file()
    records = [json.loads(line) for line in (out / "observations.jsonl").read_text().splitlines()]
    ids = {r["mask_id"] for r in records}
    assert 1 not in ids and 2 not in ids and len(ids) >= 2
    summary = json.loads((img.out_dir / "summary.json").read_text())
    assert summary["masks_with_evidence"] == len(ids)
    top = json.loads((out / "summary.json").read_text())
    assert top["vlm"]["failed"] == 1


def test_fusion_levels_hardness_scale_and_prior_on_a_hand_made_image():
    library = load_library("indoor")
    h, w = 20, 30
    whole = np.zeros((h, w), bool)
    whole[2:18, 2:20] = True
    sub = np.zeros((h, w), bool)
    sub[5:12, 5:12] = True
    props = {"density": 7850.0, "kinetic_friction": 0.4, "shore_hardness": 140.0, "youngs_modulus": 2e11}

    def rec(mask_id, level, material, conf):
        return {"view": "v", "mask_id": mask_id, "level": level, "material": material, "confidence": conf,
                "properties": {**props, "thickness_m": None}}

    records = [rec(0, "whole", "oak", 1.0), rec(1, "subpart", "steel", 0.8)]  # the whole mask is more confident
    maps = compute_image_maps(np.stack([whole, sub]), ["whole", "subpart"], records, library, hardness_scale="D")
    names = ["unknown", *maps.names]
    assert names[maps.material[8, 8]] == "steel"  # the finer level wins where both cover the pixel
    assert names[maps.material[15, 15]] == "oak"
    assert maps.material[0, 0] == 0 and not maps.covered[0, 0]
    assert maps.mask_count[8, 8] == 2 and maps.mask_count[15, 15] == 1 and maps.mask_count[0, 0] == 0
    # hardness is reported on the Shore D scale: each material's A_eq estimate converted, variances by the
    # local slope of the conversion (D 58..100 <-> A_eq 100..142 has slope 1, so steel's variance is unchanged)
    maps_aeq = compute_image_maps(np.stack([whole, sub]), ["whole", "subpart"], records, library, hardness_scale="A_eq")
    for d_mat, a_mat in zip(maps.per_material, maps_aeq.per_material):
        d_est, a_est = d_mat["estimate"]["shore_hardness"], a_mat["estimate"]["shore_hardness"]
        assert d_est["mean"] == pytest.approx(from_canonical(a_est["mean"], "D"), abs=1e-6)
        if a_est["mean"] > 101:
            assert d_est["total"] == pytest.approx(a_est["total"], rel=1e-6)
    assert maps.units["shore_hardness"] == "Shore D" and maps_aeq.units["shore_hardness"].startswith("Shore A-equivalent")
    # no observation at all: every pixel is unknown and carries the prior
    empty = compute_image_maps(np.stack([whole, sub]), ["whole", "subpart"], [], library)
    assert empty.names == [] and not empty.covered.any() and (empty.material == 0).all()
    f = empty.fields["kinetic_friction"]["total"]
    assert np.ptp(f) == 0 and f[0, 0] > maps.fields["kinetic_friction"]["total"][8, 8]


def test_input_errors(scene, tmp_path):
    with pytest.raises(ValueError, match="ground-truth"):
        SingleImageConfig(path=scene / "images", perception=_pc(vlm=SimulatedConfig()))
    with pytest.raises(InputError, match="does not exist"):
        run_single_image(SingleImageConfig(path=tmp_path / "missing.png", output_dir=tmp_path / "o", perception=_pc(vlm=ReplayConfig())))
    stranger = tmp_path / "photos" / "holiday.png"
    stranger.parent.mkdir()
    shutil.copy(scene / "images" / "frame_00000.png", stranger)
    with pytest.raises(InputError, match="not a frame of the generated scene"):
        run_single_image(SingleImageConfig(path=stranger, output_dir=tmp_path / "o2", ground_truth=scene, perception=_pc(vlm=SimulatedConfig())))
    with pytest.raises(ValueError, match="unknown property"):
        SingleImageConfig(path=stranger, properties=("colour",))


def test_changed_image_in_the_same_output_dir_is_refused(scene, tmp_path):
    photo = tmp_path / "in" / "photo.png"
    photo.parent.mkdir()
    shutil.copy(scene / "images" / "frame_00000.png", photo)
    cache = tmp_path / "cache"
    cfg = SingleImageConfig(path=photo, output_dir=tmp_path / "o", figures=False,
                            perception=_pc(vlm=ReplayConfig(source="simulated"), cache_dir=cache))
    first = run_single_image(cfg)  # empty cache: every mask is a replay miss, reported, not fatal
    assert first.perception.calls == 0 and len(first.perception.failed) == first.perception.masks > 0
    assert first.images[0].covered_fraction == 0.0
    Image.fromarray(np.asarray(Image.open(photo))[:, ::-1].copy()).save(photo)  # another picture, same name
    with pytest.raises(InputError, match="--overwrite"):
        run_single_image(cfg)
    cfg.perception.overwrite = True
    assert run_single_image(cfg).images[0].masks > 0


def test_tyro_parses_the_command(scene):
    import tyro

    from physgs_nerfstudio.single_image.command import ImageCommand

    cmd = tyro.cli(ImageCommand, args=[str(scene / "images"), "--ground-truth", str(scene),
                                       "--properties", "friction", "stiffness", "--hardness-scale", "A", "vlm:simulated"])
    assert isinstance(cmd.perception.vlm, SimulatedConfig)
    assert cmd.properties == ("kinetic_friction", "youngs_modulus") and cmd.hardness_scale == "A"


def test_command_with_an_openai_compatible_endpoint(scene, tmp_path, capsys):
    from helpers.perception_server import FakeServer

    from physgs_nerfstudio.single_image.command import ImageCommand

    photo = tmp_path / "photo.png"
    shutil.copy(scene / "images" / "frame_00000.png", photo)
    with FakeServer() as server:
        cmd = ImageCommand(path=photo, output_dir=tmp_path / "o", properties=("friction",), figures=False,
                           perception=_pc(vlm=OpenAIConfig(model="local-vlm", base_url=server.base_url, api_key_env="")))
        cmd.main()
        assert len(server.requests) > 0 and all(body["model"] == "local-vlm" for body in server.requests)
    out = capsys.readouterr().out
    assert "photo.png" in out and "VLM calls" in out
    summary = json.loads((tmp_path / "o" / "photo" / "summary.json").read_text())
    assert summary["simulated"] is False and summary["model"] == "local-vlm" and summary["properties"] == ["kinetic_friction"]
    # the server always answers ceramic 0.7 / porcelain 0.3: every covered pixel is ceramic
    with np.load(tmp_path / "o" / "photo" / "maps.npz") as z:
        names = list(z["legend_names"])
        assert set(z.files) >= {"kinetic_friction_mean", "kinetic_friction_total"} and "density_mean" not in z.files
        assert z["covered"].any() and (z["material"][z["covered"]] == names.index("ceramic")).all()
