"""The held-out split of the diagnosis (poses, or captures, in K folds plus the whole-data fit) and the
noise model each fold is judged with (gap_effects' module doc, "Held-out evaluation" and "Floor")."""
from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass

import numpy as np

from .evaluation import FitParams
from .gap_data import GapData, TimeData
from .noise_floor import Floor, sigma_from_within


@dataclass
class Folds:
    """The held-out split: fold (P,) of every pose; train (F, P), F = K + 1: fold K is the whole-data fit."""

    fold: np.ndarray
    train: np.ndarray

    @property
    def F(self) -> int:
        return int(self.train.shape[0])


@dataclass
class NoiseModel:
    """Per-fold white-noise sigma (F, 3) g and quantization step q (F,) g: the configuration's, or refitted."""

    sigma: np.ndarray
    q: np.ndarray


def heldout(x: np.ndarray, fold: np.ndarray) -> np.ndarray:
    """Pick each pose's entry from its own fold: x (F, P, ...) -> (P, ...)."""
    return x[fold, np.arange(x.shape[1])]


def make_folds(data: GapData) -> Folds:
    fold = data.folds()
    K = int(fold.max()) + 1
    train = np.ones((K + 1, data.P), bool)
    train[:K] = fold[None, :] != np.arange(K)[:, None]
    return Folds(fold, train)


def noise_model(data: GapData, floor: Floor, added: Collection[str], td: TimeData | None, fo: Folds,
                params: FitParams) -> NoiseModel:
    """The floor's sigma and q per fold; ``quantization`` and ``noise`` refit them on the training poses."""
    F, train = fo.F, fo.train
    sigma = np.broadcast_to(floor.sigma_g, (F, 3)).copy()
    q = np.full(F, floor.q_g)
    if "quantization" in added and td is not None:
        q = np.array([td.lsb_g(train[f]) for f in range(F)])
        params["lsb_g"] = float(q[-1])
    if "noise" in added:
        if td is not None:
            w2 = np.array([np.nanmean(td.diff_var[train[f]], axis=0) for f in range(F)])
        else:
            assert data.std_g is not None, "noise is testable only with per-pose std and n, or raw samples"
            nn = data.n[:, None] - 1.0
            w2 = np.array([np.sum(nn[train[f]] * data.std_g[train[f]] ** 2, 0) / np.sum(nn[train[f]])
                           for f in range(F)])
        sigma = sigma_from_within(w2, q[:, None])
        params["sigma_g"] = sigma[-1].tolist()
    return NoiseModel(sigma, q)
