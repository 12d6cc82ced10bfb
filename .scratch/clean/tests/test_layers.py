"""The package's layers hold by a tool: `lint-imports` keeps the contract of pyproject.toml
(no module imports from a layer above its own), and it does fail on an upward import."""

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _lint(root: Path) -> subprocess.CompletedProcess:
    code = "from importlinter.cli import lint_imports_command; lint_imports_command()"
    return subprocess.run([sys.executable, "-c", code, "--config", str(root / "pyproject.toml"),
                           "--no-cache"], cwd=root, capture_output=True, text=True,
                          env={"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin"})


def test_the_layers_contract_is_kept():
    r = _lint(ROOT)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "1 kept, 0 broken" in r.stdout


def test_an_upward_import_breaks_it(tmp_path):
    shutil.copytree(ROOT / "mjxrow", tmp_path / "mjxrow",
                    ignore=shutil.ignore_patterns("checkpoints", "__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    params = tmp_path / "mjxrow" / "field" / "params.py"
    params.write_text(params.read_text() + "\nfrom mjxrow.sweep import config  # noqa\n")
    r = _lint(tmp_path)
    assert r.returncode != 0
    assert "mjxrow.field.params -> mjxrow.sweep.config" in r.stdout
