"""The local backend: scenes one after another on this machine (one scene per GPU with ``--gpus``), and
the perception of the next scene overlapping the training of the current one (``--overlap-perception``).
A scene's failure is recorded in its state and the batch goes on."""

from __future__ import annotations

import queue
import threading
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

from .runner import Policy, run_stage
from .scenes import Scene
from .stages import StageSettings


def run_local(scenes: list[Scene], stages: list[str], settings: StageSettings, output_dir: Path, policy: Policy,
              run_id: str, gpus: tuple[int, ...] = (), overlap_perception: bool = False, refresh=None) -> None:  # fmt: skip
    """Run ``stages`` of every scene; ``refresh()`` is called between stages (progress display)."""
    refresh = refresh or (lambda: None)
    later = [s for s in stages if s != "perceive"]
    perceive = "perceive" in stages

    def rest(scene: Scene, gpu: int | None) -> None:
        for stage in later:
            refresh()
            run_stage(scene, stage, settings, output_dir, policy, run_id, gpu=gpu)
        refresh()

    def perceive_one(scene: Scene) -> None:
        run_stage(scene, "perceive", settings, output_dir, policy, run_id)

    workers = list(gpus) or [None]
    if len(workers) == 1 and not (perceive and overlap_perception):
        for scene in scenes:
            if perceive:
                refresh()
                perceive_one(scene)
            rest(scene, workers[0])
        return
    # perception in one helper thread, at most one scene ahead of each trainer; one trainer per GPU
    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="physgs-perceive")
    futures: dict[str, Future] = {}
    jobs: queue.Queue = queue.Queue()
    for scene in scenes:
        jobs.put(scene)
    lock = threading.Lock()
    order = list(scenes)

    def perceived(scene: Scene) -> None:
        with lock:
            if perceive and scene.name not in futures:
                futures[scene.name] = pool.submit(perceive_one, scene)
            i = order.index(scene)
            for nxt in order[i + 1: i + 1 + len(workers)]:  # the next scenes' perception overlaps this training
                if perceive and nxt.name not in futures:
                    futures[nxt.name] = pool.submit(perceive_one, nxt)
            fut = futures.get(scene.name)
        if fut is not None:
            fut.result()

    def trainer(gpu: int | None) -> None:
        while True:
            try:
                scene = jobs.get_nowait()
            except queue.Empty:
                return
            perceived(scene)
            rest(scene, gpu)

    threads = [threading.Thread(target=trainer, args=(g,), name=f"physgs-train-{g}") for g in workers]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    pool.shutdown(wait=True)
