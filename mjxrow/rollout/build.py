"""The one assembly: run configs → everything a batch of episodes needs.

    built = build(runs)                 # RunConfigs sharing their static values (one compile)
    batch = built.batch([(run, episode_index), ...])
    log = built.rollout(batch)          # jit(episodes), sharded over the local devices
    metrics = built.summarise(log)

`build` fits the static field shape, makes the MJX model, the policy (a controller from the
registry, behind the perception loop when it reads masks; segmenter weights loaded once) and the
vmap axes of its params, and the shardings; `Built.batch` generates the fields of the episodes
(one jitted `vmap(field.generate)`), draws their keys, picks their lanes, stacks their policy
params and start-pose noise, and places everything on the devices. The sweep, the episode CLI,
the benchmarks, the experiments and the tests all go through here.

Random numbers: episode `i` of a run with seed `s` uses `fold_in(key(s), i)`, split into the
field's key and the rollout's key (`episode_keys`, `split_keys`): the same seed and cell give
the same episode from every command, whatever the batching.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from mjxrow import control, runtime
from mjxrow import field as mjxrow_field
from mjxrow.field import lanes as field_lanes
from mjxrow.field.generate import PATH_LENGTH
from mjxrow.physics import sim
from mjxrow.policies import perception
from mjxrow.rollout import episode as rollout_episode
from mjxrow.rollout import step as rollout_step
from mjxrow.rollout.config import RunConfig
from mjxrow.rollout.fingerprint import program_key
from mjxrow.rollout.metrics import Log


def episode_keys(seed: int, episodes: Sequence[int] | np.ndarray) -> jax.Array:
    """PRNG keys [N] of episodes `episodes` (indices within a run): fold_in(key(seed), i).
    The same for every cell of a sweep (common random numbers) and independent of batching."""
    return _keys_fn()(int(seed), np.asarray(episodes, np.uint32))


def split_keys(keys: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Episode keys [N] → (field keys [N], rollout keys [N])."""
    k = jax.vmap(jax.random.split)(keys)
    return k[:, 0], k[:, 1]


def batch_keys(seeds: Sequence[int], episodes: Sequence[int]) -> tuple[jax.Array, jax.Array]:
    """(field keys [N], rollout keys [N]) of episode `episodes[n]` of a run of seed
    `seeds[n]`: split_keys of episode_keys, one call per distinct seed (a sweep has one)."""
    seeds, episodes = np.asarray(seeds, np.int64), np.asarray(episodes, np.uint32)
    if len(seeds) != len(episodes):
        raise ValueError(f"batch_keys: {len(seeds)} seeds for {len(episodes)} episodes")
    distinct = np.unique(seeds)
    if len(distinct) == 1:
        return _split_fn()(int(distinct[0]), episodes)
    order = np.argsort(seeds, kind="stable")  # episodes grouped by seed, then put back
    parts = [_split_fn()(int(s), episodes[order][seeds[order] == s]) for s in distinct]
    back = np.argsort(order)
    return tuple(jnp.concatenate([p[i] for p in parts])[back] for i in (0, 1))


def _fold(seed: int, episodes: jax.Array) -> jax.Array:
    base = jax.random.key(seed)
    return jax.vmap(lambda i: jax.random.fold_in(base, i))(episodes)


@functools.lru_cache(maxsize=1)
def _keys_fn():
    """jit: (seed (static), episodes uint32 [N]) → episode keys [N], one program per N."""
    return jax.jit(_fold, static_argnums=0)


@functools.lru_cache(maxsize=1)
def _split_fn():
    """jit: (seed (static), episodes [N]) → split_keys of the episode keys."""
    return jax.jit(lambda seed, i: split_keys(_fold(seed, i)), static_argnums=0)


@functools.lru_cache(maxsize=4)
def lanes_fn(mode: str):
    """jit(vmap(field.robot_lane)) for one lane choice (`sim.lane`): fields [B] → int32 [B]."""
    return jax.jit(jax.vmap(lambda f: mjxrow_field.robot_lane(f, mode=mode)))


@functools.lru_cache(maxsize=1)
def summarise_fn():
    """jit(episode.summarise) (config static): Log [B] → per-episode metrics."""
    return jax.jit(rollout_episode.summarise, static_argnums=1)


