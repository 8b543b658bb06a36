"""The base of the errors a user can fix: ``physgs`` prints them as one line, without a traceback.

Raise a subclass of :class:`PhysGSError` (usually mixed with the builtin it refines, e.g.
``class RunFilesError(PhysGSError, ValueError)``, so existing ``except ValueError`` callers still catch it)
whose message names what was wrong, where (the file), and what to do. ``physgs_nerfstudio.cli`` catches
``PhysGSError`` and prints ``physgs <command>: <message>``; anything else keeps its traceback (a bug).
"""

from __future__ import annotations

__all__ = ["PhysGSError"]


class PhysGSError(Exception):
    """A user error: bad input, a file that cannot be used, a full disk. ``str(err)`` is one line."""
