"""Train a navigation policy from pixels, evaluate it beside SegZeros and the oracle, and print
the table: one command on one GPU.

    python experiments/train_policy.py --out runs/policy [--budget-minutes 5]
        [--deadline-minutes 8.5] [--eval-reserve-minutes M] [--presets P ...] [--num-envs 15360]
        [--episodes 100] [--bc-fraction 0.5] [--observation rgb|chroma|mask|features]
        [--teacher oracle] [--seed 0] [--eval-seed 0] [--iterations N] [--init CHECKPOINT]
        [--curriculum SEARCH.yaml] [--set KEY=VALUE ...] [--no-eval] [--eval-only] [--eval-last]
        [--eval-sun DEG ...] [--ship] [--smoke]

Training (mjxrow.train.loop): behaviour cloning / DAgger from the teacher (`--teacher`, the
oracle's pure pursuit by default) for the first `--bc-fraction` of the budget, then PPO, in
`--num-envs` domain-randomised worlds (every reset a new field, sky and camera jitter; the
worlds split evenly over `--presets`; JAX gets 90 % of the GPU's memory unless
XLA_PYTHON_CLIENT_MEM_FRACTION says otherwise). The budget counts training wall time over every
command with the same `--out` (compilation excluded): a second command resumes from the orbax
state in OUT/state/ and trains until the budget is spent. `--deadline-minutes` bounds this
command's whole wall time: training stops early enough for the evaluation to finish before it
(`--eval-reserve-minutes`, by default 0.15 min per block of episodes).
Where that leaves less than the budget, the BC / PPO split is a share of the time it leaves
(counted once everything is compiled), so PPO runs in this command; `--set
ppo.start_log_std=-1.6` sets the policy's sampling std (e^-1.6 = 0.2, DAgger's noise) when PPO
takes over, and `--set ppo.teacher_cost=10` keeps PPO's mean action near the teacher's
(DAgger's loss as a term of PPO's).

`--init shipped` (or a policy folder of the same observation and network) starts from trained
weights, e.g. PPO (`--bc-fraction 0`) on the shipped BC / DAgger policy. `--curriculum
SEARCH.yaml` is the adversarial curriculum (mjxrow.train.curriculum): before the first
iteration and every `train.curriculum.every` iterations (default 20) the failure search runs
against the policy the run would ship (the weights' moving average with `train.average`),
with `train.curriculum.episodes` episodes (default 512), and a
`train.curriculum.share` (default 0.25) of every batch of resets of the searched preset takes
its failing fields; OUT/adversary.jsonl and OUT/adversary.png give the failure rate per round.
`--iterations` stops after that many iterations in all (besides the budget).

Evaluation (mjxrow.train.evaluate, through the run builder, i.e. the sweep's episodes and
metrics): `--episodes` episodes per preset at its default geometry in the Table 3 scenario
(mjxrow/sweep/presets.yaml) for the trained policy, SegZeros with the learned segmenter and the
oracle; success with its 95 % Wilson interval. `--eval-sun 80 260` runs the policy's blocks
again with the sun at those azimuths (Table 3's is 35°: pear's learned policies drift with the
sun to the side, docs/training.md). On a GPU the evaluation programs compile in a
thread while the policy trains, started once the trainer's programs are compiled (the weights
are traced, so the trained ones run in a program compiled for an untrained copy).

Writes into OUT: policy/ (the checkpoint: `controller: {name: policy, checkpoint:
OUT/policy}`; the weights' moving average over the iterations, `train.average`, default 0.8
an iteration), policy_last/ (the last weights, which `--eval-last` evaluates beside it in the
same programs), state/ (its last step written while the evaluation runs), train_log.jsonl,
learning_curve.png, eval.md, eval.json, summary.json, benchmarks.jsonl (the training throughput
as a `train` stage line). `--ship` also copies the policy (float16) to
mjxrow/checkpoints/policy/.

`--set` takes run keys for the environments and the evaluation (`camera.width=96`,
`sim.path_length=20`) and training keys (`train.unroll=16`, `env.observation=mask`,
`env.randomize.start_progress=0.5`, `env.randomize.shadow_strength=[0,1]`: cast shadows of
random strength, `env.reward.w_lateral=2`, `net.hidden=128`,
`ppo.learning_rate=1e-4`, `bc.dagger=false`, `bc.replay=8`: BC also on earlier rollouts,
`train.average=0`: policy/ holds the last weights).

`--smoke`: a CPU check in a few minutes: a tiny vineyard field, 16 × 16 images, 4 worlds, a
tiny network, 20 s of training, 2 episodes per controller (SegZeros on the ground-truth mask);
with `--curriculum`, the search's preset in its default field and ranges, its searches as
with the search's `--smoke`.

Exit codes: 0 done, 2 invalid configuration or checkpoint (the key is named), 130 interrupted.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import math
import os
import shutil
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a checkout, uninstalled

SMOKE_RUN = {"field.terrain_length": 14.0, "field.row_length": 10.0, "field.terrain_width": 5.0,
             "field.stone_density": 0.0, "field.branch_density": 0.0, "camera.width": 16,
             "camera.height": 16, "sim.path_length": 3.0, "episode.max_time": 10.0,
             "render.shadows": False, "perception.source": "ground_truth"}


# wall time kept per evaluation block (a controller on a preset) when --eval-reserve-minutes is
# not given: a block of 100 episodes ran in 6-8 s on one H200, the first of a program in 10-16 s
BLOCK_MINUTES = 0.15


def eval_blocks(args) -> int:
    """The blocks of episodes the command's evaluation runs (a preset and controller each;
    `--eval-last` adds the last weights on every preset, `--eval-sun` the policy under each
    azimuth)."""
    if args.no_eval:
        return 0
    return len(args.presets) * (len(args.controllers) + (
        int(args.eval_last) + len(args.eval_sun) if "policy" in args.controllers else 0))


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python experiments/train_policy.py",
                                description=__doc__.split("\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="Exit codes: 0 done, 2 invalid configuration, "
                                       "130 interrupted.")
    p.add_argument("--out", required=True, help="output folder (resumes what is there)")
    p.add_argument("--budget-minutes", type=float, default=5.0,
                   help="training wall time over every command with this --out (default 5)")
    p.add_argument("--deadline-minutes", type=float, default=8.5,
                   help="this command's wall-time bound, evaluation included (default 8.5; "
                        "0: none)")
    p.add_argument("--eval-reserve-minutes", type=float, default=None,
                   help="wall time kept for running the evaluation (default: "
                        f"{BLOCK_MINUTES:g} min per block of episodes, e.g. 1.5 for the policy "
                        "and its last weights on five crops)")
    p.add_argument("--presets", nargs="+", default=["zucchini", "vineyard", "pear", "lettuce",
                                                    "chard"], help="default: all five crops")
    p.add_argument("--num-envs", type=int, default=15360,
                   help="worlds in total, split evenly over the presets (default 15360: 3,072 "
                        "a crop, about 18 GB of worlds besides the rollouts and updates)")
    p.add_argument("--unroll", type=int, default=32, help="steps per rollout (default 32)")
    p.add_argument("--bc-fraction", type=float, default=0.5,
                   help="share of the budget (or of the time a deadline leaves) for BC / "
                        "DAgger before PPO (default 0.5)")
    p.add_argument("--observation", choices=("rgb", "chroma", "mask", "features"),
                   default="rgb", help="what the policy sees (default rgb; chroma: the RGB "
                        "image's chromaticity, which cast shadows change less)")
    p.add_argument("--teacher", choices=("oracle", "segzeros"), default="oracle")
    p.add_argument("--episodes", type=int, default=100, help="per preset and controller")
    p.add_argument("--controllers", nargs="+", default=["policy", "segzeros", "oracle"],
                   choices=("policy", "segzeros", "segzeros_gt", "oracle"))
    p.add_argument("--seed", type=int, default=0,
                   help="the training's: the network, its worlds and rollouts")
    p.add_argument("--eval-seed", type=int, default=0,
                   help="the evaluation's episodes (default 0: the same episodes whatever "
                        "--seed, so that commands compare on them)")
    p.add_argument("--iterations", type=int, default=None,
                   help="stop after this many iterations in all (default: the budget only)")
    p.add_argument("--init", default="", metavar="CHECKPOINT",
                   help="start from this policy checkpoint ('shipped' or a folder; same "
                        "observation and network), e.g. a BC / DAgger policy before PPO")
    p.add_argument("--curriculum", default="", metavar="SEARCH.yaml",
                   help="the adversarial curriculum: run this search against the policy every "
                        "train.curriculum.every iterations and mix its failing fields into "
                        "the resets (e.g. searches/policy_variety.yaml)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--no-eval", action="store_true", help="train only")
    p.add_argument("--eval-only", action="store_true", help="evaluate OUT/policy only")
    p.add_argument("--eval-last", action="store_true",
                   help="also evaluate OUT/policy_last (the last weights, beside their moving "
                        "average in OUT/policy)")
    p.add_argument("--eval-sun", nargs="+", type=float, default=[], metavar="DEG",
                   help="also evaluate the policy with the sun at these azimuths "
                        "(perception.sun_azimuth, degrees; Table 3's is 35), e.g. 80 260: the "
                        "sun to the side of the rows, in the programs compiled for the policy")
    p.add_argument("--overlap", choices=("auto", "on", "off"), default="auto",
                   help="compile the evaluation while training (auto: on a GPU)")
    p.add_argument("--ship", action="store_true",
                   help="copy the trained policy (float16) to mjxrow/checkpoints/policy/")
    p.add_argument("--cache-dir", default="",
                   help="JAX compilation cache (default: OUT/jax_cache; 'none' disables)")
    p.add_argument("--smoke", action="store_true", help="a few-minute CPU check")
    p.add_argument("--no-progress", action="store_true")
    return p


def configure(args) -> tuple:
    """(TrainConfig, evaluation run values) from the arguments."""
    from mjxrow import env as E
    from mjxrow.train import TINY, BCConfig, PPOConfig, TrainConfig
    from mjxrow.train import config as TC
    from mjxrow.train import evaluate as EV

    values = EV.scenario_values()
    run = {k: v for k, v in values.items()
           if not k.startswith(("episode.start_", "perception.condition"))}
    run["controller.name"] = args.teacher
    if args.teacher == "segzeros":
        run["controller.variant"] = "paper"
    from mjxrow.train.curriculum import CurriculumConfig

    cfg = TrainConfig(presets=tuple(args.presets), num_envs=args.num_envs, unroll=args.unroll,
                      budget_minutes=args.budget_minutes, bc_fraction=args.bc_fraction,
                      seed=args.seed, env=E.EnvConfig(observation=args.observation),
                      iterations=args.iterations, init=args.init,
                      curriculum=CurriculumConfig(search=args.curriculum))
    if args.smoke:
        # with a curriculum, the search's preset in its own field and ranges (which hold the
        # search's box), else a tiny vineyard field
        small = {k: v for k, v in SMOKE_RUN.items()
                 if not (args.curriculum and k.startswith("field."))}
        run.update(small)
        values.update(small)
        rz = E.Randomize(ranges=None if args.curriculum else (
            ("terrain_dh", 0.0, 0.1), ("d_RR", 2.5, 2.9)), start_progress=0.2)
        cfg = dataclasses.replace(cfg, presets=tuple(args.presets), num_envs=4, unroll=4,
                                  budget_minutes=min(args.budget_minutes, 1 / 3), net=TINY,
                                  env=dataclasses.replace(cfg.env, randomize=rz),
                                  bc=BCConfig(minibatches=2),
                                  ppo=PPOConfig(minibatches=2, epochs=2), save_every=10,
                                  curriculum=dataclasses.replace(cfg.curriculum, smoke=True))
    cfg, run_sets = TC.apply_sets(cfg, args.set)
    run.update(run_sets)
    values.update(run_sets)
    cfg = dataclasses.replace(cfg, run=tuple(sorted(run.items())))
    return cfg, values


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    t_start = time.time()
    from mjxrow import files, interrupt, limits

    try:  # the arguments checked before OUT is made
        out = files.check_out_dir(args.out, "--out")
        for name in ("seed", "eval_seed"):  # the bound of every run's seed (mjxrow.limits)
            if not 0 <= getattr(args, name) <= limits.VALUES["seed"][0]:
                raise ValueError(f"--{name.replace('_', '-')}: must lie in [0, "
                                 f"{limits.VALUES['seed'][0]}], got {getattr(args, name)}")
        for name in ("num_envs", "unroll", "episodes"):
            if getattr(args, name) < 1:
                raise ValueError(f"--{name.replace('_', '-')}: must be ≥ 1, got "
                                 f"{getattr(args, name)}")
        for a in args.eval_sun:
            if not math.isfinite(a):
                raise ValueError(f"--eval-sun: must be finite angles in degrees, got {a}")
        for name in ("budget_minutes", "deadline_minutes", "eval_reserve_minutes"):
            if getattr(args, name) is not None and not 0 <= getattr(args, name) < 1e6:
                raise ValueError(f"--{name.replace('_', '-')}: must be a number of minutes ≥ 0, "
                                 f"got {getattr(args, name)}")
    except ValueError as e:
        print(f"error: {str(e).splitlines()[0]}", file=sys.stderr)
        return 2
    # the measured runs at 15,360 worlds gave JAX 90 % of the GPU's memory (its default: 75 %)
    os.environ.setdefault("XLA_PYTHON_CLIENT_MEM_FRACTION", "0.9")
    import jax

    if args.cache_dir != "none":
        jax.config.update("jax_compilation_cache_dir", args.cache_dir or str(out / "jax_cache"))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 2.0)
    if args.smoke:
        args.ship = False  # a tiny smoke policy never replaces the shipped one
        args.episodes = min(args.episodes, 2)
        args.presets = ["vineyard"]  # or, with a curriculum, the preset its search drives
        if args.curriculum:
            from mjxrow.search import config as search_config
            try:
                args.presets = [search_config.load(args.curriculum).scenario.preset]
            except (search_config.ConfigError, OSError) as e:
                print(f"error: --curriculum: {args.curriculum}: {e}", file=sys.stderr)
                return 2
        args.controllers = list(dict.fromkeys(
            "segzeros_gt" if c == "segzeros" else c for c in args.controllers))
    try:
        cfg, values = configure(args)
    except ValueError as e:
        print(f"error: {str(e).splitlines()[0]}", file=sys.stderr)
        return 2
    # SIGTERM (a batch system's kill) and Ctrl-C: exit 130 saying how to resume
    with interrupt.HardStop(lambda: print(
            f"interrupted: the last saved training state in {out / 'state'} is kept; run the "
            "same command again to resume", file=sys.stderr)):
        return _work(args, cfg, values, out, t_start)


def _work(args, cfg, values, out: Path, t_start: float) -> int:
    """Train, evaluate and report into `out` (made here, its arguments checked)."""
    import jax

    from mjxrow.policies import checkpoint as CK
    from mjxrow.train import evaluate as EV
    from mjxrow.train import loop as L

    out.mkdir(parents=True, exist_ok=True)
    result = None
    try:
        evaluation = None
        if not args.no_eval:
            overlap = args.overlap == "on" or (args.overlap == "auto"
                                               and jax.default_backend() == "gpu")
            ahead = L.initial_policy(cfg, out / "init_policy") if overlap else None
            evaluation = EV.Evaluation(cfg.presets, args.controllers, values,
                                       str(out / "policy"), args.episodes, args.eval_seed,
                                       compile_checkpoint=str(ahead) if ahead else None)
        thread, errors = None, []
        if evaluation is not None and evaluation.compile_checkpoint:
            def prepare():
                try:
                    evaluation.prepare(log=lambda m: print(m, flush=True))
                except Exception as e:  # reported after training, then compiled again
                    errors.append(e)

            # started once the trainer's programs are compiled: its XLA compilations would
            # otherwise compete with the trainer's for the cores (and its tracing for Python's
            # lock), delaying the training; it is ready long before the training ends
            thread = threading.Thread(target=prepare, daemon=True)
        if not args.eval_only:
            deadline = None
            if args.deadline_minutes > 0 and evaluation is not None:
                reserve = args.eval_reserve_minutes
                if reserve is None:
                    reserve = BLOCK_MINUTES * eval_blocks(args)
                deadline = t_start + 60 * (args.deadline_minutes - reserve)
            elif args.deadline_minutes > 0:
                deadline = t_start + 60 * args.deadline_minutes
            # the last training state is written while the evaluation runs
            result = L.train(cfg, out, progress=not args.no_progress, deadline=deadline,
                             on_compiled=thread.start if thread is not None else None,
                             background_save=True)
        blocks = None
        if evaluation is not None:
            if thread is not None:
                if thread.ident is None:  # not started (--eval-only, or no training compiled)
                    thread.start()
                thread.join()
                if errors:
                    print(f"warning: compiling ahead failed ({errors[0]}); compiling now",
                          file=sys.stderr)
            CK.resolve(out / "policy", key="--out")
            blocks = evaluation.run(log=lambda m: print(m, flush=True))
            if args.eval_last and (out / "policy_last").is_dir():  # beside the average
                blocks += evaluation.run_policy("learned policy, last weights",
                                                str(out / "policy_last"),
                                                log=lambda m: print(m, flush=True))
            for a in args.eval_sun:  # run_policy runs the policy's blocks only
                blocks += evaluation.run_policy(f"learned policy, sun at {a:g}°",
                                                values={"perception.sun_azimuth": a},
                                                log=lambda m: print(m, flush=True))
    except ValueError as e:
        print(f"error: {str(e).splitlines()[0]}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    finally:  # the training state on disk before the command ends (seconds waited: saving's)
        if result is not None and "saving" in result:
            result["save_s"] += result.pop("saving").wait()
    report(args, cfg, result, blocks, out, time.time() - t_start)
    if args.ship:
        ck = CK.load(out / "policy", key="--out")
        dest = CK.save(CK.SHIPPED, ck.variables, ck.spec, cfg.net, ck.limits, ck.meta,
                       weights_dtype="float16")
        print(f"shipped the policy to {dest}")
    if (out / "init_policy").exists():
        shutil.rmtree(out / "init_policy")
    return 0


def report(args, cfg, result, blocks, out: Path, wall: float) -> None:
    """Print and write the final table and the training facts."""
    import jax

    from mjxrow import runtime
    from mjxrow.train import evaluate as EV

    device = jax.devices()[0].device_kind
    lines = [f"# Learned policy vs SegZeros vs oracle ({device})", ""]
    summary: dict = {"date": datetime.date.today().isoformat(), "device": device,
                     "command": "python experiments/train_policy.py " + " ".join(
                         sys.argv[1:]), "wall_s": wall}
    if result is not None:
        summary["training"] = {k: v for k, v in result.items() if k != "last"}
        method = ("BC/DAgger" if cfg.bc_fraction >= 1 else "PPO" if cfg.bc_fraction <= 0
                  else "BC/DAgger then PPO") + (
            f" with the teacher term (ppo.teacher_cost {cfg.ppo.teacher_cost:g})"
            if cfg.bc_fraction < 1 and cfg.ppo.teacher_cost > 0 else "") + (
            f" from {cfg.init}" if cfg.init else "") + (
            f", adversarial curriculum ({cfg.curriculum.search}, every "
            f"{cfg.curriculum.every} iterations, share {cfg.curriculum.share:g})"
            if cfg.curriculum.on else "") + (
            f", DAgger's data aggregated over {cfg.bc.replay} rollouts (bc.replay)"
            if cfg.bc.replay and cfg.bc_fraction > 0 else "") + (
            ", half of every update's samples mirrored left-right (bc.mirror)"
            if cfg.bc.mirror and cfg.bc_fraction > 0 else "") + (
            f", the weights' moving average (decay {cfg.average:g} an iteration)"
            if cfg.average > 0 else "")
        summary["method"] = method
        lines += [f"method: {method}",
                  f"training: {result['elapsed_s'] / 60:.2f} min of {cfg.budget_minutes:g} "
                  f"budgeted ({result['iterations']} iterations, "
                  f"{result['env_steps'] / 1e6:.2f} M env steps; compile "
                  f"{result['compile_s']:.0f} s, saving the training state "
                  f"{result['save_s']:.0f} s), {cfg.num_envs} worlds",
                  f"env-steps/s during training: {result['rollout_steps_per_s']:,.0f} in the "
                  f"rollouts, {result['steps_per_s']:,.0f} with the updates (median over "
                  f"iterations, B = {cfg.num_envs})",
                  "memory peak: " + runtime.peak_text(result["memory_peak_gib"]), ""]
        with (out / "benchmarks.jsonl").open("a") as f:
            f.write(json.dumps({
                "date": summary["date"], "device": device, "stage": "train",
                "config": f"policy training, {'+'.join(cfg.presets)}, "
                          f"{cfg.env.observation} {cfg.run_config(cfg.presets[0]).camera.width}"
                          f" px, unroll {cfg.unroll}", "batch": cfg.num_envs,
                "value": result["rollout_steps_per_s"], "unit": "env-steps/s",
                "steps_per_s_with_updates": result["steps_per_s"],
                "compile_s": result["compile_s"],
                "trace_s": result["compile_parts"]["trace_s"], "run_s": result["elapsed_s"],
                "search_s": result["search_s"], "save_s": result["save_s"], "method": method,
                "memory_peak_gib": result["memory_peak_gib"],
                "command": summary["command"]}) + "\n")
        for r in result["rounds"]:
            lines.append(f"adversary round {r['round']} (iteration {r['iteration']}): "
                         f"{r['failing_per_1000']:.0f} failing episodes per 1,000 of "
                         f"{r['episodes']}, {r['failing_candidates']} failing fields, "
                         f"{r['distinct_failures']} distinct, {r['search_s']:.0f} s")
    if blocks is not None:
        md, rows = EV.table(blocks)
        lines += [md, ""]
        summary["evaluation"] = rows
    lines.append(f"wall time of this command: {wall / 60:.2f} min")
    text = "\n".join(lines)
    print("\n" + text)
    (out / "eval.md").write_text(text + "\n")
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=str) + "\n")
    if blocks is not None:
        (out / "eval.json").write_text(json.dumps(summary["evaluation"], indent=2,
                                                  default=str) + "\n")


if __name__ == "__main__":
    sys.exit(main())
