"""experiments/sun_frames.py: the first frames of a sun sweep, with and without cast shadows."""

import re
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "experiments"))
import sun_frames  # noqa: E402

TINY = ["camera.width=16", "camera.height=16", "sim.path_length=2"]


def test_the_cast_shadows_darken_the_frame_and_the_figure_is_drawn(tmp_path, capsys):
    """At 80° the trees' shadows lie across pear's lane: the frame with cast shadows is darker
    than the same frame without them (the same field and pose). The figure is written; a
    foreign --out and bad input exit 2 and change nothing."""
    config = str(ROOT / "sweeps" / "sun.yaml")
    _, (lit,) = sun_frames.frames(config, [80.0], 0, TINY, False)
    _, (shaded,) = sun_frames.frames(config, [80.0], 0, TINY, True)
    assert lit.shape == shaded.shape == (16, 16, 3) and lit.dtype == np.uint8
    assert shaded.astype(float).mean() < lit.astype(float).mean() - 5.0
    # the shadows change the frame's chromaticity (env.observation=chroma) less than its RGB
    rgb, chroma = (sun_frames.shadow_change(shaded, lit, k) for k in ("rgb", "chroma"))
    assert 0.0 < chroma < 0.7 * rgb, (rgb, chroma)
    assert sun_frames.shadow_change(lit, lit) == 0.0
    sets = [a for s in TINY for a in ("--set", s)]
    png = tmp_path / "frames.png"
    assert sun_frames.main(["--azimuths", "80", *sets, "--out", str(png)]) == 0
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert re.search(r"^ +80\.0°  \d\.\d{3}  \d\.\d{3}$", capsys.readouterr().out, re.M)
    assert sun_frames.main(["--episode", "-1", "--out", str(png)]) == 2  # checked first
    foreign = tmp_path / "mine.png"
    foreign.write_bytes(b"not ours")
    assert sun_frames.main(["--azimuths", "80", *sets, "--out", str(foreign)]) == 2
    assert foreign.read_bytes() == b"not ours"
    assert sun_frames.main(["--episode", "-1", "--out", str(tmp_path / "x.png")]) == 2
    assert sun_frames.main(["--set", "field.bogus=1", "--out", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and "--episode" in err and "field.bogus" in err
    assert not (tmp_path / "x.png").exists()


def test_the_policy_steers_back_to_the_lane_and_its_centre_is_measured(tmp_path, capsys):
    """--checkpoint: the starts' lateral offsets are the ones the reset draws (std as set,
    heading along the straight lane; none at std 0); the fitted plane recovers a known one;
    the oracle steers back as pure pursuit does; the shipped policy turns back toward the
    lane's centre line from an offset and from a heading (every slope negative), with and
    without the shadows. Bad --checkpoint / --episodes / --offset-std / --yaw-std exit 2 and
    write nothing."""
    x, h = np.array([-1.0, 0.3, 2.0, 0.5]), np.array([0.1, -0.2, 0.0, 0.3])
    assert np.allclose(sun_frames.centre(0.2 - 0.5 * x - 2.0 * h, x, h), (-0.5, -2.0, 0.4))
    # the oracle (pure pursuit, lookahead 1 m, v_max 0.5, ω_max 1) steers back: ω ≈ -v·2e/L²
    e = np.array([-0.2, -0.1, 0.1, 0.2])
    assert np.allclose(sun_frames.teacher_turns(e, np.zeros(4), (0.5, 1.0)), -e, atol=0.01)
    config = str(ROOT / "sweeps" / "sun.yaml")
    sets = [*TINY, "episode.start_yaw_std=0"]  # heading along the lane
    eps = list(range(12))
    _, rgb, mask, pose = sun_frames.episode_frames(
        config, [80.0], eps, [*sets, "episode.start_offset_std=0.5"], True)
    assert rgb.shape == (1, 12, 16, 16, 3) and mask.shape == (1, 12, 16, 16)
    assert pose.shape == (1, 12, 2) and 0.2 < pose[0, :, 0].std() < 1.0
    assert np.abs(pose[0, :, 1]).max() < 1e-3
    _, _, _, still = sun_frames.episode_frames(
        config, [80.0], eps[:3], [*sets, "episode.start_offset_std=0"], True)
    assert np.abs(still).max() < 1e-4
    png = tmp_path / "frames.png"
    assert sun_frames.main(["--azimuths", "80", "--episodes", "12", "--checkpoint", "shipped",
                            "--set", "sim.path_length=2", "--out", str(png)]) == 0
    num = r"([-+]\d\.\d{3})"
    line = re.search(rf"^ +80\.0°  {num} \| {num}  {num} \| {num}  [-+]\d\.\d{{2}} \| "
                     r"[-+]\d\.\d{2}$", out := capsys.readouterr().out, re.M)
    assert line and all(float(v) < 0 for v in line.groups()), out
    oracle = re.search(r"teacher\) on the same starts: ([-+]\d\.\d{3}) per m", out)
    assert oracle and -1.1 < float(oracle[1]) < -0.7, out
    for bad in (["--episodes", "1"], ["--checkpoint", str(tmp_path / "none")],
                ["--offset-std", "0"], ["--yaw-std", "-1"]):
        ck = [] if "--checkpoint" in bad else ["--checkpoint", "shipped"]
        assert sun_frames.main([*bad, *ck, "--out", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert all(k in err for k in ("--episodes", "--checkpoint", "--offset-std", "--yaw-std"))
    assert not (tmp_path / "x.png").exists()
