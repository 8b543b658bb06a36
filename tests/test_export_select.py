"""Object selection for the export: the Gaussians perception labelled, not the largest blob of geometry."""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np
import pytest
import torch

from physgs_nerfstudio.export.mass import MassConfig, integrate_mass
from physgs_nerfstudio.export.occupancy import OccupancyConfig, compute_occupancy, select_gaussians
from physgs_nerfstudio.export.shapes import field_from, solid_box
from physgs_nerfstudio.export.voxel import load_voxel_grid, write_voxel_grid

SPACING = 0.05
OBJECT = (0.3, 0.3, 0.3)  # 0.027 m^3, density 800 -> 21.6 kg
FLOOR = (1.2, 1.2, 0.1)  # 0.144 m^3 of unlabelled clutter right under the object (touching it)
RHO = 800.0


@pytest.fixture(scope="module")
def scene():
    """A labelled box standing on a larger unlabelled slab (the environment): one connected blob."""
    om, os_, oq = solid_box(OBJECT, SPACING, centre=(0.0, 0.0, 0.15))
    fm, fs, fq = solid_box(FLOOR, SPACING, centre=(0.0, 0.0, -0.05))
    n_obj, n_floor = om.shape[0], fm.shape[0]
    labels = torch.cat([torch.zeros(n_obj, dtype=torch.long), torch.ones(n_floor, dtype=torch.long)])
    pf = field_from(torch.cat([om, fm]), 0.5 * torch.cat([os_, fs]), torch.cat([oq, fq]), densities=[RHO, 3000.0],
                    labels=labels)  # fmt: skip
    # the floor was never labelled by the material maps: prior alpha, labelled fraction ~0, no evidence
    alpha = pf.alpha.clone()
    alpha[n_obj:] = 1.0
    labelled = torch.cat([torch.full((n_obj,), 0.9), torch.full((n_floor,), 0.02)])
    evidence = torch.cat([torch.full((n_obj,), 3.0), torch.zeros(n_floor)])
    pf = replace(pf, alpha=alpha, labelled=labelled, evidence=evidence)
    return pf, n_obj, n_floor


def cfg(**kw) -> MassConfig:
    occ = OccupancyConfig(resolution=48, progress=False, **kw)
    return MassConfig(occupancy=occ, n_samples=500)


def test_labelled_selection_excludes_unlabelled_clutter(scene):
    pf, n_obj, _ = scene
    r = integrate_mass(pf, cfg())  # select="auto" -> labelled
    assert r.geometry["select"] == "labelled" and r.geometry["selected_gaussians"] == n_obj
    assert r.volume_m3 == pytest.approx(np.prod(OBJECT), rel=0.06)
    assert r.mean_kg == pytest.approx(RHO * np.prod(OBJECT), rel=0.06)
    share = {m.name: m.volume_share for m in r.materials}
    assert share["material_0"] > 0.97
    # geometry alone takes the object together with the floor it stands on
    big = integrate_mass(pf, cfg(select="largest"))
    assert big.geometry["select"] == "largest"
    assert big.volume_m3 > 4 * r.volume_m3 and big.mean_kg > 5 * r.mean_kg


def test_thresholds_decide_membership(scene):
    pf, n_obj, n_floor = scene
    keep, mode = select_gaussians(pf, OccupancyConfig(min_labelled=0.5))
    assert mode == "labelled" and keep[:n_obj].all() and not keep[n_obj:].any()
    # a half-labelled floor passes a low labelled threshold, but not without evidence
    half = replace(pf, labelled=torch.cat([pf.labelled[:n_obj], torch.full((n_floor,), 0.3)]))
    keep, _ = select_gaussians(half, OccupancyConfig(min_labelled=0.2))
    assert int(keep.sum()) == n_obj
    with_ev = replace(half, evidence=torch.cat([pf.evidence[:n_obj], torch.full((n_floor,), 0.5)]))
    keep, _ = select_gaussians(with_ev, OccupancyConfig(min_labelled=0.2))
    assert int(keep.sum()) == n_obj + n_floor
    keep, _ = select_gaussians(with_ev, OccupancyConfig(min_labelled=0.5))
    assert int(keep.sum()) == n_obj
    # transparent Gaussians stay out whatever their labels
    faint = replace(pf, opacities=torch.cat([torch.full((n_obj,), 0.005), pf.opacities[n_obj:]]))
    keep, mode = select_gaussians(faint, OccupancyConfig())
    assert mode == "largest" and not keep[:n_obj].any()  # nothing labelled left: logged fallback


def test_fallback_without_labelled_fractions(scene, caplog):
    pf, _, _ = scene
    bare = replace(pf, labelled=None, evidence=None)
    with caplog.at_level(logging.INFO, logger="physgs_nerfstudio.export.occupancy"):
        r = integrate_mass(bare, cfg())
    assert r.geometry["select"] == "largest" and r.geometry["select_config"] == "auto"
    assert "no labelled fractions" in caplog.text
    explicit = integrate_mass(pf, cfg(select="largest"))
    assert r.mean_kg == pytest.approx(explicit.mean_kg, rel=1e-9)
    with pytest.raises(ValueError, match="labelled fractions"):
        compute_occupancy(bare, OccupancyConfig(select="labelled", progress=False))


def test_voxel_grid_uses_the_same_selection(scene, tmp_path):
    pf, n_obj, _ = scene
    occ_cfg = cfg().occupancy
    d = load_voxel_grid(write_voxel_grid(pf, tmp_path / "v.npz", occ_cfg))
    vol = float((d["volume_fraction"]).sum()) * float(d["voxel_size_m"]) ** 3
    assert vol == pytest.approx(np.prod(OBJECT), rel=0.06)
    assert (
        d["meta"]["occupancy"]["select"] == "labelled"
        and d["meta"]["occupancy"]["selected_gaussians"] == n_obj
    )
    occ = d["occupancy"].astype(bool)
    assert (d["material_index"][occ] == 0).all()  # the floor's prior mixture does not leak into the object
    # the object's centre stays where the box is (z from 0 to 0.3)
    idx = np.argwhere(occ)
    z = d["origin_scene"][2] + (idx[:, 2] + 0.5) * float(d["voxel_size_scene"])
    assert z.min() > -0.05 and z.max() < 0.35


def test_field_checks_labelled_shape(scene):
    pf, _, _ = scene
    with pytest.raises(ValueError, match="labelled must be"):
        replace(pf, labelled=torch.ones(3))
    sub = pf.subset(torch.arange(10))
    assert sub.labelled.shape == (10,) and sub.evidence.shape == (10,)
