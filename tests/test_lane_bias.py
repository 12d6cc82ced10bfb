"""experiments/lane_bias.py: where a controller drives across the lane, in closed loop."""

import re
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "experiments"))
import lane_bias  # noqa: E402

TINY = ["camera.width=16", "camera.height=16", "sim.path_length=3"]


def test_the_oracle_drives_on_the_line_and_an_offset_start_is_seen(capsys):
    """The oracle (pure pursuit on the lane's line) drives and ends its episodes on the line;
    the same episodes moved 0.25 m to the left read 0.25 m more (the sign: + left), in every part
    of the path too. Bad input exits 2, naming the key or value."""
    sets = [a for s in TINY for a in ("--set", s)]
    assert lane_bias.main(["--controller", "oracle", "--azimuths", "80", "--episodes", "3",
                           *sets, "--set", "episode.start_offset_std=0"]) == 0
    out = capsys.readouterr().out
    line = re.search(r"^ +80\.0°  ([-+]\d\.\d\d) \(([-+]\d\.\d\d) \.\. ([-+]\d\.\d\d)\)  "
                     r"([-+]\d\.\d\d)  (\d\.\d\d)  (.*)$", out, re.M)
    assert line, out
    mid, lo, hi, end = (float(line[i]) for i in (1, 2, 3, 4))
    assert abs(mid) <= 0.02 and lo <= mid <= hi and abs(end) <= 0.05, out
    assert line[6].startswith("goal") and float(line[5]) > 0, out
    parts = re.search(r"in 5 parts of 0\.6 m.*\n +80\.0°  (.*)$", out, re.M)
    assert parts and all(abs(float(v)) <= 0.05 for v in parts[1].split()), out
    # the same episodes moved 0.25 m to +y (left of the straight rows' line): every offset
    # grows by 0.25, and the ends are kept
    args = lane_bias.parser().parse_args(["--controller", "oracle", "--azimuths", "80", *sets])
    from mjxrow.rollout import build as rollout_build

    cells = lane_bias.runs(args)
    built = rollout_build.build(cells)
    log = built.rollout(built.batch([(cells[0], e) for e in range(2)]))
    moved = log.replace(pose=log.pose.at[..., 1].add(0.25))
    shift = lane_bias.along(moved, 2, 3.0, 4) - lane_bias.along(log, 2, 3.0, 4)
    assert np.allclose(shift, 0.25, atol=1e-4)  # every part reached, each 0.25 m further left
    for a, b in zip(lane_bias.offsets(log, 2), lane_bias.offsets(moved, 2), strict=True):
        assert abs(b[0] - a[0] - 0.25) < 1e-4 and abs(b[1] - a[1] - 0.25) < 1e-4
        assert a[2] == b[2] == 1  # goal
    for bad, key in ((["--episodes", "0"], "--episodes"), (["--config", "none.yaml"], "--config"),
                     (["--set", "field.bogus=1"], "field.bogus"),
                     (["--controller", "nobody"], "nobody")):
        assert lane_bias.main(bad) == 2
        assert key in capsys.readouterr().err
