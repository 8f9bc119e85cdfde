import os
import sys

import pytest
import torch

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from ssr.golden import make_frames  # noqa: E402

# One thread: the tensors here are tiny, and on a shared 2-core machine a second OpenMP
# thread makes PyTorch ~10x slower whenever the other core is busy (spin-waiting).
torch.set_num_threads(1)

H, W = 24, 40

DATASET_SPLITS = {"train": 2, "val": 1, "test": 1}
DATASET_FRAMES = 6
DATASET_SIZE = 32


@pytest.fixture
def frames():
    """3 consecutive random frames at 40x24 (the golden inputs)."""
    return make_frames(height=H, width=W, count=3)


@pytest.fixture(scope="session")
def dataset(tmp_path_factory):
    """A tiny synthetic dataset (ssr.synth): 2 train, 1 val, 1 test sequences of 6 frames,
    32x32. Read-only: tests that break a dataset write their own."""
    from ssr.synth import write_dataset

    root = str(tmp_path_factory.mktemp("dataset"))
    return write_dataset(root, DATASET_SPLITS, DATASET_FRAMES, DATASET_SIZE, DATASET_SIZE, seed=3)
