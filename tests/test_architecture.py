"""The layer contract in pyproject.toml holds: data flows one way through the stages."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_no_stage_imports_a_later_one():
    lint_imports = Path(sys.executable).with_name("lint-imports")
    result = subprocess.run([str(lint_imports), "--no-cache"], cwd=ROOT, capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-2000:]
    assert "0 broken" in result.stdout


def test_a_backward_import_breaks_the_layers(tmp_path):
    # the contract can fail: a render module importing the pipeline's configuration is refused
    for name in ("synthpack", "training"):
        shutil.copytree(ROOT / name, tmp_path / name, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    module = tmp_path / "synthpack" / "render" / "partial_volume.py"
    text = module.read_text()
    module.write_text(text.replace("from __future__ import annotations\n",
                                   "from __future__ import annotations\nfrom ..pipeline import config\n", 1))
    lint_imports = Path(sys.executable).with_name("lint-imports")
    result = subprocess.run([str(lint_imports), "--no-cache"], cwd=tmp_path, capture_output=True, text=True,
                            timeout=120, env={**os.environ, "PYTHONPATH": str(tmp_path)})
    assert result.returncode != 0
    assert "synthpack.render.partial_volume -> synthpack.pipeline.config" in result.stdout


def test_the_package_is_a_few_stage_packages_of_small_modules():
    top = sorted(path.name for path in (ROOT / "synthpack").glob("*.py"))
    assert len(top) <= 12, top
    lines = {str(path.relative_to(ROOT)): len(path.read_text().splitlines())
             for path in (ROOT / "synthpack").rglob("*.py")}
    assert not {name: n for name, n in lines.items() if n > 700}
