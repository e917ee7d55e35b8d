"""Training pixels drawn partly where the render and the photo disagree.

Uniform pixel sampling gives every pixel the same share of the steps. The pixels that place a
thin, untextured part (a chair's seat seen edge-on, a table's top) are the few where its
silhouette crosses the background in grazing views; drawn uniformly they are a small part of a
batch, and their gradient is shared with the whole image (docs/STAGE1.md, finding 22). This
sampler keeps a running error per image tile (``tile`` × ``tile`` pixels of one photo) and draws
a fraction ``frac`` of each batch in proportion to it, the rest uniformly over all pixels:
tiles whose error falls get fewer rays, tiles that the uniform part finds wrong get more
(instant-ngp's error map, over photos instead of a texture).

Pixel convention as :func:`voxnero.cameras.rays.random_pixels`: ``pix (n, 2)`` float32
``[x = column, y = row]`` at pixel centres, ``cam (n,)`` the photo's index. The loss is not
re-weighted: the drawn pixels count more where the fit is worst (the bias is bounded by the
uniform share ``1 − frac``).
"""

from __future__ import annotations

import math

import torch

from voxnero.cameras.rays import random_pixels


class ErrorGuidedPixels:
    """Draw training pixels, a share ``frac`` of them in proportion to a per-tile error.

    Args:
        n_cams, height, width: the photos' count and size in pixels.
        tile: tile side in pixels (the last row and column of tiles may be narrower).
        frac: share of each batch drawn from the error map (0 = uniform sampling).
        decay: weight of a new measurement in a tile's running error (1 = replace).
        subpixel: draw a uniform point inside each pixel (the box filter of photos whose pixel
            is the mean over its area) instead of its centre.
        device: device of the map and of the draws.
    """

    def __init__(self, n_cams: int, height: int, width: int, tile: int = 8, frac: float = 0.5,
                 decay: float = 0.5, subpixel: bool = False,
                 device: torch.device | str = "cpu"):
        if tile < 1 or not 0.0 <= frac <= 1.0 or not 0.0 < decay <= 1.0:
            raise ValueError(f"tile ≥ 1, 0 ≤ frac ≤ 1 and 0 < decay ≤ 1 (got {tile}, {frac}, "
                             f"{decay})")
        self.n_cams, self.h, self.w, self.tile = n_cams, height, width, tile
        self.frac, self.decay, self.subpixel = frac, decay, subpixel
        self.th, self.tw = math.ceil(height / tile), math.ceil(width / tile)
        self.err = torch.zeros(n_cams * self.th * self.tw, device=device)
        """``(n_cams · th · tw,)`` running error per tile (row-major per photo); all equal
        until the first measurement, which sets every tile to its batch mean."""
        self.measured = False
        self._last: torch.Tensor | None = None

    def tiles_of(self, cam: torch.Tensor, pix: torch.Tensor) -> torch.Tensor:
        """``(n,)`` long tile index of pixels ``pix (n, 2)`` ``[x, y]`` in photos ``cam (n,)``."""
        p = pix.floor().long()
        return (cam * self.th + p[:, 1] // self.tile) * self.tw + p[:, 0] // self.tile

    def draw(self, n: int, generator: torch.Generator | None = None
             ) -> tuple[torch.Tensor, torch.Tensor]:
        """``n`` pixels: ``cam (n,)`` long and ``pix (n, 2)`` (pixel centres, or uniform points
        inside the pixels with ``subpixel``); the first
        ``n − round(frac · n)`` uniform, the rest from tiles in proportion to their error and
        uniform inside the tile. Remembered for :meth:`feedback`."""
        n_err = round(self.frac * n) if self.measured else 0
        cam, pix = random_pixels(n - n_err, self.n_cams, self.h, self.w, generator=generator,
                                 jitter=self.subpixel, device=self.err.device)
        if n_err > 0:
            kw = dict(generator=generator, device=self.err.device)
            # a floor far below any measured error keeps an all-zero map drawable without
            # reading it back to the host (a device sync per step on CUDA)
            t = torch.multinomial(self.err + 1e-30, n_err, replacement=True,
                                  generator=generator)
            c, r = t // (self.th * self.tw), t % (self.th * self.tw)
            x0, y0 = (r % self.tw) * self.tile, (r // self.tw) * self.tile
            u = torch.rand((n_err, 2), **kw)
            x = x0 + (u[:, 0] * (self.w - x0).clamp(max=self.tile)).long()
            y = y0 + (u[:, 1] * (self.h - y0).clamp(max=self.tile)).long()
            off = torch.rand((n_err, 2), **kw) if self.subpixel else 0.5
            cam = torch.cat([cam, c])
            pix = torch.cat([pix, torch.stack([x, y], -1).to(torch.float32) + off])
        self._last = self.tiles_of(cam, pix)
        return cam, pix

    @torch.no_grad()
    def feedback(self, err: torch.Tensor) -> None:
        """Fold the last draw's per-pixel errors ``(n,)`` (≥ 0, any unit) into their tiles."""
        if self._last is None:
            raise RuntimeError("feedback() before draw()")
        t, e = self._last, err.detach().to(self.err)
        if not self.measured:
            self.err.fill_(float(e.mean()))
            self.measured = True
        s = torch.zeros_like(self.err).index_add_(0, t, e)
        c = torch.zeros_like(self.err).index_add_(0, t, torch.ones_like(e))
        self.err.copy_(torch.where(c > 0, self.err + self.decay * (s / c.clamp(min=1) - self.err),
                                   self.err))
        self._last = None

    def state_dict(self) -> dict:
        """The map, for a checkpoint (a resumed run draws the same pixels)."""
        return {"err": self.err.clone(), "measured": self.measured}

    def load_state_dict(self, state: dict) -> None:
        self.err.copy_(state["err"])
        self.measured = bool(state["measured"])
