"""The suite finds a GL backend itself: MuJoCo's offscreen renderer (the agreement tests of our
renderer, the exported worlds' camera) uses OSMesa unless MUJOCO_GL says otherwise. Set here,
before any test module imports mujoco. A test that needs GL fails with the package to install
(libosmesa6) when there is none; it never skips.

The suite never reads or writes the user's compilation cache: commands that turn it on use a
fresh folder per test session (a program kept from an earlier run would skip the traces some
tests count)."""

import os
import tempfile

os.environ.setdefault("MUJOCO_GL", "osmesa")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

os.environ["MJXROW_CACHE_DIR"] = tempfile.mkdtemp(prefix="mjxrow-test-cache-")
