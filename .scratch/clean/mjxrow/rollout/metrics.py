"""Navigation metrics of logged episodes (the paper's Table 3 and more) and plant collisions;
their aggregation over episodes (means, intervals, reasons) is `rollout.aggregate`.

Each metric is one `Metric` record in the registry `METRICS` (`register`): its function, unit,
label, valid bounds, better direction and flags. `summarise`, a sweep's tables, figures and
report, the training env's `nav/<name>` metrics and the trainer's episode statistics all read
the registry, so a new metric is one `register(Metric(...))` call.

Every per-step array has the step axis last-but-features: `pose` is [..., T, 3]; any leading
batch axes are carried through, so the same functions serve one episode or a batch of them
(no vmap needed; `summarise` maps a Metric's function over a batch, so it may assume one
episode). Steps after an episode ends are masked by `Log.alive`.

Conventions: metres, radians; the lane's centre line is `Log.lane` (`mjxrow.field.lanes`: the
line y = lane_y of a straight field, or the curve of curved rows), offsets are measured from it
and headings against its direction. The robot frame has x forward and y to the left; a goal to
the left has a positive bearing.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
from flax import struct

from mjxrow.crops import prims as crops_prims
from mjxrow.field import Field
from mjxrow.field import lanes as field_lanes
from mjxrow.field.lanes import Lane

# Termination reasons; code 0 marks a step at which the episode is still running. `off_patch`:
# the robot left the simulated terrain (strayed far from its lane, or drove off its back or
# front end); `missed_goal`: it drove past the row's end (the goal's x plus the goal radius)
# beside the goal, without reaching it.
REASONS = ("running", "goal", "collision", "timeout", "flipped", "stuck", "sim_error",
           "off_patch", "missed_goal")
(RUNNING, GOAL, COLLISION, TIMEOUT, FLIPPED, STUCK, SIM_ERROR, OFF_PATCH,
 MISSED_GOAL) = range(len(REASONS))

# An episode that ended so is excluded from the trajectory metrics (see `excluded`).
EXCLUDED_REASONS = (FLIPPED, SIM_ERROR)


@struct.dataclass
class Log:
    """What one episode logs (add leading [B] axes for a batch). T = number of control steps.

    `pose[t]` is the pose after control step t, `cmd[t]` the command applied during it;
    `alive[t]` is True for every step that ran (up to and including the step that ended the
    episode); `event[t]` is the reason code of the step that ended the episode, RUNNING (0)
    elsewhere."""

    pose: jax.Array  # float32 [T, 3], (x [m], y [m], yaw [rad]) after each step
    cmd: jax.Array  # float32 [T, 2], (v [m/s], ω [rad/s]) applied during each step
    alive: jax.Array  # bool [T]
    event: jax.Array  # int32 [T], REASONS code where the episode ended, 0 elsewhere
    start: jax.Array  # float32 [3], pose at reset
    goal: jax.Array  # float32 [2], goal position (x, y) [m]
    lane: Lane  # the driven lane's centre line (its end is the goal)
    reason: jax.Array  # int32 [], REASONS code of the episode's end
    steps: jax.Array  # int32 [], number of control steps that ran
    vel: jax.Array | None = None  # float32 [T, 2], measured (forward speed, yaw rate) per step

    @property
    def lane_y(self) -> jax.Array:
        """The lane's lateral field coordinate u [m] (its y on a straight field)."""
        return self.lane.u


# ---------------------------------------------------------------------------------------------
# Geometry


def goal_bearing(pose: jax.Array, goal: jax.Array) -> jax.Array:
    """Bearing atan2(y_g, x_g) [rad] of the goal in the robot frame (x forward, y left).

    pose: [..., 3] (x, y, yaw); goal: [..., 2], broadcastable. Positive: goal to the left."""
    dx = goal[..., 0] - pose[..., 0]
    dy = goal[..., 1] - pose[..., 1]
    c, s = jnp.cos(pose[..., 2]), jnp.sin(pose[..., 2])
    return jnp.arctan2(-s * dx + c * dy, c * dx + s * dy)


