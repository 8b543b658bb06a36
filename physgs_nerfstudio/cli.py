"""The `physgs` command: one tyro subcommand per pipeline stage.

Each subcommand is a dataclass with a ``main()`` method that lives next to the code it drives; heavy
imports (nerfstudio, torch models) happen inside ``main()`` so ``physgs --help`` stays fast.
"""

from __future__ import annotations

import importlib

# name -> (module, dataclass). Order is the order of the pipeline, as shown by `physgs --help`.
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("physgs_nerfstudio.demo", "DemoCommand"),
    "synth": ("physgs_nerfstudio.synth.command", "SynthCommand"),
    "perceive": ("physgs_nerfstudio.perception.command", "PerceiveCommand"),
    "image": ("physgs_nerfstudio.single_image.command", "ImageCommand"),
    "materials": ("physgs_nerfstudio.info", "MaterialsCommand"),
    "export": ("physgs_nerfstudio.export.command", "ExportCommand"),
    "eval": ("physgs_nerfstudio.eval.command", "EvalCommand"),
    "batch": ("physgs_nerfstudio.batch.command", "BatchCommand"),
    "info": ("physgs_nerfstudio.info", "InfoCommand"),
}


def _load(name: str):
    module, cls = COMMANDS[name]
    return getattr(importlib.import_module(module), cls)


def entrypoint(argv: list[str] | None = None) -> object:
    """Parse ``argv`` (default: the process's arguments) and run the subcommand; returns the command's config."""
    import sys
    from typing import Annotated, Union

    import tyro

    from physgs_nerfstudio.advanced import cli
    from physgs_nerfstudio.errors import PhysGSError

    args = list(sys.argv[1:] if argv is None else argv)
    try:
        if args and args[0] in COMMANDS:  # one subcommand: import only its module (an export pays for no other)
            config = cli(_load(args[0]), prog=f"physgs {args[0]}", args=args[1:])
        else:
            options = tuple(Annotated[_load(name), tyro.conf.subcommand(name)] for name in COMMANDS)
            config = tyro.cli(
                Union[options],  # type: ignore[valid-type]
                prog="physgs",
                description="PhysGS for nerfstudio: physical properties with uncertainty on Gaussian splats.",
                args=args,
            )
        config.main()
    except PhysGSError as err:  # a user error: one line, no traceback
        print(f"physgs {args[0] if args else ''}: error: {one_line(err)}", file=sys.stderr)
        raise SystemExit(1) from None
    return config


def main() -> None:
    """The ``physgs`` console script: :func:`entrypoint`, then, when the command finished and declares
    ``fast_exit`` (`physgs export`), the process ends at once (:func:`exit_now`) instead of tearing down its
    interpreter: unloading torch and its CUDA context took 0.3-0.4 s of a 6 s export on this project's machines,
    with nothing left to do. Such a command also runs without the cyclic garbage collector: it allocates few
    reference cycles (its arrays and tensors are freed by reference counting), and the collector's passes over
    the objects of torch's import took 0.1-0.2 s of the export (benchmarks/README.md, session 18).
    ``PHYSGS_NO_FAST_EXIT=1`` keeps the normal exit and the collector."""
    import gc
    import os
    import sys

    fast = sys.argv[1:2] == ["export"] and not os.environ.get("PHYSGS_NO_FAST_EXIT")
    if fast:
        gc.disable()
    config = entrypoint()
    if fast and getattr(config, "fast_exit", False):
        exit_now(0)


def exit_now(code: int = 0) -> None:
    """End the process with ``code`` after flushing what it wrote (standard streams, logging handlers), skipping
    the interpreter's teardown (:func:`os._exit`). Only for a command whose work is complete: its files are closed
    and its threads are done."""
    import logging
    import os
    import sys

    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed or broken stream: nothing more can reach it
            pass
    os._exit(code)


def one_line(err: BaseException) -> str:
    """An error's message on one line (user-facing errors are printed without a traceback)."""
    return " ".join(str(err).split()) or type(err).__name__


if __name__ == "__main__":
    main()
