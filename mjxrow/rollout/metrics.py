"""Navigation metrics of logged episodes (the paper's Table 3 and more), plant collisions, and
aggregation over episodes.

Every per-step array has the step axis last-but-features: `pose` is [..., T, 3]; any leading
batch axes are carried through, so the same functions serve one episode or a batch of them
(no vmap needed). Steps after an episode ends are masked by `Log.alive`.

Conventions: metres, radians, rows along +x, the lane centre line is the line y = lane_y. The
robot frame has x forward and y to the left; a goal to the left has a positive bearing.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from mjxrow.crops import prims as crops_prims
from mjxrow.field import Field

# Termination reasons; code 0 marks a step at which the episode is still running. `off_patch`:
# the robot left the simulated terrain (strayed far from its lane, or drove off its back or
# front end); `missed_goal`: it drove past the row's end (the goal's x plus the goal radius)
# beside the goal, without reaching it.
REASONS = ("running", "goal", "collision", "timeout", "flipped", "stuck", "sim_error",
           "off_patch", "missed_goal")
(RUNNING, GOAL, COLLISION, TIMEOUT, FLIPPED, STUCK, SIM_ERROR, OFF_PATCH,
 MISSED_GOAL) = range(len(REASONS))

METRICS = ("success", "collision", "reason", "excluded", "cha", "mae", "mse", "omega_std",
           "v_mean", "time", "path_ratio", "max_offset")
BINARY = ("success", "collision", "excluded")
# Metrics of the driven trajectory: NaN for an excluded episode (one with no valid step, or one
# that ended flipped or in a simulation error), so that it is left out of a cell's mean and
# counted in `n`, never averaged in as a number.
TRAJECTORY = ("cha", "mae", "mse", "omega_std", "v_mean", "path_ratio", "max_offset")
EXCLUDED_REASONS = (FLIPPED, SIM_ERROR)
# The range a metric can take: confidence intervals are clipped to it.
RANGES: dict[str, tuple[float, float]] = {
    "success": (0.0, 1.0), "collision": (0.0, 1.0), "excluded": (0.0, 1.0),
    "cha": (-math.pi, math.pi), "mae": (0.0, math.inf), "mse": (0.0, math.inf),
    "omega_std": (0.0, math.inf), "time": (0.0, math.inf), "path_ratio": (1.0, math.inf),
    "max_offset": (0.0, math.inf)}


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
    lane_y: jax.Array  # float32 [], lateral position of the lane centre line [m]
    reason: jax.Array  # int32 [], REASONS code of the episode's end
    steps: jax.Array  # int32 [], number of control steps that ran
    vel: jax.Array | None = None  # float32 [T, 2], measured (forward speed, yaw rate) per step


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

    centre: [2] rectangle centre [m]; yaw: [] its orientation [rad]; half: [2] half length
    (along its own x) and half width [m]; e_centre: [..., 2] ellipse centres [m]; e_axes:
    [..., 2] ellipse semi-axes along world x and y [m] (> 0). Returns bool [...].

    The map that turns each ellipse into the unit circle is affine, so the rectangle becomes a
    parallelogram and the shapes overlap iff the origin lies inside the parallelogram or
    within distance 1 of one of its edges."""
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    sx = jnp.array([1.0, -1.0, -1.0, 1.0]) * half[0]
    sy = jnp.array([1.0, 1.0, -1.0, -1.0]) * half[1]
    corners = centre + jnp.stack([c * sx - s * sy, s * sx + c * sy], -1)  # [4, 2], CCW
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
    rows) and, in each, the 2·window + 1 plants nearest along x (plant index from x via d_pp).

    One field (no batch axis). Returns xy [4, 2w+1, 2] [m], the row/plant indices
    ([4, 2w+1] each) into the field's [R, P] arrays, as a tuple (xy, rows, cols)."""
    R, P = field.plant_active.shape
    row_y = jnp.where(field.row_active, field.row_y, jnp.inf)
    j = jnp.searchsorted(row_y, xy[1])
    rows = jnp.clip(j + jnp.arange(-2, 2), 0, R - 1)
    d_pp = field.params.d_pp * field.params.scale
    i = jnp.round((xy[0] - field.row_x[0]) / d_pp).astype(jnp.int32)
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
    hit = rect_ellipse_overlap(pose[:2], pose[2], jnp.asarray(half, jnp.float32), pxy,
                               jnp.maximum(axes, 1e-4))
    return jnp.any(hit & field.plant_active[rows, cols])


