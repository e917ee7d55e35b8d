"""Shading core: pure, differentiable, batched tensor functions (BRDF, env maps, split-sum,
SH / IDE encodings, importance samplers, the Monte Carlo rendering-equation estimator)."""