@functools.lru_cache(maxsize=1)
def generate_fn():
    """jit(vmap(field.generate)) over (params [B], keys [B]) for a static shape: the one.
    Optional 4th argument: the episodes' `sim.path_length` (m; where the obstacle-free start
    zone lies, field.generate), default field.generate's."""

    def gen(params, shape, keys, path_length=PATH_LENGTH):
        return jax.vmap(lambda p, k: mjxrow_field.generate(p, shape, k, path_length))(params, keys)

    return jax.jit(gen, static_argnums=1)


def stack(trees: Sequence[Any]) -> Any:
    """Pytrees → one pytree with a leading [N] axis (field.stack_leaves: numpy for host
    leaves)."""
    return jax.tree.map(lambda *xs: mjxrow_field.stack_leaves(xs), *trees)


def fit_shape(runs: Sequence[RunConfig]) -> mjxrow_field.FieldShape:
    """The static FieldShape that holds every run's field (rounded up by field.fit_shape)."""
    params = mjxrow_field.stack_params([r.field_params(host=True) for r in runs])
    return mjxrow_field.fit_shape(params, runs[0].preset)


@dataclasses.dataclass(frozen=True)
class Batch:
    """The arguments of one compiled call, placed on the devices: B episodes (padded), of
    which the first `n` are real."""

    fields: mjxrow_field.Field  # [B]
    lanes: jax.Array  # int32 [B]
    keys: jax.Array  # rollout keys [B]
    noise: sim.PoseNoise  # [B]
    params: Any  # policy params (per-episode leaves [B], shared leaves as they are)
    n: int

    def args(self, mx) -> tuple:
        return (mx, self.fields, self.lanes, self.keys, self.noise, self.params)


