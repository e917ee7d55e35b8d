"""Stage 2: materials and lights on the fixed mesh (primary-hit cache, material field, env map,
Monte Carlo rendering equation, trainer)."""
