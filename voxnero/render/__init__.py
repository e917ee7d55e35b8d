"""Shading core: pure, differentiable, batched tensor functions (CPU or CUDA).

- ``brdf``: GGX D, separable Smith G (default; height-correlated and NeRO's Schlick-GGX
  k = alpha/2 available), Schlick F, Lambert diffuse; ``ALPHA_MIN = 1e-3`` (alpha = r^2).
- ``envmap``: the Mitsuba equirectangular convention (docs/ARCHITECTURE.md), bilinear lookup,
  area-weighted mip chain + ``lookup_rough``, SH9 irradiance, and ``EnvMap`` (fixed HDR map:
  importance sampling, GGX-prefiltered split-sum radiance, exact cosine irradiance).
- ``splitsum``: pre-integrated A, B table (VNDF-sampled, cached in ~/.cache/voxnero).
- ``encoding``: real SH of any degree, Ref-NeRF IDE (kappa = 1 / r^2).
- ``sampling``: cosine and GGX-VNDF samplers with pdfs, MIS heuristics, tangent frames.
- ``estimator``: ``shade_mc``, the MIS Monte Carlo rendering equation at surface points.
"""
