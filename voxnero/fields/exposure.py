"""Per-image exposure and white balance: a gain per training photo and colour channel.

Real captures are not always taken at one exposure: on dtu_scan97 the same surface point reads
0.54–1.26× from photo to photo on the object, 0.57–1.67× on the table (docs/STAGE1.md,
finding 20), which no static
light can explain, so the surface bends to explain it. The photo of image ``i`` is modelled as
``gain_i · rendered`` with a gain per channel (exposure and white balance)::

    gain_i = exp(g_i − mean_j g_j)           (linear RGB, per channel)

The mean is removed so that the gains cannot trade a global scale against the light (the env
map keeps the photos' mean exposure; held-out views render at gain 1, the mean exposure). The
gains multiply everything a photo shows (object and background) in linear radiance.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch
from torch import nn


class ImageGains(nn.Module):
    """Learnable per-image, per-channel gains with their geometric mean fixed at 1.

    Args:
        n_images: training photos.
        log_init: optional ``(n_images, 3)`` initial log gains (centred here).
    """

    def __init__(self, n_images: int, log_init: torch.Tensor | None = None):
        super().__init__()
        self.log_gain = nn.Parameter(torch.zeros(n_images, 3))
        if log_init is not None:
            with torch.no_grad():
                self.log_gain.copy_(log_init.reshape(n_images, 3))

    def gains(self) -> torch.Tensor:
        """``(n_images, 3)`` linear gains, geometric mean 1 per channel."""
        g = self.log_gain
        return torch.exp(g - g.mean(0, keepdim=True))

    def forward(self, rgb: torch.Tensor, image: torch.Tensor) -> torch.Tensor:
        """``rgb (R, 3)`` linear radiance rendered for pixels of training images ``image``
        ``(R,)`` (long) → the photos' expected linear RGB ``(R, 3)``."""
        return rgb * self.gains()[image]


def measure_log_gains(pred: torch.Tensor, target: torch.Tensor, image: torch.Tensor,
                      n_images: int, lo: float = 0.02, hi: float = 0.95
                      ) -> tuple[torch.Tensor, torch.Tensor, float]:
    """Per-image log gains that best map a model's renders onto the photos, robustly: the
    median over each image's well-exposed pixels of ``log(target) − log(pred)``, per channel,
    centred over the images.

    Args:
        pred: ``(R, 3)`` rendered linear RGB of training pixels (a model fitted WITHOUT gains:
            it renders the photos' consensus).
        target: ``(R, 3)`` the photos' linear RGB there.
        image: ``(R,)`` long, the training image of each pixel.
        n_images: number of training images.
        lo, hi: pixels count only where every channel of both lies in ``(lo, hi)`` (dark pixels
            are noise, clipped ones a lower bound).

    Returns:
        ``(log_gains (n_images, 3), used (n_images,), explained)``: centred log gains (0 where
        an image has fewer than 16 usable pixels), the number of pixels each rests on, and the
        share of the pixels' median absolute log ratio that the gains remove
        (``1 − median|r − g_i| / median|r − median r|``; near 1 when the photos differ by
        exposure alone, near 0 when the residuals are the model's misfit).
    """
    ok = ((pred > lo) & (pred < hi) & (target > lo) & (target < hi)).all(-1)
    ratio = torch.log(target[ok]) - torch.log(pred[ok])
    img = image[ok]
    out = torch.zeros(n_images, 3, dtype=pred.dtype, device=pred.device)
    used = torch.bincount(img, minlength=n_images)
    for i in range(n_images):
        if int(used[i]) >= 16:
            out[i] = ratio[img == i].median(0).values
    has = used >= 16
    explained = 0.0
    if bool(has.any()):
        before = float((ratio - ratio.median(0).values).abs().median())
        after = float((ratio - out[img]).abs().median())
        explained = 1.0 - after / before if before > 0 else 0.0
        out[has] -= out[has].mean(0, keepdim=True)
    return out, used, explained


def gain_spread(log_gains: torch.Tensor) -> float:
    """Standard deviation over images of the mean-over-channels log gain (0.05 ≈ ±5 %
    exposure from photo to photo)."""
    return float(log_gains.mean(-1).std()) if log_gains.shape[0] > 1 else 0.0


def write_gains(path: str | Path, names: list[str], gains: torch.Tensor) -> Path:
    """Write per-photo linear gains ``(N, 3)`` by photo name (``photo = gain · render``)."""
    path = Path(path)
    path.write_text(json.dumps({
        "convention": "linear RGB: photo = gain * rendered radiance; geometric mean 1",
        "gains": {str(n): [round(float(v), 5) for v in g] for n, g in zip(names, gains,
                                                                          strict=True)}},
        indent=1))
    return path


def read_gains(path: str | Path, names: list[str]) -> torch.Tensor:
    """``(N, 3)`` gains of the photos ``names`` from a file of :func:`write_gains`.

    Raises:
        DataError: the file does not name every photo (written for another scene or split).
    """
    from voxnero.errors import DataError

    path = Path(path)
    try:
        table = json.loads(path.read_text())["gains"]
    except (OSError, ValueError, KeyError) as e:
        raise DataError(f"unreadable per-photo gains ({e})", path=path,
                        fix="delete it to train without per-photo gains") from e
    missing = [n for n in names if str(n) not in table]
    if missing:
        raise DataError(f"no gain for {len(missing)} of {len(names)} photos (e.g. "
                        f"{missing[0]!r}): written for another scene", path=path,
                        fix="delete it, or pass the stage-1 run of this scene")
    return torch.tensor([table[str(n)] for n in names], dtype=torch.float32)
