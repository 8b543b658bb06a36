"""Material-map data handling: dataparser, dataset and datamanager (alignment, downscaling, undistortion)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image
from helpers.nerfstudio_scenes import fixture_materials_json, look_at_c2w, write_material_files

from physgs_nerfstudio.nerfstudio import MaterialsFileError, PhysGSDatamanagerConfig, PhysGSDataParserConfig

SIZE = 48


def _region_labels(size: int) -> np.ndarray:
    """Nested rectangles: 0 outside, 1 in a frame, 2 in the centre."""
    lab = np.zeros((size, size), np.uint8)
    lab[size // 8 : -size // 8, size // 6 : -size // 6] = 1
    lab[size // 3 : -size // 3, size // 3 : -size // 3] = 2
    return lab


def write_region_dataset(root: Path, n: int = 4, distortion: dict | None = None, skip=()) -> dict:
    """Images whose grey level encodes the label (0 -> 0, 1 -> 100, 2 -> 200) plus material maps."""
    (root / "images").mkdir(parents=True)
    frames, labels = [], {}
    for i in range(n):
        lab = np.roll(_region_labels(SIZE), i, axis=1)
        img = np.repeat((lab.astype(np.uint8) * 100)[..., None], 3, axis=-1)
        fp = f"images/f{i}.png"
        Image.fromarray(img).save(root / fp)
        c2w = look_at_c2w(np.array([2.0 * np.cos(i), 2.0 * np.sin(i), 0.5]))
        frames.append({"file_path": fp, "transform_matrix": c2w.tolist()})
        labels[fp] = lab
    meta = {"fl_x": 50.0, "fl_y": 50.0, "cx": SIZE / 2, "cy": SIZE / 2, "w": SIZE, "h": SIZE,
            "camera_model": "OPENCV", "frames": frames, **(distortion or {})}  # fmt: skip
    (root / "transforms.json").write_text(json.dumps(meta))
    write_material_files(root, labels, fixture_materials_json(["ceramic", "rubber"]), skip=skip)
    return labels


def _datamanager(root: Path, **dataparser_kwargs):
    cfg = PhysGSDatamanagerConfig(
        dataparser=PhysGSDataParserConfig(
            data=root, load_3D_points=False, eval_mode="all", **dataparser_kwargs
        )
    )
    return cfg.setup(device="cpu")


def _labels_by_file(dm):
    return {Path(f).name: d for f, d in zip(dm.train_dataset.image_filenames, dm.cached_train)}


def test_maps_load_aligned_with_images(tmp_path: Path) -> None:
    labels = write_region_dataset(tmp_path, skip=["images/f3.png"])
    dm = _datamanager(tmp_path)
    legend = dm.material_legend
    assert legend.names == ["ceramic", "rubber"] and legend.colors.shape == (2, 3)
    assert legend.nig["tau"].shape == (2, 4)
    for name, data in _labels_by_file(dm).items():
        assert data["material"].shape == (SIZE, SIZE, 1) and data["material"].dtype == torch.uint8
        assert data["material_confidence"].shape == (SIZE, SIZE, 1)
        if name == "f3.png":  # no map: all unknown, trains RGB only
            assert int(data["material"].max()) == 0 and int(data["material_confidence"].max()) == 0
        else:
            np.testing.assert_array_equal(data["material"][..., 0].numpy(), labels[f"images/{name}"])
            conf = data["material_confidence"][..., 0].numpy()
            assert np.all(conf[labels[f"images/{name}"] > 0] == round(0.9 * 255))


def test_maps_follow_dataparser_downscale(tmp_path: Path) -> None:
    labels = write_region_dataset(tmp_path)
    (tmp_path / "images_2").mkdir()
    for fp in labels:
        Image.open(tmp_path / fp).resize((SIZE // 2, SIZE // 2), Image.Resampling.BILINEAR).save(
            tmp_path / "images_2" / Path(fp).name
        )
    dm = _datamanager(tmp_path, downscale_factor=2)
    for data in _labels_by_file(dm).values():
        lab = data["material"][..., 0].numpy()
        assert lab.shape == (SIZE // 2, SIZE // 2) == data["image"].shape[:2]
        grey = data["image"][..., 0].numpy().astype(int)
        pure = np.isin(grey, [0, 100, 200])  # pixels not blended by the image downscale
        assert pure.mean() > 0.5
        assert np.mean(lab[pure] * 100 == grey[pure]) > 0.97


def test_maps_follow_camera_res_scale_factor(tmp_path: Path) -> None:
    write_region_dataset(tmp_path)
    cfg = PhysGSDatamanagerConfig(
        dataparser=PhysGSDataParserConfig(data=tmp_path, load_3D_points=False, eval_mode="all"),
        camera_res_scale_factor=0.5,
    )
    dm = cfg.setup(device="cpu")
    for data in dm.cached_train:
        assert data["material"].shape[:2] == data["image"].shape[:2] == (SIZE // 2, SIZE // 2)


@pytest.mark.parametrize("k1", [-0.25, 0.2])
def test_maps_follow_undistortion(tmp_path: Path, k1: float) -> None:
    """Distorted images: after nerfstudio's undistortion the label map still encodes each pixel's grey level."""
    labels = write_region_dataset(tmp_path, distortion={"k1": k1, "k2": 0.0, "p1": 0.0, "p2": 0.0})
    dm = _datamanager(tmp_path)
    changed = 0
    for name, data in _labels_by_file(dm).items():
        lab = data["material"][..., 0].numpy()
        grey = data["image"][..., 0].numpy().astype(int)
        assert lab.shape == grey.shape
        pure = np.isin(grey, [0, 100, 200])
        assert pure.mean() > 0.7
        assert np.mean(lab[pure] * 100 == grey[pure]) > 0.99, name
        orig = labels[f"images/{name}"]
        changed += lab.shape != orig.shape or not np.array_equal(lab, orig)
    assert changed == len(labels)  # undistortion really moved the maps


def test_dataset_without_maps_says_run_perceive(tmp_path: Path) -> None:
    write_region_dataset(tmp_path)
    meta = json.loads((tmp_path / "transforms.json").read_text())
    for f in meta["frames"]:
        f.pop("material_path"), f.pop("material_confidence_path")
    (tmp_path / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(MaterialsFileError, match="physgs perceive"):
        _datamanager(tmp_path)


def test_missing_materials_json_says_run_perceive(tmp_path: Path) -> None:
    write_region_dataset(tmp_path)
    (tmp_path / "materials.json").unlink()
    with pytest.raises(MaterialsFileError, match="physgs perceive"):
        _datamanager(tmp_path)


def test_label_out_of_range_is_an_error(tmp_path: Path) -> None:
    write_region_dataset(tmp_path)
    bad = np.full((SIZE, SIZE), 7, np.uint8)
    Image.fromarray(bad, mode="L").save(tmp_path / "materials" / "f0.png")
    dm = _datamanager(tmp_path)
    with pytest.raises(MaterialsFileError, match="label 7"):
        dm.cached_train  # noqa: B018
