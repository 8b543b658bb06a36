"""Full-image datamanager that keeps the material maps aligned with the (undistorted) images.

nerfstudio's `FullImageDatamanager` undistorts each image once when it caches it and replaces the camera
intrinsics by the undistorted ones. The material maps must follow exactly: this subclass repeats the same
OpenCV geometry (same new camera matrix and region-of-interest crop) with *nearest-neighbour* remapping, so
labels never blend. Supported: PERSPECTIVE (k1, k2, k3, p1, p2; nerfstudio rejects k4 for images too) and
FISHEYE (k1..k4). FISHEYE624 maps raise NotImplementedError (nerfstudio builds that undistortion with its
own remap, not repeated here).
"""

from __future__ import annotations

from copy import deepcopy
from dataclasses import dataclass, field
from typing import Literal

import cv2
import numpy as np
import torch
from nerfstudio.cameras.cameras import Cameras, CameraType
from nerfstudio.data.datamanagers.full_images_datamanager import (
    FullImageDatamanager,
    FullImageDatamanagerConfig,
)

from .dataparser import PhysGSDataParserConfig
from .dataset import PhysGSDataset

MAP_KEYS = ("material", "material_confidence")


@dataclass
class PhysGSDatamanagerConfig(FullImageDatamanagerConfig):
    _target: type = field(default_factory=lambda: PhysGSDatamanager)
    dataparser: PhysGSDataParserConfig = field(default_factory=PhysGSDataParserConfig)
    """nerfstudio-format dataset + material maps (a fixed type: the maps need this dataparser)."""
    cache_images_type: Literal["uint8", "float32"] = "uint8"


def _undistort_maps(camera: Cameras, maps: list[np.ndarray]) -> list[np.ndarray]:
    """Undistorts `[H, W]` uint8 maps like `_undistort_image` undistorts the image, nearest interpolation.

    `camera` is the original (distorted) camera of the frame.
    """
    h, w = maps[0].shape[:2]
    K = camera.get_intrinsics_matrices().numpy().astype(np.float64)
    d = camera.distortion_params.numpy().astype(np.float64)
    # OpenCV's pixel grid is shifted by half a pixel from nerfstudio's (nerfstudio issue 3048)
    K[0, 2] -= 0.5
    K[1, 2] -= 0.5
    ctype = camera.camera_type.item()
    if ctype == CameraType.PERSPECTIVE.value:
        if d[3] != 0:
            raise ValueError("k4 is not supported for perspective undistortion (as in nerfstudio)")
        dist = np.array([d[0], d[1], d[4], d[5], d[2], 0.0, 0.0, 0.0])  # OpenCV order k1 k2 p1 p2 k3
        if not np.any(dist):
            return maps
        new_k, (x, y, rw, rh) = cv2.getOptimalNewCameraMatrix(K, dist, (w, h), 0)
        map1, map2 = cv2.initUndistortRectifyMap(K, dist, None, new_k, (w, h), cv2.CV_32FC1)
    elif ctype == CameraType.FISHEYE.value:
        dist = d[:4]
        new_k = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(K, dist, (w, h), np.eye(3), balance=0)
        map1, map2 = cv2.fisheye.initUndistortRectifyMap(K, dist, np.eye(3), new_k, (w, h), cv2.CV_32FC1)
        x, y, rw, rh = 0, 0, w, h
    else:
        raise NotImplementedError(
            f"material maps cannot be undistorted for camera type {CameraType(ctype).name}; "
            "undistort the dataset first (PERSPECTIVE and FISHEYE are supported)"
        )
    out = []
    for m in maps:
        r = cv2.remap(
            m, map1, map2, interpolation=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0
        )
        out.append(r[y : y + rh, x : x + rw])
    return out


class PhysGSDatamanager(FullImageDatamanager[PhysGSDataset]):
    """FullImageDatamanager over `PhysGSDataset`; material maps follow undistortion and the image cache."""

    config: PhysGSDatamanagerConfig

    @property
    def material_legend(self):
        return self.train_dataparser_outputs.metadata["material_legend"]

    def _load_images(
        self, split: Literal["train", "eval"], cache_images_device: Literal["cpu", "gpu"]
    ) -> list[dict[str, torch.Tensor]]:
        dataset = self.train_dataset if split == "train" else self.eval_dataset
        distorted_cameras = deepcopy(dataset.cameras)  # the parent replaces them by undistorted ones
        cached = super()._load_images(split, cache_images_device)
        for idx, data in enumerate(cached):
            cam = distorted_cameras[idx].reshape(())
            if cam.distortion_params is not None and torch.any(cam.distortion_params != 0):
                maps = [data[k][..., 0].numpy() for k in MAP_KEYS]
                undist = _undistort_maps(cam, maps)
                for k, m in zip(MAP_KEYS, undist):
                    data[k] = torch.from_numpy(np.ascontiguousarray(m))[..., None]
            if data["material"].shape[:2] != data["image"].shape[:2]:
                raise RuntimeError(
                    f"{split} image {idx}: material map {tuple(data['material'].shape[:2])} and image "
                    f"{tuple(data['image'].shape[:2])} differ after undistortion"
                )
            if cache_images_device == "gpu":
                for k in MAP_KEYS:
                    data[k] = data[k].to(self.device)
        return cached

    def material_views(
        self, split: Literal["train", "eval"] = "train"
    ) -> tuple[Cameras, list[dict[str, torch.Tensor]]]:
        """Cameras (undistorted) and cached data of a split, for lifting and evaluation."""
        cached = self.cached_train if split == "train" else self.cached_eval
        dataset = self.train_dataset if split == "train" else self.eval_dataset
        return dataset.cameras, cached
