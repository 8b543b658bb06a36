"""`physgs batch`: perceive -> train -> export for many scenes, resumable, locally or on Ray.

Modules (one job each; docs/architecture.md, "Batch"):

* scenes.py - which scenes: a folder of datasets, the ABO-500 layout, a text file of paths, a generated suite;
* state.py - each scene's state on disk (stage done/failed, outputs, timing, one-line error);
* stages.py - the stage commands (perception in-process, ``ns-train`` subprocess, export, eval);
* runner.py - one stage of one scene with its state bookkeeping (shared by both backends);
* ratelimit.py - the shared VLM request/token bucket (a thread-safe object, or a Ray actor);
* local.py / ray_backend.py - the two backends; progress.py - the progress display;
* plan.py - ``--dry-run``: the plan and the cost/time estimate; summary.py - totals, table, eval files;
* command.py - the ``physgs batch`` command.
"""
