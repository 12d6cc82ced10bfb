"""The suite finds a GL backend itself: MuJoCo's offscreen renderer (the agreement tests of our
renderer, the exported worlds' camera) uses OSMesa unless MUJOCO_GL says otherwise. Set here,
before any test module imports mujoco. A test that needs GL fails with the package to install
(libosmesa6) when there is none; it never skips."""

import os

os.environ.setdefault("MUJOCO_GL", "osmesa")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])
