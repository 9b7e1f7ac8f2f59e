"""The paper's fish measurements (Tables I-III) and the regressions that map length to the rest.

The paper mapped every dimension to length by polynomial regression over 49 salmon (Fig. 2)
but published only seven of them (Table I).  We fit to those seven, shipped in
``plant/fish/data/paper_table1.csv``:

- height and width: straight lines in length (the measured values are whole centimetres, so a
  higher order would fit rounding noise);
- weight: the allometric law ``W = a L^b`` fitted in log-log space (b comes out near 3.8, close
  to the 3-3.3 of growing fish plus the fuller shape of large farmed salmon).

The residual spread of each fit is kept, so a sampled population varies the way the measured
fish do around the trend, not as identical scaled copies.

>>> reg = length_regressions()
>>> [round(float(f(0.68)), 3) for f in (reg.height_m, reg.width_m, reg.weight_kg)]
[0.166, 0.078, 3.602]
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from importlib import resources

import numpy as np
import pandas as pd


def _read(name: str) -> pd.DataFrame:
    with resources.files("plant.fish").joinpath("data", name).open("r") as fh:
        return pd.read_csv(fh)


@functools.cache
def table1() -> pd.DataFrame:
    """Table I: length, height, width and weight of salmon samples #14-#20 (read once; do not modify)."""
    return _read("paper_table1.csv")


@functools.cache
def table2() -> pd.DataFrame:
    """Table II: weight of the five bodies of sample #16 (head, upper body, lower body, tail, tail fin)."""
    return _read("paper_table2.csv")


@functools.cache
def table3() -> pd.DataFrame:
    """Table III: joint limits of the Unity rag-doll, in degrees (swing 1, swing 2, twist)."""
    return _read("paper_table3.csv")


@dataclass(frozen=True)
class LengthRegressions:
    """Height, width (linear in length) and weight (power law), with the residual spread of each fit."""

    height_coef: tuple[float, float]
    """(slope, intercept) of height_m against length_m, fitted to Table I."""
    width_coef: tuple[float, float]
    """(slope, intercept) of width_m against length_m, fitted to Table I."""
    weight_coef: tuple[float, float]
    """(exponent b, log a) of ln(weight_kg) = b ln(length_m) + ln a, fitted to Table I."""
    height_sd_m: float
    """Residual standard deviation of height about the fit (Table I)."""
    width_sd_m: float
    """Residual standard deviation of width about the fit (Table I)."""
    weight_log_sd: float
    """Residual standard deviation of ln(weight) about the fit (Table I), i.e. relative spread."""

    def height_m(self, length_m: float | np.ndarray) -> float | np.ndarray:
        return self.height_coef[0] * np.asarray(length_m) + self.height_coef[1]

    def width_m(self, length_m: float | np.ndarray) -> float | np.ndarray:
        return self.width_coef[0] * np.asarray(length_m) + self.width_coef[1]

    def weight_kg(self, length_m: float | np.ndarray) -> float | np.ndarray:
        return np.exp(self.weight_coef[1]) * np.asarray(length_m) ** self.weight_coef[0]


@functools.cache
def length_regressions() -> LengthRegressions:
    """Fit the regressions to Table I (once; the result is cached)."""
    d = table1()
    length = d["length_m"].to_numpy()
    dof = len(d) - 2  # two fitted parameters per regression

    def linear(col: str) -> tuple[tuple[float, float], float]:
        coef = np.polyfit(length, d[col].to_numpy(), 1)
        resid = d[col].to_numpy() - np.polyval(coef, length)
        return (float(coef[0]), float(coef[1])), float(np.sqrt(np.sum(resid**2) / dof))

    h_coef, h_sd = linear("height_m")
    w_coef, w_sd = linear("width_m")
    log_w = np.log(d["weight_kg"].to_numpy())
    wt_coef = np.polyfit(np.log(length), log_w, 1)
    wt_resid = log_w - np.polyval(wt_coef, np.log(length))
    return LengthRegressions(
        height_coef=h_coef, width_coef=w_coef,
        weight_coef=(float(wt_coef[0]), float(wt_coef[1])),
        height_sd_m=h_sd, width_sd_m=w_sd,
        weight_log_sd=float(np.sqrt(np.sum(wt_resid**2) / dof)),
    )