def rect_ellipse_overlap(centre: jax.Array, yaw: jax.Array, half: jax.Array,
                         e_centre: jax.Array, e_axes: jax.Array) -> jax.Array:
    """Whether a rectangle overlaps axis-aligned ellipses (exact test).

    centre: [..., 2] rectangle centre [m]; yaw: [...] its orientation [rad]; half: [2] half
    length (along its own x) and half width [m]; e_centre: [..., 2] ellipse centres [m];
    e_axes: [..., 2] ellipse semi-axes along world x and y [m] (> 0); the leading axes
    broadcast. Returns bool [...].

    The map that turns each ellipse into the unit circle is affine, so the rectangle becomes a
    parallelogram and the shapes overlap iff the origin lies inside the parallelogram or
    within distance 1 of one of its edges."""
    c, s = jnp.cos(yaw)[..., None], jnp.sin(yaw)[..., None]
    sx = jnp.array([1.0, -1.0, -1.0, 1.0]) * half[0]
    sy = jnp.array([1.0, 1.0, -1.0, -1.0]) * half[1]
    corners = centre[..., None, :] + jnp.stack([c * sx - s * sy, s * sx + c * sy], -1)  # CCW
    q = (corners - e_centre[..., None, :]) / e_axes[..., None, :]  # [..., 4, 2]
    edge = jnp.roll(q, -1, axis=-2) - q
    cross = edge[..., 0] * q[..., 1] - edge[..., 1] * q[..., 0]  # edge × (origin − q), negated
    inside = jnp.all(cross <= 0, -1) | jnp.all(cross >= 0, -1)
    t = -jnp.sum(q * edge, -1) / jnp.maximum(jnp.sum(edge * edge, -1), 1e-12)
    closest = q + jnp.clip(t, 0.0, 1.0)[..., None] * edge
    near = jnp.min(jnp.sum(closest * closest, -1), -1) <= 1.0
    return inside | near


def near_plants(field: Field, xy: jax.Array, window: int) -> tuple[jax.Array, jax.Array,
                                                                    jax.Array]:
    """The plants that can be near the point `xy` [2]: the two rows on either side of it (four
    rows) and, in each, the 2·window + 1 plants nearest along the rows (plant index from the
    point's s via d_pp; field coordinates, `field.lanes`, so curved rows too).

    One field (no batch axis). Returns xy [4, 2w+1, 2] [m], the row/plant indices
    ([4, 2w+1] each) into the field's [R, P] arrays, as a tuple (xy, rows, cols)."""
    R, P = field.plant_active.shape
    s, u = field_lanes.to_field(field_lanes.field_bend(field), xy[0], xy[1])
    row_y = jnp.where(field.row_active, field.row_y, jnp.inf)
    j = jnp.searchsorted(row_y, u)
    rows = jnp.clip(j + jnp.arange(-2, 2), 0, R - 1)
    d_pp = field.params.d_pp * field.params.scale
    i = jnp.round((s - field.row_x[0]) / d_pp).astype(jnp.int32)
    cols = jnp.clip(i + jnp.arange(-window, window + 1), 0, P - 1)
    rows, cols = jnp.broadcast_arrays(rows[:, None], cols[None, :])
    return field.plant_pos[rows, cols, :2], rows, cols


def collides(pose: jax.Array, field: Field, crop: str, half: tuple[float, float] = (0.254, 0.215),
             window: int = 4) -> jax.Array:
    """Whether the robot footprint touches a plant's collision footprint. bool [].

    pose: [3] (x, y, yaw) of the footprint centre; field: one field; crop: static crop name
    (the footprint is the trunk for pear and vineyard, the leaf footprint for low crops, see
    `plants.footprint`); half: half length and half width of the robot [m]
    (0.508 × 0.430 m by default); window: plants checked on each side along a row (static).

    Only plants near the robot are tested: four rows around it and 2·window + 1 plants per
    row. That covers every plant that can touch the robot when
    window · d_pp ≥ √(half[0]² + half[1]²) + plant half length + 3·plant_jitter, true for
    every preset with the default window (chard is the tightest: 4 · 0.3 m ≥ 0.62 m)."""
    pxy, rows, cols = near_plants(field, pose[:2], window)
    axes = crops_prims.footprint(crop, field.plant_size[rows, cols])
    # in each plant's own frame (its length axis along its row): the ellipse is axis-aligned
    h = field.plant_heading[rows, cols]
    c, s = jnp.cos(h), jnp.sin(h)
    d = pose[:2] - pxy
    centre = jnp.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], -1)
    hit = rect_ellipse_overlap(centre, pose[2] - h, jnp.asarray(half, jnp.float32),
                               jnp.zeros_like(pxy), jnp.maximum(axes, 1e-4))
    return jnp.any(hit & field.plant_active[rows, cols])


