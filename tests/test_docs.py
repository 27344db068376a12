"""The README's Python example runs as written."""

from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


@pytest.mark.skipif(not README.exists(), reason="needs the source tree")
def test_readme_python_example(tmp_path, monkeypatch):
    code = README.read_text().split("```python", 1)[1].split("```", 1)[0]
    monkeypatch.chdir(tmp_path)
    ns = {}
    exec(compile(code, "README.md", "exec"), ns)
    assert (tmp_path / "cbox.exr").exists()
    res = ns["res"]
    assert res.image.shape == (256, 256, 3) and res.stats.nonfinite == 0 and res.image.mean() > 0.05
