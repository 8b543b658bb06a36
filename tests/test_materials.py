"""Material libraries: data validity, hardness scales, alias lookup, user files, NIG priors."""

from __future__ import annotations

import itertools
import logging
import math
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from physgs_nerfstudio.materials import (
    PROPERTY_KEYS,
    MaterialLibrary,
    MaterialLibraryError,
    PriorConfig,
    load_library,
    log_space_flags,
)
from physgs_nerfstudio.materials import hardness as H

DATA = Path(__file__).resolve().parents[1] / "physgs_nerfstudio" / "materials" / "data"

# Ewen et al. 2022 terrain classes (PhysGS paper Table B.2): name -> (mean, sigma)
PAPER_FRICTION = {
    "indoor": {"concrete": (0.543, 0.065), "wood": (0.372, 0.055), "rubber": (0.616, 0.048),
               "carpet": (0.583, 0.068), "laminated_flooring": (0.311, 0.045)},
    "outdoor": {"concrete": (0.543, 0.065), "wood": (0.372, 0.055), "rubber": (0.616, 0.048),
                "pebbles": (0.428, 0.059), "rock": (0.478, 0.113)},
}


@pytest.fixture(scope="module")
def libs() -> dict[str, MaterialLibrary]:
    return {env: load_library(env) for env in ("indoor", "outdoor")}


# ----------------------------------------------------------------------------------- built-in data

def test_libraries_load_with_enough_materials(libs):
    assert libs["indoor"].env == "indoor" and len(libs["indoor"]) >= 45
    assert libs["outdoor"].env == "outdoor" and len(libs["outdoor"]) >= 22
    for lib in libs.values():
        assert lib.names == [m.name for m in lib.materials]
        assert [lib.index(n) for n in lib.names] == list(range(len(lib)))


@pytest.mark.parametrize("env", ["indoor", "outdoor"])
def test_every_material_is_valid(libs, env):
    for m in libs[env]:
        assert tuple(m.properties) == PROPERTY_KEYS, m.name
        for key, r in m.properties.items():
            assert r.low <= r.typical <= r.high and r.low < r.high, (m.name, key)
            assert all(math.isfinite(v) for v in r.as_tuple()), (m.name, key)
        assert m.properties["density"].low > 0 and m.properties["youngs_modulus"].low > 0, m.name
        assert 0 <= m.properties["kinetic_friction"].low and m.properties["kinetic_friction"].high <= 2, m.name
        assert m.hardness_scale in H.SCALES
        q = m.quoted_hardness()
        assert 0 <= q.low and q.high <= 100 + 1e-9, m.name
        assert m.thickness_m is None or 0 < m.thickness_m < 0.1, m.name
        assert set(m.confusable) <= set(libs[env].names) and m.name not in m.confusable
        assert m.source.strip() and m.category.strip()
        assert libs[env].resolve(m.name) == m.name
        for alias in m.aliases:
            assert libs[env].resolve(alias) == m.name, (alias, m.name)


@pytest.mark.parametrize("env", ["indoor", "outdoor"])
def test_colours_unique_and_distinguishable(libs, env):
    colours = np.array(libs[env].colors(), dtype=float)
    assert len({tuple(c) for c in colours}) == len(colours)
    dist = min(np.linalg.norm(a - b) for a, b in itertools.combinations(colours, 2))
    assert dist >= 20.0, f"two legend colours of {env} are only {dist:.1f} apart in RGB"
    # nothing that reads as the black background (label 0 = unknown)
    assert colours.sum(axis=1).min() >= 60


@pytest.mark.parametrize("env", ["indoor", "outdoor"])
def test_paper_terrain_classes_use_paper_friction(libs, env):
    for name, (mean, sigma) in PAPER_FRICTION[env].items():
        m = libs[env][name]
        r = m.properties["kinetic_friction"]
        assert r.typical == pytest.approx(mean)
        assert r.low == pytest.approx(mean - 2 * sigma, abs=1e-3)
        assert r.high == pytest.approx(mean + 2 * sigma, abs=1e-3)
        assert "Ewen et al. 2022" in m.source


