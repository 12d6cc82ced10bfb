"""MuJoCo's batch renderer (MJX, impl "warp") beside ours on one exported field: frames/s of
both on the same camera poses, and how well their plant masks agree.

The world is the one `python -m mjxrow.worlds --preset P` exports (episode 0 of seed 0,
`field.mjcf.to_mjcf`, without the robot, whose body our renderer does not draw), plus a mocap
body carrying a camera with the robot's field of view; every world shares the field and has its
own camera pose (`lane_poses`): in the lanes between active rows, at the robot's camera height
above the terrain and its pitch, along the rows, heading +x and −x. For each `--res` and
`--shadows`:

- MuJoCo Warp: `mjx.put_model(impl="warp")`, `mjx.make_data` per world, the poses in
  `mocap_pos`/`mocap_quat`, `mjx.forward` once; the timed call is jit(vmap(`refit_bvh` →
  `render_with_segmentation`)) over the B worlds (RGB, depth and geom ids of one camera; the
  sky box drawn, textures on). Shadows: the render context's `use_shadows` and the sun's
  `castshadow` (the export leaves it off), both on or both off.
- Ours: `bench.render.batched_render` on the same poses, the field shared by the B worlds
  (vmap `in_axes` None, so the plant table is built once per call), the nominal "sunny"
  conditions with the sun in the export's light direction, `RenderConfig.shadows` as above.
- Agreement (printed and recorded on both rows): the plant-mask IoU per pose (MuJoCo's geom ids
  → class by geom name, `geom_classes`), averaged over the poses where either image has a
  plant; the share of pixels whose class (sky, soil, plant, obstacle) agrees.

Compile time (first call) apart from the median of `--repeats` calls. The persistent compilation
cache is off for this stage: its programs hold Warp's FFI callbacks, registered anew by every
process. Needs warp-lang (mujoco-mjx 3.17 carries MuJoCo Warp itself as
`mujoco.mjx.third_party.mujoco_warp`); Warp runs on a CUDA GPU or, slowly, on the CPU.

GPU: `--batch 1024` (defaults: 64 and 128 px, shadows on and off); CPU: `--batch 2 --res 16
--repeats 1`.
"""

from __future__ import annotations

import argparse
import importlib
import math

import jax
import jax.numpy as jnp
import numpy as np

from mjxrow import crops, render, runtime
from mjxrow import field as mjxrow_field
from mjxrow.bench import render as bench_render
from mjxrow.bench.timing import time_call
from mjxrow.physics.quiet import mjx
from mjxrow.worlds import mjcf, replay
from mjxrow.worlds import scene as worlds_scene

NEEDS = ("warp", "mujoco.mjx.third_party.mujoco_warp")
MISSING = ("bench render_mjwarp: needs warp-lang (mujoco-mjx carries MuJoCo Warp): pip install "
           "warp-lang")
RIG, CAMERA = "lane_rig", "lane_eye"  # the mocap body and its camera added to the export
GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


def add_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--preset", default="zucchini", choices=crops.names())
    p.add_argument("--batch", type=int, default=1024, help="worlds (camera poses) per call")
    p.add_argument("--res", type=int, nargs="+", default=[64, 128],
                   help="square image sides [px]")
    p.add_argument("--shadows", nargs="+", choices=("on", "off"), default=["on", "off"],
                   help="sun shadows in both renderers")
    p.add_argument("--repeats", type=int, default=5)


def check_packages() -> None:
    """SystemExit with the one-line MISSING message unless warp and MJX's MuJoCo Warp import."""
    for name in NEEDS:
        try:
            module = importlib.import_module(name)
        except (ImportError, RuntimeError):
            raise SystemExit(MISSING) from None
        if name == "warp":  # no banner, no line per kernel module loaded
            module.config.log_level = getattr(module, "LOG_WARNING", 30)


