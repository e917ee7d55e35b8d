"""The start of stage 1 for a near background (:func:`voxnero.shape.starts.near_start`)."""

from __future__ import annotations

from dataclasses import replace

import pytest

from voxnero.shape.config import ShapeConfig
from voxnero.shape.starts import has_race, near_start


def _cfg(coarse_iters: int = 300, near_iters: int = 2500, race: bool = True,
         candidates: list[float] | None = None) -> ShapeConfig:
    c = ShapeConfig()
    grid = c.grid if candidates is None else replace(c.grid, init_candidates=candidates)
    return replace(c, iters=1500, grid=grid, coarse=replace(
        c.coarse, iters=coarse_iters, near_iters=near_iters, race=race))


@pytest.mark.parametrize("background", ["distant", "alpha"])
def test_other_backgrounds_keep_the_race_and_the_steps(background):
    cfg, dec = _cfg(), []
    assert near_start(cfg, background, dec) is cfg
    assert dec == [] and has_race(cfg)


def test_near_background_runs_the_carved_start_alone_with_near_iters():
    dec = []
    out = near_start(_cfg(), "near", dec)
    assert not has_race(out) and out.iters == 2500 and out.coarse.iters == 300
    assert out.grid.init_candidates == []
    assert [d.name for d in dec] == ["start"] and dec[0].value == "coarse"
    assert dec[0].evidence == {"race_skipped": True, "iters": 2500, "preset_iters": 1500}


def test_near_iters_zero_keeps_the_presets_steps_and_still_skips_the_race():
    dec = []
    out = near_start(_cfg(near_iters=0), "near", dec)
    assert out.iters == 1500 and not has_race(out) and len(dec) == 1


def test_nothing_to_decide_without_a_coarse_stage_or_when_nothing_changes():
    for cfg in (_cfg(coarse_iters=0), _cfg(near_iters=0, race=False, candidates=[])):
        dec = []
        assert near_start(cfg, "near", dec) is cfg and dec == []


def test_the_opened_start_alone_is_a_race_and_a_near_background_drops_it():
    """``coarse.open_worst`` races even with ``coarse.race`` off (the carved start against its
    opened shell); a near background runs the carved start alone, without it."""
    cfg = _cfg(race=False)
    cfg = replace(cfg, coarse=replace(cfg.coarse, open_worst=True))
    assert has_race(cfg)
    dec = []
    out = near_start(cfg, "near", dec)
    assert not has_race(out) and not out.coarse.open_worst and len(dec) == 1
    assert dec[0].setting["coarse.open_worst"] is True
