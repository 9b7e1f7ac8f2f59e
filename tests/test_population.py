"""Arrivals of a continuous feed: the jitter moves each release within its bound, keeps the order,
and leaves a batch without jitter exactly as it was."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from plant.fish.population import PopulationSpec, sample_fish


def _fish(**kw):
    spec = PopulationSpec(count=200, drop="sparse", first_drop_s=4.0, drop_interval_s=1.5, **kw)
    return spec, sample_fish(spec, (0.0, 2.0), 0.25, np.random.default_rng(7))


def test_jitter_moves_each_release_within_its_bound_and_keeps_the_order():
    spec, fish = _fish(drop_interval_jitter_s=0.5)
    t = np.array([f.drop_t_s for f in fish])
    nominal = 4.0 + 1.5 * np.arange(200)
    shift = t - nominal
    assert np.all(np.abs(shift) <= 0.5) and np.all(t >= 4.0)
    assert np.all(np.diff(t) > 0.5 - 1e-12)  # at least interval - 2 x jitter apart: order kept
    # a uniform spread over +-0.5 s: mean near 0, standard deviation near 0.5 / sqrt(3) = 0.289
    inner = shift[1:]  # the first release cannot move earlier than first_drop_s
    assert abs(inner.mean()) < 0.06 and 0.25 < inner.std() < 0.33


def test_without_jitter_the_batch_is_what_it_was():
    _, plain = _fish()
    assert [f.drop_t_s for f in plain] == [4.0 + 1.5 * i for i in range(200)]
    _, jittered = _fish(drop_interval_jitter_s=0.3)
    # everything but the release times comes from the same draws
    assert [(f.length_m, f.drop_x_m, f.drop_y_m, f.drop_yaw_rad) for f in plain] == \
           [(f.length_m, f.drop_x_m, f.drop_y_m, f.drop_yaw_rad) for f in jittered]


def test_jitter_of_half_the_interval_or_more_is_refused():
    with pytest.raises(ValidationError, match="below half of drop_interval_s"):
        PopulationSpec(drop_interval_s=1.0, drop_interval_jitter_s=0.5)
