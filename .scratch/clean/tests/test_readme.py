"""The README's Python example runs as written (read from README.md itself), and names only the
public API of `mjxrow`."""

import re
from pathlib import Path

import mjxrow

README = Path(__file__).resolve().parents[1] / "README.md"


def _example() -> str:
    text = README.read_text()
    section = text[text.index("\n## Python\n"):]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_the_readme_example_runs(capsys):
    code = _example()
    assert 10 <= len(code.strip().splitlines()) <= 15
    for name in re.findall(r"mjxrow\.(\w+)", code):
        assert name in mjxrow.__all__, name
    exec(compile(code, str(README), "exec"), {})
    out = capsys.readouterr().out
    assert "reasons: goal 4" in out and "success" in out  # the oracle reaches every goal


def test_the_api_names_resolve():
    for name in mjxrow.__all__:
        assert getattr(mjxrow, name) is not None, name
