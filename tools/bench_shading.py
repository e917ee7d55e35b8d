#!/usr/bin/env python
"""Throughput of the shading core: BRDF + split-sum (stage 1) and the MIS estimator (stage 2).

Measures, as medians over repeats (after one warm-up):
  * ``brdf``: ``brdf_eval`` on N (n, v, l) triples, evaluations/s (forward; and forward+backward);
  * ``splitsum``: split-sum shading of N points (lookup of A, B + ``lookup_rough`` on a
    learnable 128 x 256 map's mip chain + diffuse SH irradiance), points/s (forward+backward);
  * ``mc``: ``shade_mc`` with a 256 x 512 ``EnvMap`` and MIS over cosine/GGX/env samples,
    direction samples/s (forward), and with a learnable map (forward+backward);
  * ``table``: time to build the split-sum table from scratch (skipped with --no-table).
Needs no data. Example::

    python tools/bench_shading.py --points 65536 --mc-points 4096 --spp 64 --repeats 5
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch


def _timeit(fn, repeats: int) -> float:
    fn()  # warm-up
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return statistics.median(ts)


def _rand_unit(n: int, g: torch.Generator, dev) -> torch.Tensor:
    return torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1).to(dev)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--points", type=int, default=65536, help="points for brdf / split-sum")
    p.add_argument("--mc-points", type=int, default=2048, help="surface points for shade_mc")
    p.add_argument("--spp", type=int, default=64, help="direction samples per point (shade_mc)")
    p.add_argument("--repeats", type=int, default=5, help="timed repeats (median reported)")
    p.add_argument("--threads", type=int, default=0, help="torch intra-op threads (0: default)")
    p.add_argument("--device", default="auto", help="cpu, cuda or auto")
    p.add_argument("--no-table", action="store_true", help="skip the table build timing")
    a = p.parse_args(argv)

    from voxnero.device import default_device
    from voxnero.render.brdf import brdf_eval
    from voxnero.render.envmap import (
        EnvMap,
        envmap_lookup,
        lookup_rough,
        mip_chain,
        sh9_irradiance,
        sh9_project,
    )
    from voxnero.render.estimator import shade_mc
    from voxnero.render.microfacet import f0_from
    from voxnero.render.splitsum import build_table, get_table, specular_split_sum

    if a.threads > 0:
        torch.set_num_threads(a.threads)
    dev = default_device(a.device)
    g = torch.Generator().manual_seed(0)
    N = a.points
    n = _rand_unit(N, g, dev)
    v = torch.nn.functional.normalize(n + 0.8 * _rand_unit(N, g, dev), dim=-1)
    l = torch.nn.functional.normalize(n + 0.8 * _rand_unit(N, g, dev), dim=-1)
    albedo = torch.rand(N, 3, generator=g).to(dev).requires_grad_()
    metal = torch.rand(N, 1, generator=g).to(dev).requires_grad_()
    rough = torch.rand(N, 1, generator=g).to(dev).requires_grad_()
    print(f"device={dev} threads={torch.get_num_threads()} points={N} repeats={a.repeats}")

    def brdf_fwd():
        with torch.no_grad():
            brdf_eval(n, v, l, albedo, metal, rough)

    def brdf_bwd():
        brdf_eval(n, v, l, albedo, metal, rough).sum().backward()

    t = _timeit(brdf_fwd, a.repeats)
    print(f"brdf      forward            {N / t / 1e6:8.2f} M evals/s   ({t * 1e3:.1f} ms)")
    t = _timeit(brdf_bwd, a.repeats)
    print(f"brdf      forward+backward   {N / t / 1e6:8.2f} M evals/s   ({t * 1e3:.1f} ms)")

    get_table(dev)
    log_env = (torch.randn(128, 256, 3, generator=g) * 0.5).to(dev).requires_grad_()

    def split_sum_step():
        img = torch.exp(log_env)
        chain = mip_chain(img)
        nv = (n * v).sum(-1, keepdim=True).clamp_min(1e-4)
        refl = 2 * nv * n - v
        spec = specular_split_sum(f0_from(albedo, metal), nv, rough,
                                  lookup_rough(chain, refl, rough))
        diff = (1 - metal) * albedo / torch.pi * sh9_irradiance(sh9_project(img), n)
        (spec + diff).sum().backward()

    t = _timeit(split_sum_step, a.repeats)
    print(f"splitsum  forward+backward   {N / t / 1e6:8.2f} M points/s  ({t * 1e3:.1f} ms, "
          "incl. mip chain + SH9 of a 128x256 learnable map)")

    M, S = a.mc_points, a.spp
    env_img = torch.rand(256, 512, 3, generator=g) * 0.5
    env_img[40:44, 100:104] = 2000.0
    env = EnvMap(env_img, device=dev)
    x = torch.zeros(M, 3, device=dev)

    def mc_fwd():
        with torch.no_grad():
            shade_mc(x, n[:M], v[:M], albedo[:M], metal[:M], rough[:M], env, S, generator=g)

    t = _timeit(mc_fwd, a.repeats)
    print(f"mc        forward (EnvMap)   {M * S / t / 1e6:8.2f} M samples/s "
          f"({M} points x {S} spp: {t * 1e3:.1f} ms)")
    learn = env_img.clone().to(dev).requires_grad_()

    def mc_bwd():
        out = shade_mc(x, n[:M], v[:M], albedo[:M], metal[:M], rough[:M],
                       lambda d: envmap_lookup(learn, d), S, generator=g)
        out.sum().backward()

    t = _timeit(mc_bwd, a.repeats)
    print(f"mc        fwd+bwd (learnable){M * S / t / 1e6:8.2f} M samples/s "
          f"({t * 1e3:.1f} ms; cosine + GGX only)")
    if not a.no_table:
        t0 = time.perf_counter()
        build_table()
        print(f"table     build 64x64x4096   {time.perf_counter() - t0:8.2f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
