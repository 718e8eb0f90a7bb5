"""The code blocks the README and the reference site mark runnable run as written.

A block is marked by an HTML comment on the line before its fence:

- ``<!-- runnable -->`` before a ```` ```bash ```` block: run with bash (``set -euo pipefail``);
  ``synthpack`` is the venv's console script, or ``python -m synthpack`` where it is missing;
- ``<!-- runnable -->`` before a ```` ```python ```` block: written to a script and run with
  this interpreter (so a block's ``if __name__ == "__main__":`` guard works as in a user's script);
- ``<!-- runnable: NAME -->`` before any block: its text is written to the file NAME (a config
  file a later block reads).

Every block runs in one folder, in order: the README's first (its walkthrough makes ``scan.tif``,
``labels.tif``, ``lib``, ...), then the site's pages in the order of mkdocs.yml's nav, so a page's
block may use what the README's made. The worktree's synthpack and ``training`` are imported
(``PYTHONPATH``). The blocks themselves are kept small (a cropped sample scan, 40 grains, one
epoch): together they take about a minute on one core.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
MARKER = re.compile(r"^<!-- runnable(?::\s*(?P<file>\S+))?\s*-->\s*$")
FENCE = re.compile(r"^```(?P<lang>\w*)\s*$")


@dataclass(frozen=True)
class Block:
    source: str          # path relative to the repository root
    line: int            # 1-based line of the fence
    lang: str
    code: str
    file: str | None     # write the block to this file instead of running it

    def __str__(self) -> str:
        return f"{self.source}:{self.line}"


def _nav_pages(nav) -> list[str]:
    pages = []
    for entry in nav:
        value = next(iter(entry.values())) if isinstance(entry, dict) else entry
        pages += _nav_pages(value) if isinstance(value, list) else [value]
    return pages


def documents() -> list[Path]:
    """The README, then every page of the site in nav order."""
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text())
    docs = ROOT / config.get("docs_dir", "docs")
    return [ROOT / "README.md"] + [docs / page for page in _nav_pages(config["nav"])]


def _name(path: Path) -> str:
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def blocks_of(path: Path) -> list[Block]:
    lines = path.read_text().splitlines()
    name = _name(path)
    found = []
    for i, line in enumerate(lines):
        marker = MARKER.match(line)
        if not marker:
            continue
        fence = FENCE.match(lines[i + 1]) if i + 1 < len(lines) else None
        if fence is None:
            raise AssertionError(f"{name}:{i + 1}: a runnable marker must sit on the line "
                                 "right before a code fence")
        end = next((j for j in range(i + 2, len(lines)) if lines[j].startswith("```")), None)
        assert end is not None, f"{name}:{i + 2}: the code block is never closed"
        lang, file = fence.group("lang"), marker.group("file")
        assert file or lang in ("bash", "python"), \
            f"{name}:{i + 2}: a runnable block is bash or python, or names the file it is"
        found.append(Block(name, i + 2, lang, "\n".join(lines[i + 2:end]) + "\n", file))
    return found


BLOCKS = [block for path in documents() for block in blocks_of(path)]


def test_the_walkthrough_and_the_pages_have_runnable_blocks():
    # the marks are what keeps the docs from drifting: losing them must fail, not skip
    readme = [b for b in BLOCKS if b.source == "README.md"]
    commands = " ".join(b.code for b in readme)
    for step in ("synthpack label", "synthpack library build", ".sieve(", "synthpack generate",
                 "synthpack compare", "synthpack export-yolo", "training.train", "training.evaluate"):
        assert step in commands, f"the README walkthrough has no runnable {step!r}"
    dask = [b for b in BLOCKS if b.source == "docs/dask.md" and b.lang == "python"]
    assert dask and 'if __name__ == "__main__":' in dask[0].code and "generate_packs(" in dask[0].code
    assert any(b.file == "pack.yaml" for b in BLOCKS)


def test_a_marker_without_a_block_is_refused(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("text\n<!-- runnable -->\nno fence here\n")
    with pytest.raises(AssertionError, match="right before a code fence"):
        blocks_of(page)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("snippets")
    bin_dir = Path(sys.executable).parent
    path = [str(bin_dir)]
    if shutil.which("synthpack", path=str(bin_dir)) is None:
        shim = folder / ".bin"
        shim.mkdir()
        (shim / "synthpack").write_text(f'#!/bin/sh\nexec "{sys.executable}" -m synthpack "$@"\n')
        (shim / "synthpack").chmod(0o755)
        path.insert(0, str(shim))
    env = {**os.environ, "PATH": os.pathsep.join(path + [os.environ.get("PATH", "")]),
           "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep),
           "MPLBACKEND": "Agg"}
    return folder, env, {"failed": None}


@pytest.mark.slow
@pytest.mark.parametrize("block", BLOCKS, ids=str)
def test_the_block_runs_as_written(block, workdir):
    folder, env, state = workdir
    if state["failed"] is not None:
        pytest.fail(f"an earlier block failed ({state['failed']}), and this one may need its output")
    state["failed"] = str(block)
    if block.file:
        (folder / block.file).write_text(block.code)
    else:
        script = folder / f"block_{Path(block.source).stem}_{block.line}.{'sh' if block.lang == 'bash' else 'py'}"
        if block.lang == "bash":
            script.write_text("set -euo pipefail\n" + block.code)
            command = ["bash", str(script)]
        else:
            script.write_text(block.code)
            command = [sys.executable, str(script)]
        start = time.perf_counter()
        result = subprocess.run(command, cwd=folder, env=env, capture_output=True, text=True, timeout=300)
        output = (result.stdout + result.stderr)[-3000:]
        assert result.returncode == 0, f"{block} exited with {result.returncode}:\n{output}"
        assert "Traceback" not in result.stderr, f"{block}:\n{output}"
        print(f"{block}: {time.perf_counter() - start:.1f} s")
    state["failed"] = None


@pytest.mark.slow
def test_the_blocks_made_what_the_docs_say(workdir):
    folder, _, state = workdir
    if state["failed"] is not None or not (folder / "scan.tif").exists():
        pytest.skip("the blocks did not all run (their own tests say why)")
    for made in ("labels.tif", "labels.png", "lib/library.json", "lib_coarse/library.json",
                 "packs/pack_0000/manifest.json", "packs/pack_0000/preview.png", "report/realism.md",
                 "yolo_ds/data.yaml", "runs/first/weights/best.pt", "eval_first/scores.json",
                 "packs_dask/pack_0000/pack.zarr", "packs_dask/pack_0001/pack.zarr"):
        assert (folder / made).exists(), made
