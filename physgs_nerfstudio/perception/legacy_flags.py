"""Deprecated command-line spellings of the perception settings, rewritten to the current ones.

Before the VLM and the segmenter were chosen by config type, they were flags: ``--vlm simulated``,
``--segmenter sam --sam-checkpoint P``. Scripts written then keep working: :func:`upgrade_argv` turns those
flags into the subcommands of :class:`~.config.PerceptionConfig` (``vlm:simulated``,
``segmenter:sam --segmenter.checkpoint P``), placed after the command's other arguments as tyro wants, and
says what to write instead.
"""

from __future__ import annotations

from collections.abc import Sequence

KINDS = {"--vlm": ("openai", "replay", "simulated"), "--segmenter": ("builtin", "sam")}
VLM_FLAGS = {"--model": "--vlm.model", "--base-url": "--vlm.base-url", "--api-key-env": "--vlm.api-key-env",
             "--replay-source": "--vlm.source"}  # fmt: skip
SEGMENTER_FLAGS = {"--sam-checkpoint": "--segmenter.checkpoint", "--sam-model-type": "--segmenter.model-type"}
HELP = (
    "Deprecated spellings, still accepted: --vlm NAME (now vlm:NAME), --segmenter NAME (segmenter:NAME), "
    "--sam-checkpoint P / --sam-model-type T (segmenter:sam --segmenter.checkpoint P --segmenter.model-type T), "
    "--model / --base-url / --api-key-env (vlm:openai --vlm.model ...), --replay-source S (vlm:replay "
    "--vlm.source S)."
)


class LegacyFlagError(ValueError):
    """Deprecated flags that cannot be rewritten (mixed with the new spelling, or an unknown choice)."""


def _split(argv: Sequence[str]) -> list[tuple[str, str | None]]:
    """Tokens as (flag, value) for the deprecated flags (value None when missing), (token, None) otherwise."""
    out: list[tuple[str, str | None]] = []
    legacy = {*KINDS, *VLM_FLAGS, *SEGMENTER_FLAGS}
    i = 0
    while i < len(argv):
        tok = argv[i]
        flag, eq, val = tok.partition("=")
        if flag in legacy:
            if not eq:
                val = argv[i + 1] if i + 1 < len(argv) else None
                i += 1
            out.append((flag, val))
        else:
            out.append((tok, None))
        i += 1
    return out


def upgrade_argv(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    """``argv`` with the deprecated perception flags rewritten; and one notice per rewritten flag."""
    tokens = _split(argv)
    rest = [t for t, v in tokens if t not in KINDS and t not in VLM_FLAGS and t not in SEGMENTER_FLAGS]
    found = [(t, v) for t, v in tokens if t in KINDS or t in VLM_FLAGS or t in SEGMENTER_FLAGS]
    if not found:
        return list(argv), []
    if any(t.startswith(("vlm:", "segmenter:")) for t in rest):
        raise LegacyFlagError("mixed spellings: write vlm:NAME / segmenter:NAME, not --vlm / --segmenter, with them")
    kinds: dict[str, str] = {}
    vlm_args: list[str] = []
    seg_args: list[str] = []
    notes = []
    for flag, val in found:
        if val is None:
            raise LegacyFlagError(f"{flag} needs a value")
        if flag in KINDS:
            if val not in KINDS[flag]:
                raise LegacyFlagError(f"{flag} {val}: choose one of {', '.join(KINDS[flag])}")
            kinds[flag] = val
            notes.append(f"{flag} {val} is deprecated: write {flag[2:]}:{val}")
        else:
            new = VLM_FLAGS.get(flag) or SEGMENTER_FLAGS[flag]
            (vlm_args if flag in VLM_FLAGS else seg_args).extend([new, val])
            notes.append(f"{flag} is deprecated: write {new}")
    vlm = kinds.get("--vlm", "replay" if "--vlm.source" in vlm_args else "openai" if vlm_args else None)
    seg = kinds.get("--segmenter", "sam" if seg_args else None)
    if vlm == "replay":  # the model of the answers is the replay config's; the endpoint flags do not apply
        vlm_args = [a for i, a in enumerate(vlm_args) if not _endpoint_only(vlm_args, i)]
    elif vlm == "simulated":
        vlm_args = []
    if seg == "builtin":
        seg_args = []
    out = list(rest)
    if vlm is not None:
        out += [f"vlm:{vlm}", *vlm_args]
    if seg is not None:
        out += [f"segmenter:{seg}", *seg_args]
    return out, notes


def _endpoint_only(args: list[str], i: int) -> bool:
    """Whether ``args[i]`` is (the value of) a flag a replay config has no field for."""
    j = i if i % 2 == 0 else i - 1
    return args[j] in ("--vlm.base-url", "--vlm.api-key-env")