def lane_poses(field: mjxrow_field.Field, cam_height: float, pitch_deg: float,
               b: int) -> tuple[np.ndarray, np.ndarray]:
    """B camera poses along the lanes of ONE field: pose i in lane i mod n (`scene.field_lanes`,
    by y) on its centre line, `cam_height` metres above the terrain, heading +x on even passes
    over the lanes and −x on odd ones, pitched by `pitch_deg` (negative looks down), at a
    golden-ratio sequence of positions between the rows' ends. Returns (cam_pos float32 [B, 3],
    cam_rot float32 [B, 3, 3]), MuJoCo's camera convention (columns right, up, backwards)."""

    f = worlds_scene.host(field)
    lanes = worlds_scene.field_lanes(f)
    i = np.arange(b)
    y = f.lane_y[lanes[i % len(lanes)]]
    x = f.row_x[0] + ((i * GOLDEN) % 1.0) * (f.row_x[1] - f.row_x[0])
    z = np.asarray(mjxrow_field.terrain_height(f.terrain, f.terrain_size, x, y)) + cam_height
    yaw = np.where((i // len(lanes)) % 2 == 0, 0.0, np.pi)
    rot = jax.vmap(render.camera_rot, in_axes=(0, None))(jnp.asarray(yaw),
                                                         jnp.float32(np.radians(pitch_deg)))
    return np.stack([x, y, z], 1).astype(np.float32), np.asarray(rot, np.float32)


def rot_quat(rot: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z) float64 [B, 4] of rotation matrices [B, 3, 3]."""
    import mujoco

    out = np.zeros((len(rot), 4))
    for q, r in zip(out, rot, strict=True):
        mujoco.mju_mat2Quat(q, np.asarray(r, np.float64).ravel())
    return out


def camera_model(xml: str, assets: dict, fovy: float, shadows: bool):
    """The exported world with a mocap body `RIG` carrying camera `CAMERA` (vertical field of
    view `fovy` [deg], looking along the body's −z) and every light's `castshadow` = `shadows`:
    a compiled mujoco.MjModel."""
    import mujoco

    spec = mujoco.MjSpec.from_string(xml, assets=assets)
    spec.worldbody.add_body(name=RIG, mocap=True).add_camera(name=CAMERA, fovy=fovy)
    for light in spec.lights:
        light.castshadow = shadows
    return spec.compile()


def geom_classes(m) -> np.ndarray:
    """uint8 [ngeom + 1]: our class (RD.SKY/SOIL/PLANT/OBSTACLE) of MuJoCo's segmentation id + 1
    (id −1, nothing hit, is sky), from the export's geom names (`field.mjcf`)."""
    import mujoco

    out = np.full(m.ngeom + 1, render.SKY, np.uint8)
    for g in range(m.ngeom):
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or ""
        out[g + 1] = (render.PLANT if name.startswith("plant_") else
                      render.OBSTACLE if name.startswith(("stone_", "branch_")) else
                      render.SOIL if name == "terrain" else render.SKY)
    return out


def warp_worlds(m, pos: np.ndarray, rot: np.ndarray):
    """(mjx.Model, mjx.Data [B]) of impl "warp": one data per pose, the rig at (pos, rot), the
    kinematics (camera and geom frames) computed."""

    mx = mjx.put_model(m, impl="warp")
    b = len(pos)
    d = jax.vmap(lambda _: mjx.make_data(m, impl="warp"))(jnp.arange(b))
    d = d.replace(mocap_pos=jnp.asarray(pos, jnp.float32)[:, None],
                  mocap_quat=jnp.asarray(rot_quat(rot), jnp.float32)[:, None])
    return mx, jax.jit(jax.vmap(mjx.forward, in_axes=(None, 0)))(mx, d)


def warp_render(m, b: int, res: int, shadows: bool):
    """(render context, jitted fn(mx, d) -> (rgb, depth, seg)) of camera `CAMERA` at res × res
    over B worlds: refit of the scene BVH, then `render_with_segmentation`."""

    rc = mjx.create_render_context(m, nworld=b, cam_res=(res, res), cam_active=[CAMERA],
                                   render_rgb=True, render_depth=True, render_seg=True,
                                   use_shadows=shadows, render_skybox=True)
    handle = rc.pytree()

    def one(mx, d):
        d = mjx.refit_bvh(mx, d, handle)
        rgb, depth, seg, _ = mjx.render_with_segmentation(mx, d, handle)
        return rgb, depth, seg

    return rc, jax.jit(jax.vmap(one, in_axes=(None, 0)))


def warp_classes(rc, seg: jax.Array, table: np.ndarray) -> np.ndarray:
    """uint8 [B, H, W] classes of the packed segmentation `seg` ([B, pixels, 2]) of the
    context's first camera."""

    ids = np.asarray(mjx.get_segmentation(rc.pytree(), 0, seg))
    return table[np.clip(ids, -1, len(table) - 2) + 1]


def agreement(ours: np.ndarray, theirs: np.ndarray) -> dict[str, float]:
    """Class images [B, H, W] of two renderers: mean plant IoU over the poses where either has a
    plant pixel (nan if none), share of pixels of the same class, share of non-sky pixels of
    each."""
    a, t = ours == render.PLANT, theirs == render.PLANT
    inter = np.sum(a & t, axis=(1, 2))
    union = np.sum(a | t, axis=(1, 2))
    seen = union > 0
    iou = float(np.mean(inter[seen] / union[seen])) if seen.any() else float("nan")
    return {"plant_iou": iou, "class_agree": float(np.mean(ours == theirs)),
            "non_sky_ours": float(np.mean(ours != render.SKY)),
            "non_sky_mjwarp": float(np.mean(theirs != render.SKY))}


def exported(preset: str):
    """(episode, MJCF text, assets) of `preset`'s world as `python -m mjxrow.worlds` exports
    it, without the robot."""

    run, shape = replay.resolve_run(preset)
    ep = replay.episode_world(run, shape, 0)
    xml, assets = mjcf.to_mjcf(ep.field, shape, preset)
    return ep, xml, assets


def run(args: argparse.Namespace) -> list[dict]:
    check_packages()
    import warp as wp

    runtime.disable_cache()
    if args.batch < 1 or min(args.res) < 1 or args.repeats < 1:
        raise SystemExit("bench render_mjwarp: --batch, --res and --repeats must be positive")
    b = args.batch
    ep, xml, assets = exported(args.preset)
    robot = ep.robot.robot
    pos, rot = lane_poses(ep.field, robot.cam_height, robot.cam_pitch_deg, b)
    sun = -np.array(mjcf.SUN_DIR) / np.linalg.norm(mjcf.SUN_DIR)  # towards the export's sun
    cond = render.conditions("sunny").replace(sun_dir=jnp.asarray(sun, jnp.float32))
    conds = jax.tree.map(lambda x: jnp.broadcast_to(x, (b, *x.shape)), cond)
    field = jax.tree.map(jnp.asarray, ep.field)
    print(f"render_mjwarp: {args.preset}, {int(ep.field.plant_active.sum())} plants, B={b} "
          f"camera poses in {len(set(pos[:, 1].round(3)))} lanes; Warp device "
          f"{wp.get_device()}", flush=True)
    rows = []
    for shadows in (s == "on" for s in args.shadows):
        m = camera_model(xml, assets, robot.cam_fovy, shadows)
        table = geom_classes(m)
        mx, d = warp_worlds(m, pos, rot)
        for res in args.res:
            rc, fn = warp_render(m, b, res, shadows)
            t_w = time_call(fn, mx, d, repeats=args.repeats)
            theirs = warp_classes(rc, fn(mx, d)[2], table)
            del rc

            intr = render.Intrinsics(res, res, robot.cam_fovy)
            cfg = render.RenderConfig(shadows=shadows)
            chunk = bench_render.auto_chunk(res, b)
            ours_fn = bench_render.batched_render(ep.shape, intr, cfg, b, chunk, shared_field=True)
            inputs = (field, jnp.asarray(pos), jnp.asarray(rot), conds)
            t_o = time_call(ours_fn, *inputs, repeats=args.repeats)
            ours = np.asarray(ours_fn(*inputs).classes)
            agree = agreement(ours, theirs)

            used = render.resolve(cfg, ep.shape.crop, intr)
            base = (f"{args.preset} {res}x{res}, fovy {robot.cam_fovy:g}, "
                    f"{'shadows' if shadows else 'no shadows'}, one field, lane poses")
            configs = {
                "mjwarp": f"{base}, MuJoCo Warp refit_bvh + render_with_segmentation "
                          f"({m.ngeom} geoms, sky box)",
                "ours": f"{base}, mjxrow.render (tile {used.tile}, {used.kernel} kernels, "
                        f"chunk {chunk})"}
            for who, t in (("mjwarp", t_w), ("ours", t_o)):
                rows.append({"stage": "render_mjwarp", "config": configs[who], "batch": b,
                             "value": b / t["median_s"], "unit": "frames/s", "renderer": who,
                             "compile_s": t["compile_s"], "runs_s": t["runs_s"], **agree})
                print(f"{who:6s} {configs[who]}, B={b}: compile {t['compile_s']:.1f} s, run "
                      f"median {t['median_s'] * 1e3:.1f} ms -> {b / t['median_s']:,.0f} "
                      "frames/s", flush=True)
            print(f"agreement {res}x{res}: plant IoU {agree['plant_iou']:.3f}, same class "
                  f"{agree['class_agree']:.3f}, non-sky {agree['non_sky_ours']:.3f} (ours) / "
                  f"{agree['non_sky_mjwarp']:.3f} (MuJoCo Warp)", flush=True)
    return rows
