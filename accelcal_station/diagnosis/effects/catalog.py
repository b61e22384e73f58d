"""The diagnosis's catalog: one module per effect (see base.GapEffect)."""
from __future__ import annotations

from .base import DeterministicEffect, StochasticEffect
from .cross_axis import CrossAxis
from .cubic import Cubic
from .drift import Drift
from .gain import Gain
from .gravity import Gravity
from .noise import Noise
from .offset import Offset
from .order_trend import OrderTrend
from .pose_error import PoseError
from .quadratic import Quadratic
from .quantization import Quantization
from .random_walk import RandomWalk
from .saturation import Saturation
from .settling import Settling
from .temperature import Temperature

# in the order of the static design's columns (cross_axis before gain: its W carries the diagonal)
DETERMINISTIC: dict[str, DeterministicEffect] = {e.name: e for e in (
    CrossAxis(), Gain(), Offset(), Cubic(), Quadratic(), Temperature(), Drift(), Gravity(), Settling(), Saturation(),
    OrderTrend())}  # order_trend: not the simulator's; the competitor of diagnosis/order.py
# drift is in both: a warm-up and trend fitted, and a random walk judged by its signature
STOCHASTIC: dict[str, StochasticEffect] = {e.name: e for e in (Noise(), PoseError(), Quantization(), RandomWalk())}
