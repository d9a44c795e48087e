"""Every docstring example in the package runs and gives what it shows."""

import doctest
import importlib
import pkgutil

import pytest

import fusion_gyrocal

MODULES = sorted(m.name for m in pkgutil.walk_packages(fusion_gyrocal.__path__, "fusion_gyrocal.")
                 if not m.name.endswith(".__main__"))  # importing an entry point runs it


def test_docstring_modules_with_examples_are_found():
    with_examples = [m for m in MODULES if ">>>" in (importlib.util.find_spec(m).loader.get_source(m) or "")]
    assert {"fusion_gyrocal.pipeline.pipeline", "fusion_gyrocal.graph.solver", "fusion_gyrocal.core.array"} <= set(with_examples)


@pytest.mark.parametrize("module", MODULES)
def test_docstring_examples_run(module):
    result = doctest.testmod(importlib.import_module(module), optionflags=doctest.ELLIPSIS)
    assert result.failed == 0
