"""`mujoco.mjx` imported without its start-up noise: MJX tries the optional MuJoCo Warp backend
(a CUDA-only package mjxrow does not use) and prints "Failed to import warp" twice when it is
absent. That line is not the user's business; anything else MJX prints still shows."""

from __future__ import annotations

import contextlib
import io
import sys

_buf = io.StringIO()
with contextlib.redirect_stdout(_buf):
    from mujoco import mjx  # noqa: E402
for _line in _buf.getvalue().splitlines():
    if not _line.startswith(("Failed to import warp", "Failed to import mujoco_warp")):
        print(_line, file=sys.stdout)

__all__ = ["mjx"]
