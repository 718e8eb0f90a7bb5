"""The walkthrough notebook: committed without outputs, and it runs top to bottom without errors."""

import json
import re
import sys
from pathlib import Path

import nbformat
import pytest

NOTEBOOK = Path(__file__).resolve().parents[1] / "notebooks" / "walkthrough.ipynb"
KERNEL = "synthpack-walkthrough-test"


def test_notebook_is_committed_without_outputs():
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    nbformat.validate(notebook)
    code = [cell for cell in notebook.cells if cell.cell_type == "code"]
    assert code, "the walkthrough has no code cells"
    dirty = [k for k, cell in enumerate(code) if cell.outputs or cell.execution_count is not None]
    assert not dirty, (f"code cells {dirty} of {NOTEBOOK.name} hold outputs or execution counts: clear them "
                       "before committing (e.g. jupyter nbconvert --clear-output --inplace)")


def _kernelspec(folder: Path) -> Path:
    """A kernelspec folder whose kernel runs this interpreter (the one synthpack is installed in)."""
    spec = folder / "kernels" / KERNEL
    spec.mkdir(parents=True)
    argv = [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"]
    (spec / "kernel.json").write_text(json.dumps({"argv": argv, "display_name": KERNEL, "language": "python"}))
    return folder


def _text(cell) -> str:
    parts = []
    for output in cell.get("outputs", []):
        parts.append(output.get("text", ""))
        parts.append(output.get("data", {}).get("text/plain", ""))
    return "".join(parts)


@pytest.mark.slow
def test_walkthrough_runs_top_to_bottom(tmp_path, monkeypatch):
    pytest.importorskip("ultralytics")
    from nbclient import NotebookClient

    work, cwd = tmp_path / "work", tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.setenv("JUPYTER_PATH", str(_kernelspec(tmp_path / "jupyter")))
    monkeypatch.setenv("SYNTHPACK_WALKTHROUGH_DIR", str(work))
    monkeypatch.delenv("MPLBACKEND", raising=False)
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    client = NotebookClient(notebook, kernel_name=KERNEL, timeout=600, startup_timeout=120,
                            resources={"metadata": {"path": str(cwd)}})
    client.execute()  # raises CellExecutionError, with the cell and its traceback, if any cell fails

    code = [cell for cell in notebook.cells if cell.cell_type == "code"]
    figures = sum("image/png" in output.get("data", {}) for cell in code for output in cell.outputs)
    assert figures >= 7, f"expected a figure for every step, got {figures}"
    text = "\n".join(_text(cell) for cell in code)
    assert "same pour as in step 3: True" in text
    polygon_dice = re.search(r"mean Dice per polygon ([0-9.]+)", text)
    assert polygon_dice and float(polygon_dice.group(1)) > 0.999  # the polygons give back the exact masks
    assert "Dice " in _text(code[-1]) and "mask mAP50" in _text(code[-1])

    assert (work / "library" / "library.json").is_file()
    assert (work / "yolo" / "data.yaml").is_file()
    assert (work / "run" / "weights" / "best.pt").is_file()
    scores = json.loads((work / "eval" / "scores.json").read_text())
    assert 0.0 <= scores["dice"] <= 1.0 and scores["n_slices"] > 0
    assert not any(cwd.iterdir()), f"the notebook wrote into its working folder: {sorted(cwd.iterdir())}"
