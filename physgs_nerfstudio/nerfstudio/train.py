"""`ns-train <method> ARGS` inside the calling process: the same configuration, parsed from the same arguments, and
nerfstudio's own ``Trainer`` (what ``nerfstudio.scripts.train`` runs on one device).

Why: ``ns-train`` builds a command line over every installed method, so a fresh process imports all of nerfstudio's
models and parses their union before it starts: on the 2-core CPU machine that took 17 s of the default demo's
run. ``physgs demo`` has most of those imports already, and parses one method.
``physgs batch`` runs it as ``python -m physgs_nerfstudio.nerfstudio.train METHOD ARGS``, a process per scene (a
kill or a crash leaves the batch's other scenes alone), without ``ns-train``'s start-up.
Single device only (``--machine.num-devices 1``); use ``ns-train`` for more.
"""

from __future__ import annotations

import random
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path

__all__ = ["main", "method_config", "train_in_process"]


def method_config(method: str):
    """A fresh ``TrainerConfig`` of one of this plugin's methods (the entry points of pyproject.toml)."""
    from method_configs import physgs_config

    factories = {"physgs": physgs_config.physgs_trainer_config,
                 "physgs-lite": physgs_config.physgs_lite_trainer_config}
    if method not in factories:
        raise ValueError(f"unknown method {method!r}: this plugin registers {', '.join(sorted(factories))}")
    return factories[method]()


def train_in_process(method: str, args: Sequence[str]) -> Path:
    """Train ``method`` as ``ns-train method *args`` would on one device, in this process; returns the run's
    config.yml. Bad arguments raise SystemExit with tyro's message, as on the command line."""
    import numpy as np
    import torch
    import tyro
    from nerfstudio.engine.trainer import TrainerConfig
    from nerfstudio.utils import writer
    from nerfstudio.utils.rich_utils import CONSOLE

    config = tyro.cli(tyro.conf.FlagConversionOff[TrainerConfig], default=method_config(method), args=list(args),
                      prog=f"ns-train {method}")  # fmt: skip
    if config.machine.num_devices * config.machine.num_machines != 1:
        raise SystemExit("training in the calling process runs on one device; run `ns-train` for more")
    if config.data:  # ns-train's --data alias
        CONSOLE.log("Using --data alias for --data.pipeline.datamanager.data")
        config.pipeline.datamanager.data = config.data
    config.set_timestamp()
    config.print_to_terminal()
    config.save_config()
    random.seed(config.machine.seed)  # ns-train's seeding (rank 0)
    np.random.seed(config.machine.seed)
    torch.manual_seed(config.machine.seed)
    writers = len(writer.EVENT_WRITERS)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            trainer = config.setup(local_rank=0, world_size=1)
            trainer.setup()
            trainer.train()
    finally:  # the run's event writers are its own: a later run in this process starts without them
        for w in writer.EVENT_WRITERS[writers:]:
            tb = getattr(w, "tb_writer", None)
            if tb is not None:
                tb.close()
        del writer.EVENT_WRITERS[writers:]
    return config.get_base_dir() / "config.yml"


def main(argv: Sequence[str] | None = None) -> None:
    """``python -m physgs_nerfstudio.nerfstudio.train METHOD ARGS``: ``ns-train METHOD ARGS`` on one device."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0].startswith("-"):
        raise SystemExit("usage: python -m physgs_nerfstudio.nerfstudio.train physgs|physgs-lite "
                         "[ns-train arguments]")
    try:
        method_config(args[0])
    except ValueError as e:
        raise SystemExit(str(e)) from None
    train_in_process(args[0], args[1:])


if __name__ == "__main__":
    from physgs_nerfstudio.cli import one_line_errors

    with one_line_errors("physgs train"):
        main()
