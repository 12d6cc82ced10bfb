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