# ---------------------------------------------------------------------------------------------
# Per-episode metrics


def lateral_offset(pose: jax.Array, lane: Lane) -> jax.Array:
    """Signed lateral offset [m] from the lane's centre line (positive: left of it, towards +u;
    +y on a straight field), perpendicular to the line. pose: [..., T, 3]; lane: [...].
    Returns [..., T]."""
    return field_lanes.project(_per_step(lane), pose[..., :2])[1]


def heading_error(pose: jax.Array, lane: Lane) -> jax.Array:
    """Signed heading error [rad] against the direction of the lane's centre line at the
    robot's place along it (positive: turned left of it), wrapped into [−π, π).
    pose: [..., T, 3]; lane: [...]. Returns [..., T]."""
    direction = field_lanes.project(_per_step(lane), pose[..., :2])[2]
    return jnp.mod(pose[..., 2] - direction + jnp.pi, 2.0 * jnp.pi) - jnp.pi


def _per_step(lane: Lane) -> Lane:
    return jax.tree.map(lambda x: jnp.asarray(x)[..., None], lane)


def _masked_mean(x, m):
    n = jnp.sum(m, -1)
    return jnp.sum(jnp.where(m, x, 0.0), -1) / jnp.maximum(n, 1), n


def valid_steps(log: Log) -> jax.Array:
    """bool [..., T]: the steps that ran with a finite pose, except the step of a sim_error (its
    pose, finite or not, is the exploded state). Trajectory metrics are taken over these."""
    pose = jnp.asarray(log.pose)
    return log.alive & jnp.all(jnp.isfinite(pose), -1) & (jnp.asarray(log.event) != SIM_ERROR)


def excluded(log: Log) -> jax.Array:
    """bool [...]: the episode has no valid step, or ended flipped or in a simulation error;
    its trajectory metrics are NaN, so that a cell's mean leaves it out."""
    n = jnp.sum(valid_steps(log), -1)
    return (n == 0) | jnp.isin(log.reason, jnp.asarray(EXCLUDED_REASONS))


def _valid_mean(log: Log, x: jax.Array) -> jax.Array:
    return _masked_mean(x, valid_steps(log))[0]


def _offset(log: Log) -> jax.Array:
    return lateral_offset(jnp.asarray(log.pose), log.lane)


def _cha(log: Log, control_dt: float) -> jax.Array:
    return _valid_mean(log, goal_bearing(jnp.asarray(log.pose), log.goal[..., None, :]))


def _max_offset(log: Log, control_dt: float) -> jax.Array:
    return jnp.max(jnp.where(valid_steps(log), jnp.abs(_offset(log)), 0.0), -1)


def _omega_std(log: Log, control_dt: float) -> jax.Array:
    ok, w = valid_steps(log), log.cmd[..., 1]
    w_mean, _ = _masked_mean(w, ok)
    w_var, _ = _masked_mean((w - w_mean[..., None]) ** 2, ok)
    return jnp.sqrt(w_var)


