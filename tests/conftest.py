"""Shared fixtures. ``shared_data`` points at the third-party inputs beside the checkout
(``../shared/data``) and skips the test cleanly when they are absent (a user's clone)."""

import os
from pathlib import Path

import pytest
import torch
from hypothesis import settings

# CI replays the same fuzzed examples on every run (a failure there is reproducible); local runs explore new ones.
settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
SAMPLES = REPO / "samples"


@pytest.fixture
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is absent")
    return SHARED_DATA


@pytest.fixture
def one_thread():
    """Small tensors: one torch thread avoids OpenMP overhead on a shared machine (restored afterwards)."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)
