"""Shading core: pure, differentiable, batched tensor functions (CPU or CUDA), in layers.

- ``microfacet``: the BRDF's terms: GGX D, separable Smith G (default; height-correlated and
  NeRO's Schlick-GGX k = alpha/2 available), Schlick F, F0; ``ALPHA_MIN = 1e-3`` (alpha = r^2).
- ``sampling``: cosine and GGX-VNDF samplers with pdfs, MIS heuristics, tangent frames.
- ``splitsum``: pre-integrated A, B table (VNDF-sampled, cached in ~/.cache/voxnero).
- ``brdf``: the one BRDF (energy-weighted Lambert + GGX specular), ``brdf_eval``.
- ``latlong``: the Mitsuba equirectangular convention (docs/ARCHITECTURE.md), pixel grid and
  solid angles, bilinear lookup, rotation of directions.
- ``mip``: area-weighted resampling, mip chain, ``lookup_rough``.
- ``sh``: real SH of any degree; SH9 projection and irradiance of a map.
- ``encoding``: Ref-NeRF IDE (kappa = 1 / r^2).
- ``envmap``: ``EnvMap`` (fixed HDR map: importance sampling, GGX-prefiltered split-sum
  radiance, exact cosine irradiance).
- ``estimator``: ``shade_mc``, the MIS Monte Carlo rendering equation at surface points.
"""