def _path_ratio(log: Log, control_dt: float) -> jax.Array:
    ok = valid_steps(log)
    n = jnp.sum(ok, -1)
    xy = jnp.where(ok[..., None], jnp.asarray(log.pose)[..., :2], jnp.nan)
    prev = jnp.concatenate([log.start[..., None, :2], xy[..., :-1, :]], -2)
    # a masked step contributes nothing; the first step after the start counts from the start
    seg = jnp.where(ok & jnp.all(jnp.isfinite(prev), -1),
                    jnp.linalg.norm(jnp.nan_to_num(xy - prev), axis=-1), 0.0)
    length = jnp.sum(seg, -1)
    last = jnp.maximum(n - 1, 0)
    end = jnp.take_along_axis(jnp.nan_to_num(xy), last[..., None, None], -2)[..., 0, :]
    end = jnp.where((n > 0)[..., None], end, log.start[..., :2])
    disp = jnp.linalg.norm(end - log.start[..., :2], axis=-1)
    return jnp.where(disp > 0.01, length / jnp.maximum(disp, 1e-9), jnp.nan)


# ---------------------------------------------------------------------------------------------
# The metric registry

BETTER = ("higher", "lower", "zero")


@dataclasses.dataclass(frozen=True)
class Metric:
    """One per-episode navigation metric: how it is computed and how it is shown. Registered
    (`register`), it is a value of `summarise` (a column of results.csv and summary.csv), a
    figure and a report section of a sweep, `nav/<name>` in the training env's metrics (`env`)
    and an episode statistic of the trainer (`train`).

    `fn(log, control_dt)`: the value for ONE episode's Log (no batch axis: `summarise` maps it
    over batches) and the control period [s]; traced jnp. `better`: 'higher' or 'lower' is
    better (figures colour the better end bright and say so), 'zero' for a signed metric whose
    best value is 0 (CHA), None for no order (the reason code)."""

    name: str  # the column in results.csv and summary.csv, `nav/<name>` in the env
    fn: Callable[[Log, float], jax.Array]  # (one episode's Log, control period [s]) → value []
    label: str  # figure title and report heading
    unit: str = ""  # of a cell's mean (a rate of a yes/no metric: 'fraction'); '' for none
    fmt: str = "{:.3g}"  # number format in figures and report tables
    better: str | None = None  # 'higher', 'lower', 'zero' or None (above)
    bounds: tuple[float, float] = (-math.inf, math.inf)  # valid values; CIs are clipped to them
    binary: bool = False  # yes/no per episode: a cell's mean is a rate (Wilson interval, 0-1)
    # of the driven trajectory: NaN for an `excluded` episode (left out of a cell's mean and of
    # its count `m_n`, never averaged in as a number); a heatmap cell with failed episodes is
    # hatched. Such a metric is a float.
    trajectory: bool = False
    env: bool = True  # reported by the training env (`nav/<name>`, float32)
    train: bool = False  # averaged over ended episodes in the trainer's statistics (needs env)

    def __post_init__(self):
        if self.better not in (*BETTER, None):
            raise ValueError(f"metric {self.name}: better must be one of {BETTER} or None, "
                             f"got {self.better!r}")
        if not self.bounds[0] <= self.bounds[1]:
            raise ValueError(f"metric {self.name}: bounds {self.bounds} are not (lo, hi)")
        if self.train and not self.env:
            raise ValueError(f"metric {self.name}: train needs env (the trainer reads nav/...)")


# name → Metric, in registration order: the order of the episode CLI's columns and of `nav/...`
# (a sweep's results.csv and summary.csv list them by name)
METRICS: dict[str, Metric] = {}
_traced = False  # whether `summarise` has been traced (register then clears JAX's caches)


def register(metric: Metric) -> Metric:
    """Add `metric` to the registry under its name. Registered after a jitted `summarise` (a
    sweep, the env) was traced, JAX's caches are cleared so that the next call retraces with
    it."""
    if metric.name in METRICS:
        raise ValueError(f"metric: {metric.name!r} is already registered (unregister it to "
                         "replace it)")
    METRICS[metric.name] = metric
    _retrace()
    return metric


def unregister(name: str) -> Metric:
    """Remove the metric `name` from the registry (and JAX's caches, as `register`)."""
    metric = METRICS.pop(name)
    _retrace()
    return metric


def _retrace() -> None:
    if _traced:
        jax.clear_caches()