def test_quoted_hardness_matches_the_yaml(libs):
    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
    raw = yaml.load((DATA / "indoor.yaml").read_text(), Loader=loader)["materials"]
    for entry in raw:
        m = libs["indoor"][entry["name"]]
        q = m.quoted_hardness()
        assert m.hardness_scale == entry["shore_hardness"]["scale"]
        assert q.typical == pytest.approx(entry["shore_hardness"]["typical"], abs=1e-9)
        assert q.low == pytest.approx(entry["shore_hardness"]["low"], abs=1e-9)


def test_thickness_for_manufactured_none_for_natural(libs):
    assert libs["indoor"]["steel"].thickness_m is not None
    assert libs["indoor"]["polyurethane_foam"].thickness_m is None
    assert all(libs["outdoor"][n].thickness_m is None for n in ("soil", "rock", "water", "grass"))


# ----------------------------------------------------------------------------------------- hardness

def test_hardness_anchor_points():
    assert H.to_canonical(70.0, "A") == pytest.approx(70.0)
    assert H.to_canonical(58.0, "D") == pytest.approx(100.0)
    assert H.to_canonical(100.0, "D") == pytest.approx(142.0)
    assert H.to_canonical(45.0, "00") == pytest.approx(5.0)
    assert H.convert(90.0, "A", "D") == pytest.approx(39.0)
    assert H.convert(80.0, "A", "00") == pytest.approx(98.0)
    assert H.to_canonical(0.0, "00") < H.to_canonical(0.0, "A") < H.to_canonical(100.0, "A") < H.to_canonical(
        100.0, "D")


@pytest.mark.parametrize("scale", H.SCALES)
def test_hardness_strictly_monotone(scale):
    x = np.linspace(-20.0, 120.0, 2801)
    y = H.to_canonical(x, scale)
    assert np.all(np.diff(y) > 0)
    h = np.linspace(-40.0, 160.0, 4001)
    assert np.all(np.diff(H.from_canonical(h, scale)) > 0)


@settings(max_examples=300, deadline=None)
@given(v=st.floats(-50, 200), s1=st.sampled_from(H.SCALES), s2=st.sampled_from(H.SCALES))
def test_hardness_round_trip(v, s1, s2):
    assert H.from_canonical(H.to_canonical(v, s1), s1) == pytest.approx(v, abs=1e-9)
    assert H.to_canonical(H.from_canonical(v, s1), s1) == pytest.approx(v, abs=1e-9)
    assert H.convert(H.convert(v, s1, s2), s2, s1) == pytest.approx(v, abs=1e-8)


def test_hardness_torch_matches_numpy_and_is_differentiable():
    x = torch.linspace(0, 100, 101, dtype=torch.float64, requires_grad=True)
    y = H.to_canonical(x, "D")
    assert torch.allclose(y.detach(), torch.as_tensor(H.to_canonical(x.detach().numpy(), "D")))
    y.sum().backward()
    assert torch.all(x.grad > 0)
    back = H.from_canonical(y.detach(), "D")
    assert torch.allclose(back, x.detach())


def test_hardness_scale_names():
    assert H.normalize_scale("shore d") == "D" and H.normalize_scale("OO") == "00"
    with pytest.raises(TypeError, match="quote"):
        H.normalize_scale(0)  # unquoted 00 in YAML
    with pytest.raises(ValueError, match="unknown hardness scale"):
        H.normalize_scale("Rockwell C")


# ------------------------------------------------------------------------------------------ aliases

@pytest.mark.parametrize(
    "env,text,expected",
    [
        ("indoor", "Stainless Steel", "stainless_steel"),
        ("indoor", "stainless-steel", "stainless_steel"),
        ("indoor", "STAINLESS_STEEL", "stainless_steel"),
        ("indoor", "inox", "stainless_steel"),
        ("indoor", "Pine Wood", "pine"),
        ("indoor", "styrofoam", "eps"),
        ("indoor", "Acrylic (PMMA)", "acrylic"),
        ("indoor", "aluminum", "aluminium"),
        ("indoor", "ceramics", "ceramic"),
        ("indoor", "Laminate Flooring", "laminated_flooring"),
        ("outdoor", "Pebbles", "pebbles"),
        ("outdoor", "rocks", "rock"),
        ("outdoor", "bushes", "shrubs"),
        ("outdoor", "tarmac", "asphalt"),
        ("indoor", "unobtainium", None),
        ("outdoor", "", None),
    ],
)
def test_resolve(libs, env, text, expected):
    assert libs[env].resolve(text) == expected


