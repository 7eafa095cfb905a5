"""Synthetic whole-body motion for any registered robot (no motion data needed): see :mod:`.motion`."""

from .body import Body, body_of
from .motion import SYNTHESIS_VERSION, SyntheticClip, clip_seed, ground_heights, synthesize

__all__ = ["Body", "body_of", "SyntheticClip", "synthesize", "clip_seed", "ground_heights", "SYNTHESIS_VERSION"]
