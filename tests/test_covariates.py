"""The covariate test's statistic and shuffles (fishfmu.analysis.covariates), against least squares done the plain
way: each shape regressed on the base by its own lstsq, each run's values looked up row by row."""

from __future__ import annotations

import numpy as np
import pytest

from fishfmu.analysis.covariates import Design, explainer, shuffler


def _explained_plainly(d: Design, shapes: np.ndarray) -> float:
    """The statistic by its definition: per shape, the base's residual regressed on the shape's part the base leaves;
    the largest share of the base's squared error removed, terms of the wrong sign left out."""
    def centre(a):
        a = np.asarray(a, dtype=float).copy()
        for g in np.unique(d.group):
            a[d.group == g] -= a[d.group == g].mean(axis=0)
        return a
    y = centre(d.y) if d.within else d.y
    s = centre(shapes) if d.within else shapes
    nu = centre(d.nuisance) if d.within else d.nuisance
    x = np.column_stack([np.zeros((len(y), 0)) if d.within else np.ones((len(y), 1)), nu])
    fit = (lambda v: x @ np.linalg.lstsq(x, v, rcond=None)[0]) if x.shape[1] else (lambda v: 0.0 * v)
    r0 = y - fit(y)
    best = 0.0
    for k in range(s.shape[1]):
        sk = s[:, k] - fit(s[:, k])
        b = float(sk @ r0) / float(sk @ sk)
        if not (d.sign and np.sign(b) == -d.sign):
            best = max(best, b * b * float(sk @ sk) / float(r0 @ r0))
    return best


@pytest.mark.parametrize("within, sign", [(False, 0), (False, 1), (True, -1), (True, 0)])
def test_the_statistic_is_least_squares_done_plainly_on_a_rank_deficient_base(within, sign):
    rng = np.random.default_rng(7)
    n = 240
    group = np.repeat(np.arange(8), n // 8).astype(str)
    strata = rng.integers(0, 3, size=n)
    # the strata's dummies sum to the constant: a base least squares must take by its rank
    nuisance = np.column_stack([(strata == s).astype(float) for s in range(3)] + [rng.normal(size=n)])
    shapes = rng.normal(size=(n, 5))
    y = 0.4 * shapes[:, 2] + rng.normal(size=n)
    d = Design(y, group, shapes, [f"s{k}" for k in range(5)], nuisance, within=within, sign=sign)
    explained = explainer(d)
    for trial in range(5):
        s = shapes[rng.permutation(n)] if trial else shapes
        assert explained(s) == pytest.approx(_explained_plainly(d, s), rel=1e-12, abs=1e-15)
    assert explained(shapes) > 0.05 if sign >= 0 else True  # the planted term is found


def test_the_runs_shuffle_gives_each_run_another_runs_value_stratum_by_stratum():
    # Three runs, a value per run and transfer; run r2 has no row at transfer 2: whoever takes r2's place there gets 0.
    group = np.array(["r0", "r0", "r0", "r1", "r1", "r1", "r2", "r2"])
    strata = np.array([0, 1, 2, 0, 1, 2, 0, 1])
    shapes = (10 * np.array([0, 0, 0, 1, 1, 1, 2, 2]) + strata).astype(float)[:, None] + 1.0
    d = Design(np.zeros(8), group, shapes, ["x"], np.zeros((8, 0)), within=False, strata=strata.astype(float))
    shuffle, seen = shuffler(d, "runs"), set()
    for seed in range(40):
        rng = np.random.default_rng(seed)
        out = shuffle(rng)[:, 0]
        partner = np.random.default_rng(seed).permutation(3)  # the same draw: which run each run takes
        for i, (g, s) in enumerate(zip(group, strata)):
            lender = partner[int(g[1])]
            want = 0.0 if (lender == 2 and s == 2) else 10 * lender + s + 1.0
            assert out[i] == want
        seen.add(tuple(partner))
    assert len(seen) == 6  # every arrangement of three runs drawn
