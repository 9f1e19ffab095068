"""The NumPy twin of kernels/shade.cl: `clraster.output.shade.shade` shades on the host,
with the same rules, any frame that has no OpenCL renderer behind it (a frame of
`clraster.reference.Renderer`, or one whose renderer is gone); the device and this path
agree within 1/255 per channel (tests/test_shade_device.py). This module names it where
the twins of the other kernels are."""

from __future__ import annotations

from ...output.shade import pixel_normals, shade

__all__ = ["pixel_normals", "shade"]
