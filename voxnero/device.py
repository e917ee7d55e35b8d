"""Choice of the torch device: CUDA when available, else CPU. Nothing requires a GPU."""

from __future__ import annotations

import torch


def default_device(requested: str | None = None) -> torch.device:
    """Return the torch device to compute on.

    Args:
        requested: "cpu", "cuda", "cuda:N" or None/"auto" (CUDA if available, else CPU).
    """
    if requested in (None, "", "auto"):
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    dev = torch.device(requested)
    if dev.type == "cuda" and not torch.cuda.is_available():
        from voxnero.errors import ConfigError

        raise ConfigError(f"device={requested!r} asked for, but CUDA is not available",
                          fix="use device=auto or device=cpu")
    return dev
