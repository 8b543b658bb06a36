"""The one error type of evaluation inputs: names the file, the entry or line, what is wrong and the fix."""

from __future__ import annotations

from pathlib import Path

from ..errors import PhysGSError

__all__ = ["EvalInputError", "input_error"]


class EvalInputError(PhysGSError, ValueError):
    """A ground-truth or prediction file cannot be used as it is.

    ``str(error)`` reads ``<file>[, <where>]: <problem>. <fix>`` so a user can open the file at the entry.
    """

    def __init__(self, path: Path | str | None, where: str | None, problem: str, fix: str = ""):
        self.path = None if path is None else Path(path)
        self.where = where
        self.problem = problem
        self.fix = fix
        location = str(self.path) if self.path is not None else "<input>"
        if where:
            location += f", {where}"
        text = f"{location}: {problem.rstrip('.')}." if self.path is not None or where else f"{problem.rstrip('.')}."
        if fix:
            text += f" {fix.rstrip('.')}."
        super().__init__(text)


def input_error(path: Path | str | None, where: str | None, problem: str, fix: str = "") -> EvalInputError:
    """Build an :class:`EvalInputError` (for ``raise input_error(...)`` one-liners)."""
    return EvalInputError(path, where, problem, fix)
