"""Folders of the checkout, for tests at any depth under ``tests/`` (a test file never counts ``parents[n]``)."""
from pathlib import Path

#: The checkout (the folder holding ``pyproject.toml``).
REPO = Path(__file__).resolve().parents[2]
#: ``tests/``: conftest.py, required_tools.txt, the test folders.
TESTS = REPO / "tests"
#: ``examples/``: the documented scenes.
EXAMPLES = REPO / "examples"
#: ``tests/data/``: fixed inputs and facts the tests read.
DATA = TESTS / "data"
