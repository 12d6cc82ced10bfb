"""experiments/plot_one_command.py: the figure from the measured commands' CSVs (the repository's
own), the Wilson interval it draws, and bad input or an --out it did not write as one line with
exit 2, the file left as it was."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))
import plot_one_command as P  # noqa: E402


def test_the_figure_of_the_repositorys_commands_and_rewriting_its_own_png(tmp_path, capsys):
    png = tmp_path / "pear.png"
    assert P.main(["--out", str(png)]) == 0
    assert png.stat().st_size > 10_000 and P.written_by(png)
    assert P.main(["--out", str(png)]) == 0  # its own PNG is replaced
    lo, hi = P.interval(0.88, 100)
    assert lo == pytest.approx(0.8018, abs=1e-3) and hi == pytest.approx(0.9306, abs=1e-3)


def test_bad_input_and_foreign_out_are_exit_2_and_untouched(tmp_path, capsys):
    mine = tmp_path / "notes.png"
    mine.write_bytes(b"not a figure of this script")
    assert P.main(["--out", str(mine)]) == 2
    assert mine.read_bytes() == b"not a figure of this script"
    assert "--out:" in capsys.readouterr().err
    bad = tmp_path / "runs.csv"
    bad.write_text("recipe,seed,weights\nx,0,last\n")
    assert P.main(["--runs", str(bad), "--out", str(tmp_path / "a.png")]) == 2
    assert "--runs: missing column 'pear'" in capsys.readouterr().err
    assert P.main(["--rollouts", str(tmp_path / "none.csv"), "--out", str(tmp_path / "a.png")]) == 2
    assert "--rollouts: cannot read" in capsys.readouterr().err
    assert not (tmp_path / "a.png").exists()
