"""experiments/plot_sun.py: sun sweeps' cells copied under a label, the figure drawn from them."""

import csv
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "experiments" / "plot_sun.py"


def _run(*args):
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, args)], capture_output=True,
                          text=True, cwd=ROOT)


def _summary(path: Path, success: list[float]) -> Path:
    cols = ["cell", "perception.sun_azimuth", "n", "success", "success_lo", "success_hi", "cha",
            "cha_lo", "cha_hi", "mae"]
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for i, s in enumerate(success):
            w.writerow([i, 35.0 + 45 * i, 10, s, s - 0.1, min(1.0, s + 0.1), 0.01 * i, -0.1, 0.1,
                        0.05])
    return path


def test_a_label_is_added_replaced_and_drawn_and_nothing_foreign_is_overwritten(tmp_path):
    data, png = tmp_path / "sun.csv", tmp_path / "sun.png"
    a = _summary(tmp_path / "a.csv", [1.0, 0.9])
    b = _summary(tmp_path / "b.csv", [0.5, 0.6, 0.7])
    r = _run("--add", f"policy={a}", f"segzeros={b}", "--device", "GPU", "--data", data,
             "--out", png)
    assert r.returncode == 0, r.stderr
    rows = list(csv.DictReader(open(data)))
    assert [(x["label"], x["azimuth"], x["success"]) for x in rows] == [
        ("policy", "35.0", "1.0"), ("policy", "80.0", "0.9"), ("segzeros", "35.0", "0.5"),
        ("segzeros", "80.0", "0.6"), ("segzeros", "125.0", "0.7")]
    assert png.read_bytes()[:4] == b"\x89PNG"
    r = _run("--add", f"policy={b}", "--data", data, "--out", png)  # its own PNG: redrawn
    assert r.returncode == 0, r.stderr
    rows = list(csv.DictReader(open(data)))
    assert sum(x["label"] == "policy" for x in rows) == 3  # the label's rows replaced
    foreign = tmp_path / "mine.png"
    foreign.write_bytes(b"not ours")
    r = _run("--data", data, "--out", foreign)
    assert r.returncode == 2 and "--out" in r.stderr and foreign.read_bytes() == b"not ours"
    r = _run("--add", f"x={tmp_path / 'data_missing.csv'}", "--data", data, "--out", png)
    assert r.returncode == 2 and "--add x" in r.stderr
    bad = tmp_path / "bad.csv"
    bad.write_text("cell,n\n0,1\n")
    before = data.read_text()
    r = _run("--add", f"x={bad}", "--data", data, "--out", png)
    assert r.returncode == 2 and "perception.sun_azimuth" in r.stderr
    assert data.read_text() == before  # nothing written on bad input