@dataclasses.dataclass
class Built:
    """Everything a group of runs sharing static values needs (see `build`)."""

    run: RunConfig  # the group's first run: its static values are everyone's
    shape: mjxrow_field.FieldShape
    episode: rollout_step.EpisodeConfig  # static part (no start noise)
    mj: Any  # mujoco.MjModel
    mx: Any  # mjx.Model, replicated over the devices
    policy: control.Policy
    axes: Any  # vmap axes of the policy params (episode.rollout's params_axes)
    base: Any  # what the policy params of every run share (perception params with weights)
    mesh: jax.sharding.Mesh
    placed: dict = dataclasses.field(default_factory=dict)
    # everything static the closed-loop program closes over, as text (`program_key`; '' when
    # some of it is code outside the mjxrow package): names the traced program kept by
    # `runtime.exported`
    key: str = ""
    # a mixed group (runs of several controllers, `build`): every run's `variant_key`, in the
    # order of the policy's variants, and each variant's controller params for the episodes
    # it does not drive
    variants: tuple = ()
    fillers: tuple = ()

    @property
    def devices(self) -> int:
        return int(self.mesh.devices.size)

    def sharding(self, batched: bool) -> jax.sharding.NamedSharding:
        spec = jax.sharding.PartitionSpec("batch" if batched else None)
        return jax.sharding.NamedSharding(self.mesh, spec)

    def padded(self, n: int) -> int:
        """n rounded up to a multiple of the device count."""
        return -(-n // self.devices) * self.devices

    def policy_params(self, run: RunConfig) -> Any:
        """One run's policy params (one episode: no batch axis)."""
        cparams = run.controller_params()
        if self.variants:  # a mixed group: this run's variant drives, the others ride along
            i = self.variants.index(run.variant_key())
            ctrl = self.fillers[:i] + (cparams,) + self.fillers[i + 1:]
            p = run.perception
            perc = None if self.base is None else perception.perception_params(
                p.conditions(), p.threshold, self.base.variables)
            return perception.MixParams(np.int32(i), perc, ctrl)
        if self.base is None:
            return cparams
        p = run.perception
        return (perception.perception_params(p.conditions(), p.threshold, self.base.variables),
                cparams)

    def _put_params(self, params: Any) -> Any:
        """Per-episode parts sharded on the batch, shared parts replicated once (cached by
        object identity in `placed`)."""
        treedef, leaves = rollout_episode.canonical_axes(self.axes)
        out = []
        for a, x in zip(leaves, treedef.flatten_up_to(params), strict=True):
            if a is not None:
                out.append(runtime.put(x, self.sharding(True)))
                continue
            if id(x) not in self.placed:
                self.placed[id(x)] = (x, runtime.put(x, self.sharding(False)))
            out.append(self.placed[id(x)][1])
        return treedef.unflatten(out)

    def batch(self, items: Sequence[tuple[RunConfig, int]], size: int | None = None) -> Batch:
        """The batch of episodes `items` ((run, episode index) pairs), padded with copies of
        the last one to `size` (default: the item count), rounded up to the device count."""
        items = list(items)
        if not items:
            raise ValueError("batch: no episodes")
        B = self.padded(max(size or len(items), len(items)))
        full = items + [items[-1]] * (B - len(items))
        put = functools.partial(runtime.put, sharding=self.sharding(True))
        by_run: dict[RunConfig, list[int]] = {}
        for i, (run, _) in enumerate(full):
            by_run.setdefault(run, []).append(i)
        runs = list(by_run)
        cache = {r: (r.field_params(host=True), self.policy_params(r), r.episode.noise)
                 for r in runs}
        fkeys, rkeys = batch_keys([r.seed for r, _ in full], [e for _, e in full])
        fparams = put(stack([cache[r][0] for r, _ in full]))
        sim_cfg = self.episode.sim
        fields = generate_fn()(fparams, self.shape, put(fkeys), sim_cfg.path_length)
        rollout_episode.check_fields(fields.replace(valid=runtime.to_host(fields.valid)))
        lanes = lanes_fn(sim_cfg.lane)(fields)
        pol = self._put_params(
            rollout_episode.stack_params([cache[r][1] for r, _ in full], self.axes)
        )
        noise = put(rollout_episode.batch_noise(stack([cache[r][2] for r, _ in full]), B))
        return Batch(fields, lanes, put(rkeys), noise, pol, len(items))

    def compiled(self):
        """The jitted rollout of this group: `(mx, fields, lanes, keys, noise, params) -> Log`."""
        return rollout_episode.compiled(self.policy, self.episode, self.axes)

    def program(self, args: tuple):
        """`compiled()` for `args` (a Batch's `args(mx)`), or the same program traced by an
        earlier process and kept beside the compilation cache (`runtime.exported`): equal
        results, no tracing."""
        fn = self.compiled()
        _PROGRAMS.add((self.key or id(fn), _arg_shapes(args)))
        if not self.key:
            return fn
        return runtime.exported(fn, args, self.key, LOG_TREE) or fn

    def executable(self, args: tuple):
        """`program(args)` lowered and compiled (or loaded from the cache) for `args`."""
        prog = self.program(args)
        return prog.lower(*args).compile()

    def rollout(self, batch: Batch, progress: Callable[[int, int], None] | None = None) -> Log:
        """The batch's Log. With `progress`, the batch runs as `episode.staged`'s three
        programs (the same numbers; its programs are traced every run, never kept), and
        `progress(control steps run, episodes ended)` is called after every STAGE_CHUNKS
        chunks of control steps: a long batch shows it moving."""
        args = batch.args(self.mx)
        if progress is None:
            return self.program(args)(*args)
        st = rollout_episode.staged(self.policy, self.episode, self.axes, STAGE_CHUNKS)
        _PROGRAMS.add((("staged", self.key or id(st)), _arg_shapes(args)))
        state, finished = st.start(*args), False
        while not finished:
            state = st.advance(self.mx, state, batch.params)
            steps, ended, finished = st.status(state)
            progress(steps, ended)
        return st.finish(state)

    def summarise(self, log: Log, n: int | None = None) -> dict[str, np.ndarray]:
        """Per-episode metrics on the host (the first `n` episodes)."""
        out = runtime.to_host(summarise_fn()(log, self.episode))
        return {k: v[:n] if np.ndim(v) else v for k, v in out.items()}


# the tree structure of a batch's Log (what the closed-loop program returns; no arrays needed)
LOG_TREE = jax.tree.structure(Log(**{
    **{f.name: 0 for f in dataclasses.fields(Log)},
    "lane": field_lanes.Lane(u=0, s_end=0, bend=field_lanes.Bend(0, 0, 0, 0))}))


def _arg_shapes(args: tuple) -> str:
    """The shapes and dtypes of a program's arguments, as one string (a `_PROGRAMS` key)."""
    return str(jax.tree.map(lambda x: (np.shape(x), str(getattr(x, "dtype", ""))), args))


STAGE_CHUNKS = 2  # chunks of control steps per program call of a batch shown as it goes
_PROGRAMS: set = set()  # (program key, argument shapes) of every closed-loop program asked for


def program_count() -> int:
    """Distinct closed-loop programs this process has run (compiled, loaded from the cache or
    deserialized): one per group static values and argument shapes."""
    return len(_PROGRAMS)


def build(runs: RunConfig | Sequence[RunConfig], shape: mjxrow_field.FieldShape | None = None,
          devices: Sequence[Any] | None = None) -> Built:
    """Assemble a group of runs that share every static value (their `static_key`): the
    field shape (fitted to all of them unless given), the MJX model, the policy and the axes
    of its params, the device mesh (all local devices unless given).

    Runs that differ only in their controller and mask source (equal `share_key`) make one
    mixed group: one program in which every episode runs every controller's stages and is
    driven by its own (`perception.mixed_policy`): one compile instead of one per controller,
    at the cost of each episode paying for all of them."""
    runs = [runs] if isinstance(runs, RunConfig) else list(runs)
    if len({r.share_key() for r in runs}) > 1:
        raise ValueError("build: the runs differ in static values besides the controller "
                         "and the mask source; group them first (RunConfig.static_key)")
    reps: dict[tuple, RunConfig] = {}  # one run per variant (controller and mask source)
    for r in runs:
        reps.setdefault(r.variant_key(), r)
    first = runs[0]
    shape = shape or fit_shape(runs)
    ep = first.episode.static()
    mj, mx = sim.make_model(shape, ep.sim, first.robot_config())
    policy, axes, base, module = _policy(list(reps.values()), shape)
    mesh = jax.sharding.Mesh(np.array(list(devices or jax.devices())), ("batch",))
    mx = runtime.put(mx, jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec()))
    key = program_key(list(reps.values()), shape, ep,
                      sim.model_xml(shape, ep.sim, first.robot_config()), module)
    mixed = len(reps) > 1
    return Built(first, shape, ep, mj, mx, policy, axes, base, mesh, key=key,
                 variants=tuple(reps) if mixed else (),
                 fillers=tuple(r.controller_params() for r in reps.values()) if mixed else ())


