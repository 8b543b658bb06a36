"""Errors meant for the person at the command line.

A :class:`PhysGSError` says what was wrong, where, and what to do, in one line; the ``physgs`` command prints
its message without a traceback and exits with status 1 (cli.py). Subclasses also derive from the builtin
exception a caller would have caught before (``ValueError``, ``RuntimeError``), so existing ``except``
clauses keep working.
"""

from __future__ import annotations


class PhysGSError(Exception):
    """A user-facing error: its message is printed as one line, without a traceback."""


class DatasetError(PhysGSError, ValueError):
    """A dataset that cannot be used as it is: a malformed transforms.json, an unreadable image, a frame path
    outside the dataset. The message names the file and the fix."""
