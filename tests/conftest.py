"""The suite finds a GL backend itself: MuJoCo's offscreen renderer (the agreement tests of our
renderer, the exported worlds' camera) uses OSMesa unless MUJOCO_GL says otherwise. Set here,
before any test module imports mujoco. A test that needs GL fails with the package to install
(libosmesa6) when there is none; it never skips.

XLA:CPU compiles with fewer optimisations (below). The suite never reads or writes the user's
compilation cache: commands that turn it on use a fresh folder per test session (a program
kept from an earlier run would skip the traces some tests count)."""

import os
import tempfile

import pytest

os.environ.setdefault("MUJOCO_GL", "osmesa")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

os.environ["MJXROW_CACHE_DIR"] = tempfile.mkdtemp(prefix="mjxrow-test-cache-")

# XLA:CPU at optimisation level 0 and without LLVM's expensive passes, for this process and the
# commands the tests start: the suite compiles many programs and runs each for a few tiny
# steps, so compiling is most of its time (test_env's reset and step alone: 68 -> 46 s; a
# renderer test that runs more than it compiles: 36 -> 35 s; the suite: 638-831 s against
# 908-948 s without them, 20-25 against 29 CPU-minutes). The programs compute the same
# operations; the tests compare results with tolerances, or runs of the same program with each
# other.
os.environ["XLA_FLAGS"] = " ".join(filter(None, [
    os.environ.get("XLA_FLAGS", ""), "--xla_backend_optimization_level=0",
    "--xla_llvm_disable_expensive_passes=true"]))


@pytest.fixture
def compiled():
    """`compiled(fn, clear=True)`: the names of the XLA programs `fn()` compiles (JAX's
    "Compiling NAME" log lines), with JAX's in-memory caches emptied first unless `clear` is
    False (as a new process would start, but for the compilation cache on disk)."""
    import logging

    import jax

    def names(fn, clear: bool = True) -> list[str]:
        seen: list[str] = []

        class Catch(logging.Handler):
            def emit(self, record):
                msg = record.getMessage()
                if msg.startswith("Compiling "):
                    seen.append(msg.split()[1])

        log = logging.getLogger("jax")
        handler, level = Catch(), log.level
        log.addHandler(handler)
        log.setLevel(logging.WARNING)
        if clear:
            jax.clear_caches()
        try:
            with jax.log_compiles(True):
                fn()
        finally:
            log.removeHandler(handler)
            log.setLevel(level)
        return seen

    return names

