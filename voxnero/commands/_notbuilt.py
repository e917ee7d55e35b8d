"""Helper for commands whose stage is not built yet: they say so plainly, no fake output."""

from __future__ import annotations

from voxnero.errors import NotBuiltError


def not_built(command: str, issue: str) -> int:
    """Raise a clear :class:`NotBuiltError` for ``command`` (tracked in ``issue``)."""
    raise NotBuiltError(f"'voxnero {command}' is not built yet ({issue}); nothing was written")
