"""The `physgs` command: one tyro subcommand per pipeline stage.

Each subcommand is a dataclass with a ``main()`` method that lives next to the code it drives; heavy
imports (nerfstudio, torch models) happen inside ``main()`` so ``physgs --help`` stays fast.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator
from contextlib import contextmanager
from typing import NoReturn

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

    args = list(sys.argv[1:] if argv is None else argv)
    with one_line_errors(f"physgs {args[0]}" if args and args[0] in COMMANDS else "physgs"):
        if args and args[0] in COMMANDS:  # one subcommand: import only its module (an export pays for no other)
            config = cli(_load(args[0]), prog=f"physgs {args[0]}", args=args[1:])
        elif any(a == "--settings" or a.startswith("--settings=") for a in args):
            raise SystemExit("give --settings after the command: physgs COMMAND --settings FILE.yaml")
        else:
            options = tuple(Annotated[_load(name), tyro.conf.subcommand(name)] for name in COMMANDS)
            config = tyro.cli(
                Union[options],  # type: ignore[valid-type]
                prog="physgs",
                description="PhysGS for nerfstudio: physical properties with uncertainty on Gaussian splats.",
                args=args,
            )
        config.main()
    return config


def main() -> None:
    """The ``physgs`` console script: :func:`entrypoint`, then, when the command finished and declares
    ``fast_exit`` (`physgs export`), the process ends at once (:func:`exit_now`) instead of tearing down its
    interpreter: unloading torch and its CUDA context took 0.3-0.4 s of a 6 s export on this project's machines,
    with nothing left to do. Such a command also runs without the cyclic garbage collector: it allocates few
    reference cycles (its arrays and tensors are freed by reference counting), and the collector's passes over
    the objects of torch's import took 0.1-0.2 s of the export.
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


MAX_LINE = 2000
"""the longest error line a command prints (a message quoting a huge input is cut)"""


def one_line(err: BaseException | str) -> str:
    """An error's message on one line: control characters (NUL, CR, escape sequences a server sent) become spaces,
    runs of white space one space, at most :data:`MAX_LINE` characters."""
    text = "".join(c if c.isprintable() else " " for c in str(err))
    text = " ".join(text.split()) or (type(err).__name__ if isinstance(err, BaseException) else "error")
    return text if len(text) <= MAX_LINE else text[: MAX_LINE - 3] + "..."


TRACEBACK_ENV = "PHYSGS_TRACEBACK"
"""set to 1 to get the traceback of an unexpected error instead of its one line"""


@contextmanager
def one_line_errors(prog: str) -> Iterator[None]:
    """The boundary of every command line entry point: whatever the command raises ends as one line on stderr,
    ``<prog>: error: <what>``, and exit status 1. A :class:`~physgs_nerfstudio.errors.PhysGSError` (a user error:
    what, where, what to do) prints its message; ``SystemExit`` with a message prints it the same way (tyro's
    own exits for ``--help`` and bad options, with their status, pass through); Ctrl-C prints ``interrupted``
    (status 130); an ``OSError`` names its file and the file system's reason; any other exception is a bug or an input no check caught: its type and message, and how to see
    its traceback (:data:`TRACEBACK_ENV`)."""
    import os
    import sys

    from physgs_nerfstudio.errors import PhysGSError

    def fail(message: str, code: int = 1) -> NoReturn:
        print(f"{prog}: error: {message}", file=sys.stderr)
        raise SystemExit(code) from None

    try:
        yield
    except PhysGSError as err:  # a user error: one line, no traceback
        fail(one_line(err))
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        raise SystemExit(130) from None
    except SystemExit as err:
        if err.code is None or isinstance(err.code, int):
            raise
        message = one_line(str(err.code))
        for prefix in (f"{prog}: error: ", f"{prog}: "):
            message = message.removeprefix(prefix)
        fail(message)
    except OSError as err:  # the file system's answer (a full disk, no permission, a file where a folder goes)
        where = f"{err.filename}: " if err.filename else ""
        fail(f"{where}{one_line(err.strerror or err)} ({type(err).__name__}); check the path, its permissions and "
             "the free space")
    except Exception as err:  # the boundary: nothing reaches the user as a traceback
        if os.environ.get(TRACEBACK_ENV):
            raise
        fail(f"{type(err).__name__}: {one_line(err)} (unexpected: set {TRACEBACK_ENV}=1 for where it came from, and "
             "report it)")


if __name__ == "__main__":
    main()
