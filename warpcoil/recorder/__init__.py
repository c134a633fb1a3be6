"""Output writers (USD animation) and atomic file helpers."""

from warpcoil.recorder.atomic import atomic_path, write_text_atomic
from warpcoil.recorder.usd import UsdRecorder, validate_usd

__all__ = ["UsdRecorder", "atomic_path", "validate_usd", "write_text_atomic"]