# ---------------------------------------------------------------------------------------------
# Per-episode metrics


def lateral_offset(pose: jax.Array, lane_y: jax.Array) -> jax.Array:
    """Signed lateral offset [m] from the lane centre line (positive: left of it, +y).
    pose: [..., T, 3]; lane_y: [...]. Returns [..., T]."""
    return pose[..., 1] - lane_y[..., None]


def _masked_mean(x, m):
    n = jnp.sum(m, -1)
    return jnp.sum(jnp.where(m, x, 0.0), -1) / jnp.maximum(n, 1), n


def summarise(log: Log, control_dt: float) -> dict[str, jax.Array]:
    """Per-episode metrics of a (batched) log. Pure jnp; returns arrays shaped like
    `log.reason` ([B] for a batch):

    - success (bool): the episode ended at the goal; collision (bool): it ended touching a plant;
    - reason (int32): REASONS code of its end;
    - cha [rad]: mean over steps of the goal's signed bearing atan2(y_g, x_g) in the robot frame;
    - mae [m], mse [m²]: mean |dev| and mean dev² of the lateral offset from the lane centre line;
    - max_offset [m]: max |dev|;
    - omega_std [rad/s]: population std of the ω commands; v_mean [m/s]: mean commanded v;
    - time [s]: time to the goal (steps · control_dt), NaN when the goal was not reached;
    - path_ratio [-]: driven path length over the straight distance from start to end, NaN when
      the robot moved less than 1 cm.

    - excluded (bool): the episode has no valid step, or ended flipped or in a simulation
      error; its trajectory metrics (TRAJECTORY) are NaN, so a cell's mean leaves it out.

    Valid steps are those that ran with a finite pose, except the step of a sim_error (its
    pose, finite or not, is the exploded state)."""
    pose = jnp.asarray(log.pose)
    ok = log.alive & jnp.all(jnp.isfinite(pose), -1) & (jnp.asarray(log.event) != SIM_ERROR)
    dev = lateral_offset(pose, jnp.asarray(log.lane_y))
    mae, n = _masked_mean(jnp.abs(dev), ok)
    mse, _ = _masked_mean(dev * dev, ok)
    max_offset = jnp.max(jnp.where(ok, jnp.abs(dev), 0.0), -1)
    cha, _ = _masked_mean(goal_bearing(pose, log.goal[..., None, :]), ok)
    v_mean, _ = _masked_mean(log.cmd[..., 0], ok)
    w = log.cmd[..., 1]
    w_mean, _ = _masked_mean(w, ok)
    w_var, _ = _masked_mean((w - w_mean[..., None]) ** 2, ok)

    xy = jnp.where(ok[..., None], pose[..., :2], jnp.nan)
    prev = jnp.concatenate([log.start[..., None, :2], xy[..., :-1, :]], -2)
    # a masked step contributes nothing; the first step after the start counts from the start
    seg = jnp.where(ok & jnp.all(jnp.isfinite(prev), -1),
                    jnp.linalg.norm(jnp.nan_to_num(xy - prev), axis=-1), 0.0)
    length = jnp.sum(seg, -1)
    last = jnp.maximum(jnp.sum(ok, -1) - 1, 0)
    end = jnp.take_along_axis(jnp.nan_to_num(xy), last[..., None, None], -2)[..., 0, :]
    end = jnp.where((n > 0)[..., None], end, log.start[..., :2])
    disp = jnp.linalg.norm(end - log.start[..., :2], axis=-1)
    success = log.reason == GOAL
    excluded = (n == 0) | jnp.isin(log.reason, jnp.asarray(EXCLUDED_REASONS))
    trajectory = dict(
        cha=cha,
        mae=mae,
        mse=mse,
        omega_std=jnp.sqrt(w_var),
        v_mean=v_mean,
        path_ratio=jnp.where(disp > 0.01, length / jnp.maximum(disp, 1e-9), jnp.nan),
        max_offset=max_offset,
    )
    trajectory = {k: jnp.where(excluded, jnp.nan, v) for k, v in trajectory.items()}
    return dict(
        success=success,
        collision=log.reason == COLLISION,
        reason=log.reason,
        excluded=excluded,
        time=jnp.where(success, log.steps * control_dt, jnp.nan),
        **trajectory,
    )