def _policy(reps: list[RunConfig], shape: mjxrow_field.FieldShape):
    """(policy, params axes, base params, segmenter module or None) of a group whose variants
    `reps` stand for (one run each; several: a mixed policy). The segmenter is loaded once."""
    first = reps[0]
    own = getattr(control.get(first.controller.name), "make_policy", None)
    if len(reps) == 1 and own is not None:  # renders its own image (control.policy)
        policy, base = own(first, shape)
        return policy, perception.PARAMS_AXES, base, None
    variants, learned = [], None
    for r in reps:
        c = control.get(r.controller.name)
        if getattr(c, "make_policy", None) is not None:
            raise ValueError(f"build: controller {c.name!r} renders its own images; it cannot "
                             "share a program with other controllers (controller.name)")
        source = r.perception.source if c.needs_mask else None
        variants.append((c.name, source))
        learned = learned or (r if source == "learned" else None)
    module = variables = None
    if learned is not None:
        module, variables = perception.load_segmenter(learned.checkpoint_path(), first.preset)
    sees = any(s is not None for _, s in variants)
    base = perception.perception_params(variables=variables) if sees else None
    if len(reps) > 1:
        policy = perception.mixed_policy(tuple(variants), shape, first.camera, module,
                                         first.render)
        return policy, perception.mix_axes(len(reps), sees), base, module
    if not sees:
        return control.as_policy(variants[0][0]), 0, None, None
    policy = perception.perception_policy(variants[0][0], shape, first.camera, variants[0][1],
                                          module, first.render)
    return policy, perception.PARAMS_AXES, base, module
