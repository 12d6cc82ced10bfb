"""mjxrow: batch evaluation of autonomous navigation in row-based crop fields with JAX and MJX.

The public Python API, as in the README:

    run = mjxrow.build_run({"preset": "vineyard", "controller.name": "oracle"})
    built = mjxrow.build(run)                          # model, policy, one compiled program
    batch = built.batch([(run, i) for i in range(4)])  # episodes 0..3 of seed 0
    log = built.rollout(batch)                         # Log [4, T]
    summary = built.summarise(log, 4)                  # per-episode metrics

The packages, bottom-up (each imports only from the ones below it; `lint-imports` keeps it so):
`commands` (the light half of every command), `limits`, `crops`, `field` (the traced generator)
→ `physics`, `render`, `seg` → `control` (leaf controllers) → `policies` (perception, the
learned policy) → `rollout` (the step, the build, the episode loop, the metrics) → `env`,
`sweep` → `search` → `worlds` → `train`, `bench` → `episode`.

The names below are loaded when first used, so that `import mjxrow` stays cheap: every command
parses its arguments (and answers `--help`) before JAX is imported (`mjxrow.commands`).
"""

import importlib as _importlib
import os as _os
import time as _time

STARTED = _time.time()  # when a command first imported the package: the start of its start-up

# XLA's C++ warnings (on GPUs, the autotuner's "Delay kernel timed out" timer lines) are not the
# user's business; errors still show. An explicit TF_CPP_MIN_LOG_LEVEL wins.
_os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

# The same config and seed give the same numbers on a GPU too: XLA's deterministic ops (no
# atomics in scatters, no autotuned algorithm that rounds otherwise), set before JAX starts its
# backend. On an H100 they cost 19 % of the run time of sweeps.yaml (B = 216) and 28 % at
# B = 4,104 (BENCHMARKS.md); MJXROW_NONDETERMINISTIC=1 or a command's --nondeterministic
# (runtime.setup) leaves them out, and an explicit xla_gpu_deterministic_ops in XLA_FLAGS wins.
DETERMINISTIC_FLAG = "--xla_gpu_deterministic_ops=true"
if (not _os.environ.get("MJXROW_NONDETERMINISTIC")
        and "xla_gpu_deterministic_ops" not in _os.environ.get("XLA_FLAGS", "")):
    _os.environ["XLA_FLAGS"] = " ".join(
        filter(None, [_os.environ.get("XLA_FLAGS", ""), DETERMINISTIC_FLAG]))

__version__ = "0.1.0"

_API = {
    # configs: one run (dotted keys, as a sweep's cell) or a whole sweep file
    "RunConfig": "mjxrow.rollout.config",
    "build_run": "mjxrow.rollout.config",
    "load_sweep": ("mjxrow.sweep.config", "load"),
    # the batch of episodes: build → batch → rollout → summarise
    "build": "mjxrow.rollout.build",
    "Built": "mjxrow.rollout.build",
    "Log": "mjxrow.rollout.metrics",
    "results_table": "mjxrow.rollout.cli",
    "aggregate": "mjxrow.rollout.aggregate",
    "format_table": "mjxrow.rollout.aggregate",
    # a whole sweep into a folder (results.csv, summary.csv, heatmaps, report.md)
    "run_sweep": ("mjxrow.sweep.run", "run"),
    # a failure search into a folder (candidates.csv, failures.csv, figures, report.md)
    "load_search": ("mjxrow.search.config", "load"),
    "run_search": ("mjxrow.search.run", "run"),
    # fields and the registries
    "FieldParams": "mjxrow.field",
    "FieldShape": "mjxrow.field",
    "make_params": "mjxrow.field",
    "generate": "mjxrow.field",
    "register_crop": ("mjxrow.crops", "register"),
    "register_controller": ("mjxrow.control", "register"),
    # training environments
    "Env": "mjxrow.env",
    "EnvConfig": "mjxrow.env",
}

__all__ = sorted(_API) + ["DETERMINISTIC_FLAG", "STARTED", "__version__"]


def __getattr__(name: str):
    where = _API.get(name)
    if where is None:
        raise AttributeError(f"module 'mjxrow' has no attribute {name!r}")
    module, attr = where if isinstance(where, tuple) else (where, name)
    value = getattr(_importlib.import_module(module), attr)
    globals()[name] = value
    return value


def __dir__():
    return __all__
