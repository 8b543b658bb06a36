"""The end of a batch: one table of every scene's stages, the totals (VLM calls, tokens, cost, device
seconds, failures by reason) in ``OUT/batch_summary.json`` and ``OUT/batch_scenes.csv``, and the eval stage:
``physgs eval``'s scorer over all scenes with ground truth (generated scenes: ``ground_truth.json``; ABO-500:
the weights of the split) -> ``OUT/eval/eval.json``, ``summary.csv``, ``items.csv``."""

from __future__ import annotations

import csv
import json
from collections import Counter
from pathlib import Path

from .scenes import SceneSet
from .state import STAGES, load_state


def collect(output_dir: Path, names: list[str]) -> dict[str, dict]:
    return {n: load_state(output_dir, n) for n in names}


def totals(states: dict[str, dict]) -> dict:
    t = {"scenes": len(states), "complete": 0, "vlm_calls": 0, "cache_hits": 0, "prompt_tokens": 0,
         "completion_tokens": 0, "cost_usd": 0.0, "train_seconds": 0.0, "export_seconds": 0.0,
         "gpu_seconds": 0.0, "gpu_seconds_failed": 0.0, "failures": 0, "failures_by_reason": {}}  # fmt: skip
    reasons: Counter = Counter()
    for state in states.values():
        stages = state.get("stages", {})
        if all((stages.get(s) or {}).get("status") == "done" for s in STAGES):
            t["complete"] += 1
        p = (stages.get("perceive") or {}).get("metrics", {})
        for k in ("vlm_calls", "cache_hits", "prompt_tokens", "completion_tokens", "cost_usd"):
            t[k] += p.get(k, 0)
        for s, key in (("train", "train_seconds"), ("export", "export_seconds")):
            m = (stages.get(s) or {}).get("metrics", {})
            t[key] += m.get(key, 0.0)
            if m.get("device") == "cuda":
                t["gpu_seconds"] += m.get(key, 0.0)
            rec = stages.get(s) or {}
            if rec.get("status") == "failed" and rec.get("device") == "cuda":  # the GPU was held all the same
                t["gpu_seconds"] += rec.get("seconds", 0.0)
                t["gpu_seconds_failed"] += rec.get("seconds", 0.0)
        for s, rec in stages.items():
            if rec.get("status") == "failed":
                reasons[f"{s}: {rec.get('error_kind') or 'error'}"] += 1
            elif rec.get("status") == "running":
                reasons[f"{s}: interrupted"] += 1
    t["failures"] = sum(reasons.values())
    t["failures_by_reason"] = dict(reasons)
    return t


def _cell(rec: dict | None) -> str:
    if not rec:
        return "-"
    status = rec.get("status", "-")
    if status == "done":
        return f"done {rec.get('seconds', 0):.0f}s"
    return {"failed": "[red]failed[/]", "running": "[yellow]interrupted[/]"}.get(status, status)


def print_summary(states: dict[str, dict], tot: dict, console, max_rows: int = 50) -> None:
    from rich.markup import escape
    from rich.table import Table

    table = Table(title=f"physgs batch: {tot['complete']}/{tot['scenes']} scenes complete")
    for col in ("scene", *STAGES, "mass kg", "error"):
        table.add_column(col)
    for i, (name, state) in enumerate(states.items()):
        if i == max_rows:
            table.add_row(f"... {len(states) - max_rows} more (batch_scenes.csv)", *[""] * (len(STAGES) + 2))
            break
        st = state.get("stages", {})
        mass = (st.get("export") or {}).get("metrics", {}).get("mass_kg")
        err = next((r.get("error") for r in st.values() if r.get("status") == "failed"), "") or ""
        table.add_row(name, *(_cell(st.get(s)) for s in STAGES), f"{mass:.3g}" if mass is not None else "-",
                      escape(err[:80]))  # fmt: skip
    console.print(table)
    console.print(f"VLM calls {tot['vlm_calls']} (cache hits {tot['cache_hits']}), tokens "
                  f"{tot['prompt_tokens']} prompt / {tot['completion_tokens']} completion, cost ${tot['cost_usd']:.4f}; "
                  f"training {tot['train_seconds']:.0f} s, export {tot['export_seconds']:.0f} s "
                  f"(GPU-seconds {tot['gpu_seconds']:.0f}, {tot['gpu_seconds_failed']:.0f} of them in failed stages); "
                  f"failures {tot['failures']}"
                  + (": " + ", ".join(f"{k} x{v}" for k, v in tot["failures_by_reason"].items()) if tot["failures"] else ""))  # fmt: skip


def write_summary(output_dir: Path, states: dict[str, dict], tot: dict, extra: dict | None = None) -> dict[str, Path]:
    output_dir = Path(output_dir)
    paths = {"json": output_dir / "batch_summary.json", "csv": output_dir / "batch_scenes.csv"}
    paths["json"].write_text(json.dumps({"totals": tot, **(extra or {})}, indent=2))
    with open(paths["csv"], "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["scene", "data", *[f"{s}_{k}" for s in STAGES for k in ("status", "seconds")], "mass_kg", "error"])
        for name, state in states.items():
            st = state.get("stages", {})
            row = [name, state.get("data", "")]
            for s in STAGES:
                rec = st.get(s) or {}
                row += [rec.get("status", ""), f"{rec.get('seconds', 0.0):.2f}" if rec else ""]
            mass = (st.get("export") or {}).get("metrics", {}).get("mass_kg")
            err = next((r.get("error") for r in st.values() if r.get("status") == "failed"), "") or ""
            w.writerow(row + ["" if mass is None else f"{mass:.6g}", err])
    return paths


def run_batch_eval(output_dir: Path, scene_set: SceneSet, states: dict[str, dict], console):
    """Score every exported scene that has ground truth; writes OUT/eval/. None when nothing is scorable."""
    from ..eval.adapters.report import read_results_dir
    from ..eval.output import print_result, write_result
    from ..eval.scorer import ScoreConfig, score

    exported = [s for s in scene_set.scenes if (states.get(s.name, {}).get("stages", {}).get("export") or {}).get("status") == "done"]
    truth, protocol = [], {"dataset": "batch", "output_dir": str(output_dir)}
    synth = [s for s in scene_set.scenes if s.truth == "synth"]
    if synth:
        from ..eval.adapters.synth import read_synth_truth

        for s in synth:
            truth += read_synth_truth(s.data)
        protocol["synth_scenes"] = len(synth)
    if scene_set.kind == "abo500" and scene_set.abo_root is not None:
        from ..eval.adapters import abo500

        ds = abo500.load_abo500(scene_set.abo_root, scene_set.split or "test")
        names = {s.name for s in scene_set.scenes}
        truth += [m for m in ds.measurements if m.item in names]
        protocol.update(abo500_root=str(scene_set.abo_root), split=scene_set.split)
    if not truth or not exported:
        return None
    preds = read_results_dir(Path(output_dir) / "scenes", method="physgs")
    if scene_set.kind == "abo500":  # NeRF2Physics' protocol: items by id, point estimates as predicted (no clamp)
        preds = abo500.align_to_items(preds, [m.item for m in truth])
        protocol["clamp_kg"] = None
    protocol["predictions"] = [str(Path(output_dir) / "scenes")]
    result = score(truth, preds, ScoreConfig(), protocol)
    print_result(result, console=console)
    write_result(result, Path(output_dir) / "eval")
    return result
