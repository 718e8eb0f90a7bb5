"""Named random streams: one spawn of the seed per purpose, never shared."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from synthpack._shared.seeds import PURPOSES, derived_seed, generator, record, stream

ROOT = Path(__file__).resolve().parents[1]


def test_a_stream_is_the_seeds_spawned_child_for_its_purpose():
    children = np.random.SeedSequence(7).spawn(len(PURPOSES))
    for index, purpose in enumerate(PURPOSES):
        assert stream(7, purpose).generate_state(4).tolist() == children[index].generate_state(4).tolist()
    pack_three = np.random.SeedSequence(7).spawn(1)[0].spawn(4)[3]  # "pack" is purpose 0
    assert derived_seed(7, "pack", 3) == int(pack_three.generate_state(1, np.uint32)[0])
    assert record()["plan"] == [PURPOSES.index("plan")]


def test_streams_of_different_purposes_and_keys_differ_and_repeat():
    draws = {purpose: generator(3, purpose).random(4).tolist() for purpose in PURPOSES}
    assert len({tuple(d) for d in draws.values()}) == len(PURPOSES)
    assert generator(3, "plan").random(4).tolist() == draws["plan"]
    assert generator(3, "pack", 1).random() != generator(3, "pack", 2).random()
    with pytest.raises(ValueError, match="unknown random stream 'plna'"):
        stream(3, "plna")


def _seeds_directly(node: ast.AST) -> bool:
    """A ``default_rng(seed)`` / ``SeedSequence([seed, STREAM])`` call: a seed turned into draws by hand."""
    if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
            and node.func.attr in ("default_rng", "SeedSequence") and node.args):
        return False
    argument = node.args[0]
    if isinstance(argument, (ast.List, ast.Tuple)):
        return True
    name = argument.id if isinstance(argument, ast.Name) else getattr(argument, "attr", "")
    return "seed" in name


def test_no_module_seeds_numpy_but_through_the_named_streams():
    # generators made from a stream (``default_rng(context.call)``) are fine; a seed turned into
    # draws by hand is not, except in seeds.py, the built-in sample scans (their own regression
    # data), one grain's deformation from the seed drawn for it, and the artefacts' public
    # ``transform(volume, rng)`` that takes a seed or a generator from its caller
    allowed = {"_shared/seeds.py", "scan/samples.py", "library/deform.py", "artefacts/_base.py"}
    found = [f"{path.relative_to(ROOT / 'synthpack')}:{node.lineno}"
             for path in sorted((ROOT / "synthpack").rglob("*.py"))
             if str(path.relative_to(ROOT / "synthpack")) not in allowed
             for node in ast.walk(ast.parse(path.read_text())) if _seeds_directly(node)]
    assert not found, found
