"""`physgs demo` end to end on a tiny setting (generated scene, simulated VLM, physgs-lite on CPU, export)."""

from __future__ import annotations

import json

import pytest

from physgs_nerfstudio.demo import DemoCommand


@pytest.mark.slow
def test_demo_end_to_end(tmp_path, capsys, monkeypatch):
    cmd = DemoCommand(output_dir=tmp_path / "demo", views=8, resolution=48, iterations=30, export_resolution=48,
                      n_samples=500)  # fmt: skip
    cmd.main()
    out = capsys.readouterr().out
    assert "SIMULATED VLM" in out and "Predicted vs ground-truth mass" in out
    summary = json.loads((tmp_path / "demo" / "demo_summary.json").read_text())
    gt = json.loads((tmp_path / "demo" / "scene" / "ground_truth.json").read_text())
    truth = gt["total_mass_kg"]
    assert summary["truth_kg"] == pytest.approx(truth)
    assert summary["predicted_kg"] > 0 and summary["interval_kg"][0] <= summary["interval_kg"][1]
    assert set(summary["metrics"]) == {"ADE", "ALDE", "APE", "MnRE"} and summary["simulated_vlm"] is True
    for name in ("property_field.ply", "voxels.npz", "report.json"):
        assert (tmp_path / "demo" / "export" / name).exists()
    report = json.loads((tmp_path / "demo" / "export" / "report.json").read_text())
    mass = report["mass"]
    for key in ("mean_kg", "median_kg", "interval_kg", "level", "volume_m3", "area_m2", "materials",
                "metres_per_unit", "scale_source", "simulated", "geometry", "units"):  # fmt: skip
        assert key in mass, key
    assert mass["mean_kg"] == pytest.approx(summary["predicted_kg"]) and mass["simulated"] is True
    assert report["ground_truth_kg"] == pytest.approx(truth)
    assert sum(m["volume_share"] for m in mass["materials"]) == pytest.approx(1.0, abs=1e-6)
    # the object is what perception labelled, not the environment the splat also reconstructs
    geo = mass["geometry"]
    assert 0 < geo["selected_gaussians"] < geo["num_gaussians"]
    # the mug (~0.45 kg, ~0.13 m across with its handle): a mug-sized object and mass, not a room's
    side = max(geo["grid"]["shape"]) * geo["voxel_size_m"]
    assert 0.05 < side < 0.3, side
    # within 10x: the tiny setting (8 views, 48 px, 30 iterations) is coarse, and with some seeds perception
    # labels the mug in few views (seed 2: 0.09 kg); selecting the environment instead gave ~64 kg
    assert truth / 10 < summary["predicted_kg"] < 10 * truth, summary
    # resumable: a second run skips every stage and reprints the same prediction
    cmd.main()
    again = json.loads((tmp_path / "demo" / "demo_summary.json").read_text())
    assert again["predicted_kg"] == pytest.approx(summary["predicted_kg"])
    assert "skipped" in capsys.readouterr().out
    _check_geometry_cache(cmd, tmp_path, report, monkeypatch)


def _check_geometry_cache(cmd: DemoCommand, tmp_path, report: dict, monkeypatch) -> None:
    """The geometry cache (export/geometry_cache.py) on the demo's run: the demo's export stored its geometry, an
    export of the same run and settings reads it instead of carving (the same mass, bit for bit), and the training
    pipeline's precompute stores the default export's geometry, which a default `physgs export` then reads."""
    from dataclasses import replace
    from types import SimpleNamespace

    import torch

    from physgs_nerfstudio.export import command as export_command
    from physgs_nerfstudio.mass import MassConfig
    from physgs_nerfstudio.nerfstudio.pipeline import PhysGSPipeline

    run_cfg = next((tmp_path / "demo" / "runs").rglob("config.yml"))
    cache_dir = run_cfg.parent / "physgs_cache"
    assert len(list(cache_dir.glob("geometry-*.pt"))) == 1
    # the pipeline's precompute: "auto" does nothing on a CPU, "on" stores the default export's geometry
    fake = SimpleNamespace(config=SimpleNamespace(precompute_geometry="auto"),
                           model=SimpleNamespace(device=torch.device("cpu")))  # fmt: skip
    PhysGSPipeline._precompute_geometry(fake, run_cfg, 29)
    assert len(list(cache_dir.glob("geometry-*.pt"))) == 1
    fake.config.precompute_geometry = "on"
    PhysGSPipeline._precompute_geometry(fake, run_cfg, 29)
    assert len(list(cache_dir.glob("geometry-*.pt"))) == 2

    def no_carving(*args, **kwargs):
        raise AssertionError("the geometry was computed again instead of read from the cache")

    monkeypatch.setattr(export_command, "object_geometry", no_carving)
    base = MassConfig()
    mass = replace(base, geometry=replace(base.geometry, resolution=cmd.export_resolution), n_samples=cmd.n_samples,
                   seed=cmd.seed)  # fmt: skip
    again = export_command.ExportCommand(load_config=run_cfg, output_dir=tmp_path / "again", mass=mass, views=(0,),
                                         device="cpu").main()  # fmt: skip
    first = report["mass"]
    assert again.mass.mean_kg == first["mean_kg"] and list(again.mass.interval_kg) == first["interval_kg"]
    assert report["geometry_source"] == "computed"
    assert json.loads((tmp_path / "again" / "report.json").read_text())["geometry_source"] == "stored"
    default = export_command.ExportCommand(load_config=run_cfg, output_dir=tmp_path / "default", outputs=("mass",),
                                           device="cpu").main()  # fmt: skip
    assert default.mass is not None and default.mass.mean_kg > 0
    # --no-geometry-cache computes it (the patched carving is called)
    with pytest.raises(AssertionError, match="computed again"):
        export_command.ExportCommand(load_config=run_cfg, output_dir=tmp_path / "cold", outputs=("mass",),
                                     device="cpu", geometry_cache=False).main()  # fmt: skip



