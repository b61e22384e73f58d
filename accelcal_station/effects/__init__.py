"""The diagnosis's catalog: one module per effect (see base.Effect)."""
from __future__ import annotations

from .base import Effect, Signature
from .noise import Noise
from .pose_error import PoseError
from .quantization import Quantization
from .random_walk import RandomWalk

STOCHASTIC: dict[str, Effect] = {e.name: e for e in (Noise(), PoseError(), Quantization(), RandomWalk())}

__all__ = ["Effect", "Signature", "STOCHASTIC", "Noise", "PoseError", "Quantization", "RandomWalk"]