# ---------------------------------------------------------------------------------------------
# Aggregation (host)


def _t_quantile(p: float, dof: int) -> float:
    from scipy.stats import t as student_t  # scipy ships with jax

    return float(student_t.ppf(p, dof))


def aggregate(table: dict[str, Any], confidence: float = 0.95) -> dict[str, dict[str, float]]:
    """Mean and confidence interval of every numeric metric over episodes (host, numpy).

    table: name → [B] values (as `summarise` returns). Non-finite values (e.g. `time` of failed
    episodes) are left out and `n` says how many values were used. Continuous metrics get a
    Student-t interval, mean ± t_{(1+c)/2, n−1} · s / √n (s with ddof = 1); binary ones
    (`success`, `collision`, any bool array) a Wilson score interval for the proportion.
    `reason` is not averaged: see `reason_counts`.

    Intervals are clipped to the metric's range (RANGES: an MSE interval never goes below 0).
    Returns name → {mean, lo, hi, n, method}; with n < 2 a t interval is (nan, nan)."""
    if not 0 < confidence < 1:
        raise ValueError(f"confidence: must lie in (0, 1), got {confidence}")
    out: dict[str, dict[str, float]] = {}
    for name, values in table.items():
        if name == "reason":
            continue
        x = np.asarray(values)
        if x.dtype.kind not in "biuf":
            continue
        binary = x.dtype == bool or name in BINARY
        x = x.astype(np.float64).reshape(-1)
        x = x[np.isfinite(x)]
        n = int(x.size)
        if n == 0:
            out[name] = dict(mean=math.nan, lo=math.nan, hi=math.nan, n=0,
                             method="wilson" if binary else "t")
            continue
        mean = float(x.mean())
        if binary:
            z = _normal_quantile(0.5 + confidence / 2)
            centre = (mean + z * z / (2 * n)) / (1 + z * z / n)
            half = z / (1 + z * z / n) * math.sqrt(mean * (1 - mean) / n + z * z / (4 * n * n))
            lo, hi, method = max(centre - half, 0.0), min(centre + half, 1.0), "wilson"
        elif n < 2:
            lo, hi, method = math.nan, math.nan, "t"
        else:
            half = _t_quantile(0.5 + confidence / 2, n - 1) * float(x.std(ddof=1)) / math.sqrt(n)
            lo, hi, method = mean - half, mean + half, "t"
        r_lo, r_hi = RANGES.get(name, (-math.inf, math.inf))
        lo, hi = min(max(lo, r_lo), r_hi), max(min(hi, r_hi), r_lo)
        out[name] = dict(mean=mean, lo=float(lo), hi=float(hi), n=n, method=method)
    return out


def _normal_quantile(p: float) -> float:
    from statistics import NormalDist

    return NormalDist().inv_cdf(p)


def reason_counts(reason: Any) -> dict[str, int]:
    """Episodes per termination reason: REASONS name → count (host). reason: int codes [B]."""
    r = np.asarray(reason).reshape(-1)
    return {name: int(np.sum(r == code)) for code, name in enumerate(REASONS) if code != RUNNING}


def format_table(table: dict[str, Any], confidence: float = 0.95) -> str:
    """`aggregate` as a text table (CHA also in degrees) with the episodes per reason."""
    lines = [f"{'metric':<12} {'mean':>10}  {f'{confidence:.0%} CI':>24}  {'n':>4}  method",
             "-" * 64]

    def row(name, a, f=1.0):
        lines.append(f"{name:<12} {a['mean'] * f:>10.4g}  [{a['lo'] * f:>10.4g}, "
                     f"{a['hi'] * f:>10.4g}]  {a['n']:>4}  {a['method']}")

    for name, a in aggregate(table, confidence).items():
        row(name, a)
        if name == "cha":
            row("cha [deg]", a, 180.0 / math.pi)
    if "reason" in table:
        counts = reason_counts(table["reason"])
        lines.append("reasons: " + ", ".join(f"{k} {v}" for k, v in counts.items() if v))
    return "\n".join(lines)