def test_index_error_is_helpful(libs):
    with pytest.raises(KeyError, match="stainless_steel"):
        libs["indoor"].index("Stainless Steel")
    with pytest.raises(KeyError, match="not in the 'indoor' library"):
        libs["indoor"].index("unobtainium")


# ------------------------------------------------------------------------------------- user files

GOOD_ENTRY = {
    "name": "jade",
    "category": "stone",
    "aliases": ["nephrite", "jadeite"],
    "color": [0, 168, 107],
    "density": {"typical": 3000, "low": 2900, "high": 3300},
    "kinetic_friction": {"typical": 0.4, "low": 0.3, "high": 0.5},
    "shore_hardness": {"scale": "D", "typical": 96, "low": 92, "high": 99},
    "youngs_modulus": {"typical": "9e10", "low": "7e10", "high": "1.1e11"},  # numeric strings are accepted
    "thickness_m": None,
    "confusable": ["marble"],
    "source": "test entry",
}


def _write(tmp_path: Path, entries, name: str = "user.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump({"materials": entries}, sort_keys=False))
    return path


def test_user_file_extends_and_overrides(tmp_path, caplog):
    base = load_library("indoor")
    override = dict(GOOD_ENTRY, name="oak", aliases=["oak wood"], color=[1, 2, 250],
                    density={"typical": 700, "low": 650, "high": 750}, confusable=[])
    path = _write(tmp_path, [GOOD_ENTRY, override])
    with caplog.at_level(logging.WARNING, logger="physgs_nerfstudio.materials.library"):
        lib = load_library("indoor", extra_files=[path])
    assert len(lib) == len(base) + 1 and lib.names[-1] == "jade"
    assert lib.resolve("Nephrite") == "jade"
    assert lib["jade"].properties["youngs_modulus"].typical == 9e10
    assert lib["oak"].properties["density"].typical == 700 and lib.index("oak") == base.index("oak")
    assert lib.resolve("red oak") is None  # the override replaced the whole entry, aliases included
    assert any("'oak'" in r.getMessage() and "overrides" in r.getMessage() for r in caplog.records)
    assert str(path) in lib.sources


def test_library_from_a_path(tmp_path):
    path = _write(tmp_path, [dict(GOOD_ENTRY, confusable=[])], name="lab.yaml")
    lib = load_library(path)
    assert lib.env == "lab" and lib.names == ["jade"]
    with pytest.raises(MaterialLibraryError, match="neither a built-in environment"):
        load_library(tmp_path / "missing.yaml")


def _replace(**changes):
    entry = dict(GOOD_ENTRY)
    for key, value in changes.items():
        if value is KeyError:
            entry.pop(key)
        else:
            entry[key] = value
    return entry


@pytest.mark.parametrize(
    "entry,message",
    [
        (_replace(density={"typical": 1000, "low": 2900, "high": 3300}), "low <= typical <= high"),
        (_replace(aliases=["Stainless Steel"]), "collides with material 'stainless_steel'"),
        (_replace(aliases=["inox"]), "collides with material 'stainless_steel'"),
        (_replace(name="oak_veneer"), "collides with material 'oak'"),
        (_replace(confusable=["kryptonite"]), "confusable 'kryptonite'"),
        (_replace(kinetic_friction={"typical": "slippery", "low": 0.3, "high": 0.5}), "must be a number"),
        (_replace(density={"typical": True, "low": 2900, "high": 3300}), "must be a number"),
        (_replace(kinetic_friction={"typical": 2.5, "low": 0.3, "high": 3.0}), r"in \[0, 2\]"),
        (_replace(youngs_modulus={"typical": -1, "low": -2, "high": 1}), "youngs_modulus must be > 0"),
        (_replace(shore_hardness={"scale": 0, "typical": 20, "low": 10, "high": 30}), "quoted"),
        (_replace(shore_hardness={"scale": "Z", "typical": 20, "low": 10, "high": 30}), "unknown hardness scale"),
        (_replace(shore_hardness={"scale": "A", "typical": 90, "low": 80, "high": 120}), r"in \[0, 100\]"),
        (_replace(density={"typical": 1, "low": 1, "high": 1}), "low < high"),
        (_replace(colour=[1, 2, 3]), "unknown keys"),
        (_replace(source=KeyError), "missing required fields"),
        (_replace(color=[0, 300, 0]), "color"),
        (_replace(color=list(load_library("indoor")["oak"].color)), "already used by 'oak'"),
        (_replace(name="Jade Stone"), "snake_case"),
        (_replace(thickness_m=3), "thickness_m"),
    ],
)
def test_broken_user_file_is_rejected_naming_file_and_entry(tmp_path, entry, message):
    path = _write(tmp_path, [entry])
    with pytest.raises(MaterialLibraryError, match=message) as info:
        load_library("indoor", extra_files=[path])
    text = str(info.value)
    assert str(path) in text
    assert "entry 0" in text


def test_duplicate_name_within_a_file(tmp_path):
    path = _write(tmp_path, [GOOD_ENTRY, dict(GOOD_ENTRY, aliases=[], color=[9, 9, 9])])
    with pytest.raises(MaterialLibraryError, match=r"entry 1 \('jade'\): duplicate name"):
        load_library("indoor", extra_files=[path])


def test_malformed_files(tmp_path):
    bad_yaml = tmp_path / "bad.yaml"
    bad_yaml.write_text("materials: [ {name: x\n")
    with pytest.raises(MaterialLibraryError, match="not valid YAML"):
        load_library("indoor", extra_files=[bad_yaml])
    no_list = tmp_path / "nolist.yaml"
    no_list.write_text("foo: 1\n")
    with pytest.raises(MaterialLibraryError, match="'materials:' list"):
        load_library("indoor", extra_files=[no_list])


# ------------------------------------------------------------------------------------------- priors

@pytest.mark.parametrize("env", ["indoor", "outdoor"])
def test_nig_prior_matches_library(libs, env):
    lib = libs[env]
    cfg = PriorConfig()
    nig = lib.nig_prior()
    assert nig.tau.shape == (len(lib), len(PROPERTY_KEYS)) and nig.tau.dtype == torch.float64
    flags = log_space_flags(cfg)
    assert flags == (True, False, False, True)
    for i, m in enumerate(lib):
        for k, key in enumerate(PROPERTY_KEYS):
            r = m.properties[key]
            f = math.log if flags[k] else (lambda v: v)
            sigma0 = (f(r.high) - f(r.low)) / 4.0
            assert nig.tau[i, k].item() == pytest.approx(f(r.typical), rel=1e-12, abs=1e-12)
            assert nig.aleatoric()[i, k].item() == pytest.approx(sigma0**2, rel=1e-12)
            assert nig.kappa[i, k].item() == cfg.kappa0 and nig.a[i, k].item() == cfg.a0


def test_nig_prior_subset_config_and_errors(libs):
    lib = libs["indoor"]
    cfg = PriorConfig(kappa0=3.0, a0=5.0, log_space={"density": False})
    nig = lib.nig_prior(["glass", "Stainless Steel"], cfg)
    assert nig.tau.shape == (2, len(PROPERTY_KEYS))
    assert nig.tau[0, 0].item() == pytest.approx(lib["glass"].properties["density"].typical)
    assert nig.tau[1, 3].item() == pytest.approx(math.log(lib["stainless_steel"].properties["youngs_modulus"].typical))
    assert torch.all(nig.kappa == 3.0) and torch.all(nig.a == 5.0)
    r = lib["glass"].properties["density"]
    assert nig.aleatoric()[0, 0].item() == pytest.approx(((r.high - r.low) / 4) ** 2)
    with pytest.raises(KeyError):
        lib.nig_prior(["unobtainium"])
    with pytest.raises(ValueError, match="a0 must be > 1"):
        PriorConfig(a0=1.0)
    with pytest.raises(ValueError, match="unknown property keys"):
        PriorConfig(log_space={"mass": True})
    # water's hardness sits below Shore A 0 (negative A_eq): it cannot be fused in log space
    with pytest.raises(ValueError, match="'water'.*shore_hardness in log space"):
        libs["outdoor"].nig_prior(["water"], PriorConfig(log_space={"shore_hardness": True}))