# The built-in metrics (this order is the registry's). `dev`: the lateral offset from the lane
# centre line; trajectory metrics are taken over the valid steps (`valid_steps`).
register(Metric("success", lambda log, dt: log.reason == GOAL, "success rate", "fraction",
                "{:.2f}", better="higher", bounds=(0.0, 1.0), binary=True, train=True))
# the episode ended touching a plant
register(Metric("collision", lambda log, dt: log.reason == COLLISION, "collision rate",
                "fraction", "{:.2f}", better="lower", bounds=(0.0, 1.0), binary=True,
                train=True))
# int32 REASONS code of the episode's end (a sweep's tables write its name)
register(Metric("reason", lambda log, dt: log.reason, "ending reason"))
register(Metric("excluded", lambda log, dt: excluded(log),
                "share of episodes excluded from the trajectory metrics", "fraction", "{:.2f}",
                better="lower", bounds=(0.0, 1.0), binary=True, env=False))
# mean over steps of the goal's signed bearing atan2(y_g, x_g) in the robot frame
register(Metric("cha", _cha, "cumulative heading average (CHA)", "rad", "{:.3f}", better="zero",
                bounds=(-math.pi, math.pi), trajectory=True, train=True))
# mean |dev|
register(Metric("mae", lambda log, dt: _valid_mean(log, jnp.abs(_offset(log))),
                "mean absolute lateral error (MAE)", "m", "{:.3f}", better="lower",
                bounds=(0.0, math.inf), trajectory=True, train=True))
# mean dev²
register(Metric("mse", lambda log, dt: _valid_mean(log, jnp.square(_offset(log))),
                "mean squared lateral error (MSE)", "m²", "{:.4f}", better="lower",
                bounds=(0.0, math.inf), trajectory=True, train=True))
# population std of the ω commands
register(Metric("omega_std", _omega_std, "std of ω commands", "rad/s", "{:.3f}", better="lower",
                bounds=(0.0, math.inf), trajectory=True, train=True))
# mean commanded v
register(Metric("v_mean", lambda log, dt: _valid_mean(log, log.cmd[..., 0]),
                "mean forward speed", "m/s", "{:.2f}", better="higher", trajectory=True))
# time to the goal (steps · control_dt), NaN when the goal was not reached
register(Metric("time", lambda log, dt: jnp.where(log.reason == GOAL, log.steps * dt, jnp.nan),
                "episode time", "s", "{:.1f}", better="lower", bounds=(0.0, math.inf),
                train=True))
# driven path length over the straight distance from start to end, NaN when the robot moved
# less than 1 cm
register(Metric("path_ratio", _path_ratio, "path length / straight length", "-", "{:.3f}",
                better="lower", bounds=(1.0, math.inf), trajectory=True))
# max |dev|
register(Metric("max_offset", _max_offset, "max lateral offset", "m", "{:.2f}", better="lower",
                bounds=(0.0, math.inf), trajectory=True, train=True))
# mean |heading − direction of the centre line| (the CHA above is the goal's bearing instead)
register(Metric("heading_error",
                lambda log, dt: _valid_mean(
                    log, jnp.abs(heading_error(jnp.nan_to_num(jnp.asarray(log.pose)), log.lane))),
                "mean absolute heading error to the lane's direction", "rad", "{:.3f}",
                better="lower", bounds=(0.0, math.pi), trajectory=True, train=True))


def summarise(log: Log, control_dt: float) -> dict[str, jax.Array]:
    """Every registered metric (`METRICS`; the built-in ones above) of a (batched) log: name →
    array shaped like `log.reason` ([B] for a batch: each Metric.fn sees one episode). Pure
    jnp. A trajectory metric (Metric.trajectory) is NaN for an `excluded` episode (no valid
    step, or ended flipped or in a simulation error), so that a cell's mean leaves it out."""
    global _traced
    _traced = True

    def one(log):
        drop = excluded(log)
        out = {}
        for m in METRICS.values():
            value = jnp.asarray(m.fn(log, control_dt))
            out[m.name] = jnp.where(drop, jnp.nan, value) if m.trajectory else value
        return out

    for _ in range(jnp.ndim(log.reason)):
        one = jax.vmap(one)
    return one(log)
