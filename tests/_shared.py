"""The real recordings the tests read: ``../shared/data`` (:func:`~fusion_gyrocal.evaluate.sim.shared_data_dir`)."""

import pytest

from fusion_gyrocal.evaluate.sim import shared_data_dir


def data_folder(folder: str):
    """``../shared/data/<folder>``; the test is skipped, saying so, where it is absent (a user's own clone)."""
    d = shared_data_dir() / folder
    if not d.is_dir():
        pytest.skip(f"../shared/data/{folder} is absent (a user's own clone)")
    return d