def test_training_in_process_takes_ns_train_arguments(tmp_path):
    # the demo's training (physgs_nerfstudio/nerfstudio/train.py) parses ns-train's arguments for one method: a
    # method this plugin does not register, a bad flag and more than one device stop before anything is written
    from physgs_nerfstudio.nerfstudio.train import method_config, train_in_process

    assert method_config("physgs-lite").method_name == "physgs-lite"
    assert method_config("physgs").method_name == "physgs"
    with pytest.raises(ValueError, match="unknown method 'splatfacto'"):
        method_config("splatfacto")
    with pytest.raises(SystemExit):
        train_in_process("physgs-lite", ["--output-dir", str(tmp_path), "--no-such-flag", "1"])
    with pytest.raises(SystemExit, match="one device"):
        train_in_process("physgs-lite", ["--output-dir", str(tmp_path), "--machine.num-devices", "2"])
    assert not any(tmp_path.iterdir())


def test_the_one_method_entry_says_what_is_wrong():
    # `python -m physgs_nerfstudio.nerfstudio.train METHOD ARGS` (physgs batch's training subprocess)
    from physgs_nerfstudio.nerfstudio.train import main

    with pytest.raises(SystemExit, match="usage"):
        main([])
    with pytest.raises(SystemExit, match="unknown method 'splatfacto'"):
        main(["splatfacto", "--data", "x"])


def _written_report(path, mass_kg: float | None, mass_error: str | None = None):
    """report.json as the export writes it (export/report.py): a mass, or mass null with the reason."""
    from physgs_nerfstudio.export.report import write_report
    from physgs_nerfstudio.mass import MassReport
    from physgs_nerfstudio.mass.integrate import MaterialMass

    report = None
    if mass_kg is not None:
        mat = MaterialMass("oak", "solid", None, 0.002, 1.0, 0.1, 700.0, (600.0, 800.0), mass_kg, (1.0, 1.6), 1.0)
        report = MassReport(mass_kg, mass_kg, (1.0, 1.6), 0.9, 100, 3, 0.002, 0.1, [mat], 1.0, "dataset", True, {})
    return write_report(report, path, {"mass_error": mass_error} if mass_error else {"ground_truth_kg": 1.2})


def test_demo_resumes_from_an_export_without_a_mass(tmp_path):
    """A demo resumed after an export whose geometry failed (report.json: mass null, mass_error) ends with one
    line naming the file, the export's reason and the `physgs export` that redoes it, not a TypeError; a report
    with a mass is read back as written."""
    from rich.console import Console

    from physgs_nerfstudio.errors import PhysGSError

    cmd = DemoCommand(output_dir=tmp_path, seed=70001, export_resolution=64, n_samples=900)
    console = Console(record=True, width=200)
    config = tmp_path / "runs" / "config.yml"
    why = "carving left no solid voxel: the object masks and the views disagree (check poses and masks)."
    path = _written_report(tmp_path / "export" / "report.json", None, why)
    with pytest.raises(PhysGSError) as err:
        cmd.stage_export(console, config, truth_kg=1.2)
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(f"{path}: ") and why.rstrip(".") in msg
    assert f"physgs export --load-config {config} --output-dir {path.parent}" in msg
    assert "--mass.geometry.resolution 64 --mass.n-samples 900 --mass.seed 70001" in msg
    assert path.is_file()  # the earlier export is kept
    path = _written_report(tmp_path / "export" / "report.json", 1.3)
    report = cmd.stage_export(console, config, truth_kg=1.2)
    assert report.mean_kg == 1.3 and report.interval_kg == (1.0, 1.6) and report.materials[0].name == "oak"
    shown = console.export_text()
    assert "report.json exists, skipped" in shown and "1.3" in shown
