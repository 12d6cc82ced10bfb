"""Deterministic GPU runs by default: `import mjxrow` puts XLA's deterministic-ops flag in
XLA_FLAGS before JAX starts its backend; MJXROW_NONDETERMINISTIC=1 or a command's
--nondeterministic leaves it out, and a user's own setting of that flag wins."""

import os
import subprocess
import sys


def _flags(env: dict, code: str = "import mjxrow") -> str:
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS",
                                                            "MJXROW_NONDETERMINISTIC")} | env
    out = subprocess.run([sys.executable, "-c", code + "; import os; "
                          "print(os.environ.get('XLA_FLAGS', ''))"], env=env,
                         capture_output=True, text=True, check=True)
    return out.stdout.strip()


def test_deterministic_ops_by_default():
    assert _flags({}) == "--xla_gpu_deterministic_ops=true"
    assert _flags({"XLA_FLAGS": "--xla_dump_to=/tmp/x"}) == \
        "--xla_dump_to=/tmp/x --xla_gpu_deterministic_ops=true"


def test_opting_out():
    assert _flags({"MJXROW_NONDETERMINISTIC": "1"}) == ""
    assert _flags({"XLA_FLAGS": "--xla_gpu_deterministic_ops=false"}) == \
        "--xla_gpu_deterministic_ops=false"  # the user's own choice stays
    code = ("import argparse, mjxrow; from mjxrow import runtime; "
            "runtime.setup(argparse.Namespace(nondeterministic=True, no_cache=True))")
    assert _flags({"XLA_FLAGS": "--xla_dump_to=/tmp/x"}, code) == "--xla_dump_to=/tmp/x"
